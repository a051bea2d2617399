"""Compiled unconstrained step and integration of every rigid body of a scene at once: the
array form of :meth:`RigidBody.unconstrained_velocity` (thesis eq. 5.2 with the gyroscopic
torque implicit or explicit) and :meth:`RigidBody.integrate`, one thread per body."""

from __future__ import annotations

import warp as wp

#: Divergence reasons written to ``diverged`` (RigidState.diverged).
NAN_VELOCITY, TOO_FAST, SPINNING, SINGULAR = 1, 2, 3, 4


@wp.func
def _rotation(orientation: wp.vec4d) -> wp.mat33d:
    # softvr's quaternions are (w, x, y, z), Warp's (x, y, z, w).
    return wp.quat_to_matrix(wp.quatd(orientation[1], orientation[2], orientation[3], orientation[0]))


@wp.func
def _skew(a: wp.vec3d) -> wp.mat33d:
    zero = wp.float64(0.0)
    return wp.mat33d(zero, -a[2], a[1], a[2], zero, -a[0], -a[1], a[0], zero)


@wp.func
def _finite(v: wp.spatial_vectord) -> bool:
    ok = True
    for i in range(6):
        if not wp.isfinite(v[i]):
            ok = False
    return ok


@wp.kernel
def unconstrained(orientation: wp.array(dtype=wp.vec4d), velocity: wp.array(dtype=wp.spatial_vectord),
                  inv_mass: wp.array(dtype=wp.float64), inertia: wp.array(dtype=wp.mat33d),
                  implicit_gyro: wp.array(dtype=wp.int32), external: wp.array(dtype=wp.spatial_vectord),
                  gravity: wp.vec3d, dt: wp.float64, free_velocity: wp.array(dtype=wp.spatial_vectord),
                  inv_inertia_world: wp.array(dtype=wp.mat33d), diverged: wp.array(dtype=wp.int32),
                  contact_count: wp.array(dtype=wp.int32)):
    """Thread per body: ``v_lin1 = v_lin0 + dt (g + f / m)``, ``A_rot omega1 = A_rot omega0 +
    dt (tau - omega0 x I_w omega0)`` (RigidBody.unconstrained_velocity); ``I_w^-1`` for the
    contact solve; 0 for a fixed body. Thread 0 also empties the step's contact set."""
    i = wp.tid()
    if i == 0:
        contact_count[0] = 0
    zero = wp.float64(0.0)
    diverged[i] = 0
    if inv_mass[i] == zero:
        free_velocity[i] = wp.spatial_vectord()
        inv_inertia_world[i] = wp.mat33d()
        return
    v = velocity[i]
    if not _finite(v):
        diverged[i] = NAN_VELOCITY
        free_velocity[i] = v
        return
    rot = _rotation(orientation[i])
    iw = rot * inertia[i] * wp.transpose(rot)
    iw = wp.float64(0.5) * (iw + wp.transpose(iw))
    w0 = wp.vec3d(v[3], v[4], v[5])
    l0 = iw * w0
    a_rot = iw
    if implicit_gyro[i] != 0:
        # -dt dF/domega for F = -omega x (I_w omega), I_w held for the step.
        a_rot = iw + dt * (_skew(w0) * iw - _skew(l0))
    if wp.determinant(a_rot) == zero:
        diverged[i] = SINGULAR
        free_velocity[i] = v
        return
    ext = external[i]
    lin = wp.vec3d(v[0], v[1], v[2]) + dt * (gravity + inv_mass[i] * wp.vec3d(ext[0], ext[1], ext[2]))
    w1 = w0 + wp.inverse(a_rot) * (dt * (wp.vec3d(ext[3], ext[4], ext[5]) - wp.cross(w0, l0)))
    free_velocity[i] = wp.spatial_vectord(lin[0], lin[1], lin[2], w1[0], w1[1], w1[2])
    inv_inertia_world[i] = wp.inverse(iw)


@wp.kernel
def integrate(new_velocity: wp.array(dtype=wp.spatial_vectord), inv_mass: wp.array(dtype=wp.float64),
              speed_limit: wp.array(dtype=wp.float64), spin_limit: wp.array(dtype=wp.float64), dt: wp.float64,
              position: wp.array(dtype=wp.vec3d), orientation: wp.array(dtype=wp.vec4d),
              velocity: wp.array(dtype=wp.spatial_vectord), diverged: wp.array(dtype=wp.int32)):
    """Thread per body: ``c += dt v_lin``, ``quat = exp(omega dt) (x) quat`` renormalized
    (RigidBody.integrate); a body past its divergence thresholds keeps its state and is
    flagged in ``diverged``. A fixed body stays put."""
    i = wp.tid()
    if inv_mass[i] == wp.float64(0.0) or diverged[i] != 0:
        return
    v = new_velocity[i]
    if not _finite(v):
        diverged[i] = NAN_VELOCITY
        return
    lin = wp.vec3d(v[0], v[1], v[2])
    w = wp.vec3d(v[3], v[4], v[5])
    if wp.length(lin) > speed_limit[i]:
        diverged[i] = TOO_FAST
        return
    if wp.length(w) > spin_limit[i]:
        diverged[i] = SPINNING
        return
    phi = dt * w
    angle = wp.length(phi)
    half = wp.float64(0.5) * angle
    s = wp.float64(0.5)  # sin(angle / 2) / angle at angle 0
    if angle > wp.float64(0.0):
        s = wp.sin(half) / angle
    dq = wp.vec4d(wp.cos(half), s * phi[0], s * phi[1], s * phi[2])
    q = orientation[i]
    # Hamilton product dq (x) q of (w, x, y, z) quaternions.
    q1 = wp.vec4d(dq[0] * q[0] - dq[1] * q[1] - dq[2] * q[2] - dq[3] * q[3],
                  dq[0] * q[1] + dq[1] * q[0] + dq[2] * q[3] - dq[3] * q[2],
                  dq[0] * q[2] - dq[1] * q[3] + dq[2] * q[0] + dq[3] * q[1],
                  dq[0] * q[3] + dq[1] * q[2] - dq[2] * q[1] + dq[3] * q[0])
    orientation[i] = q1 / wp.length(q1)
    position[i] = position[i] + dt * lin
    velocity[i] = v


@wp.kernel
def frame_metrics(position: wp.array(dtype=wp.vec3d), orientation: wp.array(dtype=wp.vec4d),
                  velocity: wp.array(dtype=wp.spatial_vectord), mass: wp.array(dtype=wp.float64),
                  inertia: wp.array(dtype=wp.mat33d), gravity: wp.array(dtype=wp.vec3d),
                  point_start: wp.array(dtype=wp.int32), point_local: wp.array(dtype=wp.vec3d),
                  plane_normal: wp.array(dtype=wp.vec3d), plane_offset: wp.array(dtype=wp.float64),
                  deepest: wp.array(dtype=wp.float64), kinetic: wp.array(dtype=wp.float64),
                  potential: wp.array(dtype=wp.float64)):
    """Thread per body: ``deepest[0]`` [m] raised to the deepest of its points ``c + R p`` below
    any plane ``n . x = offset`` (``offset - n . x``; the caller zeroes it); ``kinetic`` = ``1/2 m |v_lin|^2 +
    1/2 omega . I_w omega`` and ``potential`` = ``-m g . c`` [J] (RigidBody.kinetic_energy,
    softvr.app.gravity_potential); 0 where ``mass`` is 0 (a fixed body)."""
    i = wp.tid()
    zero = wp.float64(0.0)
    rot = _rotation(orientation[i])
    c = position[i]
    d = zero
    for p in range(point_start[i], point_start[i + 1]):
        x = c + rot * point_local[p]
        for k in range(plane_normal.shape[0]):
            d = wp.max(d, plane_offset[k] - wp.dot(x, plane_normal[k]))
    wp.atomic_max(deepest, 0, d)
    m = mass[i]
    if m == zero:
        kinetic[i] = zero
        potential[i] = zero
        return
    v = velocity[i]
    lin = wp.vec3d(v[0], v[1], v[2])
    w = wp.vec3d(v[3], v[4], v[5])
    iw = rot * inertia[i] * wp.transpose(rot)
    iw = wp.float64(0.5) * (iw + wp.transpose(iw))
    half = wp.float64(0.5)
    kinetic[i] = half * m * wp.dot(lin, lin) + half * wp.dot(w, iw * w)
    potential[i] = -m * wp.dot(c, gravity[0])
