"""Compiled frictional, adhesive contact of rigid bodies, the whole step's contacts in one
launch: match to the previous step's contacts, projected Gauss-Seidel (thesis eq. 5.6 with
D_A = M, exact for rigid bodies), adhesion's evolution (4.3.3) and what carries over.

It is :func:`softvr.contact.solve_contacts` followed by
:meth:`softvr.contact.AdhesionState.evolve` in array form, for rigid bodies: the PGS works on
body velocities instead of an assembled Delassus matrix (a row's update moves its bodies'
velocities by ``M^-1 J^T delta lambda``), which is the same iteration, since
``rel = J v_free + B lambda`` with ``B = J M^-1 J^T``. The sweep is sequential by nature; it
runs as one thread.
"""

from __future__ import annotations

import warp as wp

from softvr.contact._adhesion_kernels import adhesive_bound, bond_stiffness, carry_sorted, evolve_bond, find_key


@wp.func
def _row_response(inv_mass: wp.float64, inv_inertia: wp.mat33d, r: wp.vec3d, d: wp.vec3d) -> wp.float64:
    """``J M^-1 J^T`` of one body's share of a constraint row along ``d`` at offset ``r``."""
    rd = wp.cross(r, d)
    return inv_mass + wp.dot(rd, inv_inertia * rd)


@wp.func
def _row_velocity(v: wp.spatial_vectord, r: wp.vec3d, d: wp.vec3d) -> wp.float64:
    return wp.dot(wp.vec3d(v[0], v[1], v[2]), d) + wp.dot(wp.vec3d(v[3], v[4], v[5]), wp.cross(r, d))


@wp.func
def _push(v: wp.spatial_vectord, inv_mass: wp.float64, inv_inertia: wp.mat33d, r: wp.vec3d, d: wp.vec3d,
          amount: wp.float64) -> wp.spatial_vectord:
    """``v + M^-1 J^T amount`` for an impulse ``amount`` along ``d`` at offset ``r``."""
    dv = inv_mass * amount * d
    dw = inv_inertia * (amount * wp.cross(r, d))
    return wp.spatial_vectord(v[0] + dv[0], v[1] + dv[1], v[2] + dv[2], v[3] + dw[0], v[4] + dw[1], v[5] + dw[2])


@wp.func
def _point(v: wp.spatial_vectord, r: wp.vec3d) -> wp.vec3d:
    return wp.vec3d(v[0], v[1], v[2]) + wp.cross(wp.vec3d(v[3], v[4], v[5]), r)


@wp.func
def _row(frame: wp.mat33d, row: int) -> wp.vec3d:
    """Row ``row`` of a contact frame: the normal (0) or a tangent (1, 2)."""
    return wp.vec3d(frame[row, 0], frame[row, 1], frame[row, 2])


@wp.func
def _side_row(body: int, velocity: wp.array(dtype=wp.spatial_vectord), r: wp.vec3d, d: wp.vec3d) -> wp.float64:
    if body < 0:
        return wp.float64(0.0)
    return _row_velocity(velocity[body], r, d)


@wp.func
def _apply(body: int, velocity: wp.array(dtype=wp.spatial_vectord), inv_mass: wp.array(dtype=wp.float64),
           inv_inertia: wp.array(dtype=wp.mat33d), r: wp.vec3d, d: wp.vec3d, amount: wp.float64):
    if body >= 0:
        velocity[body] = _push(velocity[body], inv_mass[body], inv_inertia[body], r, d, amount)


@wp.kernel
def solve_rigid_contacts(count: wp.array(dtype=wp.int32), key: wp.array(dtype=wp.uint64),
                         body_a: wp.array(dtype=wp.int32), body_b: wp.array(dtype=wp.int32),
                         offset_a: wp.array(dtype=wp.vec3d), offset_b: wp.array(dtype=wp.vec3d),
                         normal: wp.array(dtype=wp.vec3d), gap: wp.array(dtype=wp.float64),
                         area: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
                         material_a: wp.array(dtype=wp.int32), material_b: wp.array(dtype=wp.int32),
                         impulse: wp.array(dtype=wp.vec3d), frame: wp.array(dtype=wp.mat33d),
                         gap_after: wp.array(dtype=wp.float64), intensity: wp.array(dtype=wp.float64),
                         slip: wp.array(dtype=wp.vec3d), carried_count: wp.array(dtype=wp.int32),
                         carried_key: wp.array(dtype=wp.uint64), carried_impulse: wp.array(dtype=wp.vec3d),
                         carried_intensity: wp.array(dtype=wp.float64), carried_slip: wp.array(dtype=wp.vec3d),
                         materials: wp.array2d(dtype=wp.float64), inv_mass: wp.array(dtype=wp.float64),
                         inv_inertia: wp.array(dtype=wp.mat33d), velocity: wp.array(dtype=wp.spatial_vectord),
                         response: wp.array(dtype=wp.vec3d), target: wp.array(dtype=wp.vec3d),
                         stiffness: wp.array(dtype=wp.float64), start: wp.array(dtype=wp.vec3d),
                         direction: wp.array(dtype=wp.vec3d), accelerate: int,
                         dt: wp.float64, max_sweeps: int, tolerance: wp.float64, stats: wp.array(dtype=wp.float64)):
    """One thread: the step's contact solve (module docstring). ``velocity`` [n] holds the
    unconstrained velocities in, the constrained ones out; ``response``, ``target``,
    ``stiffness``, ``start`` and ``direction`` [capacity] are scratch; ``accelerate`` != 0 runs
    the sweeps as a nonsmooth nonlinear conjugate gradient; ``stats`` [2]: sweeps, the largest
    normal-velocity violation [m/s]."""
    c = wp.min(count[0], key.shape[0])
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    big = wp.float64(1.0e300)
    carried = carried_count[0]
    # Frames from the unconstrained velocities, rows' responses, targets (solve_contacts).
    for i in range(c):
        a = body_a[i]
        b = body_b[i]
        n = normal[i]
        ra = offset_a[i]
        rb = offset_b[i]
        rel = wp.vec3d()
        if a >= 0:
            rel = _point(velocity[a], ra)
        if b >= 0:
            rel = rel - _point(velocity[b], rb)
        vt = rel - wp.dot(rel, n) * n
        speed = wp.length(vt)
        t1 = wp.vec3d()
        if speed > wp.float64(1e-9):
            t1 = vt / speed
        else:
            helper = wp.vec3d(one, zero, zero)
            if wp.abs(n[0]) >= wp.float64(0.9):
                helper = wp.vec3d(zero, one, zero)
            t1 = wp.normalize(wp.cross(n, helper))
        t2 = wp.cross(n, t1)
        f = wp.mat33d(n[0], n[1], n[2], t1[0], t1[1], t1[2], t2[0], t2[1], t2[2])
        frame[i] = f
        resp = wp.vec3d()
        for row in range(3):
            d = _row(f, row)
            value = zero
            if a >= 0:
                value += _row_response(inv_mass[a], inv_inertia[a], ra, d)
            if b >= 0:
                value += _row_response(inv_mass[b], inv_inertia[b], rb, d)
            resp[row] = value
        response[i] = resp
        # The previous step's record of this contact: intensity, slip, warm start.
        m = find_key(carried_key, carried, key[i])
        beta = wp.float64(-1.0)  # not tracked
        u = wp.vec3d()
        warm = wp.vec3d()
        if m >= 0:
            beta = carried_intensity[m]
            u = carried_slip[m]
            warm = carried_impulse[m]
        u = u - wp.dot(u, n) * n
        k_ad = bond_stiffness(materials, material_a[i], material_b[i], area[i], beta)
        stiffness[i] = k_ad
        intensity[i] = beta
        slip[i] = u
        tgt = wp.vec3d(-gap[i] / dt, zero, zero)
        if k_ad > zero:
            tgt = wp.vec3d(-gap[i] / dt, -wp.dot(t1, u) / dt, -wp.dot(t2, u) / dt)
        target[i] = tgt
        lam = wp.vec3d(wp.dot(n, warm), wp.dot(t1, warm), wp.dot(t2, warm))
        if k_ad <= zero:
            # Only an adhesive contact may keep a pulling (negative) normal impulse.
            ln = wp.max(lam[0], zero)
            bound = friction[i] * ln
            lam = wp.vec3d(ln, wp.clamp(lam[1], -bound, bound), wp.clamp(lam[2], -bound, bound))
        impulse[i] = lam
    # The warm starts' velocity changes, after every frame is taken from v_free.
    for i in range(c):
        f = frame[i]
        lam = impulse[i]
        for row in range(3):
            d = _row(f, row)
            _apply(body_a[i], velocity, inv_mass, inv_inertia, offset_a[i], d, lam[row])
            _apply(body_b[i], velocity, inv_mass, inv_inertia, offset_b[i], d, -lam[row])
    # Projected Gauss-Seidel (pgs_sweeps): per contact the normal row, then each tangent row
    # within the larger of the Coulomb bound and the implicit adhesive bound (eq. 4.16).
    sweeps = int(0)
    last = big  # |lambda_k - lambda_k-1|^2 of the previous sweep (none yet)
    for i in range(c):
        start[i] = impulse[i]
        direction[i] = wp.vec3d()
    for sweep in range(max_sweeps):
        biggest = zero
        for i in range(c):
            a = body_a[i]
            b = body_b[i]
            ra = offset_a[i]
            rb = offset_b[i]
            f = frame[i]
            resp = response[i]
            tgt = target[i]
            lam = impulse[i]
            k = dt * dt * stiffness[i]
            for row in range(3):
                d = _row(f, row)
                row_rel = _side_row(a, velocity, ra, d) - _side_row(b, velocity, rb, d)
                diag = resp[row]
                d_bar = diag * lam[row] + tgt[row] - row_rel
                bound = adhesive_bound(k, d_bar, diag)
                lower = wp.min(bound, zero)
                upper = big
                if row > 0:
                    upper = wp.max(friction[i] * wp.max(lam[0], zero), wp.abs(bound))
                    lower = -upper
                if diag > wp.float64(1e-300):
                    value = wp.clamp(lam[row] + (tgt[row] - row_rel) / diag, lower, upper)
                    change = value - lam[row]
                    if change != zero:
                        _apply(a, velocity, inv_mass, inv_inertia, ra, d, change)
                        _apply(b, velocity, inv_mass, inv_inertia, rb, d, -change)
                        lam[row] = value
                    biggest = wp.max(biggest, wp.abs(change) * diag)
            impulse[i] = lam
        sweeps = sweep + 1
        if biggest <= tolerance:
            break
        if accelerate != 0:
            # Nonsmooth nonlinear conjugate gradient over the sweeps (Silcowitz et al. 2010):
            # the sweep's change is a descent direction; momentum beta = |change|^2 / |last|^2
            # along the previous direction, restarted when the change grows.
            norm = zero
            for i in range(c):
                g = impulse[i] - start[i]
                norm += wp.dot(g, g)
            beta = norm / last
            last = norm
            for i in range(c):
                g = impulse[i] - start[i]
                p = direction[i]
                if beta > one:
                    p = wp.vec3d()
                else:
                    push = beta * p
                    f = frame[i]
                    for row in range(3):
                        d = _row(f, row)
                        _apply(body_a[i], velocity, inv_mass, inv_inertia, offset_a[i], d, push[row])
                        _apply(body_b[i], velocity, inv_mass, inv_inertia, offset_b[i], d, -push[row])
                    impulse[i] = impulse[i] + push
                    p = push
                direction[i] = p + g
                start[i] = impulse[i]
    # Gaps after the step, the residual, slips at the end of the step (solve_contacts).
    residual = zero
    for i in range(c):
        a = body_a[i]
        b = body_b[i]
        n = normal[i]
        rel = wp.vec3d()
        if a >= 0:
            rel = _point(velocity[a], offset_a[i])
        if b >= 0:
            rel = rel - _point(velocity[b], offset_b[i])
        approach = -wp.dot(rel, n)
        residual = wp.max(residual, approach - gap[i] / dt)
        gap_after[i] = gap[i] - dt * approach
        if stiffness[i] > zero:
            u = slip[i] + dt * rel
            slip[i] = u - wp.dot(u, n) * n
    # Adhesion's evolution (AdhesionState.evolve) and what the next step finds.
    for i in range(c):
        lam = impulse[i]
        beta_in = intensity[i]
        u = slip[i]
        beta_out = wp.float64(-1.0)
        u_out = wp.vec3d()
        ma = material_a[i]
        mb = material_b[i]
        resp = response[i]
        if ma >= 0 and mb >= 0 and resp[0] + resp[1] + resp[2] > zero:
            beta_out, u_out = evolve_bond(materials, ma, mb, beta_in, lam[0], gap_after[i], area[i], u, dt)
        intensity[i] = beta_out
        slip[i] = u_out
    # Carry over, sorted by key.
    for i in range(c):
        carry_sorted(i, key[i], wp.transpose(frame[i]) * impulse[i], intensity[i], slip[i], carried_key,
                     carried_impulse, carried_intensity, carried_slip)
    carried_count[0] = c
    stats[0] = wp.float64(sweeps)
    stats[1] = residual

