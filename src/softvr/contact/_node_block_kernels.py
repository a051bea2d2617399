"""A node sweep's contact step in one launch: one thread block whose lanes take the contacts
through every stage (the GPU's form of thesis eq. 5.6's inner loop), the block's barrier between
the stages; and a Gauss-Seidel sweep's node update in two more.

The contact step, :func:`contact_step_block`, where contacts can share nodes or coarse bodies:

    1. node and coarse-body shares zeroed; with ``start``: the last sweep's impulses into v^
    2. with ``start``: the live contacts screened, the sweep counted and ``stats`` zeroed
    3. the visited contacts (the live ones, or with ``tools`` those on a tool's rigid node)
       counted per node and coarse body, each given to a lane by its hub node (:func:`_hub`),
       and every node marked with the lanes whose contacts move it
    4. the lanes' lists of contacts, in contact order
    5. ``passes`` x (each lane walks its contacts in turn | the deferred pushes applied)

Within a lane the passes are projected Gauss-Seidel: a contact's push on a node *private* to
the lane (no other lane's contact moves it) lands at once, on the node's true mass, and the
lane's next contact sees it. Across lanes they are Jacobi on split masses (Tonge, English and
Glimberg 2012; :mod:`softvr.contact._node_parallel_kernels`): a push on a node several lanes move
(and on a coarse body) goes to ``delta`` until the barrier, every contact having read the same
values, and such a node's inverse mass counts once per contact on it. A lane's contacts all
sharing one hub node (a vertex pressed into several triangles of another body: the candy pile's
landing, 8 redundant contacts on one vertex) are then solved as the CPU solves them, where
Jacobi over them moved their impulses ~1 % a check for hundreds of sweeps. Nothing a lane
writes in a pass is read by another lane before the barrier, so the passes are deterministic
whatever the lanes' timing (only the deferred atomic sums' order is the GPU's).

Convergence (frictionless rows; with friction and adhesion measured, as for PGS itself): the
iteration is a block splitting of the contacts' Delassus operator ``W`` into the lanes' blocks
of the split operator ``W_s``, each block taken by one Gauss-Seidel sweep; by Cauchy-Schwarz
over the shared nodes ``blockdiag_lanes(W_s) >= W``, so ``M + M^T - W >= D_s > 0`` for the
splitting matrix ``M`` (the lanes' lower triangles with their diagonals), the condition for a
projected splitting of a symmetric positive system to converge.

One block runs on one streaming multiprocessor: right for a few hundred live contacts and many
dependent passes. Contacts that share nothing need no barrier at all
(:func:`softvr.contact._node_parallel_kernels.contact_step_unshared`, the 64 cubes' thousands
over the whole device). Where a block is one thread (the CPU, unless
``wp.config.enable_cpu_blocks`` runs its lanes as cooperative fibers, as the tests do) the one
lane holds every contact: Gauss-Seidel over all of them on the true masses.

A Gauss-Seidel sweep's node update before and after its contact step takes one block each
(:func:`gauss_seidel_before_contacts`, :func:`gauss_seidel_after_contacts`): a barrier where the
launches' form ended a launch (each colour, the islands, the contact nodes).
"""
from __future__ import annotations

import warp as wp

from softvr.contact._node_coarse_kernels import SIDES, Coarse, coarse_side_w
from softvr.contact._node_contact_native import screen_contacts
from softvr.contact._node_gs_coarse_kernels import aggregate_apply, aggregate_velocity
from softvr.contact._node_gs_kernels import (add_island_forces, colour_node, contact_node_update, island_response,
                                             island_solved, tool_range)
from softvr.contact._node_jacobi_kernels import pair_cross
from softvr.contact._node_parallel_kernels import (count_range, push, relative, share_of, start_sweep, updated,
                                                   warm_range)

wp.set_module_options({"enable_backward": False})

#: Lanes of :func:`contact_step_block`'s one block on CUDA: 8 warps, ~1-10 live contacts a lane
#: on the bundled scenes, and up to 255 registers a lane for its double-precision 3x3 blocks
#: (1 024 lanes would cap them at 64 and spill).
CONTACT_BLOCK_THREADS = 256


@wp.func_native("WP_TILE_SYNC();")
def block_sync():
    """The block's barrier (CUDA's ``__syncthreads``; on the CPU a switch between Warp's
    cooperative fibers, nothing where a block is one thread): every lane's writes before it are
    seen by every lane after it. Every lane of the block must reach it."""
    ...


@wp.kernel(launch_bounds=CONTACT_BLOCK_THREADS)
def gauss_seidel_before_contacts(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                                 blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                                 partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
                                 b: wp.array(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
                                 fixed_velocity: wp.array(dtype=wp.vec3d), contact_node: wp.array(dtype=wp.int32),
                                 order: wp.array(dtype=wp.int32), off_start: wp.array(dtype=wp.int32),
                                 off_col: wp.array(dtype=wp.int32), off_blocks: wp.array(dtype=wp.mat33d),
                                 colour_start: wp.array(dtype=wp.int32), omega: wp.array(dtype=wp.float64),
                                 v: wp.array(dtype=wp.vec3d), w: wp.array(dtype=wp.vec3d),
                                 v_hat: wp.array(dtype=wp.vec3d), island_start: wp.array(dtype=wp.int32),
                                 island_node: wp.array(dtype=wp.int32), island_local: wp.array(dtype=wp.int32),
                                 inverse: wp.array3d(dtype=wp.float64), rhs: wp.array2d(dtype=wp.float64),
                                 islands: int, metric: wp.array(dtype=wp.mat33d),
                                 cross_metric: wp.array(dtype=wp.mat33d), count: wp.array(dtype=wp.int32),
                                 stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                                 stencil_weights: wp.array2d(dtype=wp.float64),
                                 frame: wp.array(dtype=wp.mat33d), rigid_node: wp.array2d(dtype=wp.int32),
                                 rigid_lever: wp.array2d(dtype=wp.vec3d), impulse: wp.array(dtype=wp.vec3d),
                                 force: wp.array(dtype=wp.vec3d)):
    """A Gauss-Seidel sweep's node update up to its contact step in one block
    (:meth:`softvr.contact.node_gauss_seidel.GaussSeidelSweep.record`, steps 1-2 of
    :mod:`softvr.contact._node_gs_kernels`): ``w = v`` [n] [m/s]; the colours ``colour_start``
    [C + 1] ascending (:func:`~softvr.contact._node_gs_kernels.colour_node`, a barrier after
    each: a colour reads the ones before it); the ``islands`` rigid islands solved whole; the
    contact nodes' damped Jacobi update into ``v_hat`` (``omega`` [n]); and where there are
    islands, those in contact solved from their contacts' last ``impulse`` [c] [N s] (forces
    ``force`` [n] zeroed, summed atomically, then each island's response). The arrays are the
    launches' (``gauss_seidel``, ``island_solve``, ``contact_nodes``, ``island_force_*``,
    ``island_respond``)."""
    _block, lane = wp.tid()
    lanes = wp.block_dim()
    n = v.shape[0]
    for i in range(lane, n, lanes):
        w[i] = v[i]
    block_sync()
    for c in range(colour_start.shape[0] - 1):
        for t in range(colour_start[c] + lane, colour_start[c + 1], lanes):
            colour_node(t, row_start, block_col, blocks, d_inv, partner, cross, b, fixed, fixed_velocity, contact_node,
                        order, off_start, off_col, off_blocks, 0, w, v_hat)
        block_sync()
    for t in range(lane, islands, lanes):
        island_solved(t, island_start, island_node, island_local, row_start, block_col, blocks, b, contact_node,
                      inverse, rhs, 0, w, v_hat)
    block_sync()
    for t in range(lane, n, lanes):
        contact_node_update(t, row_start, block_col, blocks, d_inv, partner, cross, b, fixed, fixed_velocity,
                            contact_node, order, off_start, off_col, off_blocks, omega, v, w, v_hat)
    if islands > 0:
        for k in range(lane, island_start[islands], lanes):
            force[island_node[k]] = wp.vec3d()
        block_sync()
        for c in range(lane, count[0], lanes):
            add_island_forces(c, island_local, stencil_count, stencil_nodes, stencil_weights, frame, rigid_node,
                              rigid_lever, impulse, force)
        block_sync()
        for t in range(lane, islands, lanes):
            if contact_node[island_node[island_start[t]]] != 0:
                island_response(t, island_start, island_node, island_local, row_start, block_col, blocks, b, metric,
                                partner, cross_metric, inverse, rhs, force, w, v_hat)


@wp.kernel(launch_bounds=CONTACT_BLOCK_THREADS)
def gauss_seidel_after_contacts(row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                                blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d),
                                partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
                                b: wp.array(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
                                fixed_velocity: wp.array(dtype=wp.vec3d), contact_node: wp.array(dtype=wp.int32),
                                order: wp.array(dtype=wp.int32), off_start: wp.array(dtype=wp.int32),
                                off_col: wp.array(dtype=wp.int32), off_blocks: wp.array(dtype=wp.mat33d),
                                colour_start: wp.array(dtype=wp.int32), w: wp.array(dtype=wp.vec3d),
                                v_hat: wp.array(dtype=wp.vec3d), island_start: wp.array(dtype=wp.int32),
                                island_node: wp.array(dtype=wp.int32), island_local: wp.array(dtype=wp.int32),
                                inverse: wp.array3d(dtype=wp.float64), rhs: wp.array2d(dtype=wp.float64),
                                islands: int, aggregate_start: wp.array(dtype=wp.int32),
                                aggregate_nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                                centre: wp.array(dtype=wp.vec3d), ll: wp.array(dtype=wp.mat33d),
                                la: wp.array(dtype=wp.mat33d), aa: wp.array(dtype=wp.mat33d),
                                active: wp.array(dtype=wp.int32), y_lin: wp.array(dtype=wp.vec3d),
                                y_ang: wp.array(dtype=wp.vec3d), aggregates: int):
    """The rest of the sweep after its contact step, in one block (steps 3-4): ``w = v^`` at the
    contact nodes, the colours descending (their last update: into ``v_hat`` too), the islands
    solved whole again, and with ``aggregates`` > 0 the coarse correction
    (:mod:`softvr.contact._node_gs_coarse_kernels`: every aggregate's velocity from the same
    ``v_hat``, a barrier, then each applied)."""
    _block, lane = wp.tid()
    lanes = wp.block_dim()
    for i in range(lane, v_hat.shape[0], lanes):
        if contact_node[i] != 0:
            w[i] = v_hat[i]
    block_sync()
    colours = colour_start.shape[0] - 1
    for k in range(colours):
        c = colours - 1 - k
        for t in range(colour_start[c] + lane, colour_start[c + 1], lanes):
            colour_node(t, row_start, block_col, blocks, d_inv, partner, cross, b, fixed, fixed_velocity, contact_node,
                        order, off_start, off_col, off_blocks, 1, w, v_hat)
        block_sync()
    for t in range(lane, islands, lanes):
        island_solved(t, island_start, island_node, island_local, row_start, block_col, blocks, b, contact_node,
                      inverse, rhs, 1, w, v_hat)
    if aggregates > 0:
        block_sync()
        for g in range(lane, aggregates, lanes):
            aggregate_velocity(g, aggregate_start, aggregate_nodes, q, row_start, block_col, blocks, b, contact_node,
                               centre, ll, la, aa, active, v_hat, y_lin, y_ang)
        block_sync()
        for g in range(lane, aggregates, lanes):
            aggregate_apply(g, aggregate_start, aggregate_nodes, q, contact_node, centre, active, y_lin, y_ang, v_hat)


@wp.func
def _hub(c: int, stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
         stencil_weights: wp.array2d(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32)) -> int:
    """The node by which contact ``c`` is given to a lane: its first rigid side's (a rigid body's
    contacts in one lane), else its stencil's node of the largest weight (a vertex-triangle
    contact's vertex)."""
    for s in range(rigid_node.shape[1]):
        if rigid_node[c, s] >= 0:
            return rigid_node[c, s]
    best = stencil_nodes[c, 0]
    weight = wp.abs(stencil_weights[c, 0])
    for k in range(1, stencil_count[c]):
        if wp.abs(stencil_weights[c, k]) > weight:
            weight = wp.abs(stencil_weights[c, k])
            best = stencil_nodes[c, k]
    return best


@wp.func
def _mark(node: int, lane: int, partner: wp.array(dtype=wp.int32), own_min: wp.array(dtype=wp.int32),
          own_max: wp.array(dtype=wp.int32)):
    """``lane`` moves ``node`` (and its 6x6 pair's other node): the least and largest such lane
    [n] (atomic)."""
    wp.atomic_min(own_min, node, lane)
    wp.atomic_max(own_max, node, lane)
    p = partner[node]
    if p >= 0:
        wp.atomic_min(own_min, p, lane)
        wp.atomic_max(own_max, p, lane)


@wp.func
def _private(node: int, partner: wp.array(dtype=wp.int32), own_min: wp.array(dtype=wp.int32),
             own_max: wp.array(dtype=wp.int32)) -> int:
    """1 where one lane alone moves ``node`` and its pair's other node (:func:`_mark`)."""
    out = int(0)
    if own_min[node] == own_max[node]:
        out = 1
        p = partner[node]
        if p >= 0:
            if own_min[p] != own_max[p] or own_min[p] != own_min[node]:
                out = 0
    return out


@wp.func
def _split_metric(c: int, stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                 stencil_weights: wp.array2d(dtype=wp.float64), frame: wp.array(dtype=wp.mat33d),
                 rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
                 d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32),
                 cross: wp.array(dtype=wp.mat33d), fixed: wp.array(dtype=wp.int32), co: Coarse,
                 node_share: wp.array(dtype=wp.int32), body_share: wp.array(dtype=wp.int32),
                 own_min: wp.array(dtype=wp.int32), own_max: wp.array(dtype=wp.int32),
                 body_min: wp.array(dtype=wp.int32), body_max: wp.array(dtype=wp.int32)) -> wp.mat33d:
    """Contact ``c``'s block of ``J M_s^-1 J^T`` [1/kg] in its frame: each node's (and rigid
    side's) term and each coarse body's on its true mass where it is private to the contact's
    lane, else times its share (the contacts on it, :func:`share_of`)."""
    w = wp.mat33d()
    for k in range(stencil_count[c]):
        node = stencil_nodes[c, k]
        wk = stencil_weights[c, k]
        if fixed[node] == 0:
            share = share_of(node, node_share, partner)
            if _private(node, partner, own_min, own_max) != 0:
                share = wp.float64(1.0)
            w = w + (wk * wk * share) * d_inv[node]
    for s in range(rigid_node.shape[1]):
        node = rigid_node[c, s]
        if node >= 0:
            arm = wp.skew(rigid_lever[c, s])
            share = share_of(node, node_share, partner)
            if _private(node, partner, own_min, own_max) != 0:
                share = wp.float64(1.0)
            w = w + share * (arm * d_inv[node] * wp.transpose(arm))
            w = w + share * pair_cross(c, s, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever,
                                       partner, cross)
    for s in range(SIDES):
        b = co.side[c, s]
        if b < 0:
            break
        share = wp.float64(wp.max(body_share[b], 1))
        if body_min[b] == body_max[b]:
            share = wp.float64(1.0)
        w = w + share * coarse_side_w(c, s, co)
    f = frame[c]
    return f * w * wp.transpose(f)


@wp.func
def _lane_push(node: int, g: wp.vec3d, v_hat: wp.array(dtype=wp.vec3d), delta: wp.array(dtype=wp.vec3d),
               d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
               own_min: wp.array(dtype=wp.int32), own_max: wp.array(dtype=wp.int32)):
    """The push ``M^-1 e_node g`` into ``v_hat`` [m/s] at once where ``node`` is private, else into
    ``delta`` [m/s] for the barrier."""
    if _private(node, partner, own_min, own_max) != 0:
        push(node, g, v_hat, d_inv, partner, cross)
    else:
        push(node, g, delta, d_inv, partner, cross)


@wp.func
def _lane_apply(c: int, world: wp.vec3d, stencil_count: wp.array(dtype=wp.int32),
                stencil_nodes: wp.array2d(dtype=wp.int32), stencil_weights: wp.array2d(dtype=wp.float64),
                rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
                d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32), cross: wp.array(dtype=wp.mat33d),
                fixed: wp.array(dtype=wp.int32), v_hat: wp.array(dtype=wp.vec3d), delta: wp.array(dtype=wp.vec3d),
                own_min: wp.array(dtype=wp.int32), own_max: wp.array(dtype=wp.int32), co: Coarse,
                body_min: wp.array(dtype=wp.int32), body_max: wp.array(dtype=wp.int32),
                delta_lin: wp.array(dtype=wp.vec3d), delta_ang: wp.array(dtype=wp.vec3d)):
    """``v^ += M^-1 J_c^T world`` [m/s] for contact ``c``'s impulse change ``world`` [N s]
    (:func:`_lane_push` per node: private ones at once), its coarse bodies' velocities by their
    share (a private one's at once, else into ``delta_lin`` [m/s], ``delta_ang`` [rad/s] for the
    barrier)."""
    for k in range(stencil_count[c]):
        node = stencil_nodes[c, k]
        if fixed[node] == 0:
            _lane_push(node, stencil_weights[c, k] * world, v_hat, delta, d_inv, partner, cross, own_min, own_max)
    for s in range(rigid_node.shape[1]):
        node = rigid_node[c, s]
        if node >= 0:
            _lane_push(node, wp.cross(rigid_lever[c, s], world), v_hat, delta, d_inv, partner, cross, own_min,
                       own_max)
    for s in range(SIDES):
        b = co.side[c, s]
        if b < 0:
            break
        g = co.weight[c, s] * world
        t = wp.cross(co.lever[c, s], world)
        lin = co.ll[b] * g + co.la[b] * t
        ang = wp.transpose(co.la[b]) * g + co.aa[b] * t
        if body_min[b] == body_max[b]:
            wp.atomic_add(co.y_lin, b, lin)
            wp.atomic_add(co.y_ang, b, ang)
        else:
            wp.atomic_add(delta_lin, b, lin)
            wp.atomic_add(delta_ang, b, ang)


@wp.kernel(launch_bounds=CONTACT_BLOCK_THREADS)
def contact_step_block(count: wp.array(dtype=wp.int32), movable: wp.array(dtype=wp.int32),
                       stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                       stencil_weights: wp.array2d(dtype=wp.float64), frame: wp.array(dtype=wp.mat33d),
                       gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
                       rigid_node: wp.array2d(dtype=wp.int32), rigid_lever: wp.array2d(dtype=wp.vec3d),
                       d_inv: wp.array(dtype=wp.mat33d), partner: wp.array(dtype=wp.int32),
                       cross: wp.array(dtype=wp.mat33d), fixed: wp.array(dtype=wp.int32), dt: wp.float64,
                       impulse: wp.array(dtype=wp.vec3d), v_hat: wp.array(dtype=wp.vec3d),
                       stiffness: wp.array(dtype=wp.float64), slip: wp.array(dtype=wp.vec3d), co: Coarse,
                       node_share: wp.array(dtype=wp.int32), body_share: wp.array(dtype=wp.int32),
                       local_updates: int, live: wp.array(dtype=wp.int32), sweep: wp.array(dtype=wp.int32),
                       stats: wp.array(dtype=wp.float64), tool_node: wp.array(dtype=wp.int32),
                       visit: wp.array(dtype=wp.int32), start: int, tools: int, passes: int, factor: int,
                       own_min: wp.array(dtype=wp.int32), own_max: wp.array(dtype=wp.int32),
                       body_min: wp.array(dtype=wp.int32), body_max: wp.array(dtype=wp.int32),
                       delta: wp.array(dtype=wp.vec3d), delta_lin: wp.array(dtype=wp.vec3d),
                       delta_ang: wp.array(dtype=wp.vec3d), lane_count: wp.array(dtype=wp.int32),
                       lane_fill: wp.array(dtype=wp.int32), lane_list: wp.array(dtype=wp.int32),
                       crossed: wp.array(dtype=wp.int32)):
    """A sweep's contact step in one block (module docstring; launch ``dim=[1]`` with the block's
    lanes): with ``start``, the last impulses ``impulse`` [c] [N s] of the ``movable`` contacts
    applied to ``v_hat`` [n] [m/s], ``live`` [c] screened
    (:func:`softvr.contact._node_contact_native.screen_contacts`) and the sweep started
    (:func:`softvr.contact._node_parallel_kernels.start_sweep`); then ``passes`` passes over the
    contacts ``visit`` [c] marks (``factor`` x as many where some node or coarse body is moved by
    two lanes: Jacobi across lanes needs more passes than Gauss-Seidel within one; where none is,
    every lane's passes are exact Gauss-Seidel over its own, the CPU's count): ``live`` itself (the
    same array), or with ``tools`` those live ones with a rigid side on a ``tool_node`` [n], marked
    into it first. Scratch: ``node_share`` [n], ``body_share`` [B], ``own_min``, ``own_max`` [n],
    ``body_min``, ``body_max`` [B], ``delta`` [n], ``delta_lin``, ``delta_ang`` [B] (zero between
    calls), ``lane_count`` [lanes + 1], ``lane_fill`` [lanes], ``lane_list`` [capacity], ``crossed``
    [1]. The other arrays are :func:`softvr.contact._node_parallel_kernels.jacobi_range`'s."""
    _block, lane = wp.tid()
    lanes = wp.block_dim()
    n = node_share.shape[0]
    for i in range(lane, n, lanes):
        node_share[i] = 0
        own_min[i] = 1 << 30
        own_max[i] = -1
    for b in range(lane, body_share.shape[0], lanes):
        body_share[b] = 0
        body_min[b] = 1 << 30
        body_max[b] = -1
    lane_count[lane] = 0
    if lane == 0:
        lane_count[lanes] = 0
        crossed[0] = 0
    if start != 0:
        warm_range(lane, lanes, count, movable, stencil_count, stencil_nodes, stencil_weights, frame, rigid_node,
                   rigid_lever, d_inv, partner, cross, fixed, impulse, v_hat, co)
        block_sync()
        screen_contacts(lane, count[0], lanes, 0, movable, stencil_count, stencil_nodes, stencil_weights, frame, gap,
                        rigid_node, rigid_lever, dt, impulse, stiffness, v_hat, movable, co.side, co.weight, co.lever,
                        co.y_lin, co.y_ang, live, live)
        if lane == 0:
            start_sweep(sweep, stats)
    block_sync()
    if tools != 0:
        tool_range(lane, lanes, count, rigid_node, tool_node, live, visit)
    count_range(lane, lanes, count, visit, stencil_count, stencil_nodes, stencil_weights, rigid_node, fixed, co,
                node_share, body_share)
    for c in range(lane, count[0], lanes):
        if visit[c] != 0:
            owner = _hub(c, stencil_count, stencil_nodes, stencil_weights, rigid_node) % lanes
            wp.atomic_add(lane_count, owner, 1)
            for k in range(stencil_count[c]):
                node = stencil_nodes[c, k]
                if fixed[node] == 0 and stencil_weights[c, k] != wp.float64(0.0):
                    _mark(node, owner, partner, own_min, own_max)
            for s in range(rigid_node.shape[1]):
                node = rigid_node[c, s]
                if node >= 0:
                    _mark(node, owner, partner, own_min, own_max)
            for s in range(SIDES):
                b = co.side[c, s]
                if b < 0:
                    break
                wp.atomic_min(body_min, b, owner)
                wp.atomic_max(body_max, b, owner)
    block_sync()
    for c in range(lane, count[0], lanes):  # any node or coarse body two lanes move?
        if visit[c] != 0:
            for k in range(stencil_count[c]):
                node = stencil_nodes[c, k]
                if own_max[node] >= 0:  # (a fixed node or a zero weight marks nothing)
                    if _private(node, partner, own_min, own_max) == 0:
                        crossed[0] = 1
            for s in range(rigid_node.shape[1]):
                node = rigid_node[c, s]
                if node >= 0:
                    if _private(node, partner, own_min, own_max) == 0:
                        crossed[0] = 1
            for s in range(SIDES):
                b = co.side[c, s]
                if b < 0:
                    break
                if body_min[b] != body_max[b]:
                    crossed[0] = 1
    if lane == 0:  # the lanes' segments of lane_list: an exclusive scan of their counts
        total = int(0)
        for k in range(lanes):
            here = lane_count[k]
            lane_count[k] = total
            lane_fill[k] = total
            total = total + here
        lane_count[lanes] = total
    block_sync()
    for c in range(lane, count[0], lanes):
        if visit[c] != 0:
            owner = _hub(c, stencil_count, stencil_nodes, stencil_weights, rigid_node) % lanes
            lane_list[wp.atomic_add(lane_fill, owner, 1)] = c
    block_sync()
    first = lane_count[lane]
    end = lane_count[lane + 1]
    for i in range(first + 1, end):  # the segment ascending (the atomics' order is the GPU's whim)
        c = lane_list[i]
        j = i - 1
        while j >= first and lane_list[j] > c:
            lane_list[j + 1] = lane_list[j]
            j = j - 1
        lane_list[j + 1] = c
    if crossed[0] != 0:
        passes = passes * factor
    for _p in range(passes):
        for i in range(first, end):
            c = lane_list[i]
            f = frame[c]
            rel_f = f * relative(c, v_hat, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever, co)
            w_f = _split_metric(c, stencil_count, stencil_nodes, stencil_weights, frame, rigid_node, rigid_lever,
                               d_inv, partner, cross, fixed, co, node_share, body_share, own_min, own_max,
                               body_min, body_max)
            old = impulse[c]
            lam = updated(c, f, rel_f, w_f, impulse, stencil_count, rigid_node, gap, friction, dt, stiffness, slip,
                          local_updates)
            impulse[c] = lam
            d = wp.transpose(f) * (lam - old)
            if d[0] != wp.float64(0.0) or d[1] != wp.float64(0.0) or d[2] != wp.float64(0.0):
                _lane_apply(c, d, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever, d_inv,
                            partner, cross, fixed, v_hat, delta, own_min, own_max, co, body_min, body_max,
                            delta_lin, delta_ang)
        block_sync()
        for i in range(lane, n, lanes):
            g = delta[i]
            if g[0] != wp.float64(0.0) or g[1] != wp.float64(0.0) or g[2] != wp.float64(0.0):
                v_hat[i] = v_hat[i] + g
                delta[i] = wp.vec3d()
        for b in range(lane, delta_lin.shape[0], lanes):
            co.y_lin[b] = co.y_lin[b] + delta_lin[b]
            co.y_ang[b] = co.y_ang[b] + delta_ang[b]
            delta_lin[b] = wp.vec3d()
            delta_ang[b] = wp.vec3d()
        block_sync()
