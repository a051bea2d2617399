"""Contact generation of the collision points of a whole scene of FEM bodies (and the kinematic
or fixed bodies they meet) against its planes, static spheres and each other's surfaces, as recorded launches
(kernels in :mod:`softvr.collision._node_kernels`; works on :class:`softvr.sim.NodeModel` /
:class:`softvr.sim.NodeState` or any objects with those attributes)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import warp as wp

from softvr.collision import _node_kernels as _k
from softvr.collision.edges import MIN_EDGE_ANGLE, MIN_NORMAL_ALIGNMENT, PAIRS_PER_EDGE, SHARP_EDGE_ANGLE
from softvr.collision.node_rigid_detection import record_rigid_contacts, record_rigid_points
from softvr.device import blocked_replayer, chunked_replayer, load_kernels, replayer

__all__ = ["CONTACT_STENCIL", "record_carry", "record_node_detection"]

#: Nodes a contact's stencil holds (a point's 4 and a triangle's 3 x 4).
CONTACT_STENCIL = _k.CONTACT_STENCIL


def record_node_detection(model, state, dt: float, gravity, margin: float, friction: float,
                          ccd: bool = True) -> Callable[[], None]:
    """A replay filling ``state.contacts`` (warm-started from ``state.contacts.carried``) from
    the step's start ``q``, ``v``, ``gravity`` [3] [m/s^2]: points vs planes and static spheres, and surface
    vertices vs the other bodies' triangles within ``margin`` [m] (plus their motion over
    ``dt`` [s]) with Coulomb coefficient ``friction``; points vs static meshes within their
    margins, swept over their motion with ``ccd`` (``Scene.ccd``). The surfaces' BVHs are
    refitted to the points' positions in between."""
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

    spread = wp.zeros(bodies, dtype=wp.float64, device=d)
    # Speed of each body's mean motion relative to each other's [m/s] (``_k.near_bodies``).
    relative = wp.empty((bodies, bodies), dtype=wp.float64, device=d)

    def body_box(start: wp.array, lower: wp.array,
                 upper: wp.array) -> tuple[tuple[wp.array, ...], wp.array, wp.array]:
        """Which bodies' boxes each body may reach (``_k.near_bodies``: near, relative, the
        near bodies' lists and lengths) and each body's box of items ``lower``, ``upper`` [m]
        (``_k.body_bounds``), filled by launches appended to the steps."""
        box = (wp.empty(bodies, dtype=wp.vec3, device=d), wp.empty(bodies, dtype=wp.vec3, device=d))
        near = (wp.empty((bodies, bodies), dtype=wp.float32, device=d), relative,
                wp.empty((bodies, bodies), dtype=wp.int32, device=d), wp.empty(bodies, dtype=wp.int32, device=d),
                wp.empty((bodies, 2), dtype=wp.vec3, device=d), wp.empty((bodies, 2), dtype=wp.vec3, device=d))
        steps.append(replayer(wp.launch(_k.body_bounds, dim=bodies, device=d, record_cmd=True,
                                        inputs=[start, lower, upper, *box])))
        steps.append(replayer(wp.launch(_k.near_bodies, dim=bodies, device=d, record_cmd=True,
                                        inputs=[model.pair_enabled, *box, state.body_mean_u, spread, float(margin),
                                                float(dt), *near])))
        return (near, *box)

    if model.meshes or model.bvhs:  # (the vertex and edge queries read both)
        steps.append(replayer(wp.launch(_k.body_motion, dim=bodies, device=d, record_cmd=True,
                                        inputs=[model.body_point_start_wp, state.point_u, state.body_mean_u,
                                                spread])))
    # Per point, whether vertex_triangle found a hit (0 where it does not run); a row of c.hit
    # is nonzero only where it is 1 (vertex_triangle clears those rows only).
    point_hit = wp.zeros(c.hit.shape[0], dtype=wp.int32, device=d)
    c.hit.zero_()
    if model.meshes:
        near, *point_box = body_box(model.body_point_start_wp, state.point_x32, state.point_x32)
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
        steps.append(replayer(wp.launch(_k.body_creases, dim=bodies, device=d, record_cmd=True,
                                        inputs=[model.body_edge_start, state.edge_sharp, crease])))
        near, *edge_box = body_box(model.body_edge_start, state.edge_lower, state.edge_upper)
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
    out = _k.contact_out(c)
    steps.append(replayer(wp.launch(
        _k.gather_contacts, dim=1, device=d, record_cmd=True,
        inputs=[state.point_x, state.point_u, model.point_nodes, model.point_weights, model.point_margin,
                model.plane_margin, model.point_body, model.triangles, model.body_triangle_start, model.plane_normal, model.plane_offset,
                model.plane_friction, model.sphere_center, model.sphere_radius, model.sphere_friction, c.static_hit,
                c.static_normal, c.static_gap, model.static_mesh_friction, float(friction), c.hit, c.hit_face, c.hit_bary, c.hit_normal, c.hit_gap,
                point_hit, model.edges, c.pair_edge, c.pair_st, c.pair_normal, c.pair_gap, c.edge_carried, c.edge_partner,
                *found, float(dt), c.capacity, c.carried, c.count, out])))
    if model.rigid is not None:
        steps.append(record_rigid_contacts(model, state, dt))

    def detect() -> None:
        for step in steps:
            step()

    return detect


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


def record_carry(model, state) -> wp.Launch:
    """The launch storing the step's impulses as the next step's warm starts."""
    c = state.contacts
    load_kernels(_k.carry_impulses, model.device)
    # The carried entries the last replay wrote (flat, point * columns + column), for the next to
    # clear; -1: not known yet (clear all).
    written = wp.empty(c.capacity, dtype=wp.int32, device=model.device)
    written_count = wp.full(1, -1, dtype=wp.int32, device=model.device)
    return wp.launch(_k.carry_impulses, dim=1, device=model.device, record_cmd=True,
                     inputs=[c.count, c.kind, c.column, c.point, c.face, c.frame, c.impulse, c.carried,
                             c.edge_carried, c.edge_partner, written, written_count])
