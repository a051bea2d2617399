"""The node update of a multicolour symmetric block Gauss-Seidel sweep of thesis eq. 5.6 (in
place of its outer Jacobi; :mod:`softvr.contact._node_jacobi_kernels` has the contact PGS and
the Chebyshev step, which are shared). One launch per colour, the colours forward then
backward (the last colour once); one source for CPU and CUDA.

A sweep from ``v^k`` with the contact impulses ``lambda`` of the last sweep, on the work
array ``w`` (set to ``v^k`` first), for the nodes i of colour c (no block couples two nodes of
one colour):

    w_i = D_i^-1 (b_i + (J^T lambda)_i - sum_{j != i} A_ij w_j)

so its fixed point solves ``A v = b + J^T lambda``. The iteration operator is
``I - M^-1 A`` with ``M = (D + L) D^-1 (D + U)`` (L, U the block triangles of ``A`` in colour
order): M is symmetric positive definite, M^-1 A has its spectrum in (0, 1], which the
Chebyshev weights need. ``D_i^-1 (J^T lambda)_i`` is not scattered from the contacts: it is what
the contact kernel added to the last sweep's output (``v_hat - v_pre``: the kernel applies
``D_A^-1 J^T lambda`` to the node update it is given), read back per node.
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def start(v: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), offset: int):
    """``w = v`` [m/s]: the sweep's work array starts at its velocities."""
    i = wp.tid() + offset
    w[i] = v[i]


@wp.kernel
def gauss_seidel(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                 blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                 fixed: wp.array(dtype=wp.int32), fixed_velocity: wp.array(dtype=wp.vec3d),
                 order: wp.array(dtype=wp.int32), first: int, last: int, w: wp.array(dtype=wp.vec3d),
                 v_hat: wp.array(dtype=wp.vec3d), v_pre: wp.array(dtype=wp.vec3d), offset: int):
    """Update ``w`` [m/s] (neighbours not yet updated in the sweep hold its starting
    velocities) of the nodes ``order[first + t]`` of one colour; on the node's ``last`` update
    of the sweep, ``v_hat`` and ``v_pre`` [m/s] get the update without its contact term (the
    contact kernel adds it back to ``v_hat``)."""
    i = order[first + wp.tid() + offset]
    local = v_hat[i] - v_pre[i]
    if fixed[i] != 0:
        w[i] = fixed_velocity[i]
        if last != 0:
            v_hat[i] = fixed_velocity[i]
            v_pre[i] = fixed_velocity[i]
        return
    r = b[i]
    for k in range(row_start[i], row_start[i + 1]):
        j = block_col[k]
        if j != i:
            r = r - blocks[k] * w[j]
    update = d_inv[i] * r
    w[i] = update + local
    if last != 0:
        v_hat[i] = update
        v_pre[i] = update
