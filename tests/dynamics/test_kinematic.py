"""Fixed and kinematic (scripted) bodies: infinite mass, exact poses, finite-difference velocities.

Tolerances: the step velocity is the finite difference (pose(t + dt) - pose(t)) / dt, exact for
constant rates (round-off ~ eps |pose| / dt, below 1e-12 here) and off by at most
dt/2 max |pose''| otherwise. Poses after n steps are compared bit for bit.
"""

import numpy as np
import pytest

from softvr.dynamics.kinematic import FixedBody, KinematicBody
from softvr.dynamics.rigid import RigidBody, RigidFrame, quat_from_rotvec, quat_multiply, quat_to_rotvec
from softvr.errors import InputError, SimulationError

Q0 = quat_from_rotvec([0.3, -0.5, 0.2])
C0 = np.array([0.1, 0.2, -0.3])
U = np.array([0.4, -0.2, 0.05])  # [m/s]
RATE = 1.7  # [rad/s] about z
Z = np.array([0.0, 0.0, 1.0])


def steady_pose(t):
    """Constant translation U and constant rotation RATE about world z."""
    return C0 + U * t, quat_multiply(quat_from_rotvec(RATE * t * Z), Q0)


def test_constant_rates_give_the_exact_velocity():
    body = KinematicBody(steady_pose)
    assert isinstance(body, RigidFrame)
    for dt in (0.01, 0.001, 0.1):
        v = body.unconstrained_velocity(dt)
        np.testing.assert_allclose(v[:3], U, atol=1e-12)
        np.testing.assert_allclose(v[3:], RATE * Z, atol=1e-12)
    # Forces cannot change a scripted motion.
    np.testing.assert_array_equal(body.unconstrained_velocity(0.01, gravity=(0, 0, -100.0), external=np.ones(6)),
                                  body.unconstrained_velocity(0.01))


def test_after_n_steps_the_pose_is_exactly_pose_of_n_dt():
    body = KinematicBody(steady_pose, name="scope")
    dt, n = 0.01, 137
    for _ in range(n):
        body.step(dt)
    assert body.time == n * dt
    c, q = steady_pose(n * dt)
    np.testing.assert_array_equal(body.position, c)
    np.testing.assert_array_equal(body.orientation, q)
    np.testing.assert_allclose(body.v, np.concatenate([U, RATE * Z]), atol=1e-12)
    assert body.step_count == n
    # Velocities from a constraint solver (infinite mass: the free velocity plus A^-1 J^T lambda = 0)
    # are only checked; the script wins.
    body.integrate(np.zeros(6), dt)
    np.testing.assert_array_equal(body.position, steady_pose((n + 1) * dt)[0])


def test_velocity_is_the_step_mean_within_first_order_of_the_derivative():
    """c(t) = C0 + A sin(W t), rotation by theta(t) = TH sin(W t) about a fixed axis: the finite
    difference errs by at most dt/2 max|c''| = dt/2 A W^2 (and dt/2 TH W^2 for omega), and it is
    exactly the constant velocity whose rigid-body integration lands on pose(t + dt)."""
    amp, theta, w = np.array([0.05, 0.02, -0.03]), 0.8, 6.0
    axis = np.array([1.0, 2.0, 2.0]) / 3.0

    def pose(t):
        return C0 + amp * np.sin(w * t), quat_multiply(quat_from_rotvec(theta * np.sin(w * t) * axis), Q0)

    dt = 0.005
    body = KinematicBody(pose, t0=0.3)
    for _ in range(50):
        t = body.time
        v = body.unconstrained_velocity(dt)
        assert np.abs(v[:3] - amp * w * np.cos(w * t)).max() <= dt / 2 * np.abs(amp).max() * w**2
        assert np.linalg.norm(v[3:] - theta * w * np.cos(w * t) * axis) <= dt / 2 * theta * w**2
        # RigidBody's update with this velocity reaches the next pose (to round-off).
        c1, q1 = pose(t + dt)
        np.testing.assert_allclose(body.position + dt * v[:3], c1, atol=1e-15)
        q_next = quat_multiply(quat_from_rotvec(dt * v[3:]), body.orientation)
        np.testing.assert_allclose(quat_to_rotvec(quat_multiply(q_next, q1 * [1, -1, -1, -1])), 0.0, atol=1e-14)
        body.integrate(v, dt)
        assert body.time == pytest.approx(0.3 + body.step_count * dt, abs=1e-14)


def test_kinematic_body_point_velocity_follows_its_rotation():
    body = KinematicBody(steady_pose)
    v = body.unconstrained_velocity(0.01)
    body.integrate(v, 0.01)
    p = body.to_world([0.1, 0.0, 0.0])
    np.testing.assert_allclose(body.point_velocity(p), U + np.cross(RATE * Z, p - body.position), atol=1e-12)


@pytest.mark.parametrize("make", [lambda: FixedBody((1.0, 2.0, 3.0), Q0), lambda: KinematicBody(steady_pose)])
def test_infinite_mass_solve_gives_zeros(make):
    body = make()
    body.unconstrained_velocity(0.01)
    np.testing.assert_array_equal(body.solve(np.arange(6.0)), np.zeros(6))
    np.testing.assert_array_equal(body.solve(np.ones((4, 6))), np.zeros((4, 6)))
    np.testing.assert_array_equal(body.solve_columns(np.ones((6, 2))), np.zeros((6, 2)))
    assert body.block_size == 6 and body.velocity_size == 6
    with pytest.raises(InputError, match="rhs"):
        body.solve(np.ones(3))
    assert body.mass == np.inf and body.kinetic_energy() == 0.0


def test_fixed_body_never_moves():
    q = np.array([2.0, 0.0, 0.0, 2.0])  # normalized on construction
    body = FixedBody((1.0, 2.0, 3.0), q, name="floor")
    np.testing.assert_allclose(body.orientation, q / np.linalg.norm(q), rtol=1e-15)
    position, orientation = body.position.copy(), body.orientation.copy()
    for _ in range(20):
        body.step(0.01, gravity=(0, 0, -9.81), external=np.full(6, 1e6))
    np.testing.assert_array_equal(body.position, position)
    np.testing.assert_array_equal(body.orientation, orientation)
    np.testing.assert_array_equal(body.v, np.zeros(6))
    assert body.step_count == 20
    np.testing.assert_allclose(body.point_jacobian(np.zeros(3)) @ body.v, 0.0)
    with pytest.raises(SimulationError, match=r"floor: diverged at step 21"):
        body.integrate(np.full(6, np.nan), 0.01)


def test_bad_input_is_reported():
    with pytest.raises(InputError, match="orientation"):
        FixedBody(orientation=(0, 0, 0, 0))
    with pytest.raises(InputError, match="position"):
        FixedBody(position=(0, np.nan, 0))
    with pytest.raises(InputError, match="pose"):
        KinematicBody("not callable")
    with pytest.raises(InputError, match=r"pose\(0.0\) position"):
        KinematicBody(lambda t: (np.zeros(2), Q0))
    with pytest.raises(InputError, match=r"pose\(0.0\) quaternion: expected a nonzero"):
        KinematicBody(lambda t: (np.zeros(3), np.zeros(4)))
    with pytest.raises(InputError, match=r"pose\(0.0\)"):
        KinematicBody(lambda t: np.zeros(3))
    body = KinematicBody(steady_pose, name="finger")
    body.step(0.01)
    with pytest.raises(SimulationError, match=r"finger: diverged at step 2 \(velocity NaN/inf\)"):
        body.integrate(np.array([0, 0, np.inf, 0, 0, 0]), 0.01)
    with pytest.raises(InputError, match="dt"):
        body.unconstrained_velocity(-0.01)


def test_a_step_asked_again_or_with_another_dt_follows_the_script():
    """The step's velocity asked for dt, 2 dt, dt again and 2 dt at one time (the step is
    cached for the integration that follows): each the script's own finite difference
    (pose(dt) - pose(0)) / dt (linear part: round-off, ~eps |C0| / dt < 1e-12; angular: the
    constant rate about z up to the rotation vector's round-off), and the integration lands on
    pose(2 dt) bit for bit."""
    body = KinematicBody(steady_pose)
    for dt in (0.01, 0.02, 0.01, 0.02):
        v = body.unconstrained_velocity(dt)
        np.testing.assert_allclose(v[:3], (steady_pose(dt)[0] - steady_pose(0.0)[0]) / dt, rtol=0, atol=1e-12)
        np.testing.assert_allclose(v[3:], RATE * Z, rtol=0, atol=1e-9)
    body.integrate(v, 0.02)
    np.testing.assert_array_equal(body.position, steady_pose(0.02)[0])
    np.testing.assert_array_equal(body.orientation, steady_pose(0.02)[1])


def test_a_pose_turning_non_finite_is_reported_with_its_time():
    body = KinematicBody(lambda t: (np.array([0.0, np.nan if t > 0 else 0.0, 0.0]), Q0), name="hand")
    with pytest.raises(InputError, match=r"hand: pose\(0.01\) position"):
        body.unconstrained_velocity(0.01)
    turning = KinematicBody(lambda t: (C0, np.array([1.0, 0.0, np.inf if t > 0 else 0.0, 0.0])), name="probe")
    with pytest.raises(InputError, match=r"probe: pose\(0.01\) quaternion"):
        turning.unconstrained_velocity(0.01)


def test_rigid_and_kinematic_bodies_share_the_frame_interface():
    """Same attribute names and point maps for point entities (thesis 5.1.2)."""
    rigid = RigidBody.box((0.1, 0.1, 0.1), 1000.0, position=C0, orientation=Q0)
    bodies = [rigid, FixedBody(C0, Q0), KinematicBody(steady_pose)]
    r = np.array([0.01, 0.02, 0.03])
    for body in bodies:
        np.testing.assert_allclose(body.to_world(r), bodies[0].to_world(r), atol=1e-15)
        assert body.G().shape == (7, 6) and body.v.shape == (6,)


def test_a_body_that_holds_turns_and_holds_again_gets_scipys_angular_velocity_each_step():
    """A probe-like script: still for 3 steps, turning 0.02 rad about x over one, still again
    (the angular velocity of a still step is kept from the last, so a stale one would show here).
    Each step's angular velocity is SciPy's rotation vector of pose(t + dt) pose(t)^-1 over dt
    (the thesis' kinematic finite difference, module docstring): 0.02 rad / 0.01 s = 2 rad/s at
    the turn, 0 when still; 1e-9 rad/s covers the rotation vector's round-off (~eps / dt)."""
    from scipy.spatial.transform import Rotation

    dt, turn = 0.01, 0.02
    q_after = quat_multiply(quat_from_rotvec([turn, 0.0, 0.0]), Q0)

    def pose(t):
        return C0.copy(), (Q0 if t < 3.5 * dt else q_after).copy()

    def scipy_rotation(q):
        return Rotation.from_quat(np.asarray(q)[[1, 2, 3, 0]])

    body = KinematicBody(pose)
    for step in range(7):
        t = step * dt
        v = body.unconstrained_velocity(dt)
        truth = (scipy_rotation(pose(t + dt)[1]) * scipy_rotation(pose(t)[1]).inv()).as_rotvec() / dt
        np.testing.assert_allclose(v[3:], truth, rtol=0, atol=1e-9, err_msg=f"step {step}")
        body.integrate(v, dt)
    assert abs(truth).max() < 1e-9 and body.step_count == 7
