"""The contact step of a node sweep with a thread per contact (the GPU's form of thesis eq.
5.6's inner loop), and the stop's reductions with a thread per item.

The one-thread form (:mod:`softvr.contact._node_jacobi_kernels`: ``warm_impulses``,
``contacts``, ``residual``, ``largest_change``) walks the contacts in turn, which is what a CPU
core does best and what a GPU cannot do at all: one GPU thread walking a step's contacts waits
on every load in turn. Here every contact takes a thread, through these stages, each a function
over the contacts ``first, first + stride, ...``:

    warm_range        v^ += M^-1 J^T lambda, the last sweep's impulses (atomic adds: contacts
                      share nodes and coarse bodies)
    (screen)          the live contacts, as on the CPU (``screen_contacts``, already strided)
    start_sweep       the sweep counted, ``stats`` zeroed for its maxima
    count_range       per node and per coarse body, how many live contacts act on it
    jacobi_range      every live contact's PGS update from the same v^ (Jacobi over the
                      contacts; where they share nothing, on its block of J M^-1 J^T)
    apply_range       the updates' changes pushed into v^ (atomic)

Where contacts can share a node or coarse body, one thread block runs them all in one launch,
its barrier between the stages, Gauss-Seidel within each lane's contacts and Jacobi on split
masses across lanes (:func:`softvr.contact._node_block_kernels.contact_step_block`);
where none can, no stage waits for another contact's, and one launch over the whole device
runs them without a barrier (:func:`contact_step_unshared`).

Jacobi over contacts that share a node would move that node once per contact, each as if it
were alone: ``n`` contacts pressing one node overshoot it ``n``-fold and the passes diverge.
Each contact therefore solves on *split masses* (Tonge, English and Glimberg 2012, "Mass
splitting for jitter-free parallel rigid body simulation"): every node's (and coarse body's)
inverse mass multiplied by the number ``n_r`` of live contacts acting on it. Its block is then
``W_s = sum_r n_r J_rc M_r^-1 J_rc^T`` over the resources ``r`` it acts on, and since
``(sum_c J_rc lambda_c)^T M_r^-1 (sum_c J_rc lambda_c) <= n_r sum_c lambda_c^T J_rc^T M_r^-1 J_rc
lambda_c`` (Cauchy-Schwarz), ``blockdiag(W_s) >= W``: the Jacobi passes are a convergent
splitting of the contacts' Delassus operator (proved for the frictionless normal rows, a
projected Jacobi iteration on a symmetric positive system; with friction and adhesion, as for
PGS itself, measured: docs/physics-core.md). The fixed point is unchanged: a live contact's
update leaves it where it is exactly where its relative velocity meets eq. 5.5's target,
whichever positive block it divides by. A contact that shares nothing (``n_r`` = 1: a cube's
points on a plane) takes the Gauss-Seidel update itself.

Atomic adds sum in no fixed order on CUDA: a step's last bits may differ from run to run there.
"""

from __future__ import annotations

import warp as wp

from softvr.contact._node_coarse_kernels import SIDES, Coarse, coarse_side_w
from softvr.contact._node_contact_native import screen_contacts
from softvr.contact._node_jacobi_kernels import _rigid_velocity, nan_as_inf, pgs_update

_ZERO = wp.constant(wp.float64(0.0))


@wp.func
def _moving(c: int, v: wp.array(dtype=wp.vec3d), stencil_count: wp.array(dtype=wp.int32),
            stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
            rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d)) -> wp.vec3d:
    """Contact ``c``'s relative velocity [m/s] (world) in the node velocities ``v``: its stencil's
    weighted velocities and its rigid sides' ``omega x lever``."""
    rel = wp.vec3d()
    for k in range(stencil_count[c]):
        rel = rel + stencil_weights[c, k] * v[stencil_nodes[c, k]]
    return rel + _rigid_velocity(c, v, rigid_node, rigid_lever)


@wp.func
def relative(c: int, v_hat: wp.array(dtype=wp.vec3d), stencil_count: wp.array(dtype=wp.int32),
              stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
              rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
              co: Coarse) -> wp.vec3d:
    """Contact ``c``'s relative velocity ``J v^`` [m/s] (world) in the sweep's ``v^``
    (:func:`_moving`) and its coarse bodies' ``s y_lin + y_ang x L``."""
    rel = _moving(c, v_hat, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever)
    for s in range(SIDES):
        b = co.side[c, s]
        if b < 0:
            break
        rel = rel + co.weight[c, s] * co.y_lin[b] + wp.cross(co.y_ang[b], co.lever[c, s])
    return rel


@wp.func
def push(node: int, g: wp.vec3d, v_hat: wp.array(dtype=wp.vec3d), d_inv: wp.array(dtype=wp.mat33d),
          partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d)):
    """``v^ += M^-1 e_node g`` [m/s] for the generalized impulse ``g`` on ``node`` (atomic): a
    spring-held rigid body's partner node moves by its cross block."""
    wp.atomic_add(v_hat, node, d_inv[node] * g)
    p = partner[node]
    if p >= 0:
        wp.atomic_add(v_hat, p, cross[p] * g)


@wp.func
def _apply(c: int, world: wp.vec3d, stencil_count: wp.array(dtype=wp.int32),
           stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
           rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
           d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
           fixed: wp.array(dtype=wp.int32), v_hat: wp.array(dtype=wp.vec3d), co: Coarse):
    """``v^ += M^-1 J_c^T world`` [m/s] for contact ``c``'s impulse ``world`` [N s] (atomic): its
    stencil's free nodes by their weights, a rigid side's angular node by the torque ``lever x
    world``, its coarse bodies' velocities by their share (the one-thread form's ``apply``)."""
    for k in range(stencil_count[c]):
        node = stencil_nodes[c, k]
        if fixed[node] == 0:
            push(node, stencil_weights[c, k] * world, v_hat, d_inv, partner, cross)
    for s in range(rigid_node.shape[1]):
        node = rigid_node[c, s]
        if node >= 0:
            push(node, wp.cross(rigid_lever[c, s], world), v_hat, d_inv, partner, cross)
    for s in range(SIDES):
        b = co.side[c, s]
        if b < 0:
            break
        g = co.weight[c, s] * world
        t = wp.cross(co.lever[c, s], world)
        wp.atomic_add(co.y_lin, b, co.ll[b] * g + co.la[b] * t)
        wp.atomic_add(co.y_ang, b, wp.transpose(co.la[b]) * g + co.aa[b] * t)


@wp.func
def warm_range(first: int, stride: int, count: wp.array(dtype=wp.int32), movable: wp.array(dtype=wp.int32),
               stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
               stencil_weights: wp.array2d(dtype=wp.float64), frame: wp.array(dtype=wp.mat33d),
               rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
               d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
               fixed: wp.array(dtype=wp.int32), impulse: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d),
               co: Coarse):
    """``v^ += M^-1 J^T lambda`` [m/s] for the last sweep's impulses ``impulse`` [c] [N s] of the
    movable contacts among ``first, first + stride, ... < count[0]`` (atomic: contacts share
    nodes and coarse bodies; a zero impulse moves nothing)."""
    for c in range(first, count[0], stride):
        lam = impulse[c]
        if movable[c] != 0 and (lam[0] != _ZERO or lam[1] != _ZERO or lam[2] != _ZERO):
            _apply(c, wp.transpose(frame[c]) * lam, stencil_count, stencil_nodes, stencil_weights, rigid_node,
                   rigid_lever, d_inv, partner, cross, fixed, v_hat, co)


@wp.func
def count_range(first: int, stride: int, count: wp.array(dtype=wp.int32), live: wp.array(dtype=wp.int32),
                stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                stencil_weights: wp.array2d(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
                fixed: wp.array(dtype=wp.int32), co: Coarse, node_share: wp.array(dtype=wp.int32),
                body_share: wp.array(dtype=wp.int32)):
    """``node_share[i]``, ``body_share[b]`` += how many ``live`` contacts among ``first, first +
    stride, ... < count[0]`` act on free node ``i`` (a nonzero stencil weight, or a rigid side's
    angular node) and on coarse body ``b`` (atomic)."""
    for c in range(first, count[0], stride):
        if live[c] != 0:
            for k in range(stencil_count[c]):
                node = stencil_nodes[c, k]
                if fixed[node] == 0 and stencil_weights[c, k] != _ZERO:
                    wp.atomic_add(node_share, node, 1)
            for s in range(rigid_node.shape[1]):
                node = rigid_node[c, s]
                if node >= 0:
                    wp.atomic_add(node_share, node, 1)
            for s in range(SIDES):
                b = co.side[c, s]
                if b < 0:
                    break
                wp.atomic_add(body_share, b, 1)


@wp.func
def start_sweep(sweep: wp.array(dtype=wp.int32), stats: wp.array(dtype=wp.float64)):
    """The sweep counted in ``sweep[0]`` (the Chebyshev weights' index), ``stats`` zeroed for its
    maxima (the Chebyshev kernel's ``atomic`` form and :func:`residual_parallel` take them)."""
    sweep[0] = sweep[0] + 1
    for k in range(stats.shape[0]):
        stats[k] = _ZERO


@wp.func
def share_of(node: int, node_share: wp.array(dtype=wp.int32), partner: wp.array(dtype=wp.int32)) -> wp.float64:
    """The split factor ``n_r`` of ``node``: the live contacts on it, or on its 6x6 pair's other
    node where more (a spring-held rigid body's two nodes are one block of ``D_A``), at least 1."""
    n = node_share[node]
    p = partner[node]
    if p >= 0:
        n = wp.max(n, node_share[p])
    return wp.float64(wp.max(n, 1))


@wp.func
def solved(old: wp.vec3d, rel_f: wp.vec3d, w_f: wp.mat33d, f: wp.mat33d, gap: wp.float64, dt: wp.float64,
            mu: wp.float64, stiffness: wp.float64, slip: wp.vec3d, local_updates: int) -> wp.vec3d:
    """A one-node contact without a rigid side solved on its own block ``w_f`` (the one-thread
    form's ``solved``, :func:`softvr.contact._node_contact_native.pgs_passes`): the sticking
    impulse where it pushes within the Coulomb disc, else up to ``local_updates`` projected
    updates (:func:`pgs_update`), each seeing the last one's change of the relative velocity."""
    if stiffness > _ZERO:
        return pgs_update(old, rel_f, w_f, f, gap, dt, mu, stiffness, slip)
    w_nn = w_f[0, 0]
    if w_nn > _ZERO:
        if wp.determinant(w_f) > wp.float64(1e-12) * w_nn * w_nn * w_nn:
            stick = old + wp.inverse(w_f) * (wp.vec3d(-gap / dt, _ZERO, _ZERO) - rel_f)
            if stick[0] >= _ZERO and wp.sqrt(stick[1] * stick[1] + stick[2] * stick[2]) <= mu * stick[0]:
                return stick
    lam = old
    rel = rel_f
    for _u in range(local_updates):
        nxt = pgs_update(lam, rel, w_f, f, gap, dt, mu, stiffness, slip)
        step = nxt - lam
        rel = rel + w_f * step
        lam = nxt
        if wp.length(step) <= wp.float64(1e-12) * wp.length(lam):
            break
    return lam


@wp.func
def updated(c: int, f: wp.mat33d, rel_f: wp.vec3d, w_f: wp.mat33d, impulse: wp.array(dtype=wp.vec3d),
            stencil_count: wp.array(dtype=wp.int32), rigid_node: wp.array2d(dtype=wp.int32),
            gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64), dt: wp.float64,
            stiffness: wp.array(dtype=wp.float64), slip: wp.array(dtype=wp.vec3d), local_updates: int) -> wp.vec3d:
    """Contact ``c``'s impulse [N s] (its frame ``f``) after one update from its relative velocity
    ``rel_f`` [m/s] on its block ``w_f`` [1/kg], both in that frame: by :func:`pgs_update` (normal
    row to ``-gap / dt``, adhesion's bound eq. 4.16 where ``stiffness`` > 0, the tangents onto
    the Coulomb disc of ``friction`` or the bond's bound aiming at ``slip`` [m]); a one-node
    contact without a rigid side by :func:`solved`."""
    rigid = int(0)
    for s in range(rigid_node.shape[1]):
        if rigid_node[c, s] >= 0:
            rigid = 1
    if stencil_count[c] == 1 and rigid == 0:
        return solved(impulse[c], rel_f, w_f, f, gap[c], dt, friction[c], stiffness[c], slip[c], local_updates)
    return pgs_update(impulse[c], rel_f, w_f, f, gap[c], dt, friction[c], stiffness[c], slip[c])


@wp.func
def jacobi_range(first: int, stride: int, count: wp.array(dtype=wp.int32), live: wp.array(dtype=wp.int32),
                 stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                 stencil_weights: wp.array2d(dtype=wp.float64), frame: wp.array(dtype=wp.mat33d),
                 gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
                 rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d), dt: wp.float64,
                 impulse: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d),
                 stiffness: wp.array(dtype=wp.float64), slip: wp.array(dtype=wp.vec3d), co: Coarse,
                 metric: wp.array(dtype=wp.mat33d), local_updates: int, change: wp.array(dtype=wp.vec3d)):
    """One Jacobi pass over the ``live`` contacts among ``first, first + stride, ... <
    count[0]``: each one's impulse ``impulse[c]`` [N s] updated (:func:`updated`) from its
    relative velocity in ``v_hat`` [m/s] (read only: every contact of the pass sees the same) on
    the step's block ``metric[c]`` (``contact_metric``'s). The change of its world impulse goes
    to ``change[c]`` for :func:`apply_range`."""
    for c in range(first, count[0], stride):
        if live[c] == 0:
            continue
        f = frame[c]
        rel_f = f * relative(c, v_hat, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever, co)
        old = impulse[c]
        lam = updated(c, f, rel_f, metric[c], impulse, stencil_count, rigid_node, gap, friction, dt, stiffness, slip,
                      local_updates)
        impulse[c] = lam
        change[c] = wp.transpose(f) * (lam - old)


@wp.func
def apply_range(first: int, stride: int, count: wp.array(dtype=wp.int32), live: wp.array(dtype=wp.int32),
                stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                stencil_weights: wp.array2d(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
                rigid_lever: wp.array2d(dtype=wp.vec3d), d_inv: wp.array(dtype=wp.mat33d),
                partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d), fixed: wp.array(dtype=wp.int32),
                change: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d), co: Coarse):
    """The pass's impulse changes ``change[c]`` [N s] (world) of the ``live`` contacts among
    ``first, first + stride, ... < count[0]`` pushed into ``v_hat`` [m/s] and the coarse
    velocities with the true masses (atomic: contacts share nodes), after
    :func:`jacobi_range` read them all."""
    for c in range(first, count[0], stride):
        if live[c] == 0:
            continue
        d = change[c]
        if d[0] != _ZERO or d[1] != _ZERO or d[2] != _ZERO:
            _apply(c, d, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever, d_inv, partner, cross,
                   fixed, v_hat, co)


@wp.kernel
def contact_step_unshared(count: wp.array(dtype=wp.int32), movable: wp.array(dtype=wp.int32),
                          stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                          stencil_weights: wp.array2d(dtype=wp.float64), frame: wp.array(dtype=wp.mat33d),
                          gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
                          rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
                          d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32),
                          cross: wp.array(dtype=wp.mat33d), fixed: wp.array(dtype=wp.int32), dt: wp.float64,
                          impulse: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d),
                          stiffness: wp.array(dtype=wp.float64), slip: wp.array(dtype=wp.vec3d), co: Coarse,
                          metric: wp.array(dtype=wp.mat33d), local_updates: int, change: wp.array(dtype=wp.vec3d),
                          live: wp.array(dtype=wp.int32), sweep: wp.array(dtype=wp.int32),
                          stats: wp.array(dtype=wp.float64), passes: int, threads: int):
    """A sweep's whole contact step in one launch where no two contacts act on one node or coarse
    body (``_contacts_may_share`` false: a cube's points on a plane): each thread takes its
    contacts ``tid, tid + threads, ... < count[0]`` through the warm start
    (:func:`warm_range`), the screen into ``live``
    (:func:`softvr.contact._node_contact_native.screen_contacts`) and ``passes`` Jacobi passes on
    the step's ``metric`` (:func:`jacobi_range`, :func:`apply_range`), thread 0 starting the
    sweep (:func:`start_sweep`). No stage waits for another thread's: a contact's stages read
    and write only its own nodes, which no other contact moves. With one thread (the CPU) the
    stages run over all the contacts in turn, the one-thread form's order."""
    tid = wp.tid()
    warm_range(tid, threads, count, movable, stencil_count, stencil_nodes, stencil_weights, frame, rigid_node,
               rigid_lever, d_inv, partner, cross, fixed, impulse, v_hat, co)
    screen_contacts(tid, count[0], threads, 0, movable, stencil_count, stencil_nodes, stencil_weights, frame, gap,
                    rigid_node, rigid_lever, dt, impulse, stiffness, v_hat, movable, co.side, co.weight, co.lever,
                    co.y_lin, co.y_ang, live, live)
    if tid == 0:
        start_sweep(sweep, stats)
    for _p in range(passes):
        jacobi_range(tid, threads, count, live, stencil_count, stencil_nodes, stencil_weights, frame, gap, friction,
                     rigid_node, rigid_lever, dt, impulse, v_hat, stiffness, slip, co, metric, local_updates, change)
        apply_range(tid, threads, count, live, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever,
                    d_inv, partner, cross, fixed, change, v_hat, co)


@wp.kernel
def residual_parallel(count: wp.array(dtype=wp.int32), stencil_count: wp.array(dtype=wp.int32),
                      stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                      frame: wp.array(dtype=wp.mat33d), gap: wp.array(dtype=wp.float64),
                      rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
                      dt: wp.float64, v: wp.array(dtype=wp.vec3d), impulse: wp.array(dtype=wp.vec3d),
                      friction: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
                      slip: wp.array(dtype=wp.vec3d), metric: wp.array(dtype=wp.mat33d),
                      movable: wp.array(dtype=wp.int32), gap_after: wp.array(dtype=wp.float64),
                      stats: wp.array(dtype=wp.float64), threads: int):
    """The one-thread form's ``residual`` (eq. 5.5's residual in ``v`` [m/s] and ``impulse``
    [N s]: each contact's linearized gap after the step into ``gap_after`` [m], the largest
    normal-velocity error into ``stats[1]``, the largest natural residual of the movable
    contacts into ``stats[2]``, both [m/s]) with ``threads`` threads striding over the
    ``count[0]`` contacts, the maxima taken atomically into ``stats`` (zeroed since the last
    check by :func:`start_sweep`; NaN counts as +inf)."""
    for c in range(wp.tid(), count[0], threads):
        f = frame[c]
        rel_f = f * _moving(c, v, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever)
        vn = rel_f[0]
        gap_after[c] = gap[c] + dt * vn
        error = -gap[c] / dt - vn
        lam = impulse[c]
        if lam[0] > _ZERO:
            error = wp.abs(error)
        wp.atomic_max(stats, 1, nan_as_inf(error))
        if movable[c] != 0:
            w_f = metric[c]
            step = w_f * (pgs_update(lam, rel_f, w_f, f, gap[c], dt, friction[c], stiffness[c], slip[c]) - lam)
            wp.atomic_max(stats, 2, nan_as_inf(wp.max(wp.abs(step[0]), wp.max(wp.abs(step[1]), wp.abs(step[2])))))
