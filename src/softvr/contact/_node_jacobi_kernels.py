"""Compiled sweeps of thesis eq. 5.6 over the nodes of a whole scene: an outer Jacobi iteration
over the velocities with D_A the 3x3 diagonal node blocks of A, an inner projected Gauss-Seidel
over the contacts with B = J D_A^-1 J^T, and Chebyshev acceleration of the outer iteration.

One sweep k, for every free node i (fixed nodes keep their prescribed velocity):

    v^_i  = D_i^-1 (b_i - sum_{j != i} A_ij v_j^k)            (eq. 5.6: L_A + U_A on the right)
    v^   += D_A^-1 J^T lambda, lambda <- PGS on 0 <= lambda _|_ J v^ - c >= 0 (friction: the disc)
    v^k+1 = omega_k (gamma (v^ - v^k) + v^k - v^k-1) + v^k-1              (Chebyshev)

Plain Jacobi (omega = gamma = 1) converges on FEM step matrices (spectral radius of D_A^-1
(L_A + U_A) below 1 there: 0.96 on the contact bench's cube) but needs ~190 sweeps for 1e-5 m/s;
the Chebyshev semi-iteration over the spectrum [lo, hi] of D_A^-1 A (gamma = 2 / (lo + hi),
rho = (hi - lo) / (hi + lo), omega_k by the recurrence in :func:`chebyshev_weights`) needs 30-40
(docs/physics-core.md). Each contact touches the nodes of its stencil (up to 16 nodes with
weights: a point's, minus a triangle's for a contact between two bodies, each node once); the
per-contact PGS update is local, so the inner loop costs O(contacts) per sweep.
"""

from __future__ import annotations

import warp as wp

from softvr.contact._adhesion_kernels import adhesive_bound
from softvr.contact._node_coarse_kernels import Coarse, coarse_node, coarse_w
from softvr.contact._node_contact_native import (LOCAL_UPDATES, contact_residual, pgs_passes, screen_contacts,
                                                 warm_contacts)


@wp.func
def _off_block(i: int, p: int, row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
               blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d)):
    """``b_i - sum A_ij v_j`` [kg m/s] over the nodes ``j`` outside node ``i``'s block of
    ``D_A`` (``i`` itself and its pair partner ``p``, -1: none)."""
    r = b[i]
    for k in range(row_start[i], row_start[i + 1]):
        j = block_col[k]
        if j != i and j != p:
            r = r - blocks[k] * v[j]
    return r


@wp.func
def block_update(i: int, row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                 blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32),
                 cross: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d)):
    """Node ``i``'s share of ``D_A^-1 (b - (L_A + U_A) v)`` [m/s]: ``D_i^-1 r_i``, and on a
    spring-held rigid body's node, whose block of ``D_A`` is the body's 6x6 one with its
    ``partner``, ``+ (D^-1)_{i, partner} r_partner`` (``cross``)."""
    p = partner[i]
    out = d_inv[i] * _off_block(i, p, row_start, block_col, blocks, b, v)
    if p >= 0:
        out = out + cross[i] * _off_block(p, i, row_start, block_col, blocks, b, v)
    return out


@wp.func
def row_residual(i: int, row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                 blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d)):
    """Node ``i``'s residual ``(b - A v)_i`` [kg m/s] over its whole row of ``A``, the row's
    blocks taken two at a time into two sums (``b_i`` less the even ones, the odd ones apart,
    subtracted at the end): with one running sum each block's product waited for the last
    one's subtraction, and the row cost 1.25x as long (the candy pile's 29 589 blocks: 113 against
    90 us on one core). The same terms, so it differs from one running sum by rounding only
    (Higham's gamma_n bound holds for any order of the sum)."""
    r = b[i]
    odd = wp.vec3d()
    end = row_start[i + 1]
    k = row_start[i]
    while k + 1 < end:
        r = r - blocks[k] * v[block_col[k]]
        odd = odd + blocks[k + 1] * v[block_col[k + 1]]
        k = k + 2
    if k < end:
        r = r - blocks[k] * v[block_col[k]]
    return r - odd


@wp.kernel
def jacobi(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
           blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32),
           cross: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
           fixed_velocity: wp.array(dtype=wp.vec3d), own_block: wp.array(dtype=wp.int32), v: wp.array(dtype=wp.vec3d),
           v_hat: wp.array(dtype=wp.vec3d), residual: wp.array(dtype=wp.vec3d), offset: int):
    """The unconstrained Jacobi update ``v^`` [m/s] of node ``i`` (``tid + offset``) from the
    sweep's ``v``, in residual form: ``v^_i = v_i + D_i^-1 r_i`` with ``r = b - A v`` (eq. 5.6's
    ``D_A^-1 (b - (L_A + U_A) v)`` rewritten), and ``r_i`` into ``residual`` [kg m/s] for the
    coarse correction. A spring-held rigid body's node adds ``(D^-1)_{i, partner} r_partner``
    (``cross``: its block of ``D_A`` is the pair's 6x6 one). A node with no block of its own in
    ``A`` (``own_block[i]`` 0: a free rigid body's, whose ``D_A`` is its whole ``A``, kept only in
    ``d_inv``) takes ``D_i^-1 r_i``. The whole row is one loop with no test on the column (the
    form that skips the diagonal block took 1.75x as long on the candy pile); the result differs
    from that form by rounding only (:func:`block_update`, the Gauss-Seidel sweeps' form)."""
    i = wp.tid() + offset
    if fixed[i] != 0:
        v_hat[i] = fixed_velocity[i]
        return
    r = row_residual(i, row_start, block_col, blocks, b, v)
    residual[i] = r
    if own_block[i] == 0:
        v_hat[i] = d_inv[i] * r
        return
    out = v[i] + d_inv[i] * r
    p = partner[i]
    if p >= 0:
        out = out + cross[i] * row_residual(p, row_start, block_col, blocks, b, v)
    v_hat[i] = out


# The Jacobi rows on the CPU as plain C++ (:func:`jacobi_walk`): the same wp:: operations in the
# same order as :func:`jacobi` (the row's two sums of :func:`row_residual`, Warp's 3x3 product
# taking the columns in turn, ``(m_0 x_0 + m_1 x_1) + m_2 x_2``, each product and sum a statement
# of its own so that no compiler fuses them), so the same bits, at ~2 ns a block against ~4: Warp's
# loop pays its range iterator and, at every array access, the test for a negative index and a
# product by the stride. The blocks are read transposed (:func:`transpose_blocks`), so that a
# column is three doubles in a row: on the CPU (clang) the three rows of the product go as the
# lanes of one 4-wide vector, each lane the scalar code's operations (the fourth lane reads the
# next block's first double, or the padding block after the last, and is dropped; elsewhere, as
# CUDA compiles it, Warp's own product of the block transposed back). The candy pile's 29 589
# blocks: 113-123 -> 61-71 us a sweep on one core. It reads the arrays as contiguous.
#: ``product(k)``: block ``k`` of ``block`` (transposed 3x3 blocks, 9 doubles each) times the
#: 3-vector of ``x`` at column ``col[k]``, as one 4-wide vector (clang on the CPU only): each lane
#: Warp's 3x3 product's operations, ``(m_0 x_0 + m_1 x_1) + m_2 x_2``, each a statement of its own
#: (no fused multiply-add), the fourth lane the next double, dropped. Shared by the Jacobi rows
#: (:data:`_JACOBI_ROWS`) and the Gauss-Seidel rows (``_node_gs_kernels._ROW``), so both keep
#: the same bits as Warp's product.
LANES4_PRODUCT = r"""
typedef double lanes4 __attribute__((vector_size(32), aligned(8)));
auto product = [&](int k) -> lanes4 {
    const double* m = block + 9 * k;
    const double* y = x + 3 * col[k];
    lanes4 p = *(const lanes4*)m * y[0];
    lanes4 q = *(const lanes4*)(m + 3) * y[1];
    p = p + q;
    q = *(const lanes4*)(m + 6) * y[2];
    return p + q;
};
"""
_JACOBI_ROWS = r"""
typedef wp::vec_t<3, wp::float64> vec3;
typedef wp::mat_t<3, 3, wp::float64> mat3;
const wp::int32* start = row_start.data;
const wp::int32* col = block_col.data;
const double* block = (const double*)blocks_t.data;
const double* x = (const double*)v.data;
const double* rhs = (const double*)b.data;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
""" + LANES4_PRODUCT + r"""
auto row = [&](int i) -> vec3 {
    lanes4 r = {rhs[3 * i], rhs[3 * i + 1], rhs[3 * i + 2], 0.0};
    lanes4 odd = {0.0, 0.0, 0.0, 0.0};
    int k = start[i];
    const int end_k = start[i + 1];
    for (; k + 1 < end_k; k += 2) {
        r = r - product(k);
        odd = odd + product(k + 1);
    }
    if (k < end_k) r = r - product(k);
    r = r - odd;
    return vec3(r[0], r[1], r[2]);
};
#else
const mat3* transposed = (const mat3*)blocks_t.data;
const vec3* y = (const vec3*)v.data;
auto product = [&](int k) -> vec3 { return wp::mul(wp::transpose(transposed[k]), y[col[k]]); };
auto row = [&](int i) -> vec3 {
    vec3 r = vec3(rhs[3 * i], rhs[3 * i + 1], rhs[3 * i + 2]);
    vec3 odd = vec3();
    int k = start[i];
    const int end_k = start[i + 1];
    for (; k + 1 < end_k; k += 2) {
        r = wp::sub(r, product(k));
        odd = wp::add(odd, product(k + 1));
    }
    if (k < end_k) r = wp::sub(r, product(k));
    return wp::sub(r, odd);
};
#endif
const mat3* block_inv = (const mat3*)d_inv.data;
const mat3* pair_inv = (const mat3*)cross.data;
const vec3* now = (const vec3*)v.data;
const vec3* held = (const vec3*)fixed_velocity.data;
vec3* out = (vec3*)v_hat.data;
vec3* res = (vec3*)residual.data;
for (int i = first; i < last; ++i) {
    if (fixed.data[i] != 0) {
        out[i] = held[i];
        continue;
    }
    const vec3 r = row(i);
    res[i] = r;
    if (own_block.data[i] == 0) {
        out[i] = wp::mul(block_inv[i], r);
        continue;
    }
    vec3 o = wp::add(now[i], wp::mul(block_inv[i], r));
    const int p = partner.data[i];
    if (p >= 0) o = wp::add(o, wp::mul(pair_inv[i], row(p)));
    out[i] = o;
}
"""


@wp.func_native(_JACOBI_ROWS)
def _jacobi_rows(first: int, last: int, row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                 blocks_t: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                 partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                 fixed: wp.array(dtype=wp.int32), fixed_velocity: wp.array(dtype=wp.vec3d),
                 own_block: wp.array(dtype=wp.int32), v: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d),
                 residual: wp.array(dtype=wp.vec3d)):
    """:func:`jacobi`'s update of nodes ``first`` to ``last`` - 1 in turn (:data:`_JACOBI_ROWS`),
    from ``A``'s blocks transposed (``blocks_t`` [nnz + 1], :func:`transpose_blocks`)."""
    ...


@wp.kernel
def jacobi_walk(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                blocks_t: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                fixed: wp.array(dtype=wp.int32), fixed_velocity: wp.array(dtype=wp.vec3d),
                own_block: wp.array(dtype=wp.int32), v: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d),
                residual: wp.array(dtype=wp.vec3d), count: int, parts: int, offset: int):
    """:func:`jacobi` on the CPU, thread ``part`` (``tid + offset``) of ``parts`` walking the
    nodes ``count part / parts`` to ``count (part + 1) / parts`` - 1 (of ``count``) in C++
    (:func:`_jacobi_rows`): the same ``v^`` and ``residual`` to the bit, from ``A``'s blocks
    transposed (``blocks_t`` [nnz + 1] [kg], :func:`transpose_blocks`, once a step)."""
    part = wp.tid() + offset
    _jacobi_rows(count * part // parts, count * (part + 1) // parts, row_start, block_col, blocks_t, d_inv, partner,
                 cross, b, fixed, fixed_velocity, own_block, v, v_hat, residual)


@wp.kernel
def transpose_blocks(blocks: wp.array(dtype=wp.mat33d), blocks_t: wp.array(dtype=wp.mat33d), offset: int):
    """``blocks_t[k] = blocks[k]^T`` [kg] (:func:`jacobi_walk` reads a block's columns as rows;
    once a step, before the sweeps)."""
    k = wp.tid() + offset
    blocks_t[k] = wp.transpose(blocks[k])


@wp.func
def pair_cross(c: int, s: int, stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
               stencil_weights: wp.array2d(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
               rigid_lever: wp.array2d(dtype=wp.vec3d), partner: wp.array(dtype=wp.int32),
               cross: wp.array(dtype=wp.mat33d)) -> wp.mat33d:
    """The cross terms of contact ``c``'s ``J D_A^-1 J^T`` [1/kg] on its rigid side ``s`` where
    that body is spring-held (else 0): ``J_l P_la J_a^T + J_a P_al J_l^T = w_l (X + X^T)``, ``X =
    P_la [lever]x``, with ``J_l = w_l I`` on the linear node and ``J_a = -[lever]x`` on the
    angular one."""
    out = wp.mat33d()
    node = rigid_node[c, s]
    if node >= 0:
        lin = partner[node]
        if lin >= 0:
            w_l = wp.float64(0.0)
            for k in range(stencil_count[c]):
                if stencil_nodes[c, k] == lin:
                    w_l = w_l + stencil_weights[c, k]
            x = cross[lin] * wp.skew(rigid_lever[c, s])
            out = w_l * (x + wp.transpose(x))
    return out


@wp.func
def _pair_delassus(c: int, stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                   stencil_weights: wp.array2d(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
                   rigid_lever: wp.array2d(dtype=wp.vec3d), partner: wp.array(dtype=wp.int32),
                   cross: wp.array(dtype=wp.mat33d)) -> wp.mat33d:
    """The cross terms of contact ``c``'s ``J D_A^-1 J^T`` [1/kg] on its spring-held rigid sides
    (:func:`pair_cross` summed over them)."""
    out = wp.mat33d()
    for s in range(rigid_node.shape[1]):
        if rigid_node[c, s] >= 0:
            out = out + pair_cross(c, s, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever,
                                   partner, cross)
    return out


@wp.func
def _rigid_velocity(c: int, v: wp.array(dtype=wp.vec3d), rigid_node: wp.array2d(dtype=wp.int32),
                    rigid_lever: wp.array2d(dtype=wp.vec3d)) -> wp.vec3d:
    """Contact ``c``'s rigid sides' share of its relative velocity [m/s]: ``omega x lever``
    of each (:mod:`softvr.collision._node_rigid_kernels`)."""
    rel = wp.vec3d()
    for s in range(rigid_node.shape[1]):
        node = rigid_node[c, s]
        if node >= 0:
            rel = rel + wp.cross(v[node], rigid_lever[c, s])
    return rel


@wp.kernel
def contact_metric(count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
                   stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                   frame: wp.array(dtype=wp.mat33d), rigid_node: wp.array2d(dtype=wp.int32),
                   rigid_lever: wp.array2d(dtype=wp.vec3d), d_inv: wp.array(dtype=wp.mat33d),
                   partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
                   fixed: wp.array(dtype=wp.int32), co: Coarse, metric: wp.array(dtype=wp.mat33d),
                   movable: wp.array(dtype=wp.int32), threads: int, offset: int):
    """Contact ``c``'s block of ``J M^-1 J^T`` [1/kg] in its frame (normal, tangents), and
    whether an impulse can move anything (a free node of nonzero weight or a rigid side): both
    fixed over a step's sweeps, so the PGS passes read them instead of summing the stencil's
    blocks every pass (2 401 of the candy's ~3 100 contacts are the Jell-O's held bottom).
    ``threads`` threads (``tid + offset``: a launch's chunks may split over the CPU's cores,
    :func:`softvr.device.chunked_replayer`) stride over this step's contacts: a thread per slot
    of the buffer cost 4 ms a step on the candy's 188 181."""
    for c in range(wp.tid() + offset, count[0], threads):
        w = wp.mat33d()
        moves = int(0)
        for k in range(stencil_count[c]):
            node = stencil_nodes[c, k]
            wk = stencil_weights[c, k]
            if fixed[node] == 0:
                w = w + (wk * wk) * d_inv[node]
                if wk != wp.float64(0.0):
                    moves = 1
        for s in range(rigid_node.shape[1]):
            node = rigid_node[c, s]
            if node >= 0:
                # J = -[lever]x on the angular node: J D^-1 J^T = [lever]x D^-1 [lever]x^T.
                arm = wp.skew(rigid_lever[c, s])
                w = w + arm * d_inv[node] * wp.transpose(arm)
                moves = 1
        w = w + _pair_delassus(c, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever, partner, cross)
        w = w + coarse_w(c, co)
        f = frame[c]
        metric[c] = f * w * wp.transpose(f)
        movable[c] = moves


@wp.kernel
def warm_impulses(count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
                  stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                  frame: wp.array(dtype=wp.mat33d), rigid_node: wp.array2d(dtype=wp.int32),
                  rigid_lever: wp.array2d(dtype=wp.vec3d), d_inv: wp.array(dtype=wp.mat33d),
                  partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d), fixed: wp.array(dtype=wp.int32),
                  impulse: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d), co: Coarse,
                  movable: wp.array(dtype=wp.int32)):
    """``v^ += M^-1 J^T lambda`` [m/s] for the impulses ``impulse`` [c] [N s] of the last sweep
    (one thread: contacts share nodes). A zero impulse moves nothing and is passed over: most
    of a step's contacts are speculative ones that do not push. In C++
    (:func:`softvr.contact._node_contact_native.warm_contacts`)."""
    warm_contacts(count[0], 0, movable, stencil_count, stencil_nodes, stencil_weights, frame, rigid_node, rigid_lever,
                  d_inv, partner, cross, fixed, impulse, v_hat, movable, co.side, co.weight, co.lever, co.y_lin,
                  co.y_ang, co.ll, co.la, co.aa)


@wp.kernel
def screen(count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
           stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
           frame: wp.array(dtype=wp.mat33d), gap: wp.array(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
           rigid_lever: wp.array2d(dtype=wp.vec3d), dt: wp.float64, impulse: wp.array(dtype=wp.vec3d),
           stiffness: wp.array(dtype=wp.float64), v_hat: wp.array(dtype=wp.vec3d), co: Coarse,
           movable: wp.array(dtype=wp.int32), threads: int, live: wp.array(dtype=wp.int32)):
    """``live[c]`` (1: the sweep's PGS passes visit contact ``c``): a contact that can move
    something and pushes or holds (any impulse), may adhere (``stiffness`` > 0), or whose
    normal velocity in ``v^`` [m/s] is below its target ``-gap / dt``. Any other contact's
    update would leave its zero impulse at zero (its normal row projects to 0, and friction's
    disc has radius 0), so the passes skip it: most of a step's contacts are speculative ones
    that stay apart (candy pile: 24-45 of 700-1 200 push). One that the passes bring below
    its target is taken up by the next sweep's screen. ``threads`` threads (the launch's)
    stride over the contacts (:func:`softvr.contact._node_contact_native.screen_contacts`, C++)."""
    screen_contacts(wp.tid(), count[0], threads, 0, movable, stencil_count, stencil_nodes, stencil_weights, frame,
                    gap, rigid_node, rigid_lever, dt, impulse, stiffness, v_hat, movable, co.side, co.weight, co.lever,
                    co.y_lin, co.y_ang, live, live)


@wp.func
def pgs_update(old: wp.vec3d, rel_f: wp.vec3d, w_f: wp.mat33d, f: wp.mat33d, gap: wp.float64, dt: wp.float64,
               mu: wp.float64, stiffness: wp.float64, slip: wp.vec3d) -> wp.vec3d:
    """One projected Gauss-Seidel update of a contact's impulse ``old`` [N s] in its frame ``f``
    (rows: normal, tangent 1, tangent 2) from its relative velocity ``rel_f`` [m/s] and its
    block ``w_f`` of ``J M^-1 J^T`` [1/kg], both in that frame: the normal row aims at
    ``-gap / dt`` [m/s] and may pull down to the bound of eq. 4.16 where the adhesive
    ``stiffness`` A C beta^2 [N/m] > 0; the tangent rows, seeing the normal's change, aim at 0
    (a bonded contact: at ``-t . slip / dt``, ``slip`` [m] world) and are projected on the disc
    of radius ``mu lambda_n`` (or the bond spring's bound where larger). A contact whose
    ``w_f`` is 0 keeps ``old``. Used by the PGS passes (:func:`contacts`) and by the stop's
    residual (:func:`residual`)."""
    lam = old
    # Normal row (target -gap / dt: a speculative contact may close its gap, not cross it).
    k_ad = dt * dt * stiffness
    if w_f[0, 0] > wp.float64(0.0):
        lam_n = wp.max(old[0] + (-gap / dt - rel_f[0]) / w_f[0, 0], wp.float64(0.0))
        if k_ad > wp.float64(0.0):
            d_bar = w_f[0, 0] * old[0] - gap / dt - rel_f[0]
            lam_n = wp.max(old[0] + (-gap / dt - rel_f[0]) / w_f[0, 0],
                           wp.min(adhesive_bound(k_ad, d_bar, w_f[0, 0]), wp.float64(0.0)))
        rel = rel_f + w_f * wp.vec3d(lam_n - old[0], wp.float64(0.0), wp.float64(0.0))
        lam = wp.vec3d(lam_n, old[1], old[2])
        # Tangent rows together, then onto the friction disc |lam_t| <= mu lam_n. The step is
        # isotropic (1 / the larger eigenvalue of the 2x2 tangent block): the impulse it aims at
        # opposes the tangential velocity, so a sliding contact's friction ends up opposite its
        # slip (maximal dissipation); a W-metric step would tilt it towards the stiffer
        # direction (a block on a 35 degree incline then slid 0.5 % fast).
        mean = wp.float64(0.5) * (w_f[1, 1] + w_f[2, 2])
        half = wp.float64(0.5) * (w_f[1, 1] - w_f[2, 2])
        w_t = mean + wp.sqrt(half * half + w_f[1, 2] * w_f[2, 1])
        if w_t > wp.float64(0.0):
            t1 = lam[1] - rel[1] / w_t
            t2 = lam[2] - rel[2] / w_t
            limit = mu * lam_n
            norm = wp.sqrt(t1 * t1 + t2 * t2)
            if k_ad > wp.float64(0.0):
                # The spring's targets -t . u / dt; its bound is eq. 4.16 with d_bar =
                # w_t |lam_t + (target - rel_t) / w_t| (the unprojected update).
                u = f * slip
                t1 = lam[1] + (-u[1] / dt - rel[1]) / w_t
                t2 = lam[2] + (-u[2] / dt - rel[2]) / w_t
                norm = wp.sqrt(t1 * t1 + t2 * t2)
                limit = wp.max(mu * wp.max(lam_n, wp.float64(0.0)), adhesive_bound(k_ad, w_t * norm, w_t))
            if norm > limit:
                scale = limit / norm
                t1 = t1 * scale
                t2 = t2 * scale
            lam = wp.vec3d(lam_n, t1, t2)
    return lam


@wp.func
def _passes(n: int, order: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
            stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
            frame: wp.array(dtype=wp.mat33d), gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
            rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
            d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
            fixed: wp.array(dtype=wp.int32), dt: wp.float64, passes: int, impulse: wp.array(dtype=wp.vec3d),
            v_hat: wp.array(dtype=wp.vec3d), stiffness: wp.array(dtype=wp.float64), slip: wp.array(dtype=wp.vec3d),
            co: Coarse, metric: wp.array(dtype=wp.mat33d)):
    """``passes`` PGS passes over the ``n`` contacts listed in ``order`` (:func:`contacts`), in C++
    (:func:`softvr.contact._node_contact_native.pgs_passes`: :func:`pgs_update`'s operations)."""
    pgs_passes(n, order, stencil_count, stencil_nodes, stencil_weights, frame, gap, friction, rigid_node, rigid_lever,
               d_inv, partner, cross, fixed, dt, passes, impulse, v_hat, stiffness, slip, metric, co.side, co.weight,
               co.lever, co.y_lin, co.y_ang, co.ll, co.la, co.aa, LOCAL_UPDATES)


@wp.kernel
def contacts(count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
             stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
             frame: wp.array(dtype=wp.mat33d), gap: wp.array(dtype=wp.float64),
             friction: wp.array(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
             rigid_lever: wp.array2d(dtype=wp.vec3d), d_inv: wp.array(dtype=wp.mat33d),
             partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
             fixed: wp.array(dtype=wp.int32), dt: wp.float64, passes: int, impulse: wp.array(dtype=wp.vec3d),
             v_hat: wp.array(dtype=wp.vec3d), sweep: wp.array(dtype=wp.int32), stiffness: wp.array(dtype=wp.float64),
             slip: wp.array(dtype=wp.vec3d), co: Coarse, metric: wp.array(dtype=wp.mat33d),
             live: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32)):
    """The inner loop of one sweep (one thread: Gauss-Seidel in contact order), after
    :func:`warm_impulses` and :func:`screen`: ``passes`` PGS passes over the ``live``
    contacts (listed in ``order`` [c]); counts the sweep in ``sweep[0]``. A bonded contact
    (adhesive ``stiffness`` A C beta^2 [N/m] > 0, tangential ``slip`` u [m]) may pull down to
    the bound of eq. 4.16, and its tangent impulse aims at the target ``-t . u / dt`` within
    the larger of the Coulomb disc and the implicit spring's bound (docs/adhesion.md). With
    coarse bodies (``co``) the metric is the two-level ``M^-1``
    (:mod:`softvr.contact._node_coarse_kernels`). ``metric`` is :func:`contact_metric`'s.
    Skipping contacts changes the path to the fixed point, not the fixed point: at a fixed
    point of the sweeps every live contact's update leaves it unchanged and every other one
    has a zero impulse and a normal velocity at or above its target (eq. 5.5)."""
    n = int(0)
    for c in range(count[0]):
        if live[c] != 0:
            order[n] = c
            n = n + 1
    _passes(n, order, stencil_count, stencil_nodes, stencil_weights, frame, gap, friction, rigid_node, rigid_lever,
            d_inv, partner, cross, fixed, dt, passes, impulse, v_hat, stiffness, slip, co, metric)
    sweep[0] = sweep[0] + 1


@wp.kernel
def contact_step(movers: wp.array(dtype=wp.int32), mover_count: wp.array(dtype=wp.int32),
                 stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                 stencil_weights: wp.array2d(dtype=wp.float64), frame: wp.array(dtype=wp.mat33d),
                 gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
                 rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
                 d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
                 fixed: wp.array(dtype=wp.int32), dt: wp.float64, passes: int, impulse: wp.array(dtype=wp.vec3d),
                 v_hat: wp.array(dtype=wp.vec3d), sweep: wp.array(dtype=wp.int32),
                 stiffness: wp.array(dtype=wp.float64), slip: wp.array(dtype=wp.vec3d), co: Coarse,
                 metric: wp.array(dtype=wp.mat33d), live: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32)):
    """The contact step of a sweep on the CPU in one launch (one thread): :func:`warm_impulses`,
    :func:`screen` and :func:`contacts` over the step's movable contacts only, listed in
    ascending order in ``movers`` [mover_count[0]] (:func:`list_movers`, once a step): the same
    updates in the same order as the three launches, so the same result to the bit. The candy
    pile's ~3 000 contacts have ~600 movable ones (2 401 hold the Jell-O's fixed bottom): each
    launch passed over all of them, and each launch's call cost ~1 us of Python."""
    n = mover_count[0]
    warm_contacts(n, 1, movers, stencil_count, stencil_nodes, stencil_weights, frame, rigid_node, rigid_lever, d_inv,
                  partner, cross, fixed, impulse, v_hat, movers, co.side, co.weight, co.lever, co.y_lin, co.y_ang,
                  co.ll, co.la, co.aa)
    live_count = screen_contacts(0, n, 1, 1, movers, stencil_count, stencil_nodes, stencil_weights, frame, gap,
                                 rigid_node, rigid_lever, dt, impulse, stiffness, v_hat, movers, co.side, co.weight,
                                 co.lever, co.y_lin, co.y_ang, live, order)
    _passes(live_count, order, stencil_count, stencil_nodes, stencil_weights, frame, gap, friction, rigid_node,
            rigid_lever, d_inv, partner, cross, fixed, dt, passes, impulse, v_hat, stiffness, slip, co, metric)
    sweep[0] = sweep[0] + 1


@wp.kernel
def list_movers(count: wp.array(dtype=wp.int32), movable: wp.array(dtype=wp.int32), live: wp.array(dtype=wp.int32),
                movers: wp.array(dtype=wp.int32), mover_count: wp.array(dtype=wp.int32)):
    """The step's movable contacts (:func:`contact_metric`'s ``movable``) in ascending order into
    ``movers``, their number into ``mover_count[0]``, and every contact not live (one thread):
    :func:`contact_step` screens only the movable ones, so the others stay so all step."""
    n = int(0)
    for c in range(count[0]):
        live[c] = 0
        if movable[c] != 0:
            movers[n] = c
            n = n + 1
    mover_count[0] = n


@wp.func
def _chebyshev_node(i: int, v_hat: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d),
                    v_prev: wp.array(dtype=wp.vec3d), omega: wp.float64, gamma: wp.float64,
                    fixed: wp.array(dtype=wp.int32), exact: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                    co: Coarse, v_next: wp.array(dtype=wp.vec3d)) -> wp.float64:
    """Writes ``v^{k+1}`` [m/s] of node ``i`` (:func:`chebyshev`) and returns its largest
    component change [m/s]."""
    if fixed[i] != 0:
        v_next[i] = v_hat[i]
        return wp.float64(0.0)
    vh = v_hat[i]
    if co.node_body[i] >= 0:
        vh = vh + coarse_node(i, q, co)
    out = omega * (gamma * (vh - v[i]) + v[i] - v_prev[i]) + v_prev[i]
    if exact[i] != 0:
        out = vh
    d = out - v[i]
    size = wp.max(wp.abs(d[0]), wp.max(wp.abs(d[1]), wp.abs(d[2])))
    if exact[i] != 0 and not wp.isnan(size):
        size = wp.float64(0.0)
    v_next[i] = out
    return size


# _chebyshev_all: :func:`_chebyshev_node` over all nodes as one C++ loop, the same wp:: operations
# in the same order (so the same bits), with none of Warp's per-access index arithmetic
# (the shoulder's 1 247 nodes: ~12 -> ~3 us a sweep). It reads the arrays as contiguous.
_CHEBYSHEV_ALL = r"""
typedef wp::vec_t<3, wp::float64> vec3;
const vec3* hat = (const vec3*)v_hat.data;
const vec3* now = (const vec3*)v.data;
const vec3* before = (const vec3*)v_prev.data;
const vec3* x = (const vec3*)q.data;
const vec3* lin = (const vec3*)y_lin.data;
const vec3* ang = (const vec3*)y_ang.data;
const vec3* mid = (const vec3*)centre.data;
const wp::int32* is_fixed = (const wp::int32*)fixed.data;
const wp::int32* is_exact = (const wp::int32*)exact.data;
const wp::int32* body = (const wp::int32*)node_body.data;
vec3* out = (vec3*)v_next.data;
wp::float64 worst = 0.0;
for (int i = 0; i < count; ++i) {
    if (is_fixed[i] != 0) {
        out[i] = hat[i];
        continue;
    }
    vec3 vh = hat[i];
    const int b = body[i];
    if (b >= 0) vh = wp::add(vh, wp::add(lin[b], wp::cross(ang[b], wp::sub(x[i], mid[b]))));
    vec3 next = wp::add(wp::mul(omega, wp::sub(wp::add(wp::mul(gamma, wp::sub(vh, now[i])), now[i]), before[i])),
                        before[i]);
    if (is_exact[i] != 0) next = vh;
    const vec3 d = wp::sub(next, now[i]);
    wp::float64 size = wp::max(wp::abs(d[0]), wp::max(wp::abs(d[1]), wp::abs(d[2])));
    if (is_exact[i] != 0 && !wp::isnan(size)) size = 0.0;
    out[i] = next;
    if (size > worst || wp::isnan(size)) worst = size;
}
return worst;
"""


@wp.func_native(_CHEBYSHEV_ALL)
def _chebyshev_all(v_hat: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d), v_prev: wp.array(dtype=wp.vec3d),
                   omega: wp.float64, gamma: wp.float64, fixed: wp.array(dtype=wp.int32),
                   exact: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d), node_body: wp.array(dtype=wp.int32),
                   y_lin: wp.array(dtype=wp.vec3d), y_ang: wp.array(dtype=wp.vec3d), centre: wp.array(dtype=wp.vec3d),
                   v_next: wp.array(dtype=wp.vec3d), count: int) -> wp.float64:
    """:func:`_chebyshev_node` for nodes 0 to ``count`` - 1 in turn (one thread); returns their
    largest change [m/s] (NaN if any is), as :func:`chebyshev`'s one-thread loop takes it."""
    ...


@wp.func
def nan_as_inf(size: wp.float64) -> wp.float64:
    """``size`` for an atomic maximum: NaN as +inf (a maximum of floats drops NaN; the sweep
    loop stops on either, and the integration names the node)."""
    if wp.isnan(size):
        return wp.float64(wp.inf)
    return size


@wp.kernel
def chebyshev(v_hat: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d), v_prev: wp.array(dtype=wp.vec3d),
              weights: wp.array(dtype=wp.float64), gamma: wp.float64, sweep: wp.array(dtype=wp.int32),
              fixed: wp.array(dtype=wp.int32), exact: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
              co: Coarse, v_next: wp.array(dtype=wp.vec3d), change: wp.array(dtype=wp.float64), count: int,
              threads: int, atomic: int, stats: wp.array(dtype=wp.float64)):
    """``v^{k+1}`` [m/s] of the ``count`` nodes and their largest component change [m/s];
    ``weights`` [K] the omega_k, indexed by the sweep the contact kernel counted (1 after the
    first sweep). A node marked ``exact`` (a rigid body's: its update needs no acceleration)
    takes ``v^`` and counts no change (NaN still shows): its update solves its rows of eq. 5.5
    for the sweep's impulses, so what error it has is its contacts' (the contacts' residual
    measures that in m/s, :func:`residual`), and its change, an angular node's in rad/s, is no
    error estimate. A node of a coarse body adds its body's coarse velocity to ``v^`` (positions
    ``q`` [m]). ``threads`` threads (the launch's) stride over the nodes: with several (CUDA)
    each node's change goes to ``change`` [count] for :func:`largest_change`; with one (the
    CPU) the thread walks them in C++ (:func:`_chebyshev_all`) and takes the largest itself into
    ``stats[0]`` (NaN if any is), which saves that kernel's second pass over the nodes. With
    ``atomic`` 1 (the thread-per-contact sweeps, :mod:`softvr.contact._node_parallel_kernels`,
    whose ``start_sweep`` zeroed ``stats``) every thread takes its nodes' changes into
    ``stats[0]`` atomically instead (NaN as +inf)."""
    omega = weights[sweep[0] - 1]
    if threads == 1:
        stats[0] = _chebyshev_all(v_hat, v, v_prev, omega, gamma, fixed, exact, q, co.node_body, co.y_lin, co.y_ang,
                                  co.centre, v_next, count)
        return
    for i in range(wp.tid(), count, threads):
        size = _chebyshev_node(i, v_hat, v, v_prev, omega, gamma, fixed, exact, q, co, v_next)
        if atomic != 0:
            wp.atomic_max(stats, 0, nan_as_inf(size))
        else:
            change[i] = size


@wp.kernel
def rigid_contact_exact(count: wp.array(dtype=wp.int32), rigid_node: wp.array2d(dtype=wp.int32),
                        partner: wp.array(dtype=wp.int32), exact: wp.array(dtype=wp.int32), threads: int):
    """Marks ``exact`` (1: the Chebyshev step takes the node's update as it is) both nodes of
    every spring-held rigid body (``partner`` >= 0) that is a side of a contact (``threads``
    threads, the launch's, striding over this step's contacts)."""
    for c in range(wp.tid(), count[0], threads):
        for s in range(rigid_node.shape[1]):
            node = rigid_node[c, s]
            if node >= 0:
                if partner[node] >= 0:
                    exact[node] = 1
                    exact[partner[node]] = 1


@wp.kernel
def largest_change(change: wp.array(dtype=wp.float64), count: int, stats: wp.array(dtype=wp.float64)):
    """``stats[0]``: the largest of the sweep's ``change`` [count] [m/s] (one thread), NaN if
    any is: the one number the sweep loop reads back to decide whether to go on."""
    worst = wp.float64(0.0)
    for i in range(count):
        c = change[i]
        if c > worst or wp.isnan(c):
            worst = c
        if wp.isnan(worst):
            break
    stats[0] = worst


@wp.kernel
def residual(count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
             stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
             frame: wp.array(dtype=wp.mat33d), gap: wp.array(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
             rigid_lever: wp.array2d(dtype=wp.vec3d), dt: wp.float64, v: wp.array(dtype=wp.vec3d),
             impulse: wp.array(dtype=wp.vec3d), friction: wp.array(dtype=wp.float64),
             stiffness: wp.array(dtype=wp.float64), slip: wp.array(dtype=wp.vec3d), metric: wp.array(dtype=wp.mat33d),
             movable: wp.array(dtype=wp.int32), gap_after: wp.array(dtype=wp.float64),
             stats: wp.array(dtype=wp.float64)):
    """The contacts' residual of eq. 5.5 in the velocities ``v`` [m/s] and impulses ``impulse``
    [N s] (one thread). Per contact the linearized gap after the step [m] (``gap + dt n . J
    v``); ``stats[1]`` the largest normal-velocity error [m/s]: how far a contact falls short of
    its target ``-gap / dt``, or for one that pushes (normal impulse > 0) how far it is from it
    either way; ``stats[2]`` the largest natural residual [m/s] of the contacts that can move
    something (``movable``), ``|W (P(lambda) - lambda)|`` (largest component), ``P`` one update
    of :func:`pgs_update` with the contact's block ``metric`` of ``J M^-1 J^T``: the velocity
    change one more projection would make at the contact, 0 exactly where the contact meets
    its complementarity, friction disc (sticking: no slip; sliding: on the rim against the
    slip) and adhesive bounds (eq. 4.16) (Erleben 2013, the natural merit function). Every
    contact's target is then met within ``stats[2]``: the step solves eq. 5.5 with its
    targets moved by at most that much. In C++ (:func:`softvr.contact._node_contact_native.contact_residual`)."""
    contact_residual(count, stencil_count, stencil_nodes, stencil_weights, frame, gap, rigid_node, rigid_lever, dt, v,
                     impulse, friction, stiffness, slip, metric, movable, gap_after, stats)
