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


@wp.func_native(r"""
const unsigned long long* now = (const unsigned long long*)rotation.data;
unsigned long long* was = (unsigned long long*)seen.data;
const int* corner = (const int*)tets.data;
int* flag = (int*)moved.data;
const int end = start + block < rotation.shape[0] ? start + block : rotation.shape[0];
for (int e = start; e < end; ++e) {
    const unsigned long long* a = now + 9 * e;
    unsigned long long* b = was + 9 * e;
    unsigned long long differ = 0;
    for (int j = 0; j < 9; ++j) differ |= a[j] ^ b[j];
    if (differ != 0) {
        for (int j = 0; j < 9; ++j) b[j] = a[j];
        for (int j = 0; j < 4; ++j) flag[corner[4 * e + j]] = 1;
    }
}
""")
def _tets_moved(start: int, block: int, rotation: wp.array(dtype=wp.mat33d), seen: wp.array(dtype=wp.mat33d),
                tets: wp.array2d(dtype=wp.int32), moved: wp.array(dtype=wp.int32)):
    """:func:`tets_moved`'s items ``start : start + block`` in C++ (contiguous arrays)."""
    ...


@wp.kernel
def tets_moved(rotation: wp.array(dtype=wp.mat33d), seen: wp.array(dtype=wp.mat33d), tets: wp.array2d(dtype=wp.int32),
               moved: wp.array(dtype=wp.int32), block: int, offset: int):
    """``moved[i]`` = 1 on the four nodes ``tets[e]`` of a tet ``e`` whose co-rotation
    ``rotation[e]`` differs from ``seen[e]`` in any bit (a NaN in ``seen`` marks it moved), and
    then ``seen[e] = rotation[e]``; other entries of ``moved`` are left as they are (the caller
    clears them; threads that mark one node write the same 1). Items ``block`` a thread from
    ``(tid + offset) block``."""
    _tets_moved((wp.tid() + offset) * block, block, rotation, seen, tets, moved)


@wp.kernel
def node_rotations(force_start: wp.array(dtype=wp.int32), force: wp.array(dtype=wp.int32),
                   tet_weight: wp.array(dtype=wp.float64), tet_rotation: wp.array(dtype=wp.mat33d),
                   moved: wp.array(dtype=wp.int32), solved: wp.array(dtype=wp.int32),
                   rotation0: wp.array(dtype=wp.mat33d), polar_iterations: int, absolute: wp.array(dtype=wp.mat33d),
                   relative: wp.array(dtype=wp.mat33d), turned: wp.array(dtype=wp.int32), block: int, offset: int):
    """Solved node ``i = solved[k]``'s rotation: the polar part of its tets' co-rotations
    ``R_e`` summed by their stiffness ``tet_weight`` [N/m] (``force[c] = 4 tet + a`` for ``c``
    in ``force_start[i] : force_start[i + 1]``; Muller and Gross's stiffness warping) into
    ``absolute[k]``, and turned back by the factorization's ``rotation0[k]``: ``relative[i] =
    absolute[k] rotation0[k]^T``. Newton's iteration ``X <- (X + X^-T) / 2`` from the sum
    scaled to unit determinant (the sums are near rotations; P needs R to a few digits). Only
    where one of the node's tets has ``moved`` (:func:`tets_moved`; the others' sums are what
    they were, so are their rotations): ``turned[i] = 1`` there. Items ``block`` a thread."""
    start = (wp.tid() + offset) * block
    for k in range(start, wp.min(start + block, solved.shape[0])):
        i = solved[k]
        if moved[i] == 0:
            continue
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
        turned[i] = 1


@wp.func_native(r"""
const double* block = (const double*)blocks.data;
const double* x = (const double*)v.data;
const double* rhs = (const double*)b.data + 3 * i;
double r0 = rhs[0];
double r1 = rhs[1];
double r2 = rhs[2];
for (int c = ((const int*)row_start.data)[i], end = ((const int*)row_start.data)[i + 1]; c < end; ++c) {
    const double* m = block + 9 * c;
    const double* y = x + 3 * ((const int*)block_col.data)[c];
    double u = m[0] * y[0];
    double w = m[1] * y[1];
    u = u + w;
    w = m[2] * y[2];
    r0 = r0 - (u + w);
    u = m[3] * y[0];
    w = m[4] * y[1];
    u = u + w;
    w = m[5] * y[2];
    r1 = r1 - (u + w);
    u = m[6] * y[0];
    w = m[7] * y[1];
    u = u + w;
    w = m[8] * y[2];
    r2 = r2 - (u + w);
}
return wp::vec_t<3, wp::float64>(r0, r1, r2);
""")
def _row_residual(i: int, row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                  blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                  v: wp.array(dtype=wp.vec3d)) -> wp.vec3d:
    """``b_i - sum_j A_ij v_j`` [kg m/s] of node ``i`` in C++ (contiguous arrays; the same
    products and sums in the same order as Warp's ``acc - A_ij v_j``, so the same bits, at
    about half the cost of Warp's loop)."""
    ...


@wp.kernel
def turned_residual(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                    blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d), solved: wp.array(dtype=wp.int32),
                    rotation: wp.array(dtype=wp.mat33d), v: wp.array(dtype=wp.vec3d), r: wp.array(dtype=wp.vec3d),
                    block: int, offset: int):
    """``r_k = R_i^T (b_i - sum_j A_ij v_j)`` [kg m/s] of solved node ``i = solved[k]``: eq.
    5.2's residual turned back by the node's rotation since the factorization. Items ``block``
    a thread."""
    start = (wp.tid() + offset) * block
    for k in range(start, wp.min(start + block, solved.shape[0])):
        i = solved[k]
        r[k] = wp.transpose(rotation[i]) * _row_residual(i, row_start, block_col, blocks, b, v)


@wp.kernel
def turned_update(index: wp.array(dtype=wp.int32), rotation: wp.array(dtype=wp.mat33d), v: wp.array(dtype=wp.vec3d),
                  y: wp.array(dtype=wp.vec3d), u: wp.array(dtype=wp.vec3d), f: wp.array(dtype=wp.vec3d),
                  largest: wp.array(dtype=wp.float64), block: int, offset: int):
    """``u_i = v_i + R_i y_k`` [m/s] of node ``i``, ``k = index[i]`` its row among the solved
    nodes (``u_i = v_i`` on a node not solved: ``k < 0``), the change ``f_i = u_i - v_i``
    [m/s], and the largest ``|f|`` component of the thread's items in ``largest[tid + offset]``
    (NaN if one is). Items ``block`` a thread."""
    t = wp.tid() + offset
    start = t * block
    biggest = wp.float64(0.0)
    for i in range(start, wp.min(start + block, index.shape[0])):
        k = index[i]
        w = v[i]
        if k >= 0:
            w = v[i] + rotation[i] * y[k]
        u[i] = w
        d = w - v[i]
        f[i] = d
        for c in range(3):
            a = wp.abs(d[c])
            if biggest == biggest:  # a NaN stays
                if a > biggest or a != a:
                    biggest = a
    largest[t] = biggest


# factor_solve's loops in C++ (contiguous arrays): Warp's generated code spends most of a block
# on index tests and stride multiplies around its 9 multiplications (0.2 ms for the head CT's
# 204 K entries). The same operations in the same order as Warp's 3 x 3 products, so the same
# bits, four lanes at a time (clang's vector extensions; the fourth lane is padding): the
# blocks are stored transposed (a block's columns contiguous, the arrays one block longer for
# the padding lane's read). One right-hand side (NRHS 1): a lane is a row of the block, its
# products summed as Warp's matrix-vector product ((m0 y0 + m1 y1) + m2 y2; 80 -> 55 us a
# solve on the head CT); three (NRHS 3, a mat33d's columns): a lane is a column of the
# right-hand sides, the products accumulated with fused multiply-adds as Warp's matrix-matrix
# product.
_SOLVE = r"""
typedef double v4 __attribute__((vector_size(32)));
auto load = [](const double* p) -> v4 { v4 r; __builtin_memcpy(&r, p, 32); return r; };
auto splat = [](double s) -> v4 { v4 r = {s, s, s, s}; return r; };
const int* pr = (const int*)perm_r_inverse.data;
const int* pc = (const int*)perm_c.data;
const double* in = (const double*)rhs.data;
double* w = (double*)work.data;
double* out = (double*)x.data;
const int k = rhs.shape[0];
const int B = 3 * NRHS;  // doubles in a block of work
for (int half = 0; half < 2; ++half) {
    const int* start = (const int*)(half == 0 ? lower_start.data : upper_start.data);
    const int* col = (const int*)(half == 0 ? lower_col.data : upper_col.data);
    const double* off = (const double*)(half == 0 ? lower.data : upper.data);
    const double* inv = (const double*)(half == 0 ? lower_inverse.data : upper_inverse.data);
    for (int s = 0; s < k; ++s) {
        const int p = half == 0 ? s : k - 1 - s;  // forward: L w = Pr rhs; backward: U w' = w
        v4 acc[NRHS == 1 ? 1 : 3];
        for (int a = 0; a < 3; ++a) {
            const double* from = half == 0 ? in + (pr[3 * p + a] / 3) * B + (pr[3 * p + a] % 3) * NRHS
                                           : w + p * B + a * NRHS;
#if NRHS == 1
            acc[0][a] = from[0];
#else
            acc[a] = (v4){from[0], from[1], from[2], 0.0};
#endif
        }
#if NRHS == 1
        acc[0][3] = 0.0;
#endif
        for (int c = start[p], end = start[p + 1]; c < end; ++c) {
            const double* m = off + 9 * c;  // transposed: m[3 r + a] is row a, column r
            const double* y = w + col[c] * B;
#if NRHS == 1
            v4 u = load(m) * splat(y[0]);
            v4 v = load(m + 3) * splat(y[1]);
            u = u + v;
            v = load(m + 6) * splat(y[2]);
            acc[0] = acc[0] - (u + v);
#else
            const v4 y0 = load(y), y1 = load(y + 3), y2 = load(y + 6);
            for (int a = 0; a < 3; ++a) {
                acc[a] = acc[a] - __builtin_elementwise_fma(splat(m[6 + a]), y2,
                                  __builtin_elementwise_fma(splat(m[3 + a]), y1, splat(m[a]) * y0));
            }
#endif
        }
        const double* m = inv + 9 * p;
#if NRHS == 1
        v4 u = load(m) * splat(acc[0][0]);
        v4 v = load(m + 3) * splat(acc[0][1]);
        u = u + v;
        v = load(m + 6) * splat(acc[0][2]);
        u = u + v;
        for (int a = 0; a < 3; ++a) w[p * B + a] = u[a];
#else
        for (int a = 0; a < 3; ++a) {
            const v4 t = __builtin_elementwise_fma(splat(m[6 + a]), acc[2],
                         __builtin_elementwise_fma(splat(m[3 + a]), acc[1], splat(m[a]) * acc[0]));
            for (int j = 0; j < 3; ++j) w[p * B + 3 * a + j] = t[j];
        }
#endif
    }
}
for (int i = 0; i < 3 * k; ++i) {  // x = Pc w'
    const double* from = w + (pc[i] / 3) * B + (pc[i] % 3) * NRHS;
    for (int j = 0; j < NRHS; ++j) out[(i / 3) * B + (i % 3) * NRHS + j] = from[j];
}
"""


@wp.func_native("#define NRHS 1\n" + _SOLVE + "#undef NRHS\n")
def _solved(perm_r_inverse: wp.array(dtype=wp.int32), perm_c: wp.array(dtype=wp.int32),
            lower_start: wp.array(dtype=wp.int32), lower_col: wp.array(dtype=wp.int32),
            lower: wp.array(dtype=wp.mat33d), lower_inverse: wp.array(dtype=wp.mat33d),
            upper_start: wp.array(dtype=wp.int32), upper_col: wp.array(dtype=wp.int32),
            upper: wp.array(dtype=wp.mat33d), upper_inverse: wp.array(dtype=wp.mat33d),
            rhs: wp.array(dtype=wp.vec3d), work: wp.array(dtype=wp.vec3d), x: wp.array(dtype=wp.vec3d)):
    """:func:`factor_solve` with one right-hand side (:data:`_SOLVE`)."""
    ...


@wp.func_native("#define NRHS 3\n" + _SOLVE + "#undef NRHS\n")
def _solved(perm_r_inverse: wp.array(dtype=wp.int32), perm_c: wp.array(dtype=wp.int32),
            lower_start: wp.array(dtype=wp.int32), lower_col: wp.array(dtype=wp.int32),
            lower: wp.array(dtype=wp.mat33d), lower_inverse: wp.array(dtype=wp.mat33d),
            upper_start: wp.array(dtype=wp.int32), upper_col: wp.array(dtype=wp.int32),
            upper: wp.array(dtype=wp.mat33d), upper_inverse: wp.array(dtype=wp.mat33d),
            rhs: wp.array(dtype=wp.mat33d), work: wp.array(dtype=wp.mat33d), x: wp.array(dtype=wp.mat33d)):
    """:func:`factor_solve` with three right-hand sides, a mat33d's columns (:data:`_SOLVE`)."""
    ...


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
    start[p + 1]``, block columns ``col``), ``*_inverse`` the inverses of the diagonal blocks,
    all transposed and followed by one more (any) block; ``perm_r_inverse`` the inverse of
    ``Pr``'s ``perm_r``, ``perm_c`` ``Pc``'s, over the flat entries (every array contiguous;
    ``work`` one entry longer than ``rhs``). Forward ``L w = Pr rhs``, backward ``U w' = w``, ``x =
    Pc w'``. Block rows run at SciPy's CSR product speed; SuperLU's own single-vector solve
    spends ~2/3 of its time in BLAS calls per supernode."""
    _solved(perm_r_inverse, perm_c, lower_start, lower_col, lower, lower_inverse, upper_start, upper_col, upper,
            upper_inverse, rhs, work, x)


for _t in (wp.vec3d, wp.mat33d):
    wp.overload(factor_solve, {"rhs": wp.array(dtype=_t), "work": wp.array(dtype=_t), "x": wp.array(dtype=_t)})


@wp.kernel
def warp_change(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                blocks: wp.array(dtype=wp.mat33d), blocks0: wp.array(dtype=wp.mat33d),
                rotation: wp.array(dtype=wp.mat33d), solved: wp.array(dtype=wp.int32),
                moved: wp.array(dtype=wp.int32), turned: wp.array(dtype=wp.int32), change: wp.array(dtype=wp.float64),
                block: int, offset: int):
    """How far node ``i``'s row of ``A`` [kg] is from the factored ``A_0`` turned to the nodes'
    rotations ``R`` (``rotation`` [n], since the factorization): the largest Frobenius norm of
    ``R_i^T A_ij R_j - A0_ij`` over the solved nodes ``j``, over that of ``A0_ii``; 0 on a node
    not solved. Only where it can have changed since the last call: the row's blocks are sums
    over the node's tets of terms of their co-rotations (eq. 5.2 with ``R_e K_e R_e^T``), so a
    node none of whose tets has ``moved`` (:func:`tets_moved`) and none of whose row's nodes
    ``turned`` (:func:`node_rotations`) keeps ``change[i]``. Items ``block`` a thread."""
    start = (wp.tid() + offset) * block
    for i in range(start, wp.min(start + block, solved.shape[0])):
        if solved[i] == 0:
            change[i] = wp.float64(0.0)
            continue
        dirty = turned[i] + moved[i]
        for k in range(row_start[i], row_start[i + 1]):
            dirty = dirty + turned[block_col[k]]
        if dirty == 0:
            continue
        change[i] = wp.float64(0.0)
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
