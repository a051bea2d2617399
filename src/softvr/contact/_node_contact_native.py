"""The node sweeps' contact PGS (thesis eq. 5.6's inner loop, eq. 5.5's contacts:
:mod:`softvr.contact._node_jacobi_kernels`) as plain C++ (``wp.func_native``), one source for
CPU and CUDA: the last impulses applied to ``v^``, the screen of the contacts, the PGS passes over
the live ones (adhesion's bounds, eq. 4.16) and the stop's residual.

In Warp's code each call of a per-contact function (the relative velocity, the update, the
impulse's push) copied its ~20 array arguments (~80 bytes each) and the coarse struct (10
arrays), and each array access paid the index arithmetic of its strides: the shoulder's held
finger's 8 extra passes over its ~7 contacts cost ~27 us a sweep (~0.5 us a contact update),
the screen ~45 ns a contact. Here one C++ loop reads the arrays through their strides and calls
the same ``wp::`` operations in the same order as Warp's generated code of the functions it
replaced (session 12's ``_relative``, ``_apply``, ``contact_update``, and the coarse bodies'
``coarse_velocity`` and ``coarse_apply``) and of :func:`softvr.contact._node_jacobi_kernels.pgs_update`
and :func:`softvr.contact._adhesion_kernels.adhesive_bound`, which other kernels still take in
Warp (each operation a statement of its own, as in Warp's code: no multiply-add fused in one and
not the other), so the impulses and velocities are the same to the bit.
"""

from __future__ import annotations

import warp as wp

#: Projected updates of a contact's impulse on its own block per visit of the PGS passes where
#: it does not stick (:func:`pgs_passes`, its one-node contacts): the isotropic tangent step's
#: error on the block falls by ``1 - w_min / w_max`` an update (a draped cloth vertex: 0.4-0.8).
LOCAL_UPDATES = 8

# The shared C++: element access through an array's byte strides (any layout), and the
# per-contact pieces as lambdas over the snippet's arguments (their names are the parameters').
_ACCESS = r"""
typedef wp::vec_t<3, wp::float64> vec3;
typedef wp::mat_t<3, 3, wp::float64> mat3;
auto at1 = [](const auto& a, int i) -> decltype(*a.data) {
    return *(decltype(a.data))((char*)a.data + (long long)i * a.strides[0]);
};
auto at2 = [](const auto& a, int i, int j) -> decltype(*a.data) {
    return *(decltype(a.data))((char*)a.data + (long long)i * a.strides[0] + (long long)j * a.strides[1]);
};
const wp::float64 zero = 0.0;
// Contact c's relative velocity J v [m/s] (world) in the velocities vel from its stencil and its
// rigid sides' omega x lever (_node_jacobi_kernels._rigid_velocity).
auto moving = [&](const auto& vel, int c) -> vec3 {
    vec3 rel = vec3();
    const int count = at1(stencil_count, c);
    for (int k = 0; k < count; ++k) {
        const vec3 part = wp::mul(at2(stencil_weights, c, k), at1(vel, at2(stencil_nodes, c, k)));
        rel = wp::add(rel, part);
    }
    vec3 rigid = vec3();
    for (int s = 0, sides = rigid_node.shape[1]; s < sides; ++s) {
        const int node = at2(rigid_node, c, s);
        if (node >= 0) {
            const vec3 part = wp::cross(at1(vel, node), at2(rigid_lever, c, s));
            rigid = wp::add(rigid, part);
        }
    }
    return wp::add(rel, rigid);
};
"""

# Contact c's relative velocity J v^ [m/s] (world) in the sweep's v^, its coarse bodies' s y_lin +
# y_ang x L included.
_RELATIVE = r"""
auto relative = [&](int c) -> vec3 {
    const vec3 moved = moving(v_hat, c);
    vec3 coarse = vec3();
    for (int s = 0, sides = co_side.shape[1]; s < sides; ++s) {
        const int b = at2(co_side, c, s);
        if (b < 0) break;
        const vec3 part = wp::mul(at2(co_weight, c, s), at1(co_y_lin, b));
        const vec3 sum = wp::add(coarse, part);
        const vec3 turn = wp::cross(at1(co_y_ang, b), at2(co_lever, c, s));
        coarse = wp::add(sum, turn);
    }
    return wp::add(moved, coarse);
};
"""

# The PGS update of one contact (_node_jacobi_kernels.pgs_update, adhesive_bound inlined as it is).
_UPDATE = r"""
auto bound = [&](wp::float64 k, wp::float64 d_bar, wp::float64 diag) -> wp::float64 {
    const wp::float64 num = wp::mul(k, d_bar);
    const wp::float64 kd = wp::mul(k, diag);
    const wp::float64 den = wp::add(wp::float64(1.0), kd);
    return wp::div(num, den);
};
auto pgs = [&](const vec3& old, const vec3& rel_f, const mat3& w_f, const mat3& f, wp::float64 gap_c,
               wp::float64 mu, wp::float64 stiff, const vec3& slip_c) -> vec3 {
    vec3 lam = old;
    const wp::float64 dt2 = wp::mul(dt, dt);
    const wp::float64 k_ad = wp::mul(dt2, stiff);
    const wp::float64 w_nn = w_f.data[0][0];
    if (w_nn > zero) {
        const wp::float64 target = wp::div(wp::neg(gap_c), dt);
        const wp::float64 miss = wp::sub(target, rel_f[0]);
        const wp::float64 reach = wp::div(miss, w_nn);
        const wp::float64 free_n = wp::add(old[0], reach);
        wp::float64 lam_n = wp::max(free_n, zero);
        if (k_ad > zero) {
            const wp::float64 held = wp::mul(w_nn, old[0]);
            const wp::float64 ahead = wp::div(gap_c, dt);
            const wp::float64 d0 = wp::sub(held, ahead);
            const wp::float64 d_bar = wp::sub(d0, rel_f[0]);
            const wp::float64 target2 = wp::div(wp::neg(gap_c), dt);
            const wp::float64 miss2 = wp::sub(target2, rel_f[0]);
            const wp::float64 reach2 = wp::div(miss2, w_nn);
            const wp::float64 free2 = wp::add(old[0], reach2);
            const wp::float64 pull = wp::min(bound(k_ad, d_bar, w_nn), zero);
            lam_n = wp::max(free2, pull);
        }
        const vec3 dn = vec3(wp::sub(lam_n, old[0]), zero, zero);
        const vec3 moved = wp::mul(w_f, dn);
        const vec3 rel = wp::add(rel_f, moved);
        lam = vec3(lam_n, old[1], old[2]);
        const wp::float64 diag_sum = wp::add(w_f.data[1][1], w_f.data[2][2]);
        const wp::float64 mean = wp::mul(wp::float64(0.5), diag_sum);
        const wp::float64 diag_diff = wp::sub(w_f.data[1][1], w_f.data[2][2]);
        const wp::float64 half = wp::mul(wp::float64(0.5), diag_diff);
        const wp::float64 hh = wp::mul(half, half);
        const wp::float64 off = wp::mul(w_f.data[1][2], w_f.data[2][1]);
        const wp::float64 rad = wp::sqrt(wp::add(hh, off));
        const wp::float64 w_t = wp::add(mean, rad);
        if (w_t > zero) {
            wp::float64 t1 = wp::sub(lam[1], wp::div(rel[1], w_t));
            wp::float64 t2 = wp::sub(lam[2], wp::div(rel[2], w_t));
            wp::float64 limit = wp::mul(mu, lam_n);
            wp::float64 norm = wp::sqrt(wp::add(wp::mul(t1, t1), wp::mul(t2, t2)));
            if (k_ad > zero) {
                const vec3 u = wp::mul(f, slip_c);
                const wp::float64 a1 = wp::sub(wp::div(wp::neg(u[1]), dt), rel[1]);
                t1 = wp::add(lam[1], wp::div(a1, w_t));
                const wp::float64 a2 = wp::sub(wp::div(wp::neg(u[2]), dt), rel[2]);
                t2 = wp::add(lam[2], wp::div(a2, w_t));
                norm = wp::sqrt(wp::add(wp::mul(t1, t1), wp::mul(t2, t2)));
                const wp::float64 coulomb = wp::mul(mu, wp::max(lam_n, zero));
                limit = wp::max(coulomb, bound(k_ad, wp::mul(w_t, norm), w_t));
            }
            if (norm > limit) {
                const wp::float64 scale = wp::div(limit, norm);
                t1 = wp::mul(t1, scale);
                t2 = wp::mul(t2, scale);
            }
            lam = vec3(lam_n, t1, t2);
        }
    }
    return lam;
};
"""

# v^ += M^-1 J_c^T world for contact c's impulse world [N s] (its stencil's free nodes, a rigid side's
# angular node the torque lever x world, a spring-held body's partner node its cross block), and its
# coarse bodies' share (Warp's _apply, _push and coarse_apply were these operations).
_APPLY = r"""
// v^ += M^-1 e_node g: a spring-held rigid body's partner node moves by its cross block.
auto push = [&](int node, const vec3& g) {
    vec3& mine = at1(v_hat, node);
    mine = wp::add(mine, wp::mul(at1(d_inv, node), g));
    const int p = at1(partner, node);
    if (p >= 0) {
        vec3& theirs = at1(v_hat, p);
        theirs = wp::add(theirs, wp::mul(at1(cross, p), g));
    }
};
auto apply = [&](int c, const vec3& world) {
    const int count = at1(stencil_count, c);
    for (int k = 0; k < count; ++k) {
        const int node = at2(stencil_nodes, c, k);
        if (at1(fixed, node) == 0) push(node, wp::mul(at2(stencil_weights, c, k), world));
    }
    for (int s = 0, sides = rigid_node.shape[1]; s < sides; ++s) {
        const int node = at2(rigid_node, c, s);
        if (node >= 0) push(node, wp::cross(at2(rigid_lever, c, s), world));
    }
    for (int s = 0, sides = co_side.shape[1]; s < sides; ++s) {
        const int b = at2(co_side, c, s);
        if (b < 0) break;
        const vec3 g = wp::mul(at2(co_weight, c, s), world);
        const vec3 t = wp::cross(at2(co_lever, c, s), world);
        vec3& lin = at1(co_y_lin, b);
        lin = wp::add(wp::add(lin, wp::mul(at1(co_ll, b), g)), wp::mul(at1(co_la, b), t));
        vec3& ang = at1(co_y_ang, b);
        ang = wp::add(wp::add(ang, wp::mul(wp::transpose(at1(co_la, b)), g)), wp::mul(at1(co_aa, b), t));
    }
};
"""

_PASSES = _ACCESS + _RELATIVE + _UPDATE + _APPLY + r"""
// A one-node contact without rigid side solved on its own block (_node_jacobi_kernels' LOCAL_UPDATES
// docs: pgs_passes): the sticking impulse, else up to local_updates projected updates.
auto solved = [&](const vec3& old, const vec3& rel_f, const mat3& w_f, const mat3& f, wp::float64 gap_c,
                  wp::float64 mu, wp::float64 stiff, const vec3& slip_c) -> vec3 {
    if (stiff > zero) return pgs(old, rel_f, w_f, f, gap_c, mu, stiff, slip_c);
    const wp::float64 w_nn = w_f.data[0][0];
    if (w_nn > zero) {
        const wp::float64 cube = wp::mul(wp::mul(wp::mul(wp::float64(1e-12), w_nn), w_nn), w_nn);
        if (wp::determinant(w_f) > cube) {
            const vec3 aim = vec3(wp::div(wp::neg(gap_c), dt), zero, zero);
            const vec3 miss = wp::sub(aim, rel_f);
            const vec3 stick = wp::add(old, wp::mul(wp::inverse(w_f), miss));
            const wp::float64 tangent = wp::sqrt(wp::add(wp::mul(stick[1], stick[1]), wp::mul(stick[2], stick[2])));
            if (stick[0] >= zero && tangent <= wp::mul(mu, stick[0])) return stick;
        }
    }
    vec3 lam = old;
    vec3 rel = rel_f;
    for (int u = 0; u < local_updates; ++u) {
        const vec3 nxt = pgs(lam, rel, w_f, f, gap_c, mu, stiff, slip_c);
        const vec3 step = wp::sub(nxt, lam);
        rel = wp::add(rel, wp::mul(w_f, step));
        lam = nxt;
        if (wp::length(step) <= wp::mul(wp::float64(1e-12), wp::length(lam))) break;
    }
    return lam;
};
for (int pass = 0; pass < passes; ++pass) {
    for (int i = 0; i < n; ++i) {
        const int c = at1(order, i);
        const mat3 f = at1(frame, c);
        const vec3 rel_f = wp::mul(f, relative(c));
        const mat3 w_f = at1(metric, c);
        const vec3 old = at1(impulse, c);
        bool rigid = false;
        for (int s = 0, sides = rigid_node.shape[1]; s < sides; ++s) {
            if (at2(rigid_node, c, s) >= 0) {
                rigid = true;
                break;
            }
        }
        vec3 lam;
        if (at1(stencil_count, c) == 1 && !rigid) {
            lam = solved(old, rel_f, w_f, f, at1(gap, c), at1(friction, c), at1(stiffness, c), at1(slip, c));
        } else {
            lam = pgs(old, rel_f, w_f, f, at1(gap, c), at1(friction, c), at1(stiffness, c), at1(slip, c));
        }
        at1(impulse, c) = lam;
        apply(c, wp::mul(wp::transpose(f), wp::sub(lam, old)));
    }
}
"""

_WARM = _ACCESS + _APPLY + r"""
for (int m = 0; m < end; ++m) {
    const int c = listed != 0 ? at1(movers, m) : m;
    if (listed == 0 && at1(movable, c) == 0) continue;  // (a list holds movable contacts only)
    const vec3 lam = at1(impulse, c);
    if (lam[0] != zero || lam[1] != zero || lam[2] != zero) apply(c, wp::mul(wp::transpose(at1(frame, c)), lam));
}
"""

_SCREEN = _ACCESS + _RELATIVE + r"""
int live_count = 0;
for (int m = first; m < end; m += stride) {
    const int c = listed != 0 ? at1(movers, m) : m;
    int on = 0;
    if (listed != 0 || at1(movable, c) != 0) {  // (a list holds movable contacts only)
        const vec3 lam = at1(impulse, c);
        if (lam[0] != zero || lam[1] != zero || lam[2] != zero) {
            on = 1;
        } else if (at1(stiffness, c) > zero) {
            on = 1;
        } else {
            const vec3 rel = relative(c);
            const mat3 f = at1(frame, c);
            const vec3 normal = vec3(f.data[0][0], f.data[0][1], f.data[0][2]);
            if (wp::dot(normal, rel) < wp::div(wp::neg(at1(gap, c)), dt)) on = 1;
        }
    }
    at1(live, c) = on;
    if (on != 0 && listed != 0) {
        at1(order, live_count) = c;
        live_count = live_count + 1;
    }
}
return live_count;
"""


@wp.func_native(_PASSES)
def pgs_passes(n: int, order: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
               stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
               frame: wp.array(dtype=wp.mat33d), gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
               rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
               d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
               fixed: wp.array(dtype=wp.int32), dt: wp.float64, passes: int, impulse: wp.array(dtype=wp.vec3d),
               v_hat: wp.array(dtype=wp.vec3d), stiffness: wp.array(dtype=wp.float64), slip: wp.array(dtype=wp.vec3d),
               metric: wp.array(dtype=wp.mat33d), co_side: wp.array2d(dtype=wp.int32),
               co_weight: wp.array2d(dtype=wp.float64), co_lever: wp.array2d(dtype=wp.vec3d),
               co_y_lin: wp.array(dtype=wp.vec3d), co_y_ang: wp.array(dtype=wp.vec3d), co_ll: wp.array(dtype=wp.mat33d),
               co_la: wp.array(dtype=wp.mat33d), co_aa: wp.array(dtype=wp.mat33d), local_updates: int):
    """``passes`` projected Gauss-Seidel passes over the ``n`` contacts ``order[:n]`` (one thread):
    each contact's impulse ``impulse[c]`` [N s] (its frame ``frame[c]``: normal, tangents) updated
    from its relative velocity in ``v_hat`` [m/s] and its block ``metric[c]`` of ``J M^-1 J^T``
    [1/kg] by :func:`softvr.contact._node_jacobi_kernels.pgs_update` (normal row to ``-gap / dt``,
    adhesion's bound eq. 4.16 where ``stiffness`` > 0, tangents onto the Coulomb disc of
    ``friction`` or the bond's bound aiming at ``slip`` [m]), and the change pushed into ``v_hat``
    (``d_inv``, the spring-held rigid bodies' ``partner`` / ``cross`` blocks, a rigid side's
    torque ``lever x f``) and into the coarse bodies' velocities (``co_*``: the fields of
    :class:`softvr.contact._node_coarse_kernels.Coarse`).

    A contact on one node and no rigid side (a cloth vertex's) is solved on its own block: the
    sticking impulse ``old + w_f^-1 (target - rel_f)`` where it pushes within the Coulomb disc,
    else up to ``local_updates`` (:data:`LOCAL_UPDATES`) projected updates, each seeing the last
    one's change of the relative velocity (an adhesive one takes one). One projected update (the
    isotropic tangent step) leaves a contact's tangent impulse short of its block's solution by
    ``1 - w_min / w_max`` of the tangent eigenvalues, and the normal one short by its coupling to
    the tangents: an error that the next sweep inherits, so the sweep is no fixed map of ``v`` and
    its Chebyshev acceleration cycles. The draped cloth of cloth-sphere.toml (~100 frictional
    contacts, a vertex's ``w_f`` coupling normal and tangent by up to 0.67, tangent eigenvalues
    1.7-5x apart): with one update a visit its Jacobi sweeps ran to 1 000 without converging from
    its 37th step on, its Gauss-Seidel sweeps took 150 a step (60 steps); with this one, 236 and
    100. Every fixed point of this update is one of ``pgs_update``'s: the sticking impulse leaves
    ``rel`` at its target, where the projected update changes nothing. A contact spread over a
    stencil of FEM nodes or held by a rigid body keeps one update a visit (the candy pile's ~30
    pushing contacts of 5-14 nodes: the same sweeps, but the local updates in every one of their
    PGS visits cost ~12 % of its step)."""
    ...


@wp.func_native(_WARM)
def warm_contacts(end: int, listed: int, movers: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
                  stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                  frame: wp.array(dtype=wp.mat33d), rigid_node: wp.array2d(dtype=wp.int32),
                  rigid_lever: wp.array2d(dtype=wp.vec3d), d_inv: wp.array(dtype=wp.mat33d),
                  partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d), fixed: wp.array(dtype=wp.int32),
                  impulse: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d), movable: wp.array(dtype=wp.int32),
                  co_side: wp.array2d(dtype=wp.int32), co_weight: wp.array2d(dtype=wp.float64),
                  co_lever: wp.array2d(dtype=wp.vec3d), co_y_lin: wp.array(dtype=wp.vec3d),
                  co_y_ang: wp.array(dtype=wp.vec3d), co_ll: wp.array(dtype=wp.mat33d),
                  co_la: wp.array(dtype=wp.mat33d), co_aa: wp.array(dtype=wp.mat33d)):
    """``v_hat += M^-1 J^T lambda`` [m/s] for the last sweep's impulses ``impulse`` [N s] (world
    ``frame^T lambda``) of the contacts ``m = 0 .. end - 1`` (``c = movers[m]`` where ``listed``,
    else ``c = m`` if ``movable``), one thread (contacts share nodes): the stencil's free nodes by
    their weights through ``d_inv`` (a spring-held rigid body's partner node by ``cross``), a rigid
    side's angular node by the torque ``lever x f``, the coarse bodies' velocities (``co_*``) by
    their share; a zero impulse moves nothing and is passed over
    (:func:`softvr.contact._node_jacobi_kernels.warm_impulses`)."""
    ...


@wp.func_native(_SCREEN)
def screen_contacts(first: int, end: int, stride: int, listed: int, movers: wp.array(dtype=wp.int32),
                    stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                    stencil_weights: wp.array2d(dtype=wp.float64), frame: wp.array(dtype=wp.mat33d),
                    gap: wp.array(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
                    rigid_lever: wp.array2d(dtype=wp.vec3d), dt: wp.float64, impulse: wp.array(dtype=wp.vec3d),
                    stiffness: wp.array(dtype=wp.float64), v_hat: wp.array(dtype=wp.vec3d),
                    movable: wp.array(dtype=wp.int32), co_side: wp.array2d(dtype=wp.int32),
                    co_weight: wp.array2d(dtype=wp.float64), co_lever: wp.array2d(dtype=wp.vec3d),
                    co_y_lin: wp.array(dtype=wp.vec3d), co_y_ang: wp.array(dtype=wp.vec3d),
                    live: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32)) -> int:
    """``live[c]`` (1: the PGS passes visit contact ``c``) for the contacts ``m = first, first +
    stride, ... < end`` (``c = movers[m]`` where ``listed``: movable ones,
    :func:`softvr.contact._node_jacobi_kernels.list_movers`; else ``c = m``): 1 where ``c`` is
    ``movable`` and pushes or holds (any ``impulse``), may adhere (``stiffness`` > 0), or its
    normal velocity in ``v_hat`` [m/s] is below its target ``-gap / dt``
    (:func:`softvr.contact._node_jacobi_kernels.screen`). Where ``listed``, the live ones also go
    into ``order`` in turn, and their number is returned (else 0)."""
    ...


_RESIDUAL = _ACCESS + _UPDATE + r"""
wp::float64 worst = 0.0;
wp::float64 natural = 0.0;
for (int c = 0, count = at1(contact_count, 0); c < count; ++c) {
    const mat3 f = at1(frame, c);
    const vec3 rel_f = wp::mul(f, moving(v, c));
    const wp::float64 vn = rel_f[0];
    const wp::float64 gap_c = at1(gap, c);
    at1(gap_after, c) = wp::add(gap_c, wp::mul(dt, vn));
    wp::float64 error = wp::sub(wp::div(wp::neg(gap_c), dt), vn);
    const vec3 lam = at1(impulse, c);
    if (lam[0] > zero) error = wp::abs(error);
    worst = wp::max(worst, error);
    if (at1(movable, c) != 0) {
        const mat3 w_f = at1(metric, c);
        const vec3 next = pgs(lam, rel_f, w_f, f, gap_c, at1(friction, c), at1(stiffness, c), at1(slip, c));
        const vec3 step = wp::mul(w_f, wp::sub(next, lam));
        const wp::float64 largest = wp::max(wp::abs(step[0]), wp::max(wp::abs(step[1]), wp::abs(step[2])));
        natural = wp::max(natural, largest);
    }
}
at1(stats, 1) = worst;
at1(stats, 2) = natural;
"""


@wp.func_native(_RESIDUAL)
def contact_residual(contact_count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
                     stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                     frame: wp.array(dtype=wp.mat33d), gap: wp.array(dtype=wp.float64),
                     rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d), dt: wp.float64,
                     v: wp.array(dtype=wp.vec3d), impulse: wp.array(dtype=wp.vec3d),
                     friction: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
                     slip: wp.array(dtype=wp.vec3d),
                     metric: wp.array(dtype=wp.mat33d), movable: wp.array(dtype=wp.int32),
                     gap_after: wp.array(dtype=wp.float64), stats: wp.array(dtype=wp.float64)):
    """:func:`softvr.contact._node_jacobi_kernels.residual`'s loop over the ``contact_count[0]``
    contacts (one thread): each one's linearized gap after the step into ``gap_after`` [m],
    ``stats[1]`` the largest normal-velocity error [m/s], ``stats[2]`` the largest natural
    residual [m/s] of the movable contacts, from the velocities ``v`` [m/s] and the impulses
    [N s]."""
    ...
