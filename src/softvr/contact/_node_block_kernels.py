"""The contact step of a node sweep in one launch: one thread block whose lanes stride over the
contacts through every stage of :mod:`softvr.contact._node_parallel_kernels` (the GPU's form of
thesis eq. 5.6's inner loop), the block's barrier between the stages.

A scene whose contacts share nodes or coarse bodies takes ``passes`` x
:data:`softvr.contact.node_jacobi.PARALLEL_PASS_FACTOR` Jacobi passes a sweep (48 on the candy
pile), each two dependent stages (the updates, then their pushes): as launches, ~100 a sweep and
~15 000 a step, each waiting for the last to drain, where a block's barrier costs a few dozen
cycles. The stages, each over the lane's contacts ``lane, lane + lanes, ...``:

    1. node and coarse-body shares zeroed; with ``start``: the last sweep's impulses into v^
    2. with ``start``: the live contacts screened, the sweep counted and ``stats`` zeroed
    3. the visited contacts' shares counted (the live ones, or with ``tools`` those on a tool's
       rigid node, marked first)
    4. ``passes`` x (Jacobi updates on the split masses | their pushes into v^)

One block runs on one streaming multiprocessor: the form pays where a sweep has many dependent
passes over a few hundred live contacts (the candy's 24-45 pushing of ~2 600). Contacts that share
nothing need no barrier at all (:func:`softvr.contact._node_parallel_kernels.contact_step_unshared`,
the 64 cubes' thousands over the whole device). Where a block is one thread (the CPU, unless
``wp.config.enable_cpu_blocks`` runs its lanes as cooperative fibers) the one lane walks every
stage in turn: the same passes, the same sums in the same order as the launches they replace.

A Gauss-Seidel sweep's node update before and after its contact step takes one block each
(:func:`gauss_seidel_before_contacts`, :func:`gauss_seidel_after_contacts`) the same way: a
barrier where the launches' form ended a launch.
"""

from __future__ import annotations

import warp as wp

from softvr.contact._node_coarse_kernels import Coarse
from softvr.contact._node_contact_native import screen_contacts
from softvr.contact._node_gs_coarse_kernels import aggregate_apply, aggregate_velocity
from softvr.contact._node_gs_kernels import (add_island_forces, colour_node, contact_node_update, island_response,
                                             island_solved, tool_range)
from softvr.contact._node_parallel_kernels import apply_range, count_range, jacobi_range, start_sweep, warm_range

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
                       metric: wp.array(dtype=wp.mat33d), local_updates: int, change: wp.array(dtype=wp.vec3d),
                       live: wp.array(dtype=wp.int32), sweep: wp.array(dtype=wp.int32),
                       stats: wp.array(dtype=wp.float64), tool_node: wp.array(dtype=wp.int32),
                       visit: wp.array(dtype=wp.int32), start: int, tools: int, passes: int):
    """A sweep's contact step in one block (module docstring; launch ``dim=[1]`` with the
    block's lanes): with ``start``, the last impulses ``impulse`` [c] [N s] of the ``movable``
    contacts applied to ``v_hat`` [n] [m/s], ``live`` [c] screened
    (:func:`softvr.contact._node_contact_native.screen_contacts`) and the sweep started
    (:func:`softvr.contact._node_parallel_kernels.start_sweep`); then ``passes`` Jacobi passes
    on split masses over the contacts ``visit`` [c] marks: ``live`` itself (the same array), or
    with ``tools`` those live ones with a rigid side on a ``tool_node`` [n], marked into it
    first. The other arrays are
    :func:`softvr.contact._node_parallel_kernels.jacobi_range`'."""
    _block, lane = wp.tid()
    lanes = wp.block_dim()
    for i in range(lane, node_share.shape[0], lanes):
        node_share[i] = 0
    for b in range(lane, body_share.shape[0], lanes):
        body_share[b] = 0
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
    block_sync()
    for _p in range(passes):
        jacobi_range(lane, lanes, count, visit, stencil_count, stencil_nodes, stencil_weights, frame, gap, friction,
                     rigid_node, rigid_lever, d_inv, partner, cross, fixed, dt, impulse, v_hat, stiffness, slip, co,
                     node_share, body_share, metric, 1, local_updates, change)
        block_sync()
        apply_range(lane, lanes, count, visit, stencil_count, stencil_nodes, stencil_weights, rigid_node, rigid_lever,
                    d_inv, partner, cross, fixed, change, v_hat, co)
        block_sync()


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
