"""The factored contact solve with spring-held rigid bodies and coupling springs
(softvr.contact.node_factored_rigid: the whole A factored once and kept, rigid nodes unturned,
contacts' rigid sides in J, W over the contacts that may push): held to SciPy's direct solve of
eqs. 5.2 + 5.4 (a turning cube tied to a deformed block and a fixed body, its A drifting from the
factored one) and to SciPy's SLSQP on the MLCP of eq. 5.5 (a light box on springs landing on a
plane by its corners, levers and all).

The scenes here are small and their sweeps fast; the factored path is forced from the second
step on by a watch of the sweeps over one step that finds any count too many (the shoulder's
palpation takes it by the stepper's own watch: SweepWatch). Tolerances: the
solve stops when the estimated velocity error is under SWEEP_TOLERANCE (1e-5 m/s, a rigid
body's spin counted at its radius of gyration), so velocities are held to 3x that.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from softvr import Scene
from softvr.contact import node_factored_rigid
from softvr.contact.node_factored_rigid import RigidFactoredSolve, SweepWatch, rigid_factored_eligible
from softvr.dynamics import Coupling, FixedBody, RigidBody, RigidPoints
from softvr.sim._node_step import SWEEP_TOLERANCE

from tests.sim.test_node_rigid_couplings import _block, _direct_step, _embedded, _held_box, _landing_truth

VELOCITY_TOL = 3 * SWEEP_TOLERANCE  # [m/s]


@pytest.fixture
def factored(monkeypatch):
    """The stepper takes the factored solve after the first step wherever the scene is eligible
    (the sweeps watched over one step, any count too many)."""
    monkeypatch.setattr(node_factored_rigid, "WATCHED_STEPS", 1)
    monkeypatch.setattr(node_factored_rigid, "FACTORED_ABOVE_SWEEPS", -1.0)


def test_a_turning_cube_on_springs_to_a_deformed_block_steps_as_scipys_direct_solve_of_eqs_5_2_and_5_4(factored):
    # No contacts: A v = b of eq. 5.2 with the springs' terms of eq. 5.4 (rigid sides [I, -[R r]x]),
    # written out by _direct_step. The cube turns at ~2.3 rad/s, so its blocks (I_w = R I R^T,
    # the springs' levers) move away from the factored A_0 every step: the outer iteration
    # carries that drift, on one factorization.
    dt = 0.01
    block = _block((-0.05, -0.05, 0.0))
    rng = np.random.default_rng(3)
    block.q = block.q + 0.003 * rng.standard_normal(block.q.shape)
    block.v = 0.05 * rng.standard_normal(block.q.shape)
    cube = RigidBody.box((0.06, 0.04, 0.05), 800.0, position=(0.01, 0.02, 0.17), name="cube",
                         orientation=Rotation.from_rotvec([0.3, -0.5, 0.8]).as_quat(scalar_first=True),
                         velocity=(0.05, -0.1, 0.2), angular_velocity=(1.0, -2.0, 0.5))
    cube.inertia_body = np.diag(np.diag(cube.inertia_body).mean() * np.ones(3))  # no gyroscopic torque
    ground = FixedBody(position=(0.0, 0.0, 0.3), name="ground")
    scene = Scene(gravity=(0.0, 0.0, -9.81))
    for body in (block, cube, ground):
        scene.add_body(body)
    ties = [Coupling(RigidPoints(cube, [[0.03, 0.02, -0.025], [-0.03, 0.01, -0.025], [0.0, -0.02, -0.02]]),
                     _embedded(block, [[0.04, 0.03, 0.09], [-0.03, 0.02, 0.08], [0.01, -0.04, 0.095]]),
                     400.0, damping=2.0),
            Coupling(RigidPoints(ground, [[0.03, 0.0, -0.1], [-0.02, 0.01, -0.09]]),
                     RigidPoints(cube, [[0.03, 0.0, 0.025], [-0.03, 0.0, 0.025]]), 300.0, damping=1.0)]
    for tie in ties:
        scene.add_coupling(tie)
    for _ in range(4):
        v_fem, v_cube = _direct_step(block, cube, ties, dt)
        scene.step(dt)
        np.testing.assert_allclose(block.v, v_fem, atol=VELOCITY_TOL, rtol=0)
        np.testing.assert_allclose(cube.v[:3], v_cube[:3], atol=VELOCITY_TOL, rtol=0)
        # omega's error: the stop counts it at the radius of gyration (~0.022 m) and a lever of
        # ~0.04 m turns 3e-5 m/s into 7.5e-4 rad/s.
        np.testing.assert_allclose(cube.v[3:], v_cube[3:], atol=VELOCITY_TOL / 0.04, rtol=0)
    solve = scene._stepper._recorded[5]
    assert type(solve) is RigidFactoredSolve
    assert solve.factorizations == 1


def test_a_spring_held_box_landing_on_a_plane_by_its_corners_solves_scipys_mlcp_of_eq_5_5(factored):
    # Eq. 5.5 with the box's A and b written out (_landing_truth, _box_system: blockdiag(m I, I_w) + the springs'
    # (dt c + dt^2 k) D^T D) and one row n . (v + omega x r) >= -gap / dt per corner near the
    # plane (frictionless): SciPy's SLSQP minimizes 1/2 v A v - b v under them, the LCP's primal.
    # The corners' rows reach the box's angular node through their levers only.
    dt = 0.01
    scene, box, corners, ties = _held_box(collide=True)
    pressed = 0
    for step in range(4):
        truth, pushed = _landing_truth(box, corners, ties, dt)
        if step:  # the factored solve's steps (the first is the sweeps')
            pressed += pushed
        scene.step(dt)
        np.testing.assert_allclose(box.v[:3], truth[:3], atol=VELOCITY_TOL, rtol=0)
        # omega's error: a corner's lever of 0.035 m turns 3e-5 m/s into 8.6e-4 rad/s.
        np.testing.assert_allclose(box.v[3:], truth[3:], atol=VELOCITY_TOL / 0.035, rtol=0)
    assert type(scene._stepper._recorded[5]) is RigidFactoredSolve
    assert pressed > 0


def test_a_free_rigid_body_leaves_the_scene_to_the_sweeps():
    # A rigid body on no spring has no blocks of A (the sweeps solve it exactly): the factored
    # solve, which solves the rows of A, cannot take it.
    scene, box, _, ties = _held_box(collide=False)
    scene.step(0.01)
    assert rigid_factored_eligible(scene._stepper.model)
    free = RigidBody.box((0.02, 0.02, 0.02), 500.0, position=(0.2, 0.0, 0.1), name="free")
    scene.add_body(free)
    scene.step(0.01)
    assert not rigid_factored_eligible(scene._stepper.model)


def test_the_sweeps_watch_hands_over_once_the_mean_over_its_window_is_over_the_limit():
    # The rule written out: the mean of the last WATCHED_STEPS counts over FACTORED_ABOVE_SWEEPS.
    n, limit = node_factored_rigid.WATCHED_STEPS, node_factored_rigid.FACTORED_ABOVE_SWEEPS
    watch = SweepWatch()
    assert not any(watch.due(10 * int(limit)) for _ in range(n - 1))  # a window not yet full
    watch = SweepWatch()
    assert not any(watch.due(int(limit)) for _ in range(3 * n))  # at the limit, not over it
    assert watch.due(int(limit) + n)  # one step over by n: the mean over by one
    watch = SweepWatch()
    counts = [2 * int(limit)] * (n // 2) + [0] * n + [int(limit) + 1] * (n - 1)
    assert not any(watch.due(c) for c in counts)  # the old steps' counts have left the window
    assert watch.due(int(limit) + 1)
