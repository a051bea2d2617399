"""Couplings with a rigid side (thesis eq. 5.4) on the whole-scene node arrays, held to SciPy.

A rigid side's point at the world offset r from the body's centre moves at v + omega x r, so
its row of D (eq. 5.4) is [I, -[r]x] over the body's linear and angular velocity; the step is
eq. 5.2 (FEM blocks; the rigid body's blockdiag(m I, I_w), b = M v0 + dt (m g, 0): the cube's
isotropic inertia makes the gyroscopic torque omega x I omega vanish) plus (dt c + dt^2 k) D^T D
and -dt k D^T (p_a - p_b), all written out in this file.

Tolerances come from the sweeps' stopping rule (tests/sim/test_node_arrays.py): they stop when
the estimated velocity error is below SWEEP_TOLERANCE = 1e-5 m/s, so velocity checks allow 3x.
"""

import numpy as np
import scipy.optimize as so
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial.transform import Rotation

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import Coupling, EmbeddedPoints, FemBody, FixedBody, Material, RigidBody, RigidPoints, embed_in_tets
from softvr.sim import _node_step, _node_sweeps, node_model_supported
from softvr.sim._node_step import SWEEP_TOLERANCE
from softvr.volume import Volume, grid_tet_mesh

G = 9.81
VELOCITY_TOL = 3 * SWEEP_TOLERANCE  # [m/s]


def _block(corner, size=0.1, cells=2):
    spacing = np.full(3, size / cells)
    nodes, tets = grid_tet_mesh(Volume(np.zeros((cells,) * 3, np.uint8), spacing=spacing,
                                       origin=spacing / 2 + np.asarray(corner, float)), cells)
    return FemBody(nodes, tets, Material(1e5, 0.3, 1000.0, alpha=0.0, beta=1e-3), name="block")


def _embedded(body, points):
    tet, weights = embed_in_tets(body.rest, body.tets, points)
    return EmbeddedPoints(body, body.tets[tet], weights)


def _cross_matrix(r):
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


def _side_jacobian(side, p, size, offsets):
    """Rows [3, size] of point ``p`` of a coupling side: FEM weights, or [I, -[R r]x] of a rigid
    body (``offsets[id(body)]``: first of its 6 velocities), or nothing for a fixed body."""
    out = np.zeros((3, size))
    body = side.body
    if isinstance(side, EmbeddedPoints):
        for node, w in zip(side.nodes[p], side.weights[p]):
            out[:, offsets[id(body)] + 3 * node:offsets[id(body)] + 3 * node + 3] += w * np.eye(3)
    elif isinstance(body, RigidBody):
        o = offsets[id(body)]
        out[:, o:o + 3] = np.eye(3)
        out[:, o + 3:o + 6] = -_cross_matrix(body.rotation @ side.local[p])
    return out


def _direct_step(fem, cube, couplings, dt):
    """SciPy's solve of eq. 5.2 + eq. 5.4: unknowns the FEM nodes' velocities, then the cube's
    (v, omega); fixed sides contribute positions only."""
    system = fem.step_system(dt, (0.0, 0.0, -G))
    n = 3 * len(fem.q)
    size = n + 6
    offsets = {id(fem): 0, id(cube): n}
    a = sp.lil_matrix((size, size))
    a[:n, :n] = system.matrix
    b = np.zeros(size)
    b[:n] = system.rhs
    mass = np.diag(np.r_[np.full(3, cube.mass), np.zeros(3)])
    mass[3:, 3:] = cube.rotation @ cube.inertia_body @ cube.rotation.T
    a[n:, n:] = mass
    b[n:] = mass @ cube.v + dt * np.r_[0.0, 0.0, -cube.mass * G, 0.0, 0.0, 0.0]
    a = a.toarray()
    for c in couplings:
        stretch = c.a.positions() - c.b.positions()
        for p in range(len(c)):
            d = _side_jacobian(c.a, p, size, offsets) - _side_jacobian(c.b, p, size, offsets)
            a += (dt * c.damping + dt * dt * c.stiffness) * d.T @ d
            b -= dt * c.stiffness * d.T @ stretch[p]
    free = np.r_[~system.prescribed, np.ones(6, bool)]
    v = np.r_[system.value, np.zeros(6)]
    v[free] = spla.spsolve(sp.csc_matrix(a[free][:, free]), b[free] - a[free][:, ~free] @ v[~free])
    return v[:n].reshape(-1, 3), v[n:]


def test_a_step_with_rigid_sides_is_scipy_direct_solve_of_eqs_5_2_and_5_4():
    # A turning, moving cube (isotropic inertia: no gyroscopic torque) tied by three springs to a
    # moving, deformed block and by two to a fixed body; no contacts.
    dt = 0.01
    block = _block((-0.05, -0.05, 0.0))
    rng = np.random.default_rng(3)
    block.q = block.q + 0.003 * rng.standard_normal(block.q.shape)
    block.v = 0.05 * rng.standard_normal(block.q.shape)
    cube = RigidBody.box((0.06, 0.06, 0.06), 800.0, position=(0.01, 0.02, 0.17), name="cube",
                         orientation=Rotation.from_rotvec([0.3, -0.5, 0.8]).as_quat(scalar_first=True),
                         velocity=(0.05, -0.1, 0.2), angular_velocity=(1.0, -2.0, 0.5))
    ground = FixedBody(position=(0.0, 0.0, 0.3), name="ground")
    scene = Scene(gravity=(0.0, 0.0, -G))
    scene.add_body(block)
    scene.add_body(cube)
    scene.add_body(ground)
    ties = [Coupling(RigidPoints(cube, [[0.03, 0.02, -0.03], [-0.03, 0.01, -0.03], [0.0, -0.03, -0.02]]),
                     _embedded(block, [[0.04, 0.03, 0.09], [-0.03, 0.02, 0.08], [0.01, -0.04, 0.095]]),
                     400.0, damping=2.0),
            Coupling(RigidPoints(ground, [[0.03, 0.0, -0.1], [-0.02, 0.01, -0.09]]),
                     RigidPoints(cube, [[0.03, 0.0, 0.03], [-0.03, 0.0, 0.03]]), 300.0, damping=1.0)]
    for tie in ties:
        scene.add_coupling(tie)
    assert node_model_supported(scene)
    for _ in range(3):
        v_fem, v_cube = _direct_step(block, cube, ties, dt)
        scene.step(dt)
        assert scene._stepper is not None
        np.testing.assert_allclose(block.v, v_fem, atol=VELOCITY_TOL, rtol=0)
        # omega's error: a lever of ~0.04 m turns 3e-5 m/s into 7.5e-4 rad/s.
        np.testing.assert_allclose(cube.v[:3], v_cube[:3], atol=VELOCITY_TOL, rtol=0)
        np.testing.assert_allclose(cube.v[3:], v_cube[3:], atol=VELOCITY_TOL / 0.04, rtol=0)


def test_a_cube_hanging_by_springs_settles_to_the_minimum_of_its_potential_energy():
    # Two couplings of different stiffness from a fixed ceiling to the cube's top corners: it
    # hangs tilted. The rest pose minimizes sum k/2 |x + R r - a|^2 + m g z (scipy.optimize).
    # A clamped block makes the scene one the arrays hold (they need an FEM body).
    block = _block((0.3, 0.0, 0.0))
    block.fixed[:] = True
    cube = RigidBody.box((0.1, 0.1, 0.1), 1000.0, position=(0.0, 0.0, 0.5), name="cube")
    ceiling = FixedBody(position=(0.0, 0.0, 1.0), name="ceiling")
    scene = Scene(gravity=(0.0, 0.0, -G))
    for body in (block, cube, ceiling):
        scene.add_body(body)
    corners = {400.0: [[0.05, 0.05, 0.05], [0.05, -0.05, 0.05]], 150.0: [[-0.05, 0.05, 0.05], [-0.05, -0.05, 0.05]]}
    anchors = {400.0: [[0.1, 0.05, -0.3], [0.1, -0.05, -0.3]], 150.0: [[-0.05, 0.05, -0.3], [-0.05, -0.05, -0.3]]}
    for k in corners:
        scene.add_coupling(Coupling(RigidPoints(cube, corners[k]), RigidPoints(ceiling, anchors[k]), k, damping=8.0))
    assert node_model_supported(scene)

    def energy(x):
        rotation = Rotation.from_rotvec(x[3:]).as_matrix()
        e = cube.mass * G * x[2]
        for k in corners:
            e += 0.5 * k * np.sum((x[:3] + np.asarray(corners[k]) @ rotation.T - (np.asarray(anchors[k]) + ceiling.position)) ** 2)
        return e

    rest = so.minimize(energy, np.r_[cube.position, 0.0, 0.0, 0.0], method="BFGS", options={"gtol": 1e-12}).x
    for _ in range(400):
        scene.step(0.01)
    assert scene._stepper is not None
    # At rest a velocity error eps of the sweeps is an impulse error ~ m eps per step, a force
    # (m / dt) eps = 3e-3 N against springs of 1 100 N/m: 3e-6 m; 2e-5 m allows for the decay left.
    np.testing.assert_allclose(cube.position, rest[:3], atol=2e-5, rtol=0)
    np.testing.assert_allclose(cube.rotation, Rotation.from_rotvec(rest[3:]).as_matrix(), atol=2e-4, rtol=0)
    assert np.abs(cube.v).max() < 1e-3


def _held_box(*, collide: bool):
    """A light box tied by two springs at levers of 2-3 cm to a fixed body, its corners
    colliding with a frictionless plane 1 mm under them (a clamped block: the arrays need an FEM
    body), moving down: the springs couple its translation and rotation strongly."""
    block = _block((0.3, 0.0, 0.0))
    block.fixed[:] = True
    half = 0.02
    box = RigidBody.box((2 * half,) * 3, 300.0, position=(0.0, 0.0, half + 0.001), name="box",
                        orientation=Rotation.from_rotvec([0.02, -0.03, 0.01]).as_quat(scalar_first=True),
                        velocity=(0.01, -0.02, -0.08), angular_velocity=(0.5, -0.3, 0.2))
    anchor = FixedBody(position=(0.0, 0.0, 0.0), name="anchor")
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.0, pgs_iterations=2000)
    scene.add_body(block)
    corners = half * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    if collide:
        scene.add_plane(Plane(friction=0.0))
        scene.add_body(box, collision_points=RigidPoints(box, corners))
    else:
        scene.add_body(box)
    scene.add_body(anchor)
    ties = [Coupling(RigidPoints(box, [[0.03, 0.0, 0.0], [0.0, -0.025, 0.01]]),
                     RigidPoints(anchor, [[0.05, 0.01, 0.03], [-0.01, -0.04, 0.0]]), 200.0, damping=0.5)]
    scene.add_coupling(ties[0])
    return scene, box, corners, ties


def _box_system(box, ties, dt):
    """The box's 6x6 ``A`` of eq. 5.2 + 5.4 and ``b``, written out: blockdiag(m I, I_w)
    (+ the springs' (dt c + dt^2 k) D^T D, D = [I, -[R r]x]) and M v_free - dt k D^T (p_a - p_b);
    v_free = v + dt g (a cube: no gyroscopic torque)."""
    a = np.zeros((6, 6))
    a[:3, :3] = box.mass * np.eye(3)
    a[3:, 3:] = box.rotation @ box.inertia_body @ box.rotation.T
    b = a @ np.r_[box.v[:3] + dt * np.array([0.0, 0.0, -G]), box.v[3:]]
    for c in ties:
        stretch = c.a.positions() - c.b.positions()
        for p in range(len(c)):
            d = np.hstack([np.eye(3), -_cross_matrix(box.rotation @ c.a.local[p])])
            a += (dt * c.damping + dt * dt * c.stiffness) * d.T @ d
            b -= dt * c.stiffness * d.T @ stretch[p]
    return a, b


def test_a_spring_held_rigid_bodys_two_nodes_are_one_6x6_block_of_d_a():
    # D_A^-1 of the sweeps on the body's nodes is the inverse of its whole 6x6 block of A
    # (numpy.linalg.inv of the block written out in _box_system), cross terms included.
    dt = 0.01
    scene, box, _, ties = _held_box(collide=False)
    a, _ = _box_system(box, ties, dt)
    scene.step(dt)
    model, state = scene._stepper.model, scene._stepper.state
    lin, ang = (int(x) for x in model.couplings.pair_node.numpy()[0])
    d_inv, cross = state.d_inv.numpy(), model.couplings.cross.numpy()
    got = np.block([[d_inv[lin], cross[lin]], [cross[ang], d_inv[ang]]])
    truth = np.linalg.inv(a)
    # The levers matter: the 3x3 blocks' own inverse is far from the 6x6 one's diagonal block.
    assert np.abs(truth[:3, :3] - np.linalg.inv(a[:3, :3])).max() > 0.5 * np.abs(truth[:3, :3]).max()
    np.testing.assert_allclose(got, truth, rtol=1e-10, atol=1e-12 * np.abs(truth).max())


def test_a_spring_held_box_landing_on_a_plane_solves_scipys_mlcp_of_eq_5_5():
    # Eq. 5.5 with the box's A and b written out (_box_system) and one row n . (v + omega x r)
    # >= -gap / dt per corner (speculative contacts, frictionless): SciPy's SLSQP minimizes
    # 1/2 v A v - b v under them, the same LCP's primal. Three steps, each from the arrays' state.
    dt = 0.01
    scene, box, corners, ties = _held_box(collide=True)
    assert node_model_supported(scene)
    normal = np.array([0.0, 0.0, 1.0])
    pressed = 0
    for _ in range(3):
        a, b = _box_system(box, ties, dt)
        levers = corners @ box.rotation.T
        jac = np.hstack([np.tile(normal, (8, 1)), np.cross(levers, normal)])
        gap = box.position[2] + levers[:, 2]
        near = gap < 0.002 + 0.1 * dt  # within the margin plus the motion over the step
        rows, floor = jac[near], -gap[near] / dt
        truth = so.minimize(lambda v: 0.5 * v @ a @ v - b @ v, np.linalg.solve(a, b), jac=lambda v: a @ v - b,
                            constraints=[{"type": "ineq", "fun": lambda v: rows @ v - floor, "jac": lambda v: rows}],
                            method="SLSQP", options={"ftol": 1e-15, "maxiter": 1000}).x
        pressed += int((rows @ np.linalg.solve(a, b) < floor).sum())  # rows the contact must push
        scene.step(dt)
        assert scene._stepper is not None
        np.testing.assert_allclose(box.v[:3], truth[:3], atol=VELOCITY_TOL, rtol=0)
        # omega's error: a corner's lever of 0.035 m turns 3e-5 m/s into 8.6e-4 rad/s.
        np.testing.assert_allclose(box.v[3:], truth[3:], atol=VELOCITY_TOL / 0.035, rtol=0)
    assert pressed > 0


def test_a_rigid_body_held_only_by_springs_to_a_fixed_body_steps_exactly_in_one_sweep():
    # Its 6x6 block of D_A is all of its A (the springs' other ends are driven), so a sweep's
    # update is numpy.linalg.solve of eq. 5.2 + 5.4 written out (_box_system), exactly, as a
    # free rigid body's is: the sweeps stop at their first check (2 sweeps) with the box's
    # velocity that solve to rounding (its 6x6 inverse: ~cond(A) eps relative; 1e-9 allows it).
    # Extrapolated like an FEM node's, it took 30-100 sweeps (the shoulder's haptic probe).
    dt = 0.01
    scene, box, _, ties = _held_box(collide=False)
    for _ in range(3):
        a, b = _box_system(box, ties, dt)
        truth = np.linalg.solve(a, b)
        solution = scene.step(dt)
        assert scene._stepper is not None
        assert solution.iterations <= 2
        np.testing.assert_allclose(box.v, truth, rtol=0, atol=1e-9 * np.abs(truth).max())


def test_two_rigid_bodies_held_by_springs_to_each_other_step_as_one_island_solve(monkeypatch):
    # A box on a fixed anchor's springs and a second box on the first's (the shoulder's finger
    # on its handle and the inner finger on the skin's spring), Gauss-Seidel sweeps forced: the
    # two bodies' 12x12 block of A (eq. 5.2 + 5.4, written out here) has no block to any other
    # node solved for, so each sweep solves it whole (softvr.contact._node_gs_kernels.island_solve)
    # and the step is numpy.linalg.solve of it at the first check (2 sweeps), to rounding.
    def gauss_seidel(*args, **kwargs):
        monkeypatch.setattr(_node_sweeps, "sweep_costs", lambda *a: (1e9, 1.0))
        return _node_sweeps.choose_sweeps(*args, **kwargs)

    monkeypatch.setattr(_node_step, "choose_sweeps", gauss_seidel)
    dt = 0.01
    scene, box, _, ties = _held_box(collide=False)
    other = RigidBody.box((0.02, 0.02, 0.02), 500.0, position=(0.0, 0.05, 0.03), name="other",
                          velocity=(0.02, 0.0, -0.03), angular_velocity=(0.0, 1.0, -0.5))
    scene.add_body(other)
    skin = Coupling(RigidPoints(other, [[0.0, -0.01, 0.0]]), RigidPoints(box, [[0.0, 0.02, 0.01]]), 150.0, damping=1.0)
    scene.add_coupling(skin)
    for _ in range(3):
        a = np.zeros((12, 12))
        b = np.zeros(12)
        a[:6, :6], b[:6] = _box_system(box, ties, dt)
        for o, body in ((6, other),):
            m = np.diag(np.r_[np.full(3, body.mass), np.zeros(3)])
            m[3:, 3:] = body.rotation @ body.inertia_body @ body.rotation.T
            a[o:o + 6, o:o + 6] += m
            b[o:o + 6] += m @ np.r_[body.v[:3] + dt * np.array([0.0, 0.0, -G]), body.v[3:]]
        stretch = skin.a.positions() - skin.b.positions()
        d = np.hstack([np.zeros((3, 6)), np.eye(3), -_cross_matrix(other.rotation @ skin.a.local[0])])
        d[:, :6] = -np.hstack([np.eye(3), -_cross_matrix(box.rotation @ skin.b.local[0])])
        a += (dt * skin.damping + dt * dt * skin.stiffness) * d.T @ d
        b -= dt * skin.stiffness * d.T @ stretch[0]
        truth = np.linalg.solve(a, b)
        solution = scene.step(dt)
        assert scene._stepper is not None
        assert solution.iterations <= 2
        got = np.r_[box.v, other.v]
        np.testing.assert_allclose(got, truth, rtol=0, atol=1e-9 * np.abs(truth).max())
