"""Compiled parts of the factored contact solve with rigid sides
(:mod:`softvr.contact.node_factored_rigid`): the contacts' Delassus matrix (thesis eq. 5.5)

    W_cd = sum_s sum_t B_cs X_{n(c,s) n(t,d)} B_dt^T                 [1/kg]

over each contact's slots ``s`` (its stencil's nodes and its rigid sides' angular nodes that
the solve moves), ``B_cs`` the slot's block of ``J R`` (frame rows) and ``X`` the 3 x 3 blocks
of ``R^T P^-1 R`` between the touched nodes (the kept columns of ``A_0^-1``, Woodbury's
correction applied); and the outer iteration's steps between the triangular solves (the
contacts' velocities, the impulses' right-hand side, the update with Anderson's step), so that
an iteration is a fixed sequence of replayed launches with no NumPy between them. Each is one
thread (a few hundred microseconds of work at most; no dense product through NumPy's BLAS,
whose threads spin on a loaded machine).
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def delassus(sizes: wp.array(dtype=wp.int32), slot_node: wp.array2d(dtype=wp.int32),
             slot_block: wp.array2d(dtype=wp.mat33d), inverse: wp.array2d(dtype=wp.float64),
             half: wp.array2d(dtype=wp.mat33d), w: wp.array2d(dtype=wp.float64)):
    """``w`` [3 m, 3 m] [1/kg] over ``m = sizes[2]`` contacts and ``u = sizes[1] / 3`` touched
    nodes, one thread: block (c, d) is ``sum_s sum_t slot_block[c, s] X slot_block[d, t]^T``
    with ``X`` the block of ``inverse`` [3 u, 3 u] [1/kg] at touched nodes ``slot_node[c, s]``,
    ``slot_node[d, t]`` (-1: an unused slot), through ``half[c, q] = sum_s slot_block[c, s]
    X_{slot_node[c, s] q}`` [m, u] (a product a slot and node, not a slot pair and contact pair)."""
    m = sizes[2]
    touched = sizes[1] // 3
    for c in range(m):
        for q in range(touched):
            acc = wp.mat33d()
            for s in range(slot_node.shape[1]):
                p = slot_node[c, s]
                if p >= 0:
                    x = wp.mat33d()
                    for i in range(3):
                        for j in range(3):
                            x[i, j] = inverse[3 * p + i, 3 * q + j]
                    acc = acc + slot_block[c, s] * x
            half[c, q] = acc
    for c in range(m):
        for d in range(m):
            acc = wp.mat33d()
            for t in range(slot_node.shape[1]):
                q = slot_node[d, t]
                if q >= 0:
                    acc = acc + half[c, q] * wp.transpose(slot_block[d, t])
            for i in range(3):
                for j in range(3):
                    w[3 * c + i, 3 * d + j] = acc[i, j]


@wp.func
def _dof(y: wp.array(dtype=wp.vec3d), d: int) -> wp.float64:
    """Entry ``d`` of the flat velocities ``y`` (``3 row + component``)."""
    return y[d // 3][d % 3]


@wp.func
def _woodbury(s_count: int, local_t: wp.array2d(dtype=wp.float64), local_dofs: wp.array(dtype=wp.int32),
              y: wp.array(dtype=wp.vec3d), z: wp.array(dtype=wp.float64)):
    """Woodbury's weights ``z = T y[local_dofs]`` [3 s] of the local correction's columns."""
    for i in range(s_count):
        acc = wp.float64(0.0)
        for j in range(s_count):
            acc = acc + local_t[i, j] * _dof(y, local_dofs[j])
        z[i] = acc


@wp.kernel
def contact_velocity(sizes: wp.array(dtype=wp.int32), local_dofs: wp.array(dtype=wp.int32),
                     local_t: wp.array2d(dtype=wp.float64), dofs: wp.array(dtype=wp.int32),
                     near: wp.array2d(dtype=wp.float64), y: wp.array(dtype=wp.vec3d),
                     slot_node: wp.array2d(dtype=wp.int32), node: wp.array2d(dtype=wp.int32),
                     block: wp.array2d(dtype=wp.mat33d), slot_block: wp.array2d(dtype=wp.mat33d),
                     v: wp.array(dtype=wp.vec3d), z: wp.array(dtype=wp.float64), at: wp.array(dtype=wp.float64),
                     u: wp.array(dtype=wp.vec3d)):
    """The contacts' velocities without this iteration's impulses ``u_c = J_c v + J_c P^-1 r``
    [m/s] (frames), one thread: ``P^-1 r`` at the touched nodes turned back, ``at = y[dofs] -
    near^T T y[local_dofs]`` [3 u] (Woodbury's correction, ``z = T y[local_dofs]`` [3 s]), with
    ``y = A_0^-1 R^T r`` [k], ``near`` [3 s, 3 u] and ``T`` [3 s, 3 s] [1/kg]; then per contact
    and slot ``block`` (``J``'s block, frames) on ``v[node]`` and ``slot_block`` (``J R``) on
    ``at`` at touched node ``slot_node`` (-1: none). ``sizes``: 3 s, 3 u, contacts."""
    s_count = sizes[0]
    u_count = sizes[1]
    _woodbury(s_count, local_t, local_dofs, y, z)
    for e in range(u_count):
        acc = _dof(y, dofs[e])
        for i in range(s_count):
            acc = acc - near[i, e] * z[i]
        at[e] = acc
    for c in range(sizes[2]):
        rel = wp.vec3d()
        for s in range(node.shape[1]):
            rel = rel + block[c, s] * v[node[c, s]]
            p = slot_node[c, s]
            if p >= 0:
                rel = rel + slot_block[c, s] * wp.vec3d(at[3 * p], at[3 * p + 1], at[3 * p + 2])
        u[c] = rel


@wp.kernel
def impulse_push(sizes: wp.array(dtype=wp.int32), dofs: wp.array(dtype=wp.int32),
                 slot_node: wp.array2d(dtype=wp.int32), slot_block: wp.array2d(dtype=wp.mat33d),
                 impulse: wp.array(dtype=wp.vec3d), rhs: wp.array(dtype=wp.vec3d)):
    """``rhs = R^T J^T lambda`` [N s] at the touched nodes' rows (``dofs``, 3 a node), one
    thread: the sum over contacts and slots of ``slot_block^T impulse`` (frames). The other rows
    are left as they are (zero)."""
    for p in range(sizes[1] // 3):
        rhs[dofs[3 * p] // 3] = wp.vec3d()
    for c in range(sizes[2]):
        for s in range(slot_node.shape[1]):
            p = slot_node[c, s]
            if p >= 0:
                row = dofs[3 * p] // 3
                rhs[row] = rhs[row] + wp.transpose(slot_block[c, s]) * impulse[c]


@wp.kernel
def outer_update(sizes: wp.array(dtype=wp.int32), local_dofs: wp.array(dtype=wp.int32),
                 local_t: wp.array2d(dtype=wp.float64), local_columns: wp.array2d(dtype=wp.float64),
                 index: wp.array(dtype=wp.int32), rotation: wp.array(dtype=wp.mat33d),
                 weight: wp.array(dtype=wp.vec3d), y: wp.array(dtype=wp.vec3d), y2: wp.array(dtype=wp.vec3d),
                 z: wp.array(dtype=wp.float64), v: wp.array(dtype=wp.vec3d), u: wp.array(dtype=wp.vec3d),
                 last_f: wp.array(dtype=wp.vec3d), last_g: wp.array(dtype=wp.vec3d),
                 df: wp.array2d(dtype=wp.vec3d), dg: wp.array2d(dtype=wp.vec3d), gram: wp.array2d(dtype=wp.float64),
                 system: wp.array2d(dtype=wp.float64), gamma: wp.array(dtype=wp.float64),
                 ring: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.float64)):
    """The end of an outer iteration, one thread: ``y += y2`` (the impulses' response, where
    ``sizes[2]`` contacts), Woodbury's ``y -= C_S T y[local_dofs]`` (``local_columns`` [3 k, 3
    s] the columns of ``A_0^-1`` at ``S``), ``u = v + R y`` [m/s] (``index``: node -> row, -1
    not solved), ``out[0]`` the largest ``|u - v|`` times ``weight`` [m/s] (``out[1]`` 1 where
    any is not finite), and ``v`` the next iterate of Anderson acceleration (type II, memory
    ``df.shape[0]``: :class:`softvr.contact.node_factored._Anderson`, the same arithmetic) of
    ``v <- u``; ``ring`` [3]: started, iterates remembered, next row of ``df`` and ``dg``."""
    k = y.shape[0]
    if sizes[2] > 0:
        for r in range(k):
            y[r] = y[r] + y2[r]
    s_count = sizes[0]
    if s_count > 0:
        _woodbury(s_count, local_t, local_dofs, y, z)
        for r in range(k):
            d = wp.vec3d()
            for c in range(3):
                acc = wp.float64(0.0)
                for i in range(s_count):
                    acc = acc + local_columns[3 * r + c, i] * z[i]
                d[c] = acc
            y[r] = y[r] - d
    change = wp.float64(0.0)
    bad = wp.float64(0.0)
    for i in range(v.shape[0]):
        row = index[i]
        if row < 0:
            u[i] = v[i]
        else:
            u[i] = v[i] + rotation[i] * y[row]
        step = wp.cw_mul(u[i] - v[i], weight[i])
        for c in range(3):
            a = wp.abs(step[c])
            if not wp.isfinite(a):
                bad = wp.float64(1.0)
            elif a > change:
                change = a
    out[0] = change
    out[1] = bad
    memory = df.shape[0]
    if ring[0] == 0:
        for i in range(v.shape[0]):
            last_f[i] = u[i] - v[i]
            last_g[i] = u[i]
            v[i] = u[i]
        ring[0] = 1
        return
    s = ring[2]
    for i in range(v.shape[0]):
        f = u[i] - v[i]
        df[s, i] = f - last_f[i]
        dg[s, i] = u[i] - last_g[i]
        last_f[i] = f
        last_g[i] = u[i]
    ring[2] = (s + 1) % memory
    count = wp.min(ring[1] + 1, memory)
    ring[1] = count
    for j in range(count):
        acc = wp.float64(0.0)
        rhs = wp.float64(0.0)
        for i in range(v.shape[0]):
            acc = acc + wp.dot(df[j, i], df[s, i])
            rhs = rhs + wp.dot(df[j, i], last_f[i])
        gram[s, j] = acc
        gram[j, s] = acc
        system[j, count] = rhs
    # A repeated residual leaves the Gram matrix singular; one that did not change at all, zero
    # on its diagonal (its gamma then 0): the same regularization as _Anderson's.
    for j in range(count):
        for q in range(count):
            system[j, q] = gram[j, q]
        system[j, j] = gram[j, j] * wp.float64(1.0 + 1.0e-10) + wp.float64(2.2250738585072014e-308)
    for col in range(count):  # Gaussian elimination, partial pivoting
        pivot = col
        for j in range(col + 1, count):
            if wp.abs(system[j, col]) > wp.abs(system[pivot, col]):
                pivot = j
        if pivot != col:
            for q in range(count + 1):
                t = system[col, q]
                system[col, q] = system[pivot, q]
                system[pivot, q] = t
        for j in range(col + 1, count):
            factor = system[j, col] / system[col, col]
            for q in range(col, count + 1):
                system[j, q] = system[j, q] - factor * system[col, q]
    for col in range(count - 1, -1, -1):
        acc = system[col, count]
        for q in range(col + 1, count):
            acc = acc - system[col, q] * gamma[q]
        gamma[col] = acc / system[col, col]
    for i in range(v.shape[0]):
        nxt = u[i]
        for j in range(count):
            nxt = nxt - gamma[j] * dg[j, i]
        v[i] = nxt
