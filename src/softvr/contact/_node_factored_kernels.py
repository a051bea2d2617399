"""Compiled parts of the factored contact solve (:mod:`softvr.contact.node_factored`): the
nodes' rotations since the factorization, the residual of the momentum equation of thesis eq.
5.2 over the node blocks turned back by them and the update turned forward, the triangular
solves with the kept factorization's 3 x 3 blocks, and projected Gauss-Seidel on a small
dense Delassus matrix (thesis eq. 5.5's LCP in the contacts' impulses).

Residual of solved node ``i`` (row ``k``), turned by its rotation ``R_i``:

    r_k = R_i^T (b_i - sum_j A_ij v_j)                               [kg m/s]

PGS on ``W`` (3 m x 3 m, contact frames: normal, tangent 1, tangent 2) from the contacts'
relative velocities ``u`` [m/s] without the impulses:

    rel_c = u_c + sum_d W_cd lambda_d,   lambda_c <- pgs_update(lambda_c, rel_c, W_cc)

the same projection (normal target ``-gap / dt``, friction disc, adhesive bounds) as the node
sweeps' contacts (:func:`softvr.contact._node_jacobi_kernels.pgs_update`).
"""

from __future__ import annotations

from typing import Any

import warp as wp

from softvr.contact._node_jacobi_kernels import pgs_update


@wp.kernel
def node_rotations(force_start: wp.array(dtype=wp.int32), force: wp.array(dtype=wp.int32),
                   tet_weight: wp.array(dtype=wp.float64), tet_rotation: wp.array(dtype=wp.mat33d),
                   solved: wp.array(dtype=wp.int32), rotation0: wp.array(dtype=wp.mat33d), polar_iterations: int,
                   absolute: wp.array(dtype=wp.mat33d), relative: wp.array(dtype=wp.mat33d), offset: int):
    """Solved node ``i = solved[k]``'s rotation: the polar part of its tets' co-rotations
    ``R_e`` summed by their stiffness ``tet_weight`` [N/m] (``force[c] = 4 tet + a`` for ``c``
    in ``force_start[i] : force_start[i + 1]``; Muller and Gross's stiffness warping) into
    ``absolute[k]``, and turned back by the factorization's ``rotation0[k]``: ``relative[i] =
    absolute[k] rotation0[k]^T``. Newton's iteration ``X <- (X + X^-T) / 2`` from the sum
    scaled to unit determinant (the sums are near rotations; P needs R to a few digits)."""
    k = wp.tid() + offset
    i = solved[k]
    x = wp.mat33d()
    for c in range(force_start[i], force_start[i + 1]):
        e = force[c] // 4
        x = x + tet_weight[e] * tet_rotation[e]
    det = wp.determinant(x)
    scale = wp.pow(wp.abs(det), wp.float64(1.0) / wp.float64(3.0))
    if det < wp.float64(0.0):
        scale = -scale
    x = x / scale
    for _ in range(polar_iterations):
        x = wp.float64(0.5) * (x + wp.transpose(wp.inverse(x)))
    absolute[k] = x
    relative[i] = x * wp.transpose(rotation0[k])


@wp.kernel
def turned_residual(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                    blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d), solved: wp.array(dtype=wp.int32),
                    rotation: wp.array(dtype=wp.mat33d), v: wp.array(dtype=wp.vec3d), r: wp.array(dtype=wp.vec3d),
                    offset: int):
    """``r_k = R_i^T (b_i - sum_j A_ij v_j)`` [kg m/s] of solved node ``i = solved[k]``: eq.
    5.2's residual turned back by the node's rotation since the factorization."""
    k = wp.tid() + offset
    i = solved[k]
    acc = b[i]
    for c in range(row_start[i], row_start[i + 1]):
        acc = acc - blocks[c] * v[block_col[c]]
    r[k] = wp.transpose(rotation[i]) * acc


@wp.kernel
def turned_update(index: wp.array(dtype=wp.int32), rotation: wp.array(dtype=wp.mat33d), v: wp.array(dtype=wp.vec3d),
                  y: wp.array(dtype=wp.vec3d), u: wp.array(dtype=wp.vec3d), offset: int):
    """``u_i = v_i + R_i y_k`` [m/s] of node ``i``, ``k = index[i]`` its row among the solved
    nodes (``u_i = v_i`` on a node not solved: ``k < 0``)."""
    i = wp.tid() + offset
    k = index[i]
    if k < 0:
        u[i] = v[i]
    else:
        u[i] = v[i] + rotation[i] * y[k]


@wp.func
def _entry(x: wp.array(dtype=Any), i: int):
    """Entry ``i`` of ``x`` read as a flat vector [3 len(x)] (vec3d: a number; mat33d: a row,
    the entry's value in each of three right-hand sides)."""
    return x[i // 3][i % 3]


@wp.func
def _stack(a: wp.float64, b: wp.float64, c: wp.float64) -> wp.vec3d:
    """Three flat entries as one block."""
    return wp.vec3d(a, b, c)


@wp.func
def _stack(a: wp.vec3d, b: wp.vec3d, c: wp.vec3d) -> wp.mat33d:
    """Three flat entries of three right-hand sides as one block (rows: the entries)."""
    return wp.matrix_from_rows(a, b, c)


@wp.kernel
def factor_solve(perm_r_inverse: wp.array(dtype=wp.int32), perm_c: wp.array(dtype=wp.int32),
                 lower_start: wp.array(dtype=wp.int32), lower_col: wp.array(dtype=wp.int32),
                 lower: wp.array(dtype=wp.mat33d), lower_inverse: wp.array(dtype=wp.mat33d),
                 upper_start: wp.array(dtype=wp.int32), upper_col: wp.array(dtype=wp.int32),
                 upper: wp.array(dtype=wp.mat33d), upper_inverse: wp.array(dtype=wp.mat33d),
                 rhs: wp.array(dtype=Any), work: wp.array(dtype=Any), x: wp.array(dtype=Any)):
    """``x = A^-1 rhs`` (one thread; vec3d: one right-hand side, mat33d: three, its columns)
    with SuperLU's ``Pr A Pc = L U`` held as 3 x 3 blocks of the factors' rows (``work``'s
    order): ``lower`` / ``upper`` the blocks off the diagonal (block row ``p``: ``start[p] :
    start[p + 1]``, block columns ``col``), ``*_inverse`` the inverses of the diagonal blocks;
    ``perm_r_inverse`` the inverse of ``Pr``'s ``perm_r``, ``perm_c`` ``Pc``'s, over the flat
    entries. Block rows run at SciPy's CSR product speed; SuperLU's own single-vector solve
    spends ~2/3 of its time in BLAS calls per supernode."""
    k = work.shape[0]
    for p in range(k):  # forward: L w = Pr rhs
        acc = _stack(_entry(rhs, perm_r_inverse[3 * p]), _entry(rhs, perm_r_inverse[3 * p + 1]),
                     _entry(rhs, perm_r_inverse[3 * p + 2]))
        for c in range(lower_start[p], lower_start[p + 1]):
            acc = acc - lower[c] * work[lower_col[c]]
        work[p] = lower_inverse[p] * acc
    for t in range(k):  # backward: U w' = w
        p = k - 1 - t
        acc = work[p]
        for c in range(upper_start[p], upper_start[p + 1]):
            acc = acc - upper[c] * work[upper_col[c]]
        work[p] = upper_inverse[p] * acc
    for i in range(k):  # x = Pc w'
        x[i] = _stack(_entry(work, perm_c[3 * i]), _entry(work, perm_c[3 * i + 1]), _entry(work, perm_c[3 * i + 2]))


for _t in (wp.vec3d, wp.mat33d):
    wp.overload(factor_solve, {"rhs": wp.array(dtype=_t), "work": wp.array(dtype=_t), "x": wp.array(dtype=_t)})


@wp.kernel
def warp_change(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                blocks: wp.array(dtype=wp.mat33d), blocks0: wp.array(dtype=wp.mat33d),
                rotation: wp.array(dtype=wp.mat33d), solved: wp.array(dtype=wp.int32),
                change: wp.array(dtype=wp.float64), offset: int):
    """How far node ``i``'s row of ``A`` [kg] is from the factored ``A_0`` turned to the nodes'
    rotations ``R`` (``rotation`` [n], since the factorization): the largest Frobenius norm of
    ``R_i^T A_ij R_j - A0_ij`` over the solved nodes ``j``, over that of ``A0_ii``; 0 on a node
    not solved."""
    i = wp.tid() + offset
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
