"""Couplings (thesis 5.3.2, eq. 5.4: zero-length springs between point entities of two bodies)
on the whole-scene node arrays, held to SciPy: a step is the direct solve of eq. 5.2 with the
coupling blocks assembled here from eq. 5.4, coupled blocks hanging from a fixed body settle to
the static solution of K u = f, and a block dragged by a kinematic body reaches its velocity
without gaining energy in the body's frame.

Tolerances come from the sweeps' stopping rule (tests/sim/test_node_arrays.py): they stop when
the estimated velocity error is below SWEEP_TOLERANCE = 1e-5 m/s, a geometric-tail estimate,
so the tests allow 3x.
"""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import (Coupling, EmbeddedPoints, FemBody, FixedBody, KinematicBody, Material,
                             RigidPoints, embed_in_tets)
from softvr.sim import node_model_supported
from softvr.sim._node_step import SWEEP_TOLERANCE
from softvr.volume import Volume, grid_tet_mesh

G = 9.81
VELOCITY_TOL = 3 * SWEEP_TOLERANCE  # [m/s]


def _block(corner, size=0.1, cells=2, material=None, corotational=True, name="block"):
    spacing = np.full(3, size / cells)
    nodes, tets = grid_tet_mesh(Volume(np.zeros((cells,) * 3, np.uint8), spacing=spacing,
                                       origin=spacing / 2 + np.asarray(corner, float)), cells)
    material = material or Material(1e5, 0.3, 1000.0, alpha=0.0, beta=1e-3)
    return FemBody(nodes, tets, material, corotational=corotational, name=name)


def _embedded(body, points):
    tet, weights = embed_in_tets(body.rest, body.tets, points)
    return EmbeddedPoints(body, body.tets[tet], weights)


def _add(scene, body):
    return scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(body.q))[:, None],
                                                                np.ones((len(body.q), 1))))


def sprung_block_scene():
    """A 10 cm block (E 100 kPa) standing on a plane and hanging by four springs (k 300 N/m,
    stretched 5 mm) from a fixed ceiling: ``(scene, block, block index, coupling)``."""
    material = Material(1e5, 0.3, 1000.0, alpha=20.0, beta=1e-3)
    block = _block((-0.05, -0.05, 0.0), material=material)
    ceiling = FixedBody(name="ceiling")
    scene = Scene(gravity=(0.0, 0.0, -G))
    index = _add(scene, block)
    scene.add_body(ceiling)
    scene.add_plane(Plane(friction=0.5))
    hooks = np.array([[x, y, 0.098] for x in (-0.03, 0.03) for y in (-0.03, 0.03)])
    link = Coupling(_embedded(block, hooks), RigidPoints.from_world(ceiling, hooks + [0.0, 0.0, 0.005]), 300.0,
                    damping=1.0)
    scene.add_coupling(link)
    return scene, block, index, link


def _relative_jacobian(coupling, offsets, size):
    """D [3 springs, size] of eq. 5.4 written out here: side a's point velocity minus side b's,
    over velocities laid out by ``offsets`` (first index of an FEM body's nodes by the body's id;
    of a rigid side's point velocities, 3 per spring, by the side's id)."""
    rows, cols, vals = [], [], []
    for side, sign in ((coupling.a, 1.0), (coupling.b, -1.0)):
        start = offsets[id(side.body) if hasattr(side, "weights") else id(side)]
        for p in range(len(coupling)):
            stencil = zip(side.nodes[p], side.weights[p]) if hasattr(side, "weights") else [(p, 1.0)]
            for node, w in stencil:
                for x in range(3):
                    rows.append(3 * p + x)
                    cols.append(start + 3 * node + x)
                    vals.append(sign * w)
    return sp.csr_matrix((vals, (rows, cols)), shape=(3 * len(coupling), size))


def _direct_step(scene, fem, couplings, driven_v, dt):
    """SciPy's solution of A v = b (eq. 5.2 per FEM body plus eq. 5.4's blocks): unknowns are
    the FEM node velocities, then each driven side's point velocities (prescribed:
    ``driven_v[id(side)]`` [points, 3])."""
    offsets, size = {}, 0
    systems = [b.step_system(dt, scene.gravity) for b in fem]
    for body in fem:
        offsets[id(body)] = size
        size += 3 * len(body.q)
    fem_size = size
    driven = [s for c in couplings for s in (c.a, c.b) if not hasattr(s, "weights")]
    for side in driven:
        offsets[id(side)] = size
        size += 3 * len(side.local)
    a = sp.lil_matrix((size, size))
    b = np.zeros(size)
    prescribed = np.ones(size, bool)
    value = np.zeros(size)
    for body, system in zip(fem, systems):
        o = offsets[id(body)]
        n = 3 * len(body.q)
        a[o:o + n, o:o + n] = system.matrix
        b[o:o + n] = system.rhs
        prescribed[o:o + n] = system.prescribed
        value[o:o + n] = system.value
    for side in driven:
        value[offsets[id(side)]:offsets[id(side)] + 3 * len(side.local)] = driven_v[id(side)].ravel()
    a = a.tocsr()
    for c in couplings:
        d = _relative_jacobian(c, offsets, size)
        a = a + (dt * c.damping + dt * dt * c.stiffness) * (d.T @ d)
        b = b - dt * c.stiffness * (d.T @ (c.a.positions() - c.b.positions()).ravel())
    a = a.tocsc()
    free = ~prescribed
    v = value.copy()
    v[free] = spla.spsolve(a[free][:, free], b[free] - a[free][:, ~free] @ value[~free])
    return [v[offsets[id(body)]:offsets[id(body)] + 3 * len(body.q)].reshape(-1, 3) for body in fem]


def test_a_coupled_step_without_contact_is_scipy_direct_solve_of_eqs_5_2_and_5_4():
    # Two deformed, moving blocks tied to each other (4-node stencils on both sides), one also to
    # a fixed body, the other to a kinematic one (driven sides: their velocities prescribed).
    dt = 0.01
    left = _block((-0.12, -0.05, 0.0), name="left")
    right = _block((0.02, -0.05, 0.0), name="right")
    rng = np.random.default_rng(5)
    for body in (left, right):
        body.q = body.q + 0.003 * rng.standard_normal(body.q.shape)
        body.v = 0.05 * rng.standard_normal(body.q.shape)
    ground = FixedBody(position=(-0.07, 0.0, 0.15), name="ground")
    hand = KinematicBody(lambda t: ((0.07 + 0.2 * t, 0.0, 0.15 - 0.1 * t), (1.0, 0.0, 0.0, 0.0)), name="hand")
    scene = Scene(gravity=(0.0, 0.0, -G))
    for body in (left, right):
        _add(scene, body)
    scene.add_body(ground)
    scene.add_body(hand, collision_points=RigidPoints(hand, [[0.0, 0.0, 0.0], [0.0, 0.01, 0.0]]))
    seam = np.array([[-0.05, -0.02, 0.03], [-0.04, 0.02, 0.07], [-0.03, 0.0, 0.05]])
    top_left = np.array([[-0.09, -0.03, 0.095], [-0.05, 0.03, 0.09]])
    top_right = np.array([[0.05, 0.0, 0.095], [0.09, -0.02, 0.09]])
    couplings = [
        Coupling(_embedded(left, seam), _embedded(right, seam + [0.09, 0.0, 0.0]), 800.0,
                 damping=2.0, name="seam"),
        Coupling(RigidPoints.from_world(ground, top_left + [0.0, 0.0, 0.02]), _embedded(left, top_left), 500.0,
                 damping=1.0, name="ground"),
        Coupling(_embedded(right, top_right), RigidPoints.from_world(hand, top_right + [0.01, 0.0, 0.02]), 600.0,
                 name="hand"),
    ]
    for c in couplings:
        scene.add_coupling(c)
    assert node_model_supported(scene)
    for step in range(3):
        t = hand.time
        u = (np.array([0.07 + 0.2 * (t + dt), 0.0, 0.15 - 0.1 * (t + dt)]) - [0.07 + 0.2 * t, 0.0, 0.15 - 0.1 * t]) / dt
        driven_v = {id(couplings[1].a): np.zeros((2, 3)), id(couplings[2].b): np.tile(u, (2, 1))}
        expected = _direct_step(scene, [left, right], couplings, driven_v, dt)
        scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper", step
        for body, v in zip((left, right), expected):
            np.testing.assert_allclose(body.v, v, atol=VELOCITY_TOL, rtol=0)



def test_a_spring_on_tet_nodes_adds_blocks_only_between_nodes_it_weighs():
    """Eq. 5.4's terms (dt c + dt^2 k) B_i^T B_j vanish where w_i or w_j is 0: a spring tying
    node 0 of one block to node 0 of another, embedded as (1, 0, 0, 0) in a tet of each, couples
    the blocks' A in exactly one block pair, (dt c + dt^2 k) (1)(-1) I, and the step is still
    SciPy's direct solve of eqs. 5.2 and 5.4 (with all four nodes of each stencil, zeros included)."""
    dt = 0.01
    left = _block((-0.12, -0.05, 0.0), name="left")
    right = _block((0.02, -0.05, 0.0), name="right")
    scene = Scene(gravity=(0.0, 0.0, -G))
    assert [_add(scene, body) for body in (left, right)] == [0, 1]  # body_node_start's first two
    tet_l, tet_r = (int(np.flatnonzero((b.tets == 0).any(axis=1))[0]) for b in (left, right))
    weights = [[0.0, 0.0, 0.0, 0.0]]

    def at_node_0(body, tet):
        w = np.array(weights)
        w[0, list(body.tets[tet]).index(0)] = 1.0
        return EmbeddedPoints(body, body.tets[tet][None, :], w)

    c, k = 2.0, 800.0
    seam = Coupling(at_node_0(left, tet_l), at_node_0(right, tet_r), k, damping=c, name="seam")
    scene.add_coupling(seam)
    expected = _direct_step(scene, [left, right], [seam], {}, dt)
    scene.step(dt)
    st = scene._stepper
    assert type(st).__name__ == "NodeStepper"
    first = st.model.body_node_start
    rows, cols = st.model.block_row.numpy(), st.model.block_col.numpy()
    cross = np.flatnonzero((rows < first[1]) & (cols >= first[1]) & (cols < first[2]))
    assert [(int(rows[i]), int(cols[i])) for i in cross] == [(first[0], first[1])]
    np.testing.assert_array_equal(st.state.blocks.numpy()[cross[0]], -(dt * c + dt * dt * k) * np.eye(3))
    for body, v in zip((left, right), expected):
        np.testing.assert_allclose(body.v, v, atol=VELOCITY_TOL, rtol=0)

def test_two_blocks_hanging_from_a_fixed_body_settle_to_the_static_solution():
    # Linear FEM (R = I), heavily damped: at rest the forces balance, and with every spring
    # unstretched at the rest shape that is (K + sum k D^T D) u = f_gravity (D over the FEM
    # nodes: the fixed side does not move), solved by SciPy.
    material = Material(1e5, 0.3, 500.0, alpha=20.0, beta=0.0)
    upper = _block((-0.05, -0.05, -0.1), material=material, corotational=False, name="upper")
    lower = _block((-0.05, -0.05, -0.2), material=material, corotational=False, name="lower")
    ceiling = FixedBody(name="ceiling")
    scene = Scene(gravity=(0.0, 0.0, -G))
    for body in (upper, lower):
        _add(scene, body)
    scene.add_body(ceiling)
    grid = np.array([[x, y] for x in (-0.03, 0.0, 0.03) for y in (-0.03, 0.03)])
    hooks = np.column_stack([grid, np.full(len(grid), -0.002)])
    seam = np.column_stack([grid, np.full(len(grid), -0.1)])  # on the face the blocks share
    couplings = [Coupling(RigidPoints.from_world(ceiling, hooks), _embedded(upper, hooks), 2000.0, damping=5.0),
                 Coupling(_embedded(upper, seam), _embedded(lower, seam), 2000.0, damping=5.0)]
    for c in couplings:
        scene.add_coupling(c)
    for _ in range(400):
        scene.step(0.01)
    assert type(scene._stepper).__name__ == "NodeStepper"
    n = len(upper.q)
    size = 6 * n + 3 * len(hooks)
    offsets = {id(upper): 0, id(lower): 3 * n, id(couplings[0].a): 6 * n}
    k = sp.block_diag([upper.stiffness_matrix(upper.rest), lower.stiffness_matrix(lower.rest)]).tocsr()
    for c in couplings:
        d = _relative_jacobian(c, offsets, size)[:, :6 * n]
        k = k + c.stiffness * (d.T @ d)
    f = np.concatenate([(b.mass[:, None] * [0.0, 0.0, -G]).ravel() for b in (upper, lower)])
    u = spla.spsolve(k.tocsc(), f)
    got = np.concatenate([(b.q - b.rest).ravel() for b in (upper, lower)])
    np.testing.assert_allclose(got, u, atol=2e-3 * np.abs(u).max())


def test_a_block_on_the_ground_held_up_by_springs_shares_its_weight_between_them():
    # Newton's first law at rest (eqs. 5.2, 5.4, 5.5 solved together by the sweeps): the plane's
    # force plus the springs' (stretched 5 mm up to a fixed body, pulling ~k n 5 mm < m g) carry
    # m g. The contact impulses and the velocities share the sweeps' tolerance: over a step the
    # balance is off by at most M VELOCITY_TOL / dt.
    scene, block, index, link = sprung_block_scene()
    dt = 0.01
    for _ in range(150):
        solution = scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    weight = block.mass.sum() * G
    springs = link.forces().sum(axis=0)  # on side a, the block
    assert 0.1 * weight < springs[2] < 0.9 * weight
    np.testing.assert_allclose(solution.force_on(index, dt) + springs, [0.0, 0.0, weight],
                               atol=block.mass.sum() * VELOCITY_TOL / dt)


def test_a_kinematic_body_drags_a_block_at_its_velocity_without_adding_energy():
    # No gravity; a hand moving at constant u tied by damped springs to a block at rest. In the
    # hand's frame (Galilean: u constant) this is a linear spring-mass-damper system let go with
    # the block's kinetic energy 1/2 M u^2, and backward Euler (eqs. 5.2, 5.4; linear FEM,
    # Rayleigh damping) gives E_n+1 - E_n = -dt v^T C v - 1/2 dv^T M dv - 1/2 dx^T K dx <= 0.
    # The sweeps' velocity error (VELOCITY_TOL) may add up to M |v - u| VELOCITY_TOL a step.
    # No mass-proportional damping: it drags against the world frame, not the hand's.
    u = np.array([0.2, 0.0, 0.0])
    material = Material(1e5, 0.3, 500.0, alpha=0.0, beta=1e-3)
    block = _block((-0.05, -0.05, -0.1), material=material, corotational=False)
    hand = KinematicBody(lambda t: (u * t, (1.0, 0.0, 0.0, 0.0)), name="hand")
    hooks = np.array([[x, y, -0.01] for x in (-0.03, 0.0, 0.03) for y in (-0.03, 0.03)])
    link = Coupling(RigidPoints.from_world(hand, hooks), _embedded(block, hooks), 1000.0, damping=2.0)
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    _add(scene, block)
    scene.add_body(hand)
    scene.add_coupling(link)
    k = block.stiffness_matrix(block.rest)
    mass = block.mass.sum()

    def energy():
        x = (block.q - block.rest).ravel()  # K annihilates the translation
        return 0.5 * float(block.mass @ ((block.v - u) ** 2).sum(axis=1)) + 0.5 * float(x @ (k @ x)) + link.energy()

    energies = [energy()]
    for _ in range(200):
        scene.step(0.01)
        assert type(scene._stepper).__name__ == "NodeStepper"
        energies.append(energy())
    assert energies[0] == pytest.approx(0.5 * mass * u @ u, rel=1e-12)
    slack = mass * np.linalg.norm(u) * VELOCITY_TOL
    assert np.diff(energies).max() <= slack
    np.testing.assert_allclose(block.v, np.tile(u, (len(block.q), 1)), atol=VELOCITY_TOL, rtol=0)
    # At steady state nothing accelerates, so the springs pull with no net force.
    assert np.abs(link.forces().sum(axis=0)).max() < mass * VELOCITY_TOL / 0.01


def test_couplings_the_arrays_do_not_hold_step_per_object():
    left = _block((-0.12, -0.05, 0.0), name="left")
    right = _block((0.02, -0.05, 0.0), name="right")
    scene = Scene()
    for body in (left, right):
        _add(scene, body)
    tie = Coupling(_embedded(left, [[-0.03, 0.0, 0.05]]), _embedded(right, [[0.03, 0.0, 0.05]]), 500.0)
    scene.add_coupling(tie)
    assert node_model_supported(scene)
    # A five-node stencil (more than a tet's four) is not held (a rigid body's side is:
    # tests/sim/test_node_rigid_couplings.py).
    five = EmbeddedPoints(left, [[0, 1, 2, 3, 4]], [[0.2] * 5])
    wide = Scene()
    for body in (left, right):
        _add(wide, body)
    wide.add_coupling(Coupling(five, _embedded(right, [[0.03, 0.0, 0.05]]), 500.0))
    assert not node_model_supported(wide)
    wide.step(0.01)
    assert wide._stepper is None


def test_a_coupling_between_two_driven_bodies_moves_nothing():
    # Both ends prescribed (per object such a coupling joins no island): the block beside them
    # falls freely, v = -g dt after one step (K f_el = 0 at rest, A v = M v0 + dt M g).
    block = _block((-0.05, -0.05, 0.2))
    ground, hand = FixedBody(name="ground"), KinematicBody(lambda t: ((0.1 * t, 0.0, 0.0), (1, 0, 0, 0)), name="hand")
    scene = Scene(gravity=(0.0, 0.0, -G))
    _add(scene, block)
    scene.add_body(ground)
    scene.add_body(hand)
    scene.add_coupling(Coupling(RigidPoints(ground, [[0.0, 0.0, 0.0]]), RigidPoints(hand, [[0.0, 0.0, 0.0]]), 100.0))
    scene.step(0.01)
    assert type(scene._stepper).__name__ == "NodeStepper"
    np.testing.assert_allclose(block.v, np.tile([0.0, 0.0, -G * 0.01], (len(block.q), 1)), atol=VELOCITY_TOL)
