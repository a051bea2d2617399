"""Contact generation of the collision points of a whole scene of FEM bodies (and the kinematic
or fixed bodies they meet) against its planes, static spheres and each other's surfaces, as recorded launches
(kernels in :mod:`softvr.collision._node_kernels`; works on :class:`softvr.sim.NodeModel` /
:class:`softvr.sim.NodeState` or any objects with those attributes)."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np
import warp as wp

from softvr.collision import _node_kernels as _k
from softvr.collision.edges import MIN_EDGE_ANGLE, MIN_NORMAL_ALIGNMENT, PAIRS_PER_EDGE, SHARP_EDGE_ANGLE
from softvr.collision.node_rigid_detection import CONTACT_THREADS, record_rigid_contacts, record_rigid_points
from softvr.device import blocked_replayer, chunked_replayer, in_order, load_kernels, replayer, stride_threads

__all__ = ["CONTACT_STENCIL", "record_carry", "record_node_detection"]

#: Nodes a contact's stencil holds (a point's 4 and a triangle's 3 x 4).
CONTACT_STENCIL = _k.CONTACT_STENCIL


def record_node_detection(model, state, dt: float, gravity, margin: float, friction: float,
                          ccd: bool = True, parallel: bool | None = None) -> Callable[[], None]:
    """A replay filling ``state.contacts`` (warm-started from ``state.contacts.carried``) from
    the step's start ``q``, ``v``, ``gravity`` [3] [m/s^2]: points vs planes and static spheres, and surface
    vertices vs the other bodies' triangles within ``margin`` [m] (plus their motion over
    ``dt`` [s]) with Coulomb coefficient ``friction``; points vs static meshes within their
    margins, swept over their motion with ``ccd`` (``Scene.ccd``). The surfaces' BVHs are
    refitted to the points' positions in between. ``parallel``: the GPU's forms, a thread per
    point or edge for the bodies' motion, boxes and creases and a thread per candidate pair for
    the gather (:func:`_record_gather`); None: on any device but the CPU."""
    c, d = state.contacts, model.device
    g = wp.vec3d(*np.asarray(gravity, float))
    for kernel in (_k.point_motion, _k.body_motion, _k.body_bounds, _k.near_bodies, _k.vertex_triangle,
                   _k.face_normals, _k.edge_geometry, _k.body_creases, _k.edge_edge, _k.point_static_mesh,
                   _k.gather_contacts):
        load_kernels(kernel, d)
    # The per-point and per-edge launches are split over the CPU cores (chunked_replayer).
    motion = blocked_replayer(_k.point_motion, model.point_count,
                              [state.q, state.v, model.fixed, state.fixed_velocity, model.point_nodes,
                               model.point_weights, g, float(dt), state.point_x, state.point_x32, state.point_u],
                              d, min_chunk=1024)
    steps = [motion]
    if model.rigid is not None and model.rigid.point_index.shape[0]:
        steps.append(record_rigid_points(model, state))
    if model.static_mesh_ids.shape[0]:
        steps.append(chunked_replayer(_k.point_static_mesh, model.point_count,
                                      [state.point_x32, state.point_u, model.point_margin, model.static_mesh_ids,
                                       model.static_mesh_thickness, float(dt), int(ccd), c.static_hit,
                                       c.static_normal, c.static_gap], d, min_chunk=256))
    bodies = len(model.body_node_start) - 1
    parallel = (not wp.get_device(d).is_cpu) if parallel is None else parallel
    if parallel:
        for kernel in (_k.point_sums, _k.body_means, _k.point_spread, _k.item_bounds, _k.edge_creases):
            load_kernels(kernel, d)

    def record(kernel, dim: int, inputs: list) -> Callable[[], None]:
        return replayer(wp.launch(kernel, dim=dim, device=d, record_cmd=True, inputs=inputs))

    spread = wp.zeros(bodies, dtype=wp.float64, device=d)
    # Speed of each body's mean motion relative to each other's [m/s] (``_k.near_bodies``).
    relative = wp.empty((bodies, bodies), dtype=wp.float64, device=d)

    def body_box(start: wp.array, lower: wp.array, upper: wp.array,
                 item_body: wp.array) -> tuple[tuple[wp.array, ...], wp.array, wp.array]:
        """Which bodies' boxes each body may reach (``_k.near_bodies``: near, relative, the
        near bodies' lists and lengths) and each body's box of items ``lower``, ``upper`` [m]
        (``_k.body_bounds``; ``parallel``: ``_k.item_bounds`` over the items, of bodies
        ``item_body``), filled by launches appended to the steps."""
        box = (wp.empty(bodies, dtype=wp.vec3, device=d), wp.empty(bodies, dtype=wp.vec3, device=d))
        near = (wp.empty((bodies, bodies), dtype=wp.float32, device=d), relative,
                wp.empty((bodies, bodies), dtype=wp.int32, device=d), wp.empty(bodies, dtype=wp.int32, device=d),
                wp.empty((bodies, 2), dtype=wp.vec3, device=d), wp.empty((bodies, 2), dtype=wp.vec3, device=d))
        if parallel:
            items = item_body.shape[0]
            steps.extend([partial(box[0].fill_, wp.vec3(1.0e30, 1.0e30, 1.0e30)),
                          partial(box[1].fill_, wp.vec3(-1.0e30, -1.0e30, -1.0e30))])
            if items:
                steps.append(record(_k.item_bounds, items, [item_body, lower, upper, *box]))
        else:
            steps.append(record(_k.body_bounds, bodies, [start, lower, upper, *box]))
        steps.append(replayer(wp.launch(_k.near_bodies, dim=bodies, device=d, record_cmd=True,
                                        inputs=[model.pair_enabled, *box, state.body_mean_u, spread, float(margin),
                                                float(dt), *near])))
        return (near, *box)

    if (model.meshes or model.bvhs) and parallel:  # (the vertex and edge queries read both)
        sums, counts = wp.zeros(bodies, dtype=wp.vec3d, device=d), wp.zeros(bodies, dtype=wp.int32, device=d)
        steps.extend([sums.zero_, counts.zero_])
        if model.point_count:
            steps.append(record(_k.point_sums, model.point_count, [model.point_body, state.point_u, sums, counts]))
        steps.append(record(_k.body_means, bodies, [sums, counts, state.body_mean_u, spread]))
        if model.point_count:
            steps.append(record(_k.point_spread, model.point_count,
                                [model.point_body, state.point_u, state.body_mean_u, spread]))
    elif model.meshes or model.bvhs:
        steps.append(record(_k.body_motion, bodies, [model.body_point_start_wp, state.point_u, state.body_mean_u,
                                                     spread]))
    # Per point, whether vertex_triangle found a hit (0 where it does not run); a row of c.hit
    # is nonzero only where it is 1 (vertex_triangle clears those rows only).
    point_hit = wp.zeros(c.hit.shape[0], dtype=wp.int32, device=d)
    c.hit.zero_()
    if model.meshes:
        near, *point_box = body_box(model.body_point_start_wp, state.point_x32, state.point_x32, model.point_body)
        steps.append(_refit_reached(model.meshes, model.mesh_ids, near[0], later=False))
        steps.append(blocked_replayer(_k.vertex_triangle, model.point_count,
                                      [model.point_body, state.point_x, state.point_u, state.body_mean_u,
                                       *near, model.mesh_ids, *point_box, float(margin), float(dt),
                                       c.hit, c.hit_face, c.hit_bary, c.hit_normal, c.hit_gap, point_hit], d,
                                      min_chunk=256))
    # Per edge, whether edge_edge found pairs this step and the last (1 at first: unknown).
    found = [wp.full(max(model.edges.shape[0], 1), 1, dtype=wp.int32, device=d) for _ in range(2)]
    if model.bvhs:
        edges = model.edges.shape[0]
        normals = wp.empty(model.triangles.shape[0], dtype=wp.vec3, device=d)
        steps.append(blocked_replayer(_k.face_normals, model.triangles.shape[0],
                                      [state.point_x32, model.triangles, normals], d, min_chunk=1024))
        steps.append(blocked_replayer(_k.edge_geometry, edges,
                                      [state.point_x32, normals, model.edges, model.edge_faces,
                                       float(np.cos(SHARP_EDGE_ANGLE)), state.edge_lower, state.edge_upper,
                                       state.edge_normal, state.edge_sharp, state.crease_lower, state.crease_upper],
                                      d, min_chunk=1024))
        crease = wp.empty(bodies, dtype=wp.int32, device=d)
        if parallel:
            steps.extend([crease.zero_, record(_k.edge_creases, edges, [model.edge_body, state.edge_sharp, crease])])
        else:
            steps.append(record(_k.body_creases, bodies, [model.body_edge_start, state.edge_sharp, crease]))
        near, *edge_box = body_box(model.body_edge_start, state.edge_lower, state.edge_upper, model.edge_body)
        steps.append(_refit_reached(model.bvhs, model.bvh_ids, near[0], later=True))
        # (only bodies with a crease: a smooth edge queries no other, ``_k.edge_edge``)
        steps.append(_refit_reached(model.crease_bvhs, model.crease_bvh_ids, near[0], later=True, only=crease))
        steps.append(blocked_replayer(_k.edge_edge, edges,
                                      [model.edges, model.edge_body, model.body_edge_start, state.point_x32,
                                       state.point_u, state.body_mean_u, *near, model.bvh_ids, model.crease_bvh_ids,
                                       *edge_box,
                                       state.edge_normal, state.edge_sharp, crease, float(margin), float(dt),
                                       float(np.sin(MIN_EDGE_ANGLE)), float(MIN_NORMAL_ALIGNMENT), PAIRS_PER_EDGE,
                                       c.hit, c.pair_edge, c.pair_st, c.pair_normal, c.pair_gap, *found], d,
                                      min_chunk=512))
    inputs = [state.point_x, state.point_u, model.point_nodes, model.point_weights, model.point_margin,
              model.plane_margin, model.point_body, model.triangles, model.body_triangle_start, model.plane_normal,
              model.plane_offset, model.plane_friction, model.sphere_center, model.sphere_radius,
              model.sphere_friction, c.static_hit, c.static_normal, c.static_gap, model.static_mesh_friction,
              float(friction), c.hit, c.hit_face, c.hit_bary, c.hit_normal, c.hit_gap, point_hit, model.edges,
              c.pair_edge, c.pair_st, c.pair_normal, c.pair_gap, c.edge_carried, c.edge_partner, *found, float(dt),
              c.capacity, c.carried]
    if parallel:
        steps.append(_record_gather(model, state, inputs))
    else:
        steps.append(replayer(wp.launch(_k.gather_contacts, dim=1, device=d, record_cmd=True,
                                        inputs=[*inputs, c.count, _k.contact_out(c)])))
    if model.rigid is not None:
        steps.append(record_rigid_contacts(model, state, dt))

    def detect() -> None:
        for step in steps:
            step()

    return detect


def _gather_candidates(model, state) -> int:
    """How many candidate pairs the gather tries (:func:`softvr.collision._node_kernels.gather_candidate`):
    points x (planes + static spheres + static meshes), vertices x bodies, edges x pair slots."""
    c = state.contacts
    points = model.point_nodes.shape[0]
    statics = model.plane_normal.shape[0] + model.sphere_radius.shape[0] + model.static_mesh_friction.shape[0]
    return points * statics + c.hit.shape[0] * c.hit.shape[1] + model.edges.shape[0] * c.pair_edge.shape[1]


def _record_gather(model, state, inputs: list) -> Callable[[], None]:
    """The gather with a thread per candidate pair (a GPU's form; one thread walking the candy's
    ~10^5 candidate pairs would wait on every load in turn): each pair flags whether it makes a
    contact, an exclusive scan of the flags gives each contact its row, and each pair writes its
    own (:func:`softvr.collision._node_kernels.gather_pairs`, ``write`` 0 then 1): the one-thread
    gather's contacts in its order."""
    c, d = state.contacts, model.device
    count = _gather_candidates(model, state)
    if not count:
        return c.count.zero_
    load_kernels(_k.gather_pairs, d)
    out = _k.contact_out(c)
    flags, rows = wp.zeros(count, dtype=wp.int32, device=d), wp.zeros(count, dtype=wp.int32, device=d)
    mark, write = (replayer(wp.launch(_k.gather_pairs, dim=count, device=d, record_cmd=True,
                                      inputs=[*inputs, out, stage, flags, rows, c.count])) for stage in (0, 1))

    def gather() -> None:
        mark()
        wp.utils.array_scan(flags, rows, inclusive=False)
        write()

    return gather


def _refit_reached(structures: list, ids: wp.array, near: wp.array, later: bool,
                   only: wp.array | None = None) -> Callable[[], None]:
    """A step refitting the BVHs ``structures`` (``wp.Mesh`` or ``wp.Bvh``; body b's has id
    ``ids[b]``) to the points' positions: on the CPU only those of the bodies b some body a
    (``later``: a < b, the edge queries' order) may reach this step (``near[a, b]`` >= 0,
    ``_k.near_bodies``, read in place) and, given ``only`` [bodies], where ``only[b]`` != 0
    (read in place too), since no other is queried before its next refit (a refit recomputes
    every box from the points); all of them elsewhere (no host read there)."""
    if not wp.get_device(near.device).is_cpu:
        def refit_all() -> None:
            for s in structures:
                s.refit()

        return refit_all
    owner = ids.numpy()
    body = [int(np.flatnonzero(owner == s.id)[0]) for s in structures]
    reach = near.numpy()
    wanted = only.numpy() if only is not None else None
    # The (a, b) entries that count: a < b for the edge queries (one mask, not a slice and a
    # max a structure: ~2 us each, 28 a shoulder step).
    counted = np.triu(np.ones(reach.shape, bool), k=1) if later else np.ones(reach.shape, bool)

    def refit() -> None:
        reached = ((reach >= 0) & counted).any(axis=0)
        if wanted is not None:
            reached &= wanted != 0
        for s, b in zip(structures, body):
            if reached[b]:
                s.refit()

    return refit


def record_carry(model, state, parallel: bool | None = None) -> Callable[[], None]:
    """A replay storing the step's impulses as the next step's warm starts; ``parallel``: with
    a thread per contact (:func:`_record_parallel_carry`); None: on any device but the CPU."""
    c = state.contacts
    if (not wp.get_device(model.device).is_cpu) if parallel is None else parallel:
        return _record_parallel_carry(model, state)
    load_kernels(_k.carry_impulses, model.device)
    # The carried entries the last replay wrote (flat, point * columns + column), for the next to
    # clear; -1: not known yet (clear all).
    written = wp.empty(c.capacity, dtype=wp.int32, device=model.device)
    written_count = wp.full(1, -1, dtype=wp.int32, device=model.device)
    return replayer(wp.launch(_k.carry_impulses, dim=1, device=model.device, record_cmd=True,
                              inputs=[c.count, c.kind, c.column, c.point, c.face, c.frame, c.impulse, c.carried,
                                      c.edge_carried, c.edge_partner, written, written_count]))


def _record_parallel_carry(model, state) -> Callable[[], None]:
    """:func:`record_carry`'s replay with threads striding over the contacts (a GPU's form): the
    entries the last replay wrote cleared (``written[c]``, the flat entry of its contact ``c``,
    -1 for none; all of the table on the first replay), then each contact's impulse written.
    No two contacts write one entry (a point meets a column once, an edge pair has its slot)."""
    c, d = state.contacts, model.device
    for kernel in (_k.clear_carried, _k.carry_parallel):
        load_kernels(kernel, d)
    threads = stride_threads(d, CONTACT_THREADS)
    written = wp.full(c.capacity, -1, dtype=wp.int32, device=d)
    written_count = wp.full(1, -1, dtype=wp.int32, device=d)
    clear = replayer(wp.launch(_k.clear_carried, dim=threads, device=d, record_cmd=True,
                               inputs=[c.carried, written, written_count, threads]))
    carry = replayer(wp.launch(_k.carry_parallel, dim=threads, device=d, record_cmd=True,
                               inputs=[c.count, c.kind, c.column, c.point, c.face, c.frame, c.impulse, c.carried,
                                       c.edge_carried, c.edge_partner, written, written_count, threads]))
    return in_order(clear, carry)
