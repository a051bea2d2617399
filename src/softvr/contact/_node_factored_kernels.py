"""Compiled parts of the factored contact solve (:mod:`softvr.contact.node_factored`): the
residual of the momentum equation of thesis eq. 5.2 over the node blocks, and projected
Gauss-Seidel on a small dense Delassus matrix (thesis eq. 5.5's LCP in the contacts' impulses).

Residual of node ``i`` (free nodes; a fixed node's is 0):

    r_i = b_i - sum_j A_ij v_j                                       [kg m/s]

PGS on ``W`` (3 m x 3 m, contact frames: normal, tangent 1, tangent 2) from the contacts'
relative velocities ``u`` [m/s] without the impulses:

    rel_c = u_c + sum_d W_cd lambda_d,   lambda_c <- pgs_update(lambda_c, rel_c, W_cc)

the same projection (normal target ``-gap / dt``, friction disc, adhesive bounds) as the node
sweeps' contacts (:func:`softvr.contact._node_jacobi_kernels.pgs_update`).
"""

from __future__ import annotations

import warp as wp

from softvr.contact._node_jacobi_kernels import pgs_update


@wp.kernel
def momentum_residual(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                      blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
                      v: wp.array(dtype=wp.vec3d), r: wp.array(dtype=wp.vec3d), offset: int):
    """``r_i = b_i - sum_j A_ij v_j`` [kg m/s] of node ``i`` (``tid + offset``); 0 on a fixed node."""
    i = wp.tid() + offset
    if fixed[i] != 0:
        r[i] = wp.vec3d()
        return
    acc = b[i]
    for k in range(row_start[i], row_start[i + 1]):
        acc = acc - blocks[k] * v[block_col[k]]
    r[i] = acc


@wp.kernel
def warp_change(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                blocks: wp.array(dtype=wp.mat33d), blocks0: wp.array(dtype=wp.mat33d),
                rotation: wp.array(dtype=wp.mat33d), solved: wp.array(dtype=wp.int32),
                change: wp.array(dtype=wp.float64)):
    """How far node ``i``'s row of ``A`` [kg] is from the factored ``A_0`` turned to the nodes'
    rotations ``R`` (``rotation`` [n], since the factorization): the largest Frobenius norm of
    ``R_i^T A_ij R_j - A0_ij`` over the solved nodes ``j``, over that of ``A0_ii``; 0 on a node
    not solved."""
    i = wp.tid()
    change[i] = wp.float64(0.0)
    if solved[i] == 0:
        return
    ri = wp.transpose(rotation[i])
    worst = wp.float64(0.0)
    own = wp.float64(0.0)
    for k in range(row_start[i], row_start[i + 1]):
        j = block_col[k]
        if j == i:
            own = wp.ddot(blocks0[k], blocks0[k])
        if solved[j] != 0:
            d = ri * blocks[k] * rotation[j] - blocks0[k]
            worst = wp.max(worst, wp.ddot(d, d))
    if own > wp.float64(0.0):
        change[i] = wp.sqrt(worst / own)


@wp.func
def _block(w: wp.array2d(dtype=wp.float64), c: int, d: int) -> wp.mat33d:
    """Block (c, d) [1/kg] of the dense ``w``."""
    return wp.mat33d(w[3 * c, 3 * d], w[3 * c, 3 * d + 1], w[3 * c, 3 * d + 2],
                     w[3 * c + 1, 3 * d], w[3 * c + 1, 3 * d + 1], w[3 * c + 1, 3 * d + 2],
                     w[3 * c + 2, 3 * d], w[3 * c + 2, 3 * d + 1], w[3 * c + 2, 3 * d + 2])


@wp.kernel
def dense_pgs(contacts: wp.array(dtype=wp.int32), w: wp.array2d(dtype=wp.float64), u: wp.array(dtype=wp.vec3d),
              frame: wp.array(dtype=wp.mat33d), gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
              stiffness: wp.array(dtype=wp.float64), slip: wp.array(dtype=wp.vec3d), dt: wp.float64, passes: int,
              tolerance: wp.float64, impulse: wp.array(dtype=wp.vec3d), rel: wp.array(dtype=wp.vec3d),
              done: wp.array(dtype=wp.int32)):
    """Up to ``passes`` PGS passes (one thread, contacts in order) over ``count = contacts[0]``
    contacts on the Delassus matrix ``w`` (its first 3 count rows and columns) [1/kg], from the impulses ``impulse`` [count] [N s]
    (frame) and the relative velocities without them ``u`` [count] [m/s] (frame); stops after a
    pass that moved no contact's velocity by more than ``tolerance`` [m/s]. ``rel`` [count]
    [m/s] ends as ``u + W lambda``; ``done[0]`` the passes made."""
    count = contacts[0]
    for c in range(count):
        acc = u[c]
        for d in range(count):
            acc = acc + _block(w, c, d) * impulse[d]
        rel[c] = acc
    made = int(0)
    for _ in range(passes):
        made = made + 1
        worst = wp.float64(0.0)
        for c in range(count):
            w_cc = _block(w, c, c)
            old = impulse[c]
            lam = pgs_update(old, rel[c], w_cc, frame[c], gap[c], dt, friction[c], stiffness[c], slip[c])
            step = lam - old
            if step[0] != wp.float64(0.0) or step[1] != wp.float64(0.0) or step[2] != wp.float64(0.0):
                impulse[c] = lam
                for d in range(count):
                    rel[d] = rel[d] + _block(w, d, c) * step
                moved = w_cc * step
                worst = wp.max(worst, wp.max(wp.abs(moved[0]), wp.max(wp.abs(moved[1]), wp.abs(moved[2]))))
        if worst <= tolerance:
            break
    done[0] = made
