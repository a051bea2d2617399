"""Rigid body against physics and against the closed forms of its own integrator.

Tolerances:

* Backward Euler is first order. Under constant force its velocities are exactly
  ``v_n = v_0 + n a dt`` and its positions ``c_n = c_0 + dt sum_{k=1..n} v_k`` (compared to
  round-off), which differ from the analytic parabola by exactly ``a dt t / 2``.
* The orientation update is the exact exponential map, so a constant ``omega`` (torque-free
  spin about a principal axis) rotates by exactly ``n |omega| dt`` after n steps (round-off only).
* Off a principal axis the gyroscopic torque changes ``omega`` and both treatments err at first
  order in ``|L|`` (derivations in the tests): bounds ``T dt (c |omega|_max)^2 / 2`` and halving
  ``dt`` halving the drift.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from softvr.dynamics.body import ContactObject
from softvr.dynamics.rigid import (
    RigidBody,
    RigidFrame,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    quat_to_matrix,
    quat_to_rotvec,
)
from softvr.errors import InputError, SimulationError

G = np.array([0.0, 0.0, -9.81])
ZERO_G = (0.0, 0.0, 0.0)
Q0 = Rotation.from_euler("zyx", [40, -25, 70], degrees=True)
Q0_WXYZ = np.roll(Q0.as_quat(), 1)  # scipy is (x, y, z, w)


def rotation_angle(q_from, q_to):
    """Angle [rad] in [0, pi] of the rotation taking orientation q_from to q_to."""
    return float(np.linalg.norm(quat_to_rotvec(quat_multiply(q_to, quat_conjugate(q_from)))))


def test_quaternion_helpers_agree_with_scipy():
    rng = np.random.default_rng(1)
    phi = rng.normal(size=(20, 3)) * 1.5
    q = quat_from_rotvec(phi)
    ref = Rotation.from_rotvec(phi)
    np.testing.assert_allclose(quat_to_matrix(q), ref.as_matrix(), atol=1e-14)
    # (w, x, y, z) vs scipy's (x, y, z, w), up to the sign of the quaternion.
    ref_q = np.roll(ref.as_quat(), 1, axis=-1)
    sign = np.sign(np.sum(q * ref_q, axis=-1, keepdims=True))
    np.testing.assert_allclose(q, sign * ref_q, atol=1e-14)
    np.testing.assert_allclose(quat_to_rotvec(q), ref.as_rotvec(), atol=1e-13)
    # Composition order: (a (x) b) rotates by b first, then a.
    a, b = q[0], q[1]
    np.testing.assert_allclose(quat_to_matrix(quat_multiply(a, b)), quat_to_matrix(a) @ quat_to_matrix(b), atol=1e-14)
    # Tiny angles stay accurate (no small-angle cancellation).
    np.testing.assert_allclose(quat_to_rotvec(quat_from_rotvec([1e-12, -2e-12, 3e-12])), [1e-12, -2e-12, 3e-12],
                               rtol=1e-12)


def test_box_and_sphere_mass_and_inertia_are_the_textbook_ones():
    box = RigidBody.box((0.3, 0.2, 0.1), 1000.0)
    # m = rho a b c = 6 kg; I = m/12 (b^2 + c^2, a^2 + c^2, a^2 + b^2).
    assert box.mass == pytest.approx(6.0, rel=1e-14)
    np.testing.assert_allclose(box.inertia_body, np.diag([0.025, 0.05, 0.065]), rtol=1e-14, atol=1e-18)
    assert box.extent == pytest.approx(0.3, rel=1e-12)  # its equivalent box is itself
    sphere = RigidBody.sphere(0.1, 1000.0)
    m = 4.0 / 3.0 * np.pi * 0.1**3 * 1000.0
    assert sphere.mass == pytest.approx(m, rel=1e-14)
    np.testing.assert_allclose(sphere.inertia_body, 0.4 * m * 0.01 * np.eye(3), rtol=1e-14, atol=1e-18)
    assert isinstance(box, RigidFrame) and isinstance(box, ContactObject)


def test_world_momentum_and_energy_match_point_masses():
    """Eight point masses m/8 at the 2-point Gauss-Legendre nodes (+-a / (2 sqrt 3) per axis) have
    exactly the second moments of the uniform box, so they give its momenta and energy exactly."""
    size = np.array([0.3, 0.2, 0.1])
    v, w = np.array([0.5, -1.0, 2.0]), np.array([3.0, -2.0, 1.5])
    body = RigidBody.box(size, 1000.0, position=(1.0, 2.0, 3.0), orientation=Q0_WXYZ, velocity=v,
                         angular_velocity=w)
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    points = body.to_world(signs * size / (2 * np.sqrt(3)))
    pm = body.mass / 8
    vel = body.point_velocity(points)
    np.testing.assert_allclose(vel, v + np.cross(w, points - body.position), atol=1e-14)
    np.testing.assert_allclose(body.linear_momentum(), pm * vel.sum(0), rtol=1e-13)
    np.testing.assert_allclose(body.angular_momentum(), pm * np.cross(points - body.position, vel).sum(0),
                               rtol=1e-12)
    assert body.kinetic_energy() == pytest.approx(0.5 * pm * np.sum(vel**2), rel=1e-13)
    # p_dot = J v (thesis 5.1.2), and to_body inverts to_world.
    np.testing.assert_allclose(np.einsum("nij,j->ni", body.point_jacobian(points), body.v), vel, atol=1e-13)
    np.testing.assert_allclose(body.to_body(points), signs * size / (2 * np.sqrt(3)), atol=1e-15)


def test_projectile_matches_backward_euler_and_the_parabola():
    """Gravity is the only force, so v_n = v_0 + n g dt and c_n = c_0 + n dt v_0 + g dt^2 n (n+1) / 2
    = parabola + g dt t / 2 (first-order error, zero horizontally). Spin does not affect the
    centre of mass (sphere: no gyroscopic torque)."""
    c0, v0, w0 = np.array([0.1, -0.2, 1.0]), np.array([3.0, -1.0, 4.0]), np.array([0.0, 7.0, 2.0])
    body = RigidBody.sphere(0.05, 1000.0, position=c0, velocity=v0, angular_velocity=w0)
    dt, n = 0.01, 100
    for _ in range(n):
        body.step(dt, gravity=G)
    t = n * dt
    np.testing.assert_allclose(body.velocity, v0 + n * dt * G, atol=1e-12)
    np.testing.assert_allclose(body.position, c0 + n * dt * v0 + G * dt * dt * n * (n + 1) / 2, atol=1e-12)
    error = body.position - (c0 + v0 * t + 0.5 * G * t * t)
    np.testing.assert_allclose(error, 0.5 * G * dt * t, atol=1e-12)
    np.testing.assert_allclose(body.angular_velocity, w0, atol=1e-12)
    assert body.step_count == n


def test_torque_free_spin_about_a_principal_axis_rotates_at_exactly_omega():
    """omega = |omega| R e_k is an eigenvector of I_w, so omega x I_w omega = 0: omega stays constant
    and the exact exponential map turns the body by n |omega| dt (checked below pi)."""
    dt, n, rate = 0.01, 90, 3.0
    for mode in ("implicit", "explicit"):
        for k in range(3):
            w0 = rate * Q0.as_matrix()[:, k]
            body = RigidBody.box((0.3, 0.2, 0.1), 1000.0, orientation=Q0_WXYZ, angular_velocity=w0, gyroscopic=mode)
            for _ in range(n):
                body.step(dt, gravity=ZERO_G)
            np.testing.assert_allclose(body.angular_velocity, w0, atol=1e-12)
            assert rotation_angle(Q0_WXYZ, body.orientation) == pytest.approx(n * rate * dt, abs=1e-12)
            expected = quat_multiply(quat_from_rotvec(n * dt * w0), Q0_WXYZ)
            np.testing.assert_allclose(body.orientation, expected, atol=1e-13)
            assert np.linalg.norm(body.orientation) == pytest.approx(1.0, abs=1e-15)


def test_constant_torque_on_a_sphere_gives_the_backward_euler_closed_form():
    """Isotropic inertia: no gyroscopic torque, omega_n = n dt tau / I, and rotations about one
    axis commute, so the angle is exactly dt sum omega_k = dt^2 (tau / I) n (n + 1) / 2."""
    body = RigidBody.sphere(0.1, 1000.0)
    inertia = body.inertia_body[0, 0]
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    tau = 0.02 * axis
    dt, n = 0.01, 40
    for _ in range(n):
        body.step(dt, gravity=ZERO_G, external=np.concatenate([np.zeros(3), tau]))
    np.testing.assert_allclose(body.angular_velocity, n * dt * tau / inertia, atol=1e-12)
    angle = dt * dt * (0.02 / inertia) * n * (n + 1) / 2
    np.testing.assert_allclose(quat_to_rotvec(body.orientation), angle * axis, atol=1e-12)
    np.testing.assert_allclose(body.position, 0.0, atol=0)  # torque moves no centre of mass


def test_G_maps_velocity_to_the_state_derivative():
    """(q(h) - q(0)) / h = G v + O(h): the exponential map's second-order term is (h omega)^2 / 8,
    so the difference is at most h |omega|^2 / 8 (h = 1e-7 here)."""
    v = np.array([0.3, -0.4, 0.5, 2.0, -1.0, 3.0])
    body = RigidBody.box((0.3, 0.2, 0.1), 1000.0, orientation=Q0_WXYZ, velocity=v[:3], angular_velocity=v[3:])
    q0 = np.concatenate([body.position, body.orientation])
    g = body.G()
    assert g.shape == (7, 6)
    h = 1e-7
    body.integrate(v, h)
    fd = (np.concatenate([body.position, body.orientation]) - q0) / h
    np.testing.assert_allclose(fd, g @ v, atol=h * np.sum(v[3:] ** 2) / 8 + 1e-8)  # + round-off eps/h


@pytest.mark.parametrize("mode", ["implicit", "explicit"])
def test_solve_inverts_the_mass_matrix_and_the_step_is_linear_in_force(mode):
    body = RigidBody.box((0.3, 0.2, 0.1), 1000.0, orientation=Q0_WXYZ, velocity=(1.0, 0.0, 0.0),
                         angular_velocity=(4.0, 3.0, 2.0), gyroscopic=mode)
    with pytest.raises(InputError, match="unconstrained_velocity"):
        body.solve(np.ones(6))
    dt = 0.01
    m = body.mass_matrix()
    free = body.unconstrained_velocity(dt, gravity=G)
    x = np.array([1.0, -2.0, 0.5, 0.3, -0.1, 0.2])
    np.testing.assert_allclose(m @ body.solve(x), x, atol=1e-12)
    batch = np.stack([x, 2 * x, -x])
    np.testing.assert_allclose(body.solve(batch), np.stack([body.solve(y) for y in batch]), atol=1e-15)
    np.testing.assert_allclose(body.solve_columns(batch.T), body.solve(batch).T, atol=0)
    assert body.solve_columns(batch.T).shape == (6, 3)
    # The Delassus operator J M^-1 J^T of two contact points is symmetric positive semi-definite.
    j = body.point_jacobian(body.to_world([[0.15, 0.1, 0.05], [-0.15, 0.0, -0.05]])).reshape(6, 6)
    delassus = j @ body.solve_columns(j.T)
    np.testing.assert_allclose(delassus, delassus.T, atol=1e-14)
    assert np.linalg.eigvalsh(delassus).min() > -1e-14
    # The step is linear in the external force: v(f) = v(0) + A^-1 (dt f), with A = M (explicit)
    # or M + dt ([w]x I_w - [I_w w]x) (implicit: first order in dt, non-symmetric).
    a = body.system_matrix()
    gyro = a[3:, 3:] - m[3:, 3:]
    if mode == "explicit":
        np.testing.assert_array_equal(a, m)
    else:
        w, iw = body.angular_velocity, m[3:, 3:]
        np.testing.assert_allclose(gyro @ x[3:], dt * (np.cross(w, iw @ x[3:]) - np.cross(iw @ w, x[3:])), atol=1e-15)
    f = np.array([3.0, 1.0, -2.0, 0.05, -0.02, 0.01])
    np.testing.assert_allclose(body.unconstrained_velocity(dt, gravity=G, external=f),
                               free + np.linalg.solve(a, dt * f), atol=1e-12)


def test_explicit_gyroscopic_momentum_grows_by_exactly_dt_squared_omega_cross_L():
    """Explicit: I_w w1 = L0 - dt w0 x L0, and the exact rotation about w1 leaves |I_w w1| unchanged,
    so |L1|^2 = |L0|^2 + dt^2 |w0 x L0|^2 per step (to round-off): |L| only grows."""
    body = RigidBody.box((0.3, 0.2, 0.1), 1000.0, orientation=Q0_WXYZ, angular_velocity=(4.0, 3.0, 2.0),
                         gyroscopic="explicit")
    dt = 0.01
    for _ in range(100):
        l0, w0 = body.angular_momentum(), body.angular_velocity.copy()
        body.step(dt, gravity=ZERO_G)
        l1 = body.angular_momentum()
        growth = dt * dt * np.sum(np.cross(w0, l0) ** 2)
        assert l1 @ l1 - l0 @ l0 == pytest.approx(growth, rel=1e-9, abs=1e-14 * (l0 @ l0))


@pytest.mark.parametrize("mode", ["implicit", "explicit"])
def test_asymmetric_spin_momentum_drift_is_first_order(mode):
    """Torque-free tumbling conserves the world vector L exactly. Bounds, with
    |w x I w| <= (I3 - I1)/2 |w|^2, |L| >= I1 |w|, c = (I3 - I1) / (2 I1), T = 1 s:

    * magnitude: the step changes |L| by ~ dt^2 |w x L|^2 / (2 |L|^2) relative (derived in the
      explicit test; implicit: the same as a loss, plus a Newton residual dt (dw x I dw) of order
      dt^3), so the relative drift is below T dt (c w_max)^2 / 2;
    * vector: L1 = exp(dt w1) (L0 - dt w0 x L0) = L0 + dt dw x L0 - dt^2/2 w x (w x L0) + ..., with
      |dw| <= dt c |w|^2, i.e. at most 1.5 c dt^2 |w|^2 |L| per step and 1.5 c T dt w_max^2 in all
      (a wrong sign of the gyroscopic torque would make it O(1)).

    Both first order: halving dt halves them."""
    drifts, vector_drifts = [], []
    for dt in (0.01, 0.005):
        body = RigidBody.box((0.3, 0.2, 0.1), 1000.0, orientation=Q0_WXYZ, angular_velocity=(4.0, 3.0, 2.0),
                             gyroscopic=mode)
        l0 = body.angular_momentum()
        moments = np.linalg.eigvalsh(body.inertia_body)
        c = (moments[2] - moments[0]) / (2 * moments[0])
        w_max, drift, vector_drift = 0.0, 0.0, 0.0
        for _ in range(round(1.0 / dt)):
            body.step(dt, gravity=ZERO_G)
            w_max = max(w_max, float(np.linalg.norm(body.angular_velocity)))
            drift = max(drift, abs(np.linalg.norm(body.angular_momentum()) / np.linalg.norm(l0) - 1))
            vector_drift = max(vector_drift, np.linalg.norm(body.angular_momentum() - l0) / np.linalg.norm(l0))
        assert drift < dt * (c * w_max) ** 2 / 2
        assert vector_drift < 1.5 * c * dt * w_max**2
        drifts.append(drift)
        vector_drifts.append(vector_drift)
    assert drifts[0] / drifts[1] == pytest.approx(2.0, rel=0.1)
    assert vector_drifts[0] / vector_drifts[1] == pytest.approx(2.0, rel=0.1)


def test_implicit_gyroscopic_stays_bounded_where_explicit_blows_up():
    """Fast tumbling, dt |w| ~ 1.5: the implicit treatment only dissipates (energy and |L| never
    rise), the explicit one gains energy every step until the divergence check stops it."""
    w0 = (40.0, 60.0, 30.0)
    implicit = RigidBody.box((0.3, 0.2, 0.1), 1000.0, angular_velocity=w0)
    e, l = implicit.kinetic_energy(), np.linalg.norm(implicit.angular_momentum())
    for _ in range(200):
        implicit.step(0.02, gravity=ZERO_G)
        e1, l1 = implicit.kinetic_energy(), np.linalg.norm(implicit.angular_momentum())
        assert e1 <= e * (1 + 1e-12) and l1 <= l * (1 + 1e-12)
        e, l = e1, l1
    explicit = RigidBody.box((0.3, 0.2, 0.1), 1000.0, angular_velocity=w0, gyroscopic="explicit", name="drill")
    with pytest.raises(SimulationError, match=r"drill: diverged at step \d+ \(angular speed"):
        for _ in range(200):
            explicit.step(0.02, gravity=ZERO_G)


def test_bad_input_is_reported():
    good = {"mass": 1.0, "inertia": [0.1, 0.1, 0.1]}
    cases = [
        ({"mass": -1.0}, "mass"),
        ({"mass": float("nan")}, "mass"),
        ({"inertia": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}, "positive definite"),
        ({"inertia": [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]}, "asymmetric"),
        ({"inertia": [1.0, 1.0, 3.0]}, "I1 \\+ I2 >= I3"),
        ({"inertia": np.eye(2)}, "inertia"),
        ({"orientation": (0, 0, 0, 0)}, "orientation: expected a nonzero quaternion"),
        ({"orientation": (1, 0, float("inf"), 0)}, "orientation"),
        ({"velocity": (0, float("nan"), 0)}, "velocity"),
        ({"angular_velocity": (1, 2)}, "angular_velocity"),
        ({"gyroscopic": "semi"}, "gyroscopic"),
    ]
    for kwargs, message in cases:
        args = good | kwargs
        with pytest.raises(InputError, match=message):
            RigidBody(args.pop("mass"), args.pop("inertia"), **args)
    with pytest.raises(InputError, match="size"):
        RigidBody.box((0.1, 0.0, 0.1), 1000.0)
    with pytest.raises(InputError, match="density"):
        RigidBody.sphere(0.1, -5.0)
    body = RigidBody(2.0, [0.1, 0.1, 0.1], orientation=(2.0, 0.0, 0.0, 0.0))
    np.testing.assert_array_equal(body.orientation, [1.0, 0.0, 0.0, 0.0])  # normalized
    with pytest.raises(InputError, match="dt"):
        body.step(0.0)
    with pytest.raises(InputError, match="external"):
        body.step(0.01, external=np.zeros(3))


def test_divergence_names_the_body_and_the_step():
    body = RigidBody.box((0.1, 0.1, 0.1), 1000.0, name="humerus")
    body.step(0.01)
    body.v[4] = np.nan
    with pytest.raises(SimulationError, match=r"humerus: diverged at step 2 \(velocity NaN/inf\)"):
        body.step(0.01)
    body = RigidBody.box((0.1, 0.1, 0.1), 1000.0, name="scapula")
    with pytest.raises(SimulationError, match=r"scapula: diverged at step 1 \(speed"):
        body.integrate(np.array([1e6, 0, 0, 0, 0, 0]), 0.01)
    assert body.step_count == 0 and np.all(body.position == 0)  # a failed step changes nothing
