"""The step matrix A = M (1 + dt alpha) + (dt beta + dt^2) K of thesis eq. 5.2 and the elastic
forces f_e = -R_e K_e (R_e^T x_e - X_e) as the node arrays compute them
(softvr.dynamics.node_arrays.record_elements, record_system), held to an independent dense
NumPy assembly of the linear co-rotational FEM the thesis uses (5.1, [MKN+04]): K_e = V B^T C B
of the linear tet (textbook, built here from the rest positions), R_e the polar rotation of
F = Ds Dm^-1 (SciPy's ``polar``).

Tolerance: a block sums at most 24 tets' contributions (a grid tet mesh's node), each within
(eps_R + 20 u) |s K_e| of the exact R K_e R^T (``assemble_isotropic``'s bound: eps_R ~1e-15,
u = 1.1e-16; the general kernel's two 3x3 products likewise), so |A - A_ref| <= 24 * 4e-15
max |s K_e| ~ 1e-13 max |s K_e|; 2e-13 is allowed. A wrong term (lambda and mu swapped, a
missing transpose) is off by O(1) of that scale.
Forces: f_e,a sums four K_e,ab (R^T x_b - X_b), each term within ~(eps_R + 20 u) |K_e| |x|
(R^T x_b carries R's error times the position |x|; ~1e-14 relative), so 1e-13 max |K_e| max |x|.
"""

import numpy as np
import scipy.linalg

from softvr import Scene
from softvr.dynamics import EmbeddedPoints, FemBody, Material
from softvr.dynamics.node_arrays import fixed_only, isotropic_terms
from softvr.sim._node_step import NodeStepper
from softvr.volume import Volume, grid_tet_mesh

DT = 0.008  # [s]
TOL = 2e-13  # relative to max |(dt beta + dt^2) K_e| (module docstring)
FORCE_TOL = 1e-13  # relative to max |K_e| max |x| (module docstring)


def _voigt_b(grad: np.ndarray) -> np.ndarray:
    """Engineering strain (xx, yy, zz, xy, yz, zx) from the 12 nodal displacements, [6, 12]."""
    b = np.zeros((6, 12))
    for a, (gx, gy, gz) in enumerate(grad):
        c = 3 * a
        b[0, c], b[1, c + 1], b[2, c + 2] = gx, gy, gz
        b[3, c], b[3, c + 1] = gy, gx
        b[4, c + 1], b[4, c + 2] = gz, gy
        b[5, c], b[5, c + 2] = gz, gx
    return b


def _isotropic_c(lam: float, mu: float) -> np.ndarray:
    c = np.zeros((6, 6))
    c[:3, :3] = lam
    c[range(3), range(3)] += 2 * mu
    c[range(3, 6), range(3, 6)] = mu
    return c


def _body(anisotropic: bool = False) -> tuple[FemBody, list]:
    """A deformed, turned 3^3-cell cube with per-tet Young's moduli and Poisson ratios, and its
    tets' C matrices (one tet's made anisotropic when asked: its K_e set here)."""
    spacing = np.full(3, 0.1)
    nodes, tets = grid_tet_mesh(Volume(np.zeros((3, 3, 3), np.uint8), spacing=spacing, origin=spacing / 2), 3)
    rng = np.random.default_rng(7)
    young = rng.uniform(1e4, 1e6, len(tets))
    nu = rng.uniform(0.1, 0.45, len(tets))
    body = FemBody(nodes, tets, Material(1e5, 0.3, 1000.0, alpha=0.1, beta=0.01), per_tet_young=young,
                   per_tet_poisson=nu)
    lam, mu = young * nu / ((1 + nu) * (1 - 2 * nu)), young / (2 * (1 + nu))
    cs = [_isotropic_c(lam[e], mu[e]) for e in range(len(tets))]
    if anisotropic:
        cs[5] = cs[5] + np.diag([3e5, 0, 0, 0, 0, 0])  # stiffer along x: not isotropic
        grad, volume = _gradients(nodes[tets[5]])
        b = _voigt_b(grad)
        body._ke[5] = volume * b.T @ cs[5] @ b
    turn = scipy.linalg.expm(np.cross(np.eye(3), [0.3, -0.5, 0.8]))
    body.q = nodes @ turn.T + 0.01 * rng.standard_normal(nodes.shape)
    return body, cs


def _gradients(x: np.ndarray) -> tuple[np.ndarray, float]:
    """The linear tet's shape-function gradients [4, 3] [1/m] and volume [m^3] at corners ``x``."""
    dm = (x[1:] - x[0]).T
    inv = np.linalg.inv(dm)
    return np.vstack([-inv.sum(axis=0), inv]), np.linalg.det(dm) / 6.0


def _polar(body: FemBody, t: np.ndarray) -> np.ndarray:
    """SciPy's polar rotation of tet ``t``'s F = Ds Dm^-1 at ``body.q`` [3, 3]."""
    dm = (body.rest[t][1:] - body.rest[t][0]).T
    return scipy.linalg.polar((body.q[t][1:] - body.q[t][0]).T @ np.linalg.inv(dm))[0]


def _reference(body: FemBody, cs: list, rotations: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Dense A [3n, 3n] [kg] of eq. 5.2 and the scale max |(dt beta + dt^2) K_e| (R_e: SciPy's
    polar rotation at ``body.q``, or ``rotations`` [m, 3, 3])."""
    n = len(body.rest)
    a = np.zeros((3 * n, 3 * n))
    s = DT * body.material.beta + DT * DT
    mass = np.zeros(n)
    scale = 0.0
    for e, t in enumerate(body.tets):
        grad, volume = _gradients(body.rest[t])
        b = _voigt_b(grad)
        ke = s * volume * b.T @ cs[e] @ b
        scale = max(scale, np.abs(ke).max())
        r = _polar(body, t) if rotations is None else rotations[e]
        big = np.kron(np.eye(4), r)
        dof = (3 * t[:, None] + np.arange(3)).ravel()
        a[np.ix_(dof, dof)] += big @ ke @ big.T
        mass[t] += body.material.density * volume / 4
    a[range(3 * n), range(3 * n)] += np.repeat(mass * (1 + DT * body.material.alpha), 3)
    return a, scale


def _forces(body: FemBody, cs: list, rotations: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """f_e [m, 4, 3] [N] of every tet and the scale max |K_e| max |x| [N] (R_e as
    :func:`_reference`'s)."""
    out = np.zeros((len(body.tets), 4, 3))
    scale = 0.0
    for e, t in enumerate(body.tets):
        grad, volume = _gradients(body.rest[t])
        b = _voigt_b(grad)
        ke = volume * b.T @ cs[e] @ b
        scale = max(scale, np.abs(ke).max() * np.abs(body.q).max())
        r = _polar(body, t) if rotations is None else rotations[e]
        out[e] = -(r @ (ke @ (body.q[t] @ r - body.rest[t]).ravel()).reshape(4, 3).T).T
    return out, scale


def _assembled(body: FemBody, lag: float | None = None, moved: np.ndarray | None = None
               ) -> tuple[np.ndarray, NodeStepper]:
    """Dense A [3n, 3n] [kg] from the node arrays' blocks after their elements and assembly
    (with ``Scene.rotation_lag`` ``lag`` [rad]; again after the nodes moved to ``moved`` [n, 3]
    [m] where given)."""
    scene = Scene(gravity=(0.0, 0.0, -9.81), rotation_lag=lag)
    scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(body.q))[:, None],
                                                         np.ones((len(body.q), 1))))
    stepper = NodeStepper(scene)
    stepper._record(DT)
    for q in [None] if moved is None else [None, moved]:
        if q is not None:
            stepper.state.q.assign(q)
        stepper._recorded[1]()  # rotations and element forces
        stepper._recorded[2]()  # A
    m = stepper.model
    blocks, rows, cols = stepper.state.blocks.numpy(), m.block_row.numpy(), m.block_col.numpy()
    n = m.node_count
    a = np.zeros((n, 3, n, 3))
    a[rows, :, cols, :] = blocks
    return a.reshape(3 * n, 3 * n), stepper


def test_isotropic_assembly_and_forces_are_the_corotated_fem_of_eq_5_2():
    body, cs = _body()
    a, stepper = _assembled(body)
    assert isotropic_terms(stepper.model.ke.numpy(), stepper.model.dm_inv.numpy()) is not None  # fast path
    expected, scale = _reference(body, cs)
    assert np.abs(a - expected).max() <= TOL * scale
    forces, scale = _forces(body, cs)
    assert np.abs(stepper.state.element_forces.numpy() - forces).max() <= FORCE_TOL * scale


def test_an_anisotropic_tet_takes_the_general_kernels_and_they_are_still_exact():
    body, cs = _body(anisotropic=True)
    a, stepper = _assembled(body)
    assert isotropic_terms(stepper.model.ke.numpy(), stepper.model.dm_inv.numpy()) is None  # general path
    expected, scale = _reference(body, cs)
    assert np.abs(a - expected).max() <= TOL * scale
    forces, scale = _forces(body, cs)
    assert np.abs(stepper.state.element_forces.numpy() - forces).max() <= FORCE_TOL * scale


def test_a_clamped_layers_tets_and_fixed_blocks_are_skipped_and_the_free_rows_are_still_eq_5_2():
    """The cube's two lowest node layers clamped: the tets of its lowest cell layer (a third of
    them: every node fixed) and the blocks joining two fixed nodes are left out of the element
    terms and the assembly (``fixed_only``: a fixed row is never read), and every free node's
    row of A (all its columns, fixed ones included) is still the dense reference's, within TOL;
    the skipped blocks stay zero."""
    body, cs = _body()
    body.fixed[:] = body.rest[:, 2] < 0.2  # node layers z = 0.05 and 0.15 of 0.05 .. 0.35
    a, stepper = _assembled(body)
    skipped_tets, skipped_blocks = fixed_only(stepper.model)
    assert skipped_tets.sum() == len(body.tets) // 3
    expected, scale = _reference(body, cs)
    free = np.repeat(~body.fixed, 3)
    assert np.abs(a[free] - expected[free]).max() <= TOL * scale
    fixed = np.repeat(body.fixed, 3)
    pairs = np.abs(expected[np.ix_(fixed, fixed)]) > 0  # the fixed-fixed blocks A has
    assert pairs.any() and not a[np.ix_(fixed, fixed)].any()
    assert skipped_blocks.any()


LAG = 1e-3  # [rad] Scene.rotation_lag of the lagging test


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """The angle [rad] of the rotation a^T b."""
    return float(np.arccos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0)))


def test_a_lagging_tet_holds_its_terms_or_its_r_e_within_the_lag_and_the_rest_is_eq_5_2():
    """``Scene.rotation_lag`` = LAG after a first assembly, three kinds of tets (sorted here by
    NumPy and SciPy's polar rotations before and after the move, each kind 45 of the 135):
    the nodes all move 1 um at random (the lowest cell layer's tets: every node within its
    reach LAG / sum_a |g_a| (2.1e-5 .. 2.9e-5 m) of where its terms were computed: they hold
    R_e and their forces, although each turned by ~1e-5 rad), the layer z = 0.2 m moves 40 um
    more (the middle cell layer: out of reach, turned by 1.3e-4 .. 5e-4 rad < LAG: last step's
    R_e kept, forces at the new positions) and the top layer turns by 20 LAG (the top cell
    layer: turned > 2 LAG, the new polar rotation). A and the element forces are then the
    dense eq. 5.2 of those R_e (and the held tets' first forces) within the module's TOL /
    FORCE_TOL, also on the blocks the lagging assembly left as they were."""
    body, cs = _body()
    first = np.array([_polar(body, t) for t in body.tets])
    first_forces, _ = _forces(body, cs)
    reach = np.array([LAG / np.linalg.norm(_gradients(body.rest[t])[0], axis=1).sum() for t in body.tets])
    rng = np.random.default_rng(3)
    moved = body.q + 1e-6 * rng.standard_normal(body.q.shape)
    moved[np.abs(body.rest[:, 2] - 0.2) < 0.01] += 4e-5 * np.array([0.6, 0.0, 0.8])
    top = body.rest[:, 2] > 0.25
    centre = moved[top].mean(axis=0)
    turn = scipy.linalg.expm(np.cross(np.eye(3), [0.0, 0.0, 20 * LAG]))
    moved[top] = (moved[top] - centre) @ turn.T + centre
    start = body.q.copy()
    a, stepper = _assembled(body, LAG, moved)
    body.q = moved
    second = np.array([_polar(body, t) for t in body.tets])
    angles = np.array([_angle(r0, r1) for r0, r1 in zip(first, second)])
    reached = np.array([np.linalg.norm(moved[t] - start[t], axis=1).max() for t in body.tets]) / reach
    held = reached < 0.9
    kept = (reached > 1.1) & (angles < LAG / 2)
    turned = (reached > 1.1) & (angles > 2 * LAG)
    assert held.sum() == kept.sum() == turned.sum() == len(body.tets) // 3  # every tet sorted
    assert angles[held | kept].min() > 1e-6  # without the lag every one of them would turn
    rotations = stepper.state.rotations.numpy()
    assert np.abs(rotations[held | kept] - first[held | kept]).max() <= 1e-12
    assert np.abs(rotations[turned] - second[turned]).max() <= 1e-12
    chosen = np.where((held | kept)[:, None, None], first, second)
    expected, scale = _reference(body, cs, chosen)
    assert np.abs(a - expected).max() <= TOL * scale
    forces, scale = _forces(body, cs, chosen)
    forces[held] = first_forces[held]
    assert np.abs(stepper.state.element_forces.numpy() - forces).max() <= FORCE_TOL * scale
