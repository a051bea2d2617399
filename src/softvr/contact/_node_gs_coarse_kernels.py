"""Compiled coarse correction of the multicolour Gauss-Seidel sweeps (thesis eq. 5.6, its outer
iteration made two-level; :mod:`softvr.contact.node_gs_coarse` records them). One source for CPU
and CUDA.

After a symmetric Gauss-Seidel sweep has written ``v^`` (forward colours, the contact nodes'
damped update and the contact PGS, backward colours), each aggregate ``g`` of a held body's free
nodes (:func:`softvr.contact.node_coarse.coarse_aggregates`) takes the rigid motion that solves
its Galerkin system over the residual the sweep left:

    r = b - A v^                                    (the aggregates' rows, whole)
    y_g = (P_g^T A P_g)^-1 P_g^T r                  P_g,i = [I, -[rho_i]x]
    v^_i += y_lin + y_ang x rho_i                   (i in g)

over the aggregate's nodes that are not contact nodes (``rho_i`` the node's offset from their
mass centre at the step's start). The contact nodes are held: their velocities are the PGS's
projection, and moving them would undo it (the fixed point stays eq. 5.5's ``A v = b + J^T
lambda``: at it ``r`` vanishes on every non-contact row, so ``y`` = 0). The aggregates' solves
are independent (block-diagonal, one thread each), all from the same ``v^``, then applied.

Without contacts the sweep's error operator becomes ``(I - Q A)(I - M^-1 A)``, ``Q = sum_g
P_g (P_g^T A P_g)^-1 P_g^T`` and ``M = (D + L) D^-1 (D + U)``: both factors are self-adjoint in
the ``A`` inner product and the second is positive semidefinite, so its eigenvalues are real
and the Chebyshev weights over bounds of the spectrum of ``I`` minus it stay sound
(:func:`softvr.contact.node_gs_coarse.gauss_seidel_coarse_spectrum` estimates them). The
aggregates' rigid motions are the smooth modes that the node sweeps remove slowest (the
shoulder's deltoid and tendons); Toselli and Widlund, Domain Decomposition Methods (2005),
ch. 2, for the two-level multiplicative Schwarz iteration.
"""

from __future__ import annotations

import warp as wp

from softvr.contact._node_coarse_kernels import store_inverse

#: Fewest free nodes (not contact nodes) an aggregate needs to take a coarse correction: its
#: six rigid motions must move them independently.
MIN_FREE = 4


@wp.kernel
def prepare_aggregates(start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32),
                       q: wp.array(dtype=wp.vec3d), mass: wp.array(dtype=wp.float64),
                       row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                       blocks: wp.array(dtype=wp.mat33d), node_aggregate: wp.array(dtype=wp.int32),
                       contact_node: wp.array(dtype=wp.int32), centre: wp.array(dtype=wp.vec3d),
                       ll: wp.array(dtype=wp.mat33d), la: wp.array(dtype=wp.mat33d), aa: wp.array(dtype=wp.mat33d),
                       active: wp.array(dtype=wp.int32)):
    """Aggregate ``g`` (nodes ``nodes[start[g]:start[g + 1]]``, ``node_aggregate`` [n] each
    node's): the mass centre [m] of its nodes that are not ``contact_node``, and the blocks of
    ``(P_g^T A P_g)^-1`` over them (``ll`` [1/kg], ``la`` [1/(kg m)], ``aa`` [1/(kg m^2)]) from
    this step's ``blocks`` by the Schur complement of the linear block; ``active[g]`` 0 where
    fewer than :data:`MIN_FREE` such nodes remain or their rotations are degenerate (the
    Schur complement's determinant under 1e-9 of its scale)."""
    g = wp.tid()
    active[g] = 0
    total = wp.float64(0.0)
    c = wp.vec3d()
    count = int(0)
    for t in range(start[g], start[g + 1]):
        i = nodes[t]
        if contact_node[i] == 0:
            total = total + mass[i]
            c = c + mass[i] * q[i]
            count = count + 1
    if count < MIN_FREE:
        return
    c = c / total
    centre[g] = c
    sll = wp.mat33d()
    sla = wp.mat33d()
    saa = wp.mat33d()
    for t in range(start[g], start[g + 1]):
        i = nodes[t]
        if contact_node[i] == 0:
            ri = wp.skew(q[i] - c)
            for k in range(row_start[i], row_start[i + 1]):
                j = block_col[k]
                if node_aggregate[j] == g and contact_node[j] == 0:
                    a = blocks[k]
                    rj = wp.skew(q[j] - c)
                    sll = sll + a
                    sla = sla - a * rj
                    saa = saa - ri * a * rj
    schur = saa - wp.transpose(sla) * wp.inverse(sll) * sla
    scale = wp.trace(schur) / wp.float64(3.0)
    if not (wp.determinant(schur) > wp.float64(1e-9) * scale * scale * scale):
        return
    store_inverse(g, sll, sla, saa, ll, la, aa)
    active[g] = 1


# aggregate_velocity: :func:`coarse_velocities`' thread as C++, the same wp:: operations in the same
# order as Warp's code of it and of :func:`softvr.contact._node_jacobi_kernels.row_residual` (so the
# same bits), with none of Warp's per-access index arithmetic and range iterators (the shoulder's 33
# aggregates over ~5 000 blocks of A: ~28 -> ~21 us a sweep). It reads the arrays as contiguous
# (:meth:`softvr.contact.node_gauss_seidel.GaussSeidelSweep.record` checks that they are).
_AGGREGATE_VELOCITY = r"""
typedef wp::vec_t<3, wp::float64> vec3;
typedef wp::mat_t<3, 3, wp::float64> mat3;
const wp::int32* rows = (const wp::int32*)row_start.data;
const wp::int32* col = (const wp::int32*)block_col.data;
const mat3* a = (const mat3*)blocks.data;
const vec3* x = (const vec3*)v_hat.data;
const vec3* rhs = (const vec3*)b.data;
const vec3* at = (const vec3*)q.data;
const wp::int32* held = (const wp::int32*)contact_node.data;
const wp::int32* member = (const wp::int32*)nodes.data;
vec3 force = vec3();
vec3 torque = vec3();
if (((const wp::int32*)active.data)[g] != 0) {
    const vec3 c = ((const vec3*)centre.data)[g];
    for (int t = ((const wp::int32*)start.data)[g], last = ((const wp::int32*)start.data)[g + 1]; t < last; ++t) {
        const int i = member[t];
        if (held[i] != 0) continue;
        vec3 r = rhs[i];
        vec3 odd = vec3();
        const int end = rows[i + 1];
        int k = rows[i];
        while (k + 1 < end) {
            const vec3 even_part = wp::mul(a[k], x[col[k]]);
            r = wp::sub(r, even_part);
            const vec3 odd_part = wp::mul(a[k + 1], x[col[k + 1]]);
            odd = wp::add(odd, odd_part);
            k = k + 2;
        }
        if (k < end) {
            const vec3 part = wp::mul(a[k], x[col[k]]);
            r = wp::sub(r, part);
        }
        r = wp::sub(r, odd);
        force = wp::add(force, r);
        const vec3 arm = wp::sub(at[i], c);
        const vec3 turn = wp::cross(arm, r);
        torque = wp::add(torque, turn);
    }
}
const mat3 m_la = ((const mat3*)la.data)[g];
const vec3 lin_f = wp::mul(((const mat3*)ll.data)[g], force);
const vec3 lin_t = wp::mul(m_la, torque);
((vec3*)y_lin.data)[g] = wp::add(lin_f, lin_t);
const vec3 ang_f = wp::mul(wp::transpose(m_la), force);
const vec3 ang_t = wp::mul(((const mat3*)aa.data)[g], torque);
((vec3*)y_ang.data)[g] = wp::add(ang_f, ang_t);
"""


@wp.func_native(_AGGREGATE_VELOCITY)
def aggregate_velocity(g: int, start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32),
                        q: wp.array(dtype=wp.vec3d), row_start: wp.array(dtype=wp.int32),
                        block_col: wp.array(dtype=wp.int32), blocks: wp.array(dtype=wp.mat33d),
                        b: wp.array(dtype=wp.vec3d), contact_node: wp.array(dtype=wp.int32),
                        centre: wp.array(dtype=wp.vec3d), ll: wp.array(dtype=wp.mat33d), la: wp.array(dtype=wp.mat33d),
                        aa: wp.array(dtype=wp.mat33d), active: wp.array(dtype=wp.int32),
                        v_hat: wp.array(dtype=wp.vec3d), y_lin: wp.array(dtype=wp.vec3d),
                        y_ang: wp.array(dtype=wp.vec3d)):
    """Aggregate ``g``'s ``y_lin`` [m/s] and ``y_ang`` [rad/s] (:func:`coarse_velocities`)."""
    ...


@wp.kernel
def coarse_velocities(start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                      row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                      blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                      contact_node: wp.array(dtype=wp.int32), centre: wp.array(dtype=wp.vec3d),
                      ll: wp.array(dtype=wp.mat33d), la: wp.array(dtype=wp.mat33d), aa: wp.array(dtype=wp.mat33d),
                      active: wp.array(dtype=wp.int32), v_hat: wp.array(dtype=wp.vec3d),
                      y_lin: wp.array(dtype=wp.vec3d), y_ang: wp.array(dtype=wp.vec3d)):
    """Aggregate ``g``'s coarse velocity ``y = (P^T A P)^-1 P^T r`` (``y_lin`` [m/s], ``y_ang``
    [rad/s]) from the residual ``r = b - A v^`` [kg m/s] of its nodes that are not contact nodes
    (:func:`softvr.contact._node_jacobi_kernels.row_residual`'s sum): their force and torque about
    the centre, solved (0 where not ``active``). In C++ (:data:`_AGGREGATE_VELOCITY`)."""
    aggregate_velocity(wp.tid(), start, nodes, q, row_start, block_col, blocks, b, contact_node, centre, ll, la, aa,
                        active, v_hat, y_lin, y_ang)


# aggregate_apply: :func:`apply_coarse`'s thread as C++, the same wp:: operations in the same order
# (~3.4 -> ~1 us a sweep on the shoulder's 766 aggregated nodes).
_AGGREGATE_APPLY = r"""
typedef wp::vec_t<3, wp::float64> vec3;
if (((const wp::int32*)active.data)[g] == 0) return;
const vec3 c = ((const vec3*)centre.data)[g];
const vec3 lin = ((const vec3*)y_lin.data)[g];
const vec3 ang = ((const vec3*)y_ang.data)[g];
const wp::int32* held = (const wp::int32*)contact_node.data;
const wp::int32* member = (const wp::int32*)nodes.data;
const vec3* at = (const vec3*)q.data;
vec3* out = (vec3*)v_hat.data;
for (int t = ((const wp::int32*)start.data)[g], last = ((const wp::int32*)start.data)[g + 1]; t < last; ++t) {
    const int i = member[t];
    if (held[i] != 0) continue;
    const vec3 moved = wp::add(out[i], lin);
    const vec3 arm = wp::sub(at[i], c);
    const vec3 turn = wp::cross(ang, arm);
    out[i] = wp::add(moved, turn);
}
"""


@wp.func_native(_AGGREGATE_APPLY)
def aggregate_apply(g: int, start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32),
                     q: wp.array(dtype=wp.vec3d), contact_node: wp.array(dtype=wp.int32),
                     centre: wp.array(dtype=wp.vec3d), active: wp.array(dtype=wp.int32),
                     y_lin: wp.array(dtype=wp.vec3d), y_ang: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d)):
    """Aggregate ``g``'s correction of ``v_hat`` [m/s] (:func:`apply_coarse`)."""
    ...


@wp.kernel
def apply_coarse(start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                 contact_node: wp.array(dtype=wp.int32), centre: wp.array(dtype=wp.vec3d),
                 active: wp.array(dtype=wp.int32), y_lin: wp.array(dtype=wp.vec3d), y_ang: wp.array(dtype=wp.vec3d),
                 v_hat: wp.array(dtype=wp.vec3d)):
    """``v^_i += y_lin + y_ang x rho_i`` [m/s] over aggregate ``g``'s nodes that are not contact
    nodes (after every aggregate's :func:`coarse_velocities` read the same ``v^``). In C++
    (:data:`_AGGREGATE_APPLY`)."""
    aggregate_apply(wp.tid(), start, nodes, q, contact_node, centre, active, y_lin, y_ang, v_hat)
