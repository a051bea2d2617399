"""``Scene.rotation_lag`` in a scene whose ``A`` the couplings' springs also write (thesis eq.
5.2 with eq. 5.4's terms, 5.3.2), held to a dense NumPy assembly written out here: the
co-rotated linear FEM's (dt beta + dt^2) R_e K_e R_e^T (K_e = V B^T C B of the linear tet,
textbook, from the rest positions) plus the lumped M (1 + dt alpha), plus (dt c + dt^2 k) D^T D
of every spring (D: side a's point velocity minus side b's, the FEM sides' barycentric weights).

The lag keeps a tet's R_e (and holds its forces) while it turns less than the lag; the blocks
none of whose tets turned are not assembled again, except those the springs add to after the
assembly (kept, they would take the springs' terms again every step). So with the R_e the
step used (``state.rotations``), every block over the FEM nodes is the dense sum to
round-off: a block sums at most 24 tets' contributions and a few springs' terms, each within
~4e-15 of its size (``tests/dynamics/test_node_assembly.py``'s bound), so 2e-13 of the largest
entry is allowed; a spring's terms taken twice are off by (dt c + dt^2 k) ~ 0.1 kg, O(1) of
it. And those R_e are within the lag's bound of SciPy's polar rotation of F at the step's
positions: a kept R_e within LAG of the polar rotation where it was computed (the Newton
correction's angle, to first order), and a held one's F moved since by at most LAG (each
node within LAG / sum_a |g_a|), which turns the polar rotation by at most
2 LAG / (sigma_2 + sigma_3) (F's two smallest singular values; the polar factor's derivative).
"""

import numpy as np
import scipy.linalg
from scipy.spatial.transform import Rotation

from softvr import Scene
from softvr.dynamics import Coupling, EmbeddedPoints, FemBody, FixedBody, Material, RigidBody, RigidPoints, embed_in_tets
from softvr.sim import node_model_supported
from softvr.volume import Volume, grid_tet_mesh

G = 9.81
DT = 0.01  # [s]
# [rad] Large for a test: the sprung blocks swing, their tets turning 0.01-0.2 rad a step, and
# at this lag 17-52 of the 80 keep their R_e in each step after the first (the bookkeeping is
# the same at any lag; the shoulder's is 1e-4).
LAG = 0.05
TOL = 2e-13  # of the largest entry of A (module docstring)


def _block(corner, name):
    spacing = np.full(3, 0.05)
    nodes, tets = grid_tet_mesh(Volume(np.zeros((2, 2, 2), np.uint8), spacing=spacing,
                                       origin=spacing / 2 + np.asarray(corner, float)), 2)
    return FemBody(nodes, tets, Material(1e5, 0.3, 1000.0, alpha=0.5, beta=1e-3), name=name)


def _embedded(body, points):
    tet, weights = embed_in_tets(body.rest, body.tets, points)
    return EmbeddedPoints(body, body.tets[tet], weights)


def _tet_terms(rest: np.ndarray, material: Material) -> tuple[np.ndarray, np.ndarray, float]:
    """K_e [12, 12] [N/m] of the linear tet V B^T C B (isotropic C), its rest shape-function
    gradients [4, 3] [1/m] and volume [m^3]."""
    dm = (rest[1:] - rest[0]).T
    inv = np.linalg.inv(dm)
    grad = np.vstack([-inv.sum(axis=0), inv])
    volume = np.linalg.det(dm) / 6.0
    b = np.zeros((6, 12))
    for a, (gx, gy, gz) in enumerate(grad):
        b[:, 3 * a:3 * a + 3] = [[gx, 0, 0], [0, gy, 0], [0, 0, gz], [gy, gx, 0], [0, gz, gy], [gz, 0, gx]]
    e, nu = material.young, material.poisson
    lam, mu = e * nu / ((1 + nu) * (1 - 2 * nu)), e / (2 * (1 + nu))
    c = np.zeros((6, 6))
    c[:3, :3] = lam
    c[range(6), range(6)] += [2 * mu] * 3 + [mu] * 3
    return volume * b.T @ c @ b, grad, volume


def _dense_a(bodies, rotations, couplings) -> np.ndarray:
    """A [3n, 3n] [kg] over the bodies' nodes (laid out body after body) of eq. 5.2 with the
    tets' ``rotations`` [m, 3, 3] (body after body) and eq. 5.4's spring terms."""
    offsets = np.cumsum([0] + [len(b.rest) for b in bodies])
    n = offsets[-1]
    a = np.zeros((3 * n, 3 * n))
    mass = np.zeros(n)
    e = 0
    for body, o in zip(bodies, offsets):
        m = body.material
        for t in body.tets:
            ke, _, volume = _tet_terms(body.rest[t], m)
            big = np.kron(np.eye(4), rotations[e])
            dof = (3 * (o + t)[:, None] + np.arange(3)).ravel()
            a[np.ix_(dof, dof)] += (DT * m.beta + DT * DT) * big @ ke @ big.T
            mass[o + t] += m.density * volume / 4
            e += 1
        a[3 * o:3 * (o + len(body.rest)), 3 * o:3 * (o + len(body.rest))] += np.diag(
            np.repeat(mass[o:o + len(body.rest)] * (1 + DT * m.alpha), 3))
    start = {id(b): o for b, o in zip(bodies, offsets)}
    for c in couplings:
        for p in range(len(c)):
            d = np.zeros((3, 3 * n))
            for side, sign in ((c.a, 1.0), (c.b, -1.0)):
                if isinstance(side, EmbeddedPoints):  # a rigid or fixed side has no FEM columns
                    for node, w in zip(side.nodes[p], side.weights[p]):
                        k = 3 * (start[id(side.body)] + node)
                        d[:, k:k + 3] += sign * w * np.eye(3)
            a += (DT * c.damping + DT * DT * c.stiffness) * d.T @ d
    return a


def _polar_bound(bodies, rotations) -> tuple[np.ndarray, np.ndarray]:
    """Each tet's angle [rad] between ``rotations`` and SciPy's polar rotation of F at ``q``,
    and its bound LAG (1 + 2 / (sigma_2 + sigma_3)) (module docstring)."""
    angles, bounds = [], []
    e = 0
    for body in bodies:
        for t in body.tets:
            _, grad, _ = _tet_terms(body.rest[t], body.material)
            f = body.q[t].T @ grad
            polar = scipy.linalg.polar(f)[0]
            sigma = np.linalg.svd(f, compute_uv=False)
            angles.append(Rotation.from_matrix(rotations[e].T @ polar).magnitude())
            bounds.append(LAG * (1.0 + 2.0 / (sigma[1] + sigma[2])))
            e += 1
    return np.array(angles), np.array(bounds)


def test_a_lagging_coupled_scenes_a_is_eq_5_2_of_its_kept_rotations_plus_eq_5_4_springs_once():
    # Two deformed, moving blocks sewn together (4-node stencils on both sides), one hung from
    # a fixed body, the other tied to a turning rigid cube: every kind of spring side.
    left, right = _block((-0.12, -0.05, 0.0), "left"), _block((0.02, -0.05, 0.0), "right")
    rng = np.random.default_rng(5)
    for body in (left, right):
        body.q = body.q + 0.003 * rng.standard_normal(body.q.shape)
        body.v = 0.05 * rng.standard_normal(body.q.shape)
    ground = FixedBody(position=(-0.07, 0.0, 0.15), name="ground")
    cube = RigidBody.box((0.04, 0.04, 0.04), 800.0, position=(0.07, 0.0, 0.15), name="cube",
                         orientation=Rotation.from_rotvec([0.3, -0.5, 0.8]).as_quat(scalar_first=True),
                         angular_velocity=(1.0, -2.0, 0.5))
    scene = Scene(gravity=(0.0, 0.0, -G), rotation_lag=LAG)
    for body in (left, right):
        scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(body.q))[:, None],
                                                             np.ones((len(body.q), 1))))
    scene.add_body(ground)
    scene.add_body(cube)
    seam = np.array([[-0.05, -0.02, 0.03], [-0.04, 0.02, 0.07], [-0.03, 0.0, 0.05]])
    top_left = np.array([[-0.09, -0.03, 0.095], [-0.05, 0.03, 0.09]])
    top_right = np.array([[0.05, 0.0, 0.095], [0.09, -0.02, 0.09]])
    couplings = [
        Coupling(_embedded(left, seam), _embedded(right, seam + [0.09, 0.0, 0.0]), 800.0, damping=2.0),
        Coupling(RigidPoints.from_world(ground, top_left + [0.0, 0.0, 0.02]), _embedded(left, top_left), 500.0,
                 damping=1.0),
        Coupling(_embedded(right, top_right), RigidPoints.from_world(cube, top_right + [0.0, 0.0, 0.04]), 600.0,
                 damping=1.0),
    ]
    for c in couplings:
        scene.add_coupling(c)
    assert node_model_supported(scene)
    bodies = (left, right)
    lagging = 0
    for step in range(6):
        q = [body.q.copy() for body in bodies]
        scene.step(DT)
        st = scene._stepper
        assert type(st).__name__ == "NodeStepper" and st.rigid is not None, step
        m = st.model
        n = m.body_node_start[2]  # the blocks' nodes, then the ground's and the cube's
        tets = np.concatenate([body.tets + m.body_node_start[i] for i, body in enumerate(bodies)])
        assert np.array_equal(m.tets.numpy().reshape(-1, 4)[:len(tets)], tets)  # body after body
        rotations = st.state.rotations.numpy()[:len(tets)]
        rows, cols = m.block_row.numpy(), m.block_col.numpy()
        inside = (rows < n) & (cols < n)
        a = np.zeros((n, 3, n, 3))
        a[rows[inside], :, cols[inside], :] = st.state.blocks.numpy()[inside]
        expected = _dense_a(bodies, rotations, couplings)
        assert np.abs(a.reshape(3 * n, 3 * n) - expected).max() <= TOL * np.abs(expected).max(), step
        moved = [body.q.copy() for body in bodies]
        for body, x in zip(bodies, q):  # the positions the step's A was computed at
            body.q = x
        angles, bounds = _polar_bound(bodies, rotations)
        for body, x in zip(bodies, moved):
            body.q = x
        assert np.all(angles <= bounds), (step, float((angles / bounds).max()))
        lagging += int((angles > 1e-9).sum())
    assert lagging > 0  # the lag acted: some tets kept an R_e off the polar rotation
