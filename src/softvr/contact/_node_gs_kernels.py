"""The node update of a multicolour symmetric block Gauss-Seidel sweep of thesis eq. 5.6 (in
place of its outer Jacobi; :mod:`softvr.contact._node_jacobi_kernels` has the contact PGS and
the Chebyshev step, which are shared). One source for CPU and CUDA.

A sweep from ``v^k`` on the work array ``w`` (set to ``v^k`` first), with the nodes in some
contact's stencil ("contact nodes") set apart:

    1. colours 0 .. C-1, the free nodes i of each that are not contact nodes (no block couples
       two nodes of one colour):  w_i = D_i^-1 (b_i - sum_{j != i} A_ij w_j)
    2. the contact nodes, damped Jacobi on the swept neighbours:
       v^_i = (1 - omega_i) v^k_i + omega_i D_i^-1 (b_i - sum_{j != i} A_ij w_j)
       (omega_i = 1 on a rigid body whose D_A block, or island, is all of its A: exact)
    3. the contact PGS (shared kernel, metric omega_i D_A^-1) projects v^ of the contact nodes,
       then more passes over the exact rigid bodies' contacts (:func:`tool_contacts`);
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
[0, 1), so M^-1 A still has none above 1, which the Chebyshev weights need. An exact rigid
body's rows have blocks only on its own (or its island's) nodes and driven ones, so its
undamped update solves them: S is 0 there, and the Chebyshev step leaves those nodes as they are.
"""

from __future__ import annotations

import warp as wp

from softvr.contact._node_jacobi_kernels import LANES4_PRODUCT, block_update


@wp.kernel
def start(v: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), offset: int):
    """``w = v`` [m/s]: the sweep's work array starts at its velocities."""
    i = wp.tid() + offset
    w[i] = v[i]


# The row product of the colour passes as plain C++ (one source for CPU and CUDA): the same
# operations in the same order as Warp's ``r = r - off_blocks[k] * w[off_col[k]]`` (its 3x3
# product takes the columns in turn, ``(m_0 x_0 + m_1 x_1) + m_2 x_2``, each product and sum a
# statement of its own so that no compiler fuses them), so the same bits, at ~2.9 ns a block on
# the CPU against ~5.3: Warp's own loop pays its range iterator and, at every array access, the
# test for a negative index and a product by the stride. The blocks are stored transposed
# (:func:`gather_off_blocks`), so that a column is three doubles in a row: on the CPU (clang)
# the three rows of the product go as the lanes of one 4-wide vector, each lane the scalar
# code's operations (the fourth lane reads the next block's first double, or the padding block
# after the last, and is dropped; 3.5 ns a block as scalar code): the Jacobi rows' product,
# ``_node_jacobi_kernels.LANES4_PRODUCT``. It reads the arrays as
# contiguous (:meth:`softvr.contact.node_gauss_seidel.GaussSeidelSweep.record` checks that they are).
_ROW = r"""
const wp::int32* start = off_start.data;
const wp::int32* col = off_col.data;
const double* block = (const double*)off_blocks.data;
const double* x = (const double*)w.data;
const double* rhs = (const double*)b.data + 3 * i;
double r0 = rhs[0];
double r1 = rhs[1];
double r2 = rhs[2];
#if defined(__clang__) && !defined(__CUDA_ARCH__)
""" + LANES4_PRODUCT + r"""
lanes4 r = {r0, r1, r2, 0.0};
for (int k = start[t], end = start[t + 1]; k < end; ++k) r = r - product(k);
r0 = r[0];
r1 = r[1];
r2 = r[2];
#else
for (int k = start[t], end = start[t + 1]; k < end; ++k) {
    const double* m = block + 9 * k;
    const double* y = x + 3 * col[k];
    double p0 = m[0] * y[0];
    double p1 = m[1] * y[0];
    double p2 = m[2] * y[0];
    double q0 = m[3] * y[1];
    double q1 = m[4] * y[1];
    double q2 = m[5] * y[1];
    p0 = p0 + q0;
    p1 = p1 + q1;
    p2 = p2 + q2;
    q0 = m[6] * y[2];
    q1 = m[7] * y[2];
    q2 = m[8] * y[2];
    p0 = p0 + q0;
    p1 = p1 + q1;
    p2 = p2 + q2;
    r0 = r0 - p0;
    r1 = r1 - p1;
    r2 = r2 - p2;
}
#endif
"""
_OFF_ROW_SNIPPET = _ROW + "return wp::vec_t<3, wp::float64>(r0, r1, r2);\n"
# _plain_node: the row times d_inv as Warp's 3x3 product takes it (the columns in turn).
_PLAIN_NODE_SNIPPET = r"""
if (contact_node.data[i] != 0) return;
double* out = (double*)w.data + 3 * i;
double* out_hat = (double*)v_hat.data + 3 * i;
if (fixed.data[i] != 0) {
    const double* f = (const double*)fixed_velocity.data + 3 * i;
    double f0 = f[0], f1 = f[1], f2 = f[2];
    out[0] = f0; out[1] = f1; out[2] = f2;
    if (last != 0) { out_hat[0] = f0; out_hat[1] = f1; out_hat[2] = f2; }
    return;
}
""" + _ROW + r"""
const double* d = (const double*)d_inv.data + 9 * i;
double u0 = d[0] * r0;
double u1 = d[3] * r0;
double u2 = d[6] * r0;
double s0 = d[1] * r1;
double s1 = d[4] * r1;
double s2 = d[7] * r1;
u0 = u0 + s0;
u1 = u1 + s1;
u2 = u2 + s2;
s0 = d[2] * r2;
s1 = d[5] * r2;
s2 = d[8] * r2;
u0 = u0 + s0;
u1 = u1 + s1;
u2 = u2 + s2;
out[0] = u0; out[1] = u1; out[2] = u2;
if (last != 0) { out_hat[0] = u0; out_hat[1] = u1; out_hat[2] = u2; }
"""


@wp.func_native(r"""
const double* from = (const double*)v.data;
double* to = (double*)w.data;
for (int k = 0, end = 3 * v.shape[0]; k < end; ++k) to[k] = from[k];
""")
def _copy(v: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d)):
    """``w = v`` [m/s] (both [n], contiguous) as one plain loop over the doubles (~0.5 us on
    the shoulder's 1 247 nodes against ~3 for Warp's loop of 3-vectors)."""
    ...


@wp.func_native(_PLAIN_NODE_SNIPPET)
def _plain_node(t: int, i: int, contact_node: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32),
                fixed_velocity: wp.array(dtype=wp.vec3d), d_inv: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                off_start: wp.array(dtype=wp.int32), off_col: wp.array(dtype=wp.int32),
                off_blocks: wp.array(dtype=wp.mat33d), last: int, w: wp.array(dtype=wp.vec3d),
                v_hat: wp.array(dtype=wp.vec3d)):
    """Steps 1 and 4 for node ``i`` (the ``t``-th in colour order) when it has no pair partner
    (or is fixed, or a contact node): nothing for a contact node; ``w`` [m/s] (and on the
    sweep's ``last`` update ``v_hat``) = its ``fixed_velocity`` for a fixed node, else
    ``d_inv_i (b_i - sum_{j != i} A_ij w_j)`` (:data:`_OFF_ROW_SNIPPET`'s row). In C++: with
    the row product, the node's own loads and tests cost half the colour pass in Warp's code
    (the shoulder's forward walk 34 -> 26 us)."""
    ...


@wp.func_native(_OFF_ROW_SNIPPET)
def _off_row(t: int, i: int, off_start: wp.array(dtype=wp.int32), off_col: wp.array(dtype=wp.int32),
             off_blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
             w: wp.array(dtype=wp.vec3d)) -> wp.vec3d:
    """``b_i - sum_{j != i} A_ij w_j`` [kg m/s] of node ``i``, the ``t``-th in colour order,
    from the colour-ordered copy of its off-diagonal blocks (transposed,
    :func:`gather_off_blocks`): the same terms in the same order as
    :func:`softvr.contact._node_jacobi_kernels.block_update` takes them from ``A``'s rows, so
    the same sum to the bit, but read one after the other and with no test per block
    (:data:`_ROW`)."""
    ...


@wp.func_native(r"""
typedef wp::mat_t<3, 3, wp::float64> mat3;
const mat3* from = (const mat3*)blocks.data;
const wp::int32* source = (const wp::int32*)off_source.data;
mat3* to = (mat3*)off_blocks.data;
for (int k = first, end = off_source.shape[0]; k < end; k += stride) to[k] = wp::transpose(from[source[k]]);
""")
def _gather(first: int, stride: int, blocks: wp.array(dtype=wp.mat33d), off_source: wp.array(dtype=wp.int32),
            off_blocks: wp.array(dtype=wp.mat33d)):
    """``off_blocks[k] = blocks[off_source[k]]^T`` for ``k = first, first + stride, ...``
    (:func:`gather_off_blocks`; contiguous arrays)."""
    ...


@wp.kernel
def gather_off_blocks(blocks: wp.array(dtype=wp.mat33d), off_source: wp.array(dtype=wp.int32),
                      off_blocks: wp.array(dtype=wp.mat33d), threads: int):
    """``off_blocks[k] = blocks[off_source[k]]^T`` [kg]: this step's off-diagonal blocks of ``A``
    in colour order, transposed (:data:`_ROW`; once a step, before the sweeps). ``threads``
    threads (the launch's) stride over the blocks, as one C++ loop each: on the CPU one thread,
    ~5 us for the shoulder's 6 100 blocks against ~29 for a Warp thread a block."""
    _gather(wp.tid(), threads, blocks, off_source, off_blocks)


@wp.func
def colour_node(t: int, row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                fixed: wp.array(dtype=wp.int32), fixed_velocity: wp.array(dtype=wp.vec3d),
                contact_node: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32),
                off_start: wp.array(dtype=wp.int32), off_col: wp.array(dtype=wp.int32),
                off_blocks: wp.array(dtype=wp.mat33d), last: int, w: wp.array(dtype=wp.vec3d),
                v_hat: wp.array(dtype=wp.vec3d)):
    """Steps 1 and 4 for node ``order[t]`` (:func:`gauss_seidel`)."""
    i = order[t]
    if partner[i] >= 0:
        if fixed[i] == 0 and contact_node[i] == 0:
            value = block_update(i, row_start, block_col, blocks, d_inv, partner, cross, b, w)
            w[i] = value
            if last != 0:
                v_hat[i] = value
            return
    _plain_node(t, i, contact_node, fixed, fixed_velocity, d_inv, b, off_start, off_col, off_blocks, last, w, v_hat)


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
    colour_node(first + wp.tid() + offset, row_start, block_col, blocks, d_inv, partner, cross, b, fixed,
                fixed_velocity, contact_node, order, off_start, off_col, off_blocks, last, w, v_hat)


@wp.kernel
def gauss_seidel_walk(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                      blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                      partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
                      b: wp.array(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
                      fixed_velocity: wp.array(dtype=wp.vec3d), contact_node: wp.array(dtype=wp.int32),
                      order: wp.array(dtype=wp.int32), off_start: wp.array(dtype=wp.int32),
                      off_col: wp.array(dtype=wp.int32), off_blocks: wp.array(dtype=wp.mat33d),
                      colour_start: wp.array(dtype=wp.int32), free_end: wp.array(dtype=wp.int32),
                      listed: wp.array(dtype=wp.int32), listed_count: wp.array(dtype=wp.int32), backward: int,
                      last: int, v: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d),
                      v_hat: wp.array(dtype=wp.vec3d)):
    """Steps 1 (``backward`` 0: colours 0 .. C-1, after ``w = v`` [m/s], :func:`start`) or 4
    (C-1 .. 0) in one thread, colour ``c`` being the nodes ``order[colour_start[c] :
    colour_start[c + 1]]`` walked in that order, as a one-chunk CPU launch of
    :func:`gauss_seidel` walks them: the same updates in the same order, so the same bits, in
    one launch instead of one a colour (and one for the start). The forward walk stops at
    ``free_end[c]`` [C], before the colour's fixed nodes: their update would write the fixed
    velocity that ``w = v`` gave them already
    (:func:`softvr.contact.node_gauss_seidel.free_first`); the backward one writes it into
    ``v_hat``. The backward walk first sets ``w = v_hat`` at the contact nodes, the colour
    positions ``listed[:listed_count[0]]`` (:func:`list_contact_nodes`), as :func:`projected`
    would."""
    if backward == 0:
        _copy(v, w)
    else:  # step 3's w_i = v^_i at the contact nodes (:func:`projected`), from their list
        for s in range(listed_count[0]):
            i = order[listed[s]]
            w[i] = v_hat[i]
    colours = colour_start.shape[0] - 1
    for k in range(colours):
        c = k
        if backward != 0:
            c = colours - 1 - k
        end = colour_start[c + 1]
        if backward == 0:
            end = free_end[c]
        for t in range(colour_start[c], end):
            colour_node(t, row_start, block_col, blocks, d_inv, partner, cross, b, fixed, fixed_velocity,
                        contact_node, order, off_start, off_col, off_blocks, last, w, v_hat)


@wp.func
def contact_node_update(t: int, row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                        blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                        partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
                        b: wp.array(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
                        fixed_velocity: wp.array(dtype=wp.vec3d), contact_node: wp.array(dtype=wp.int32),
                        order: wp.array(dtype=wp.int32), off_start: wp.array(dtype=wp.int32),
                        off_col: wp.array(dtype=wp.int32), off_blocks: wp.array(dtype=wp.mat33d),
                        omega: wp.array(dtype=wp.float64), v: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d),
                        v_hat: wp.array(dtype=wp.vec3d)):
    """Step 2 for node ``order[t]`` if it is a contact node (:func:`contact_nodes`)."""
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
    v_hat[i] = (wp.float64(1.0) - omega[i]) * v[i] + omega[i] * update


@wp.kernel
def contact_nodes(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                  blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                  partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                  fixed: wp.array(dtype=wp.int32), fixed_velocity: wp.array(dtype=wp.vec3d),
                  contact_node: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32),
                  off_start: wp.array(dtype=wp.int32), off_col: wp.array(dtype=wp.int32),
                  off_blocks: wp.array(dtype=wp.mat33d), omega: wp.array(dtype=wp.float64), v: wp.array(dtype=wp.vec3d),
                  w: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d), offset: int):
    """Step 2: the damped Jacobi update ``v_hat`` [m/s] of the contact nodes (``order[t]``,
    thread t) from the sweep's start ``v`` and the swept ``w`` [m/s], each node damped by its
    ``omega`` [n]."""
    contact_node_update(wp.tid() + offset, row_start, block_col, blocks, d_inv, partner, cross, b, fixed,
                        fixed_velocity, contact_node, order, off_start, off_col, off_blocks, omega, v, w, v_hat)


@wp.kernel
def listed_contact_nodes(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                         blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                         partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
                         b: wp.array(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
                         fixed_velocity: wp.array(dtype=wp.vec3d), contact_node: wp.array(dtype=wp.int32),
                         order: wp.array(dtype=wp.int32), off_start: wp.array(dtype=wp.int32),
                         off_col: wp.array(dtype=wp.int32), off_blocks: wp.array(dtype=wp.mat33d),
                         omega: wp.array(dtype=wp.float64), v: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d),
                         v_hat: wp.array(dtype=wp.vec3d), listed: wp.array(dtype=wp.int32),
                         listed_count: wp.array(dtype=wp.int32)):
    """Step 2 as :func:`contact_nodes` in one thread over the ``listed_count[0]`` colour
    positions ``listed`` of the contact nodes (:func:`list_contact_nodes`) instead of a thread
    a node: on the CPU, where the walk runs, a step's few dozen contact nodes of the
    shoulder's 1 247 (each node's update reads only ``w``, so any order gives the same bits)."""
    for s in range(listed_count[0]):
        contact_node_update(listed[s], row_start, block_col, blocks, d_inv, partner, cross, b, fixed, fixed_velocity,
                            contact_node, order, off_start, off_col, off_blocks, omega, v, w, v_hat)


@wp.kernel
def list_contact_nodes(order: wp.array(dtype=wp.int32), contact_node: wp.array(dtype=wp.int32),
                       listed: wp.array(dtype=wp.int32), listed_count: wp.array(dtype=wp.int32)):
    """``listed[:listed_count[0]]``: the colour positions ``t`` of the contact nodes
    (``contact_node[order[t]]`` != 0), ascending (one thread; after each marking)."""
    count = int(0)
    for t in range(order.shape[0]):
        if contact_node[order[t]] != 0:
            listed[count] = t
            count = count + 1
    listed_count[0] = count


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
                       contact_node: wp.array(dtype=wp.int32), asleep: wp.array(dtype=wp.int32), threads: int):
    """``contact_node[i] = 1`` for the nodes contact ``c``'s impulse moves (its stencil and its
    rigid sides' angular nodes, -1: none) unless the contact sleeps: ``asleep[c] = 1`` where it
    has no impulse, no adhesion (``stiffness`` 0), a gap > 0 [m], and its normal velocity in the
    step's start velocities ``v`` [m/s] closes at most ``share`` of that gap in ``dt`` [s]
    (``wake_all``: none sleeps). ``threads`` threads stride over the first ``count[0]``
    contacts (not one a slot of the capacity: the shoulder's 18 508, ~200 used);
    ``contact_node`` zeroed before (or left as it is, to mark more)."""
    for c in range(wp.tid(), count[0], threads):
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
        if sleeps == 0:
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


@wp.func
def tool_range(first: int, stride: int, count: wp.array(dtype=wp.int32), rigid_node: wp.array2d(dtype=wp.int32),
               tool_node: wp.array(dtype=wp.int32), live: wp.array(dtype=wp.int32),
               tool_live: wp.array(dtype=wp.int32)):
    """:func:`tool_contacts`' contacts ``first, first + stride, ... < count[0]``."""
    for c in range(first, count[0], stride):
        on = int(0)
        if live[c] != 0:
            for s in range(rigid_node.shape[1]):
                node = rigid_node[c, s]
                if node >= 0:
                    if tool_node[node] != 0:
                        on = 1
        tool_live[c] = on


@wp.kernel
def tool_contacts(count: wp.array(dtype=wp.int32), rigid_node: wp.array2d(dtype=wp.int32),
                  tool_node: wp.array(dtype=wp.int32), live: wp.array(dtype=wp.int32),
                  tool_live: wp.array(dtype=wp.int32), threads: int):
    """``tool_live[c] = 1`` for the ``live`` contacts [c] with a rigid side on a ``tool_node``
    [n] (a rigid body whose sweep update is exact: :func:`softvr.dynamics.node_rigid.rigid_islands`),
    the ones the sweep's extra PGS passes revisit (``threads`` threads, the launch's, striding
    over this step's contacts)."""
    tool_range(wp.tid(), threads, count, rigid_node, tool_node, live, tool_live)


@wp.kernel
def scale(d_inv: wp.array(dtype=wp.mat33d), cross: wp.array(dtype=wp.mat33d), omega: wp.array(dtype=wp.float64),
          out: wp.array(dtype=wp.mat33d), out_cross: wp.array(dtype=wp.mat33d)):
    """``out = omega D_A^-1`` [1/kg]: the contact PGS's metric for damped contact nodes (its
    diagonal blocks ``d_inv``, and ``cross`` the off-diagonal ones of spring-held rigid bodies'
    6x6 blocks), each node's by its ``omega`` [n] (a body's two nodes share theirs)."""
    i = wp.tid()
    out[i] = omega[i] * d_inv[i]
    out_cross[i] = omega[i] * cross[i]


@wp.kernel
def island_inverse(island_start: wp.array(dtype=wp.int32), island_node: wp.array(dtype=wp.int32),
                   island_local: wp.array(dtype=wp.int32), row_start: wp.array(dtype=wp.int32),
                   block_col: wp.array(dtype=wp.int32), blocks: wp.array(dtype=wp.mat33d),
                   scratch: wp.array3d(dtype=wp.float64), inverse: wp.array3d(dtype=wp.float64)):
    """``inverse[t]`` [3 k, 3 k] (mixed units, [1/kg] to [1/(kg m^2)]) = the inverse of island
    ``t``'s block ``A_II`` of ``A`` over its ``k`` nodes ``island_node[island_start[t]:
    island_start[t + 1]]`` (``island_local``: a node's place in its island), by Gauss-Jordan
    elimination on ``scratch[t]`` (A_II is symmetric positive definite: no pivoting)."""
    t = wp.tid()
    s = island_start[t]
    count = island_start[t + 1] - s
    size = 3 * count
    for r in range(size):
        for c in range(size):
            scratch[t, r, c] = wp.float64(0.0)
            inverse[t, r, c] = wp.float64(0.0)
        inverse[t, r, r] = wp.float64(1.0)
    for li in range(count):
        i = island_node[s + li]
        for k in range(row_start[i], row_start[i + 1]):
            lj = island_local[block_col[k]]
            if lj >= 0:
                block = blocks[k]
                for x in range(3):
                    for y in range(3):
                        scratch[t, 3 * li + x, 3 * lj + y] = block[x, y]
    for p in range(size):
        pivot = scratch[t, p, p]
        for c in range(size):
            scratch[t, p, c] = scratch[t, p, c] / pivot
            inverse[t, p, c] = inverse[t, p, c] / pivot
        for r in range(size):
            if r != p:
                f = scratch[t, r, p]
                for c in range(size):
                    scratch[t, r, c] = scratch[t, r, c] - f * scratch[t, p, c]
                    inverse[t, r, c] = inverse[t, r, c] - f * inverse[t, p, c]


@wp.func
def _island_residual(i: int, row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                     blocks: wp.array(dtype=wp.mat33d), island_local: wp.array(dtype=wp.int32),
                     b: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d)) -> wp.vec3d:
    """``b_i - sum_{j not in I} A_ij w_j`` [kg m/s] of island node ``i`` (the j: driven nodes)."""
    r = b[i]
    for k in range(row_start[i], row_start[i + 1]):
        j = block_col[k]
        if island_local[j] < 0:
            r = r - blocks[k] * w[j]
    return r


@wp.func
def _island_row(t: int, li: int, size: int, inverse: wp.array3d(dtype=wp.float64),
                rhs: wp.array2d(dtype=wp.float64)) -> wp.vec3d:
    """Island ``t``'s node ``li``'s three rows of ``A_II^-1 rhs[t]`` [m/s, rad/s]."""
    out = wp.vec3d()
    for x in range(3):
        acc = wp.float64(0.0)
        for c in range(size):
            acc = acc + inverse[t, 3 * li + x, c] * rhs[t, c]
        out[x] = acc
    return out


@wp.func
def island_solved(t: int, island_start: wp.array(dtype=wp.int32), island_node: wp.array(dtype=wp.int32),
                  island_local: wp.array(dtype=wp.int32), row_start: wp.array(dtype=wp.int32),
                  block_col: wp.array(dtype=wp.int32), blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                  contact_node: wp.array(dtype=wp.int32), inverse: wp.array3d(dtype=wp.float64),
                  rhs: wp.array2d(dtype=wp.float64), last: int, w: wp.array(dtype=wp.vec3d),
                  v_hat: wp.array(dtype=wp.vec3d)):
    """:func:`island_solve` of island ``t``."""
    s = island_start[t]
    count = island_start[t + 1] - s
    for li in range(count):
        if contact_node[island_node[s + li]] != 0:
            return
    for li in range(count):
        r = _island_residual(island_node[s + li], row_start, block_col, blocks, island_local, b, w)
        for x in range(3):
            rhs[t, 3 * li + x] = r[x]
    for li in range(count):
        out = _island_row(t, li, 3 * count, inverse, rhs)
        i = island_node[s + li]
        w[i] = out
        if last != 0:
            v_hat[i] = out


@wp.kernel
def island_solve(island_start: wp.array(dtype=wp.int32), island_node: wp.array(dtype=wp.int32),
                 island_local: wp.array(dtype=wp.int32), row_start: wp.array(dtype=wp.int32),
                 block_col: wp.array(dtype=wp.int32), blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                 contact_node: wp.array(dtype=wp.int32), inverse: wp.array3d(dtype=wp.float64),
                 rhs: wp.array2d(dtype=wp.float64), last: int, w: wp.array(dtype=wp.vec3d),
                 v_hat: wp.array(dtype=wp.vec3d)):
    """Island ``t``'s velocities [m/s, rad/s] solved exactly from its rows of ``A v = b``,
    ``w_I = A_II^-1 (b_I - sum_{j not in I} A_Ij w_j)`` (the j: driven nodes), into ``w`` and,
    on the sweep's ``last`` pass, ``v_hat``: a block Gauss-Seidel step whose block is the whole
    island (after the colour passes, which updated its bodies one at a time). An island with a
    contact node is left to those (its contacts' metric is each body's own 6x6 block)."""
    island_solved(wp.tid(), island_start, island_node, island_local, row_start, block_col, blocks, b, contact_node,
                  inverse, rhs, last, w, v_hat)


@wp.kernel
def mark_islands(island_start: wp.array(dtype=wp.int32), island_node: wp.array(dtype=wp.int32),
                 contact_node: wp.array(dtype=wp.int32)):
    """Island ``t``'s nodes all contact nodes if any is (:func:`island_contact` updates them)."""
    t = wp.tid()
    touched = int(0)
    for k in range(island_start[t], island_start[t + 1]):
        if contact_node[island_node[k]] != 0:
            touched = 1
    if touched != 0:
        for k in range(island_start[t], island_start[t + 1]):
            contact_node[island_node[k]] = 1


@wp.func
def add_island_forces(c: int, island_local: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
                      stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                      frame: wp.array(dtype=wp.mat33d), rigid_node: wp.array2d(dtype=wp.int32),
                      rigid_lever: wp.array2d(dtype=wp.vec3d), impulse: wp.array(dtype=wp.vec3d),
                      force: wp.array(dtype=wp.vec3d)):
    """Contact ``c``'s last impulse (world ``frame^T lambda``) added into ``force`` at the island
    nodes of its stencil (its weight times it) and of its rigid sides (the lever's torque),
    atomically (:func:`island_force_add`'s threads share nodes). A zero impulse adds zeros, which
    leave every sum as it is (the sums start at +0): most of a step's contacts push nothing."""
    lam = impulse[c]
    if lam[0] == wp.float64(0.0) and lam[1] == wp.float64(0.0) and lam[2] == wp.float64(0.0):
        return
    world = wp.transpose(frame[c]) * lam
    for k in range(stencil_count[c]):
        node = stencil_nodes[c, k]
        if island_local[node] >= 0:
            wp.atomic_add(force, node, stencil_weights[c, k] * world)
    for side in range(rigid_node.shape[1]):
        node = rigid_node[c, side]
        if node >= 0:
            if island_local[node] >= 0:
                wp.atomic_add(force, node, wp.cross(rigid_lever[c, side], world))


@wp.func
def island_response(t: int, island_start: wp.array(dtype=wp.int32), island_node: wp.array(dtype=wp.int32),
                    island_local: wp.array(dtype=wp.int32), row_start: wp.array(dtype=wp.int32),
                    block_col: wp.array(dtype=wp.int32), blocks: wp.array(dtype=wp.mat33d),
                    b: wp.array(dtype=wp.vec3d), metric: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32),
                    cross_metric: wp.array(dtype=wp.mat33d), inverse: wp.array3d(dtype=wp.float64),
                    rhs: wp.array2d(dtype=wp.float64), force: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d),
                    v_hat: wp.array(dtype=wp.vec3d)):
    """Island ``t``'s ``v^_I = A_II^-1 (b_I - sum_{j not in I} A_Ij w_j + f) - P f`` from its
    nodes' generalized impulses ``force`` (:func:`island_contact`)."""
    s = island_start[t]
    n = island_start[t + 1] - s
    for li in range(n):
        i = island_node[s + li]
        r = _island_residual(i, row_start, block_col, blocks, island_local, b, w) + force[i]
        for x in range(3):
            rhs[t, 3 * li + x] = r[x]
    for li in range(n):
        i = island_node[s + li]
        out = _island_row(t, li, 3 * n, inverse, rhs)
        pushed = metric[i] * force[i]
        if partner[i] >= 0:
            pushed = pushed + cross_metric[i] * force[partner[i]]
        v_hat[i] = out - pushed


@wp.kernel
def island_contact(island_start: wp.array(dtype=wp.int32), island_node: wp.array(dtype=wp.int32),
                   island_local: wp.array(dtype=wp.int32), row_start: wp.array(dtype=wp.int32),
                   block_col: wp.array(dtype=wp.int32), blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                   metric: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32),
                   cross_metric: wp.array(dtype=wp.mat33d), contact_node: wp.array(dtype=wp.int32),
                   inverse: wp.array3d(dtype=wp.float64), rhs: wp.array2d(dtype=wp.float64),
                   count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
                   stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                   frame: wp.array(dtype=wp.mat33d), rigid_node: wp.array2d(dtype=wp.int32),
                   rigid_lever: wp.array2d(dtype=wp.vec3d), impulse: wp.array(dtype=wp.vec3d),
                   force: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d)):
    """Step 2 on an island in contact (its nodes all contact nodes, :func:`mark_islands`; one
    thread for all islands: contacts may share them): with ``f = J_I^T lambda`` [N s, N m s]
    the generalized impulses of the contacts' last ``impulse`` (world ``frame^T lambda``: a
    stencil node takes its weight times it, a rigid side's angular node its lever's torque),

        v^_I = A_II^-1 (b_I - sum_{j not in I} A_Ij w_j + f) - P f

    [m/s, rad/s], P (``metric``, ``cross_metric``: :func:`island_metric`) the metric with
    which the contact PGS then applies ``P J^T lambda``: the sweep's update is the
    island's exact response to the last impulses, and the PGS's change of them moves each body
    by its own block of the island's inverse; the fixed point is the island's rows of
    ``A v = b + J^T lambda``. Undamped, as every exact rigid body's contact-node update
    (:class:`softvr.contact.node_gauss_seidel.GaussSeidelSweep`)."""
    for t in range(island_start.shape[0] - 1):
        s = island_start[t]
        n = island_start[t + 1] - s
        if contact_node[island_node[s]] == 0:
            continue
        for li in range(n):
            force[island_node[s + li]] = wp.vec3d()
        for c in range(count[0]):
            add_island_forces(c, island_local, stencil_count, stencil_nodes, stencil_weights, frame, rigid_node,
                              rigid_lever, impulse, force)
        island_response(t, island_start, island_node, island_local, row_start, block_col, blocks, b, metric, partner,
                        cross_metric, inverse, rhs, force, w, v_hat)


@wp.kernel
def island_metric(island_start: wp.array(dtype=wp.int32), island_node: wp.array(dtype=wp.int32),
                  island_local: wp.array(dtype=wp.int32), partner: wp.array(dtype=wp.int32),
                  inverse: wp.array3d(dtype=wp.float64), metric: wp.array(dtype=wp.mat33d),
                  cross_metric: wp.array(dtype=wp.mat33d)):
    """The contact PGS's metric on island ``t``'s nodes [1/kg, mixed]: each body's own 6x6 block of ``A_II^-1`` (its response to an impulse on it, the island's other
    bodies moving as its springs make them), in place of the inverse of the body's own block."""
    t = wp.tid()
    s = island_start[t]
    for k in range(s, island_start[t + 1]):
        i = island_node[k]
        li = island_local[i]
        lp = island_local[partner[i]]
        own = wp.mat33d()
        other = wp.mat33d()
        for x in range(3):
            for y in range(3):
                own[x, y] = inverse[t, 3 * li + x, 3 * li + y]
                other[x, y] = inverse[t, 3 * li + x, 3 * lp + y]
        metric[i] = own
        cross_metric[i] = other


# The Gauss-Seidel sweeps' one-thread walks over a step's contacts in a GPU's form (a thread per
# contact or island; one GPU thread walking the contacts waits on every load in turn).


@wp.kernel
def woken_parallel(count: wp.array(dtype=wp.int32), asleep: wp.array(dtype=wp.int32),
                   impulse: wp.array(dtype=wp.vec3d), flag: wp.array(dtype=wp.int32), threads: int):
    """:func:`woken` with ``threads`` threads striding over the contacts, ``flag`` zeroed before
    (every thread that finds one writes the same 1)."""
    for c in range(wp.tid(), count[0], threads):
        lam = impulse[c]
        if asleep[c] != 0 and (lam[0] != wp.float64(0.0) or lam[1] != wp.float64(0.0) or lam[2] != wp.float64(0.0)):
            flag[0] = 1


@wp.kernel
def island_force_clear(island_node: wp.array(dtype=wp.int32), force: wp.array(dtype=wp.vec3d)):
    """:func:`island_contact`'s forces zeroed at every island node (a thread each)."""
    force[island_node[wp.tid()]] = wp.vec3d()


@wp.kernel
def island_force_add(island_local: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32),
                     stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                     stencil_weights: wp.array2d(dtype=wp.float64), frame: wp.array(dtype=wp.mat33d),
                     rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
                     impulse: wp.array(dtype=wp.vec3d), force: wp.array(dtype=wp.vec3d), threads: int):
    """:func:`island_contact`'s generalized impulses ``f = J_I^T lambda`` [N s, N m s] of the
    contacts' last impulses at the island nodes, ``threads`` threads striding over the contacts
    (atomic adds: contacts share nodes; on one CPU thread in contact order, the one-thread
    form's order)."""
    for c in range(wp.tid(), count[0], threads):
        add_island_forces(c, island_local, stencil_count, stencil_nodes, stencil_weights, frame, rigid_node,
                          rigid_lever, impulse, force)


@wp.kernel
def island_respond(island_start: wp.array(dtype=wp.int32), island_node: wp.array(dtype=wp.int32),
                   island_local: wp.array(dtype=wp.int32), row_start: wp.array(dtype=wp.int32),
                   block_col: wp.array(dtype=wp.int32), blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                   metric: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32),
                   cross_metric: wp.array(dtype=wp.mat33d), contact_node: wp.array(dtype=wp.int32),
                   inverse: wp.array3d(dtype=wp.float64), rhs: wp.array2d(dtype=wp.float64),
                   force: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d)):
    """:func:`island_contact`'s response of island ``t`` (a thread each) in contact, from
    :func:`island_force_add`'s forces."""
    t = wp.tid()
    if contact_node[island_node[island_start[t]]] != 0:
        island_response(t, island_start, island_node, island_local, row_start, block_col, blocks, b, metric, partner,
                        cross_metric, inverse, rhs, force, w, v_hat)

