"""The node update of a multicolour symmetric block Gauss-Seidel sweep of thesis eq. 5.6 (in
place of its outer Jacobi; :mod:`softvr.contact._node_jacobi_kernels` has the contact PGS and
the Chebyshev step, which are shared). One source for CPU and CUDA.

A sweep from ``v^k`` on the work array ``w`` (set to ``v^k`` first), with the nodes in some
contact's stencil ("contact nodes") set apart:

    1. colours 0 .. C-1, the free nodes i of each that are not contact nodes (no block couples
       two nodes of one colour):  w_i = D_i^-1 (b_i - sum_{j != i} A_ij w_j)
    2. the contact nodes, damped Jacobi on the swept neighbours:
       v^_i = (1 - omega) v^k_i + omega D_i^-1 (b_i - sum_{j != i} A_ij w_j)
    3. the contact PGS (shared kernel, metric omega D_A^-1) projects v^ of the contact nodes;
       w_i = v^_i there
    4. colours C-1 .. 0 again (backward), v^_i = w_i

A contact "sleeps" (its nodes are not contact nodes, so they take the Gauss-Seidel update) while
it has no impulse, a gap, and its normal velocity at the step's start closes at most half the
gap over the step: most of a step's contacts are speculative ones that stay apart, and the
damped Jacobi update of their nodes was the slowest part of the sweeps (the shoulder's thin
labrum tendon, 22 of its 28 nodes in some contact that never pushed: 65 sweeps a decade). If
the PGS gives a sleeping contact an impulse, every contact is woken, the nodes marked, and the
Chebyshev iteration restarted (:meth:`softvr.contact.node_gauss_seidel.GaussSeidelSweep.wake`).

Its fixed point solves ``A v = b + J^T lambda`` with lambda complementary, and the update that
the PGS projects does not depend on last sweep's impulses (only on ``v^k``), so the Chebyshev
step over ``v`` alone is sound, as with Jacobi. Without contacts the sweep is symmetric block
Gauss-Seidel: error operator ``I - M^-1 A`` with ``M = (D + L) D^-1 (D + U)`` (L, U the block
triangles in colour order; M^-1 A has its spectrum in (0, 1]). With contacts it is
``F^* S F`` (F the forward half, ``F^*`` its A-adjoint the backward half, S the damped Jacobi
step of the contact nodes): with ``omega <= 1 / lambda_max(D_A^-1 A)``, S has its spectrum in
[0, 1), so M^-1 A still has none above 1, which the Chebyshev weights need.
"""

from __future__ import annotations

import warp as wp

from softvr.contact._node_jacobi_kernels import block_update


@wp.kernel
def start(v: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), offset: int):
    """``w = v`` [m/s]: the sweep's work array starts at its velocities."""
    i = wp.tid() + offset
    w[i] = v[i]


@wp.func
def _off_row(t: int, i: int, off_start: wp.array(dtype=wp.int32), off_col: wp.array(dtype=wp.int32),
             off_blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d)):
    """``b_i - sum_{j != i} A_ij w_j`` [kg m/s] of node ``i``, the ``t``-th in colour order,
    from the colour-ordered copy of its off-diagonal blocks: the same terms in the same order
    as :func:`softvr.contact._node_jacobi_kernels.block_update` takes them from ``A``'s rows,
    so the same sum to the bit, but read one after the other and with no test per block."""
    r = b[i]
    for k in range(off_start[t], off_start[t + 1]):
        r = r - off_blocks[k] * w[off_col[k]]
    return r


@wp.kernel
def gather_off_blocks(blocks: wp.array(dtype=wp.mat33d), off_source: wp.array(dtype=wp.int32),
                      off_blocks: wp.array(dtype=wp.mat33d)):
    """``off_blocks[k] = blocks[off_source[k]]`` [kg]: this step's off-diagonal blocks of ``A``
    in colour order (once a step, before the sweeps)."""
    k = wp.tid()
    off_blocks[k] = blocks[off_source[k]]


@wp.kernel
def gauss_seidel(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                 blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                 partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                 fixed: wp.array(dtype=wp.int32), fixed_velocity: wp.array(dtype=wp.vec3d),
                 contact_node: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32),
                 off_start: wp.array(dtype=wp.int32), off_col: wp.array(dtype=wp.int32),
                 off_blocks: wp.array(dtype=wp.mat33d), first: int, last: int, w: wp.array(dtype=wp.vec3d),
                 v_hat: wp.array(dtype=wp.vec3d), offset: int):
    """Steps 1 and 4: update ``w`` [m/s] of the nodes ``order[first + t]`` of one colour that
    are not contact nodes (neighbours not yet updated hold the sweep's start); on their
    ``last`` update of the sweep, ``v_hat`` [m/s] too. A node without a pair partner reads its
    row from the colour-ordered off-diagonal copy (``off_*``, :func:`gather_off_blocks`)."""
    t = first + wp.tid() + offset
    i = order[t]
    if contact_node[i] != 0:
        return
    value = fixed_velocity[i]
    if fixed[i] == 0:
        if partner[i] >= 0:
            value = block_update(i, row_start, block_col, blocks, d_inv, partner, cross, b, w)
        else:
            value = d_inv[i] * _off_row(t, i, off_start, off_col, off_blocks, b, w)
    w[i] = value
    if last != 0:
        v_hat[i] = value


@wp.kernel
def contact_nodes(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                  blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                  partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                  fixed: wp.array(dtype=wp.int32), fixed_velocity: wp.array(dtype=wp.vec3d),
                  contact_node: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32),
                  off_start: wp.array(dtype=wp.int32), off_col: wp.array(dtype=wp.int32),
                  off_blocks: wp.array(dtype=wp.mat33d), omega: wp.float64, v: wp.array(dtype=wp.vec3d),
                  w: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d), offset: int):
    """Step 2: the damped Jacobi update ``v_hat`` [m/s] of the contact nodes (``order[t]``,
    thread t) from the sweep's start ``v`` and the swept ``w`` [m/s]."""
    t = wp.tid() + offset
    i = order[t]
    if contact_node[i] == 0:
        return
    if fixed[i] != 0:
        v_hat[i] = fixed_velocity[i]
        return
    update = wp.vec3d()
    if partner[i] >= 0:
        update = block_update(i, row_start, block_col, blocks, d_inv, partner, cross, b, w)
    else:
        update = d_inv[i] * _off_row(t, i, off_start, off_col, off_blocks, b, w)
    v_hat[i] = (wp.float64(1.0) - omega) * v[i] + omega * update


@wp.kernel
def projected(contact_node: wp.array(dtype=wp.int32), v_hat: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d),
              offset: int):
    """Step 3's ``w_i = v^_i`` [m/s] at the contact nodes."""
    i = wp.tid() + offset
    if contact_node[i] != 0:
        w[i] = v_hat[i]


@wp.kernel
def mark_contact_nodes(count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
                       stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                       frame: wp.array(dtype=wp.mat33d), gap: wp.array(dtype=wp.float64),
                       rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
                       impulse: wp.array(dtype=wp.vec3d), stiffness: wp.array(dtype=wp.float64),
                       v: wp.array(dtype=wp.vec3d), dt: wp.float64, share: wp.float64, wake_all: int,
                       contact_node: wp.array(dtype=wp.int32), asleep: wp.array(dtype=wp.int32)):
    """``contact_node[i] = 1`` for the nodes contact ``c``'s impulse moves (its stencil and its
    rigid sides' angular nodes, -1: none) unless the contact sleeps: ``asleep[c] = 1`` where it
    has no impulse, no adhesion (``stiffness`` 0), a gap > 0 [m], and its normal velocity in the
    step's start velocities ``v`` [m/s] closes at most ``share`` of that gap in ``dt`` [s]
    (``wake_all``: none sleeps). One thread per contact slot, the first ``count[0]`` used;
    ``contact_node`` zeroed before (or left as it is, to mark more)."""
    c = wp.tid()
    if c >= count[0]:
        return
    sleeps = int(0)
    lam = impulse[c]
    if wake_all == 0 and gap[c] > wp.float64(0.0) and stiffness[c] == wp.float64(0.0) and \
            lam[0] == wp.float64(0.0) and lam[1] == wp.float64(0.0) and lam[2] == wp.float64(0.0):
        rel = wp.vec3d()
        for k in range(stencil_count[c]):
            rel = rel + stencil_weights[c, k] * v[stencil_nodes[c, k]]
        for s in range(rigid_node.shape[1]):
            if rigid_node[c, s] >= 0:
                rel = rel + wp.cross(v[rigid_node[c, s]], rigid_lever[c, s])
        normal = wp.vec3d(frame[c][0, 0], frame[c][0, 1], frame[c][0, 2])
        if wp.dot(normal, rel) * dt >= -share * gap[c]:
            sleeps = 1
    asleep[c] = sleeps
    if sleeps != 0:
        return
    for k in range(stencil_count[c]):
        contact_node[stencil_nodes[c, k]] = 1
    for s in range(rigid_node.shape[1]):
        if rigid_node[c, s] >= 0:
            contact_node[rigid_node[c, s]] = 1


@wp.kernel
def woken(count: wp.array(dtype=wp.int32), asleep: wp.array(dtype=wp.int32), impulse: wp.array(dtype=wp.vec3d),
          flag: wp.array(dtype=wp.int32)):
    """``flag[0] = 1`` if a sleeping contact (``asleep``) has taken an impulse [N s] (one thread)."""
    out = int(0)
    for c in range(count[0]):
        lam = impulse[c]
        if asleep[c] != 0 and (lam[0] != wp.float64(0.0) or lam[1] != wp.float64(0.0) or lam[2] != wp.float64(0.0)):
            out = 1
            break
    flag[0] = out


@wp.kernel
def scale(d_inv: wp.array(dtype=wp.mat33d), cross: wp.array(dtype=wp.mat33d), omega: wp.float64,
          out: wp.array(dtype=wp.mat33d), out_cross: wp.array(dtype=wp.mat33d)):
    """``out = omega D_A^-1`` [1/kg]: the contact PGS's metric for damped contact nodes (its
    diagonal blocks ``d_inv``, and ``cross`` the off-diagonal ones of spring-held rigid bodies'
    6x6 blocks)."""
    i = wp.tid()
    out[i] = omega * d_inv[i]
    out_cross[i] = omega * cross[i]
