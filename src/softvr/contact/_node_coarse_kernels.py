"""Compiled coarse correction of the node sweeps (thesis eq. 5.6's outer Jacobi made two-level):
the rigid motions of aggregates of nodes (each free FEM body whole; a held body's nodes in
spatial aggregates) as a coarse space, solved every sweep.

Node-block Jacobi removes an error mode by about its eigenvalue of ``D_A^-1 A`` per sweep. On a
small stiff body at a long step (candy: ``dt^2 E / (rho h^2)`` ~ 130) the body's rigid motions
are the slowest modes: the stiffness does not act on them, so ``D_A^-1 A`` there is about
``M / (M + dt^2 K_ii)`` (candy: 6e-4, 75-82 Chebyshev sweeps per decade against 8 on the
Jell-O). The two-level additive preconditioner (Toselli and Widlund, Domain Decomposition
Methods, 2005, ch. 2; Nicolaides 1987 for the coarse space of each subdomain's kernel)

    M^-1 = D_A^-1 + sum_b P_b (P_b^T A P_b)^-1 P_b^T,    P_b,i = [I, -[rho_i]x]

(``rho_i`` node ``i``'s offset from its aggregate's mass centre at the step's start; ``P_b y``
moves the aggregate by the linear velocity ``y[:3]`` and the angular ``y[3:]``; the inverse is
taken per aggregate, block-diagonal: additive Schwarz over the aggregates) is symmetric and
positive definite, so Chebyshev over the spectrum of ``M^-1 A`` is sound (candy: 18 sweeps per
decade). A sweep is then, with ``r = b - A v^k``:

    v^   = v^k + D_A^-1 r                                 (the Jacobi kernel, unchanged)
    y_b  = (P_b^T A P_b)^-1 P_b^T r                       (:func:`coarse_residual`)
    PGS over the contacts with the metric M^-1: a contact's impulse f moves its stencil's nodes
         by D_A^-1 w_k f and its bodies' coarse velocities by (P^T A P)^-1 (s f, L x f), with
         s = sum_k w_k and L = sum_k w_k rho_k over the stencil's nodes of that body
    v^_i += y_lin + y_ang x rho_i                         (in the Chebyshev kernel)

The contacts must take the same metric as the residual: the fixed point of
``v <- v + M^-1 (b - A v + J^T lambda)`` is eq. 5.5's ``A v = b + J^T lambda`` only then.
"""

from __future__ import annotations

import warp as wp

#: Coarse sides a contact can have: one per node of its stencil (collision.node_detection's
#: CONTACT_STENCIL), since a held body's aggregates may split a stencil.
SIDES = 16


@wp.struct
class Coarse:
    """Coarse bodies and a contact's coarse sides (one argument for the sweep kernels).

    Attributes
    ----------
    node_body : array(int32) [n]
        Coarse body (aggregate) of each node, -1 for none.
    centre : array(vec3d) [m] [B]
        Mass centre of each coarse body at the step's start.
    ll, la, aa : array(mat33d) [B]
        Blocks of ``(P^T A P)^-1`` (linear-linear [1/kg], linear-angular [1/(kg m)],
        angular-angular [1/(kg m^2)]; angular-linear is ``la^T``).
    y_lin, y_ang : array(vec3d) [B]
        The sweep's coarse velocity of each body: linear [m/s], angular [rad/s].
    side : array2d(int32) [c, SIDES]
        Contact ``c``'s coarse bodies, first ones first (-1: none from there on).
    weight : array2d(float64) [c, SIDES]
        ``s``: the sum of the contact's stencil weights on that body's nodes (+1 side a, -1 b).
    lever : array2d(vec3d) [c, SIDES] [m]
        ``L``: the stencil weights times the nodes' offsets from the body's centre, summed.
    """

    node_body: wp.array(dtype=wp.int32)
    centre: wp.array(dtype=wp.vec3d)
    ll: wp.array(dtype=wp.mat33d)
    la: wp.array(dtype=wp.mat33d)
    aa: wp.array(dtype=wp.mat33d)
    y_lin: wp.array(dtype=wp.vec3d)
    y_ang: wp.array(dtype=wp.vec3d)
    side: wp.array2d(dtype=wp.int32)
    weight: wp.array2d(dtype=wp.float64)
    lever: wp.array2d(dtype=wp.vec3d)


@wp.func
def store_inverse(b: int, ll: wp.mat33d, la: wp.mat33d, aa: wp.mat33d, out_ll: wp.array(dtype=wp.mat33d),
                  out_la: wp.array(dtype=wp.mat33d), out_aa: wp.array(dtype=wp.mat33d)):
    """The blocks of the inverse of the symmetric 6x6 ``[[ll, la], [la^T, aa]]`` into
    ``out_*[b]``, by the Schur complement of the linear block ``ll``."""
    p_inv = wp.inverse(ll)
    s_inv = wp.inverse(aa - wp.transpose(la) * p_inv * la)
    lever = p_inv * la
    out_ll[b] = p_inv + lever * s_inv * wp.transpose(lever)
    out_la[b] = -(lever * s_inv)
    out_aa[b] = s_inv


@wp.func
def row_blocks(i: int, b: int, c: wp.vec3d, q: wp.array(dtype=wp.vec3d), row_start: wp.array(dtype=wp.int32),
               block_col: wp.array(dtype=wp.int32), blocks: wp.array(dtype=wp.mat33d), co: Coarse, ll: wp.mat33d,
               la: wp.mat33d, aa: wp.mat33d):
    """``ll``, ``la``, ``aa`` plus node ``i``'s row of ``P_b^T A P_b`` (body ``b``, centre ``c``
    [m]): the blocks between its own body's nodes only."""
    ri = wp.skew(q[i] - c)
    for k in range(row_start[i], row_start[i + 1]):
        j = block_col[k]
        if co.node_body[j] == b:
            a = blocks[k]
            rj = wp.skew(q[j] - c)
            ll = ll + a
            la = la - a * rj
            aa = aa - ri * a * rj
    return ll, la, aa


@wp.kernel
def prepare_bodies(start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                   mass: wp.array(dtype=wp.float64), row_start: wp.array(dtype=wp.int32),
                   block_col: wp.array(dtype=wp.int32), blocks: wp.array(dtype=wp.mat33d), co: Coarse,
                   offset: int):
    """Coarse body ``b`` = ``tid + offset`` (nodes ``nodes[start[b]:start[b + 1]]``): its mass
    centre and the blocks of ``(P_b^T A P_b)^-1`` from this step's ``blocks`` (only those
    between its own nodes), by the Schur complement of the linear block. A thread writes only
    its body's, so a launch splits over the cores (:func:`softvr.device.chunked_replayer`)."""
    b = wp.tid() + offset
    total = wp.float64(0.0)
    c = wp.vec3d()
    for t in range(start[b], start[b + 1]):
        i = nodes[t]
        total = total + mass[i]
        c = c + mass[i] * q[i]
    c = c / total
    co.centre[b] = c
    ll = wp.mat33d()
    la = wp.mat33d()
    aa = wp.mat33d()
    for t in range(start[b], start[b + 1]):
        ll, la, aa = row_blocks(nodes[t], b, c, q, row_start, block_col, blocks, co, ll, la, aa)
    store_inverse(b, ll, la, aa, co.ll, co.la, co.aa)


@wp.func
def contact_side(c: int, stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                 stencil_weights: wp.array2d(dtype=wp.float64), q: wp.array(dtype=wp.vec3d), co: Coarse):
    """Contact ``c``'s coarse sides: per coarse body met by its stencil, ``s`` and ``L``
    (:class:`Coarse`)."""
    for s in range(SIDES):
        co.side[c, s] = -1
    for k in range(stencil_count[c]):
        node = stencil_nodes[c, k]
        b = co.node_body[node]
        if b >= 0:
            s = int(0)
            while co.side[c, s] >= 0 and co.side[c, s] != b:
                s = s + 1
            if co.side[c, s] < 0:
                co.side[c, s] = b
                co.weight[c, s] = wp.float64(0.0)
                co.lever[c, s] = wp.vec3d()
            w = stencil_weights[c, k]
            co.weight[c, s] = co.weight[c, s] + w
            co.lever[c, s] = co.lever[c, s] + w * (q[node] - co.centre[b])


@wp.kernel
def contact_sides(count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
                  stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                  q: wp.array(dtype=wp.vec3d), co: Coarse, threads: int):
    """The coarse sides of contacts ``wp.tid() + threads k`` below ``count[0]`` (no kernel reads
    the sides past the count; one thread per row of the buffer's capacity cost ~1.3 ms a step
    on the candy, 188 181 rows for ~3 000 contacts)."""
    for c in range(wp.tid(), count[0], threads):
        contact_side(c, stencil_count, stencil_nodes, stencil_weights, q, co)


# _body_sums: a coarse body's force and torque of the sweep's residual as plain C++, the same
# wp:: operations in the same order as Warp's loop would take them (so the same bits), with none
# of its per-access index arithmetic (the candy's 1 709 nodes of coarse bodies: 7.4 -> 5.4 us a
# sweep with the launch). It reads the arrays as contiguous.
_BODY_SUMS = r"""
typedef wp::vec_t<3, wp::float64> vec3;
const vec3* x = (const vec3*)q.data;
const vec3* r = (const vec3*)residual.data;
const vec3 c = ((const vec3*)centre.data)[b];
vec3 force = vec3();
vec3 torque = vec3();
for (int t = start.data[b], end = start.data[b + 1]; t < end; ++t) {
    const int i = nodes.data[t];
    force = wp::add(force, r[i]);
    torque = wp::add(torque, wp::cross(wp::sub(x[i], c), r[i]));
}
wp::vec_t<6, wp::float64> sums;
for (int k = 0; k < 3; ++k) {
    sums[k] = force[k];
    sums[3 + k] = torque[k];
}
return sums;
"""


@wp.func_native(_BODY_SUMS)
def _body_sums(b: int, start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32),
               q: wp.array(dtype=wp.vec3d), residual: wp.array(dtype=wp.vec3d),
               centre: wp.array(dtype=wp.vec3d)) -> wp.types.vector(length=6, dtype=wp.float64):
    """``(sum r_i, sum (q_i - c_b) x r_i)`` [N s, N m s] over coarse body ``b``'s nodes
    (``nodes[start[b]:start[b + 1]]``), in node order (:data:`_BODY_SUMS`)."""
    ...


@wp.kernel
def coarse_residual(start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                    residual: wp.array(dtype=wp.vec3d), co: Coarse):
    """Coarse body ``b``'s velocity ``y = (P^T A P)^-1 P^T r`` from the sweep's residual
    ``r = b - A v`` [kg m/s] (the Jacobi kernel's, :func:`softvr.contact._node_jacobi_kernels.jacobi`):
    the force and the torque about the centre of ``r`` (:func:`_body_sums`), solved."""
    b = wp.tid()
    sums = _body_sums(b, start, nodes, q, residual, co.centre)
    force = wp.vec3d(sums[0], sums[1], sums[2])
    torque = wp.vec3d(sums[3], sums[4], sums[5])
    co.y_lin[b] = co.ll[b] * force + co.la[b] * torque
    co.y_ang[b] = wp.transpose(co.la[b]) * force + co.aa[b] * torque


@wp.func
def coarse_side_w(c: int, s: int, co: Coarse) -> wp.mat33d:
    """Contact ``c``'s share of ``J M^-1 J^T`` [1/kg] through its coarse side ``s`` (body
    ``co.side[c, s]`` >= 0): ``[s I, -[L]x] (P^T A P)^-1 [s I, -[L]x]^T``."""
    b = co.side[c, s]
    sw = co.weight[c, s]
    arm = wp.skew(co.lever[c, s])
    la = co.la[b]
    return (sw * sw) * co.ll[b] + sw * (la * arm + wp.transpose(la * arm)) - arm * co.aa[b] * arm


@wp.func
def coarse_w(c: int, co: Coarse) -> wp.mat33d:
    """Contact ``c``'s share of ``J M^-1 J^T`` [1/kg] through the coarse space: the sum over its
    sides (:func:`coarse_side_w`)."""
    w = wp.mat33d()
    for s in range(SIDES):
        if co.side[c, s] < 0:
            break
        w = w + coarse_side_w(c, s, co)
    return w


@wp.func
def coarse_node(i: int, q: wp.array(dtype=wp.vec3d), co: Coarse) -> wp.vec3d:
    """Node ``i``'s velocity [m/s] from its body's coarse velocity: ``y_lin + y_ang x rho_i``."""
    b = co.node_body[i]
    if b < 0:
        return wp.vec3d()
    return co.y_lin[b] + wp.cross(co.y_ang[b], q[i] - co.centre[b])


# The same sums with a thread per listed node (a GPU's form: one thread walking a body's nodes waits
# on every load in turn), taken with atomic adds into per-body totals that a thread per body then
# solves. The totals' order of summation is free on CUDA: the last bits may differ run to run.


@wp.kernel
def body_mass_parallel(nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                       mass: wp.array(dtype=wp.float64), co: Coarse, total: wp.array(dtype=wp.float64),
                       moment: wp.array(dtype=wp.vec3d)):
    """Per coarse body its mass ``total`` [kg] and first moment ``moment`` [kg m] (zeroed
    before), a thread per listed node ``nodes[t]``."""
    i = nodes[wp.tid()]
    b = co.node_body[i]
    wp.atomic_add(total, b, mass[i])
    wp.atomic_add(moment, b, mass[i] * q[i])


@wp.kernel
def body_centre_parallel(total: wp.array(dtype=wp.float64), moment: wp.array(dtype=wp.vec3d), co: Coarse):
    """Coarse body ``b``'s mass centre [m] from :func:`body_mass_parallel`'s totals."""
    b = wp.tid()
    co.centre[b] = moment[b] / total[b]


@wp.kernel
def body_blocks_parallel(nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                         row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                         blocks: wp.array(dtype=wp.mat33d), co: Coarse, ll: wp.array(dtype=wp.mat33d),
                         la: wp.array(dtype=wp.mat33d), aa: wp.array(dtype=wp.mat33d)):
    """:func:`prepare_bodies`' blocks of ``P_b^T A P_b`` (zeroed before) summed over the row of
    listed node ``nodes[t]`` (a thread each), the blocks between its own body's nodes only."""
    i = nodes[wp.tid()]
    b = co.node_body[i]
    sum_ll, sum_la, sum_aa = row_blocks(i, b, co.centre[b], q, row_start, block_col, blocks, co, wp.mat33d(),
                                        wp.mat33d(), wp.mat33d())
    wp.atomic_add(ll, b, sum_ll)
    wp.atomic_add(la, b, sum_la)
    wp.atomic_add(aa, b, sum_aa)


@wp.kernel
def body_inverse_parallel(ll: wp.array(dtype=wp.mat33d), la: wp.array(dtype=wp.mat33d),
                          aa: wp.array(dtype=wp.mat33d), co: Coarse):
    """Coarse body ``b``'s inverse blocks (:func:`store_inverse`) from :func:`body_blocks_parallel`'s sums."""
    b = wp.tid()
    store_inverse(b, ll[b], la[b], aa[b], co.ll, co.la, co.aa)


@wp.kernel
def residual_sums_parallel(nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                           residual: wp.array(dtype=wp.vec3d), co: Coarse, force: wp.array(dtype=wp.vec3d),
                           torque: wp.array(dtype=wp.vec3d)):
    """:func:`coarse_residual`'s force [N s] and torque [N m s] of the sweep's residual per coarse
    body (zeroed before), a thread per listed node ``nodes[t]``."""
    i = nodes[wp.tid()]
    b = co.node_body[i]
    r = residual[i]
    wp.atomic_add(force, b, r)
    wp.atomic_add(torque, b, wp.cross(q[i] - co.centre[b], r))


@wp.kernel
def coarse_solve_parallel(force: wp.array(dtype=wp.vec3d), torque: wp.array(dtype=wp.vec3d), co: Coarse):
    """Coarse body ``b``'s velocity ``y = (P^T A P)^-1 (force, torque)`` (:func:`coarse_residual`)."""
    b = wp.tid()
    co.y_lin[b] = co.ll[b] * force[b] + co.la[b] * torque[b]
    co.y_ang[b] = wp.transpose(co.la[b]) * force[b] + co.aa[b] * torque[b]
