"""Compiled contact generation for the collision points of a whole scene of FEM bodies (and the
kinematic / fixed bodies they meet): points against static planes, the array form of
:func:`softvr.collision.points_vs_plane`, and surface vertices against the other bodies'
triangles and their edges against each other's edges, the array forms of
:func:`softvr.collision.surface_vs_surface` and :func:`softvr.collision.edges_vs_edges`.

Every collision point ``p = sum_k w_k q_k`` has a stencil of up to 4 nodes (a kinematic body's
surface vertex is a driven node of its own). A contact's stencil joins both sides': the point's
nodes with their weights, and for a vertex-triangle contact the triangle's three vertices'
nodes with minus their barycentric share (a node met twice is summed once), so that
``sum_k w_k v_k`` is the velocity of side a relative to side b; an edge-edge contact joins
the two edges' end points, weighted by where the closest points lie along them.

Detection is speculative: a vertex makes a contact with a triangle of another body when the
closest point is within the margin plus the vertex's motion relative to that body over the
step (the explicit prediction ``v + dt g``), at the gap of the step's start; the solve's
``n . J v >= -gap / dt`` then keeps it from crossing during the step to first order. A contact
starts with last step's impulse of the same (point, plane) or (vertex, body) pair (its key),
read from the carried table, which holds last step's pairs only, so a pair that is no longer in
contact forgets it.
"""

from __future__ import annotations

import warp as wp

from softvr.collision.edges import edge_pair
from softvr.collision.mesh import NORMAL_FROM_OFFSET, query_point

#: Nodes in a collision point's stencil (4: a point embedded in a tet; unused entries -1).
STENCIL = 4
#: Nodes in a contact's stencil: a point's 4 and a triangle's 3 x 4.
CONTACT_STENCIL = 16
#: ``NodeContacts.kind`` codes.
PLANE = wp.constant(0)
VERTEX_TRIANGLE = wp.constant(1)
EDGE_EDGE = wp.constant(2)
#: A rigid body's box or sphere primitive against a plane or another primitive (the rigid path's
#: detection, :mod:`softvr.collision._node_rigid_kernels`).
PRIMITIVE = wp.constant(3)
#: A collision point against a static sphere.
SPHERE = wp.constant(4)
#: A collision point against a static triangle mesh.
MESH = wp.constant(5)


@wp.func
def plane_frame(n: wp.vec3d) -> wp.mat33d:
    """Rows: the unit normal and two unit tangents (any pair: friction is a disc)."""
    helper = wp.vec3d(wp.float64(1.0), wp.float64(0.0), wp.float64(0.0))
    if wp.abs(n[0]) > wp.float64(0.9):
        helper = wp.vec3d(wp.float64(0.0), wp.float64(1.0), wp.float64(0.0))
    t1 = wp.normalize(wp.cross(n, helper))
    t2 = wp.cross(n, t1)
    return wp.mat33d(n[0], n[1], n[2], t1[0], t1[1], t1[2], t2[0], t2[1], t2[2])


@wp.kernel
def point_motion(q: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
                 fixed_velocity: wp.array(dtype=wp.vec3d), point_nodes: wp.array2d(dtype=wp.int32),
                 point_weights: wp.array2d(dtype=wp.float64), gravity: wp.vec3d, dt: wp.float64,
                 point_x: wp.array(dtype=wp.vec3d), point_x32: wp.array(dtype=wp.vec3),
                 point_u: wp.array(dtype=wp.vec3d), block: int, offset: int):
    """Position [m] (also in single precision, the surfaces' BVH vertices) and predicted
    velocity [m/s] of point ``p`` at the step's start: the explicit ``v + dt g`` of its free
    nodes, the prescribed velocity of its driven ones. A thread takes ``block`` points, from (thread +
    ``offset``) x ``block`` (:data:`softvr.device.ITEMS_A_CPU_THREAD`)."""
    begin = (wp.tid() + offset) * block
    for p in range(begin, wp.min(begin + block, point_nodes.shape[0])):
        x = wp.vec3d()
        u = wp.vec3d()
        for k in range(STENCIL):
            node = point_nodes[p, k]
            if node >= 0:
                w = point_weights[p, k]
                x = x + w * q[node]
                if fixed[node] != 0:
                    u = u + w * fixed_velocity[node]
                else:
                    u = u + w * (v[node] + dt * gravity)
        point_x[p] = x
        point_x32[p] = wp.vec3(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))
        point_u[p] = u


@wp.kernel
def body_motion(body_point_start: wp.array(dtype=wp.int32), point_u: wp.array(dtype=wp.vec3d),
                body_mean_u: wp.array(dtype=wp.vec3d), body_spread: wp.array(dtype=wp.float64)):
    """Mean predicted velocity [m/s] of body ``b``'s collision points (the vertex queries
    sweep a vertex relative to it, as :func:`softvr.collision.surface_vs_surface` does), and
    the largest speed [m/s] of a point relative to it (:func:`near_bodies`): bodies at rest
    all fall by ``dt g`` in the prediction, which the points' own speeds counted on every
    body (8 mm of reach at the shoulder's 20 ms), their relative speeds not."""
    b = wp.tid()
    u = wp.vec3d()
    first = body_point_start[b]
    last = body_point_start[b + 1]
    for p in range(first, last):
        u = u + point_u[p]
    if last > first:
        u = u / wp.float64(last - first)
    spread = wp.float64(0.0)
    for p in range(first, last):
        spread = wp.max(spread, wp.length(point_u[p] - u))
    body_mean_u[b] = u
    body_spread[b] = spread


@wp.kernel
def body_bounds(body_start: wp.array(dtype=wp.int32), lower: wp.array(dtype=wp.vec3), upper: wp.array(dtype=wp.vec3),
                body_lower: wp.array(dtype=wp.vec3), body_upper: wp.array(dtype=wp.vec3)):
    """Body ``b``'s box [m]: the union of the boxes (``lower``, ``upper``) of its items
    ``body_start[b] : [b + 1]`` (its edges: its edge BVH's root box after the refit; or its
    collision points, as both: a box holding every triangle of its surface mesh)."""
    b = wp.tid()
    lo = wp.vec3(1.0e30, 1.0e30, 1.0e30)
    hi = wp.vec3(-1.0e30, -1.0e30, -1.0e30)
    for e in range(body_start[b], body_start[b + 1]):
        lo = wp.min(lo, lower[e])
        hi = wp.max(hi, upper[e])
    body_lower[b] = lo
    body_upper[b] = hi


@wp.func
def _off_box(lo: wp.vec3, hi: wp.vec3, grow: float, box_lower: wp.vec3, box_upper: wp.vec3) -> bool:
    """Whether box [lo - grow, hi + grow] misses [box_lower, box_upper] by Warp's (inclusive)
    box test; monotone in ``grow`` under rounding, so a miss at a larger ``grow`` is one at
    any smaller."""
    return (lo[0] - grow > box_upper[0] or lo[1] - grow > box_upper[1] or lo[2] - grow > box_upper[2]
            or hi[0] + grow < box_lower[0] or hi[1] + grow < box_lower[1] or hi[2] + grow < box_lower[2])


@wp.kernel
def near_bodies(pair_enabled: wp.array2d(dtype=wp.int32), body_lower: wp.array(dtype=wp.vec3),
                body_upper: wp.array(dtype=wp.vec3), body_mean_u: wp.array(dtype=wp.vec3d),
                body_spread: wp.array(dtype=wp.float64), margin: wp.float64, dt: wp.float64,
                near: wp.array2d(dtype=wp.float32), relative: wp.array2d(dtype=wp.float64),
                near_list: wp.array2d(dtype=wp.int32), near_len: wp.array(dtype=wp.int32),
                reach_lower: wp.array2d(dtype=wp.vec3), reach_upper: wp.array2d(dtype=wp.vec3)):
    """Row a (thread a): ``relative[a, b]`` [m/s]: the speed of b's mean motion relative to a's; ``near[a, b]``
    [m]: a bound of the reach of any item of body a towards body b, margin + dt (a's largest
    point speed relative to a's mean ``body_spread`` + ``relative[a, b]``; an item's speed
    relative to b is at most that), where a and b make contacts and a's box (``body_lower``,
    ``body_upper`` [m], :func:`body_bounds`) grown by it meets b's box; else -1. An item of a
    lies in a's box and moves no faster, so its own box test (:func:`vertex_triangle`,
    :func:`edge_edge`: the same bound with its own speed) misses b wherever its box grown by
    ``near[a, b]`` does, and that test needs neither its speed nor b's: an item that no body
    passes is done on a few reads. 1.01 and 2e-6 m (vs their 1.001 and 1e-6 m) cover the two
    formulas' different float32 / float64 rounding. ``near_list[a, :near_len[a]]``: the bodies
    b of ``near[a, b]`` >= 0, ascending (an item loops over those, 1-2 of the shoulder's 15).
    ``reach_lower[a, k]``, ``reach_upper[a, k]`` [m]: the union of those bodies' boxes grown by
    ``near[a, b]`` (k = 0: all of them, for :func:`vertex_triangle`; k = 1: those b > a, for
    :func:`edge_edge`), grown by 1e-5 m + 1e-6 of its coordinates past the float32 rounding of
    the two tests: an item whose box misses it misses each body's test (:func:`near_count`),
    one test instead of one a near body (the candy's Jell-O: 8, most of its edges far)."""
    a = wp.tid()
    count = int(0)
    big = wp.vec3(1.0e30, 1.0e30, 1.0e30)
    lo_all = big
    hi_all = -big
    lo_later = big
    hi_later = -big
    for b in range(near.shape[1]):
        near[a, b] = -1.0
        relative[a, b] = wp.length(body_mean_u[b] - body_mean_u[a])
        if pair_enabled[a, b] != 0:
            bound = float((margin + dt * (body_spread[a] + relative[a, b])) * wp.float64(1.01)) + 2.0e-6
            if not _off_box(body_lower[a], body_upper[a], bound, body_lower[b], body_upper[b]):
                near[a, b] = bound
                near_list[a, count] = b
                count += 1
                grow = wp.vec3(bound, bound, bound)
                lo_all = wp.min(lo_all, body_lower[b] - grow)
                hi_all = wp.max(hi_all, body_upper[b] + grow)
                if b > a:
                    lo_later = wp.min(lo_later, body_lower[b] - grow)
                    hi_later = wp.max(hi_later, body_upper[b] + grow)
    near_len[a] = count
    reach_lower[a, 0] = _loosened(lo_all, -1.0)
    reach_upper[a, 0] = _loosened(hi_all, 1.0)
    reach_lower[a, 1] = _loosened(lo_later, -1.0)
    reach_upper[a, 1] = _loosened(hi_later, 1.0)


@wp.func
def _loosened(x: wp.vec3, side: float) -> wp.vec3:
    """Corner ``x`` [m] of a union box moved outwards (``side`` -1: lower, 1: upper) by 1e-5 m +
    1e-6 of each coordinate (left as is where the union is empty, +-1e30)."""
    if wp.abs(x[0]) >= 1.0e29:
        return x
    return wp.vec3(x[0] + side * (1.0e-5 + 1.0e-6 * wp.abs(x[0])), x[1] + side * (1.0e-5 + 1.0e-6 * wp.abs(x[1])),
                   x[2] + side * (1.0e-5 + 1.0e-6 * wp.abs(x[2])))


@wp.func
def near_count(a: int, first: int, lo: wp.vec3, hi: wp.vec3, near: wp.array2d(dtype=wp.float32),
               near_list: wp.array2d(dtype=wp.int32), near_len: wp.array(dtype=wp.int32),
               reach_lower: wp.array2d(dtype=wp.vec3), reach_upper: wp.array2d(dtype=wp.vec3),
               body_lower: wp.array(dtype=wp.vec3), body_upper: wp.array(dtype=wp.vec3)) -> int:
    """How many bodies b >= ``first`` (0 or a + 1) box [lo, hi] (an item of body a) may reach by
    :func:`near_bodies`' bound (walking a's list of near bodies once the box meets their
    union)."""
    count = int(0)
    column = wp.min(first, 1)
    if _off_box(lo, hi, 0.0, reach_lower[a, column], reach_upper[a, column]):
        return count
    for k in range(near_len[a]):
        b = near_list[a, k]
        if b >= first:
            if not _off_box(lo, hi, near[a, b], body_lower[b], body_upper[b]):
                count += 1
    return count


@wp.kernel
def vertex_triangle(point_body: wp.array(dtype=wp.int32), point_x: wp.array(dtype=wp.vec3d),
                    point_u: wp.array(dtype=wp.vec3d), body_mean_u: wp.array(dtype=wp.vec3d),
                    near: wp.array2d(dtype=wp.float32), relative: wp.array2d(dtype=wp.float64),
                    near_list: wp.array2d(dtype=wp.int32), near_len: wp.array(dtype=wp.int32),
                    reach_lower: wp.array2d(dtype=wp.vec3), reach_upper: wp.array2d(dtype=wp.vec3),
                    mesh_ids: wp.array(dtype=wp.uint64), body_lower: wp.array(dtype=wp.vec3),
                    body_upper: wp.array(dtype=wp.vec3), margin: wp.float64, dt: wp.float64,
                    hit: wp.array2d(dtype=wp.int32), hit_face: wp.array2d(dtype=wp.int32),
                    hit_bary: wp.array2d(dtype=wp.vec3d), hit_normal: wp.array2d(dtype=wp.vec3d),
                    hit_gap: wp.array2d(dtype=wp.float64), point_hit: wp.array(dtype=wp.int32), block: int,
                    offset: int):
    """Surface vertex ``p`` against every other body's closed surface it may meet: the closest
    point within the margin plus the vertex's relative motion [m]; the normal points out of
    that body (towards the vertex), the gap [m] is negative inside it (by the closest
    feature's pseudo normal, as :func:`softvr.collision.query_points`). A body whose points'
    box (``body_lower``, ``body_upper``, :func:`body_bounds`) is farther than a bound of the
    reach, margin + dt (|u - a's mean| + ``relative[a, b]``, :func:`near_bodies`), holds no
    face within it and is not queried (1.001 and 1e-6 m cover the bound's and Warp's float32 distance's rounding); nor
    is one that makes no contacts with the vertex's body or that its body's bound misses
    (``near``, :func:`near_bodies`), tested first. ``point_hit[p]``: 1 if the vertex met some
    body (so that :func:`gather_contacts` reads the row ``hit[p]`` of those only); a row is
    nonzero only where it is 1, so only those rows are cleared the next time (B writes a
    vertex, most of them 0 already). A thread takes ``block`` points, from (thread +
    ``offset``) x ``block`` (:data:`softvr.device.ITEMS_A_CPU_THREAD`)."""
    begin = (wp.tid() + offset) * block
    for p in range(begin, wp.min(begin + block, point_body.shape[0])):
        a = point_body[p]
        x = point_x[p]
        xf = wp.vec3(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))
        if point_hit[p] != 0:
            for b in range(mesh_ids.shape[0]):
                hit[p, b] = 0
        point_hit[p] = 0
        if near_count(a, 0, xf, xf, near, near_list, near_len, reach_lower, reach_upper, body_lower, body_upper) == 0:
            continue
        speed = wp.length(point_u[p] - body_mean_u[a])
        for k in range(near_len[a]):
            b = near_list[a, k]
            bound = float((margin + dt * (speed + relative[a, b])) * wp.float64(1.001)) + 1.0e-6
            if not _off_box(xf, xf, bound, body_lower[b], body_upper[b]):
                reach = margin + dt * wp.length(point_u[p] - body_mean_u[b])
                query = wp.mesh_query_point_sign_normal(mesh_ids[b], xf, wp.float32(reach))
                if query.result:
                    c = wp.mesh_eval_position(mesh_ids[b], query.face, query.u, query.v)
                    cd = wp.vec3d(wp.float64(c[0]), wp.float64(c[1]), wp.float64(c[2]))
                    away = x - cd
                    dist = wp.length(away)
                    sign = wp.float64(query.sign)
                    fn = wp.mesh_eval_face_normal(mesh_ids[b], query.face)
                    n = wp.vec3d(wp.float64(fn[0]), wp.float64(fn[1]), wp.float64(fn[2]))
                    if dist > wp.float64(NORMAL_FROM_OFFSET):
                        n = away / dist * sign
                    hit[p, b] = 1
                    point_hit[p] = 1
                    hit_face[p, b] = query.face
                    u = wp.float64(query.u)
                    w = wp.float64(query.v)
                    hit_bary[p, b] = wp.vec3d(u, w, wp.float64(1.0) - u - w)
                    hit_normal[p, b] = n
                    hit_gap[p, b] = dist * sign


@wp.kernel
def point_static_mesh(point_x32: wp.array(dtype=wp.vec3), point_u: wp.array(dtype=wp.vec3d),
                      point_margin: wp.array(dtype=wp.float64), mesh_ids: wp.array(dtype=wp.uint64),
                      thickness: wp.array(dtype=wp.float32), dt: wp.float64, ccd: int,
                      static_hit: wp.array2d(dtype=wp.int32), static_normal: wp.array2d(dtype=wp.vec3),
                      static_gap: wp.array2d(dtype=wp.float32), offset: int):
    """Collision point ``p`` against every static triangle mesh (open sheets), as
    :func:`softvr.collision.points_vs_mesh`: the closest point within the point's margin [m]
    or, with ``ccd``, the first crossing of its predicted motion over ``dt`` [s]; the normal
    faces the point's side, the gap [m] keeps the mesh's half ``thickness`` [m]."""
    p = wp.tid() + offset
    u = point_u[p] * dt
    motion = wp.vec3(wp.float32(u[0]), wp.float32(u[1]), wp.float32(u[2]))
    reach = wp.float32(point_margin[p])
    for k in range(mesh_ids.shape[0]):
        h, n, g, c = query_point(mesh_ids[k], point_x32[p], motion, reach, thickness[k], ccd, 0)
        static_hit[p, k] = h
        static_normal[p, k] = n
        static_gap[p, k] = g


@wp.func
def _face_normal(points: wp.array(dtype=wp.vec3), triangles: wp.array2d(dtype=wp.int32), t: int) -> wp.vec3:
    a = points[triangles[t, 0]]
    n = wp.cross(points[triangles[t, 1]] - a, points[triangles[t, 2]] - a)
    size = wp.length(n)
    if size > 0.0:
        n = n / size
    return n


@wp.kernel
def face_normals(point_x32: wp.array(dtype=wp.vec3), triangles: wp.array2d(dtype=wp.int32),
                 normal: wp.array(dtype=wp.vec3), block: int, offset: int):
    """Triangle ``t``'s unit normal (once a triangle: :func:`edge_geometry` reads it for each of
    its three edges). A thread takes ``block`` triangles, from (thread +
    ``offset``) x ``block`` (:data:`softvr.device.ITEMS_A_CPU_THREAD`)."""
    begin = (wp.tid() + offset) * block
    for t in range(begin, wp.min(begin + block, triangles.shape[0])):
        normal[t] = _face_normal(point_x32, triangles, t)


@wp.kernel
def edge_geometry(point_x32: wp.array(dtype=wp.vec3), face_normal: wp.array(dtype=wp.vec3),
                  edges: wp.array2d(dtype=wp.int32), edge_faces: wp.array2d(dtype=wp.int32), sharp_cosine: float,
                  lower: wp.array(dtype=wp.vec3), upper: wp.array(dtype=wp.vec3), normal: wp.array(dtype=wp.vec3),
                  sharp: wp.array(dtype=wp.int32), crease_lower: wp.array(dtype=wp.vec3),
                  crease_upper: wp.array(dtype=wp.vec3), block: int, offset: int):
    """Edge ``e``'s box [m] (the BVH's), the unit mean normal of its one or two triangles
    (``face_normal``, :func:`face_normals`), and whether it is a crease (faces at more than the
    sharp angle) or a border, as :meth:`softvr.collision.EdgeSet.edge_normals`; its box again in
    ``crease_lower``, ``crease_upper`` [m] if it is one, else an empty box (lower 1e30, upper
    -1e30: no query box meets it, and it adds nothing to a node's box in a refit), the boxes of the
    crease BVHs that the smooth edges query (:func:`edge_edge`). A thread takes ``block`` edges, from (thread +
    ``offset``) x ``block`` (:data:`softvr.device.ITEMS_A_CPU_THREAD`)."""
    begin = (wp.tid() + offset) * block
    for e in range(begin, wp.min(begin + block, edges.shape[0])):
        p = point_x32[edges[e, 0]]
        q = point_x32[edges[e, 1]]
        lower[e] = wp.min(p, q)
        upper[e] = wp.max(p, q)
        first = face_normal[edge_faces[e, 0]]
        n = first
        crease = int(1)
        if edge_faces[e, 1] >= 0:
            second = face_normal[edge_faces[e, 1]]
            n = first + second
            if wp.dot(first, second) >= sharp_cosine:
                crease = 0
        size = wp.length(n)
        if size > 0.0:
            n = n / size
        normal[e] = n
        sharp[e] = crease
        if crease != 0:
            crease_lower[e] = lower[e]
            crease_upper[e] = upper[e]
        else:
            crease_lower[e] = wp.vec3(1.0e30, 1.0e30, 1.0e30)
            crease_upper[e] = wp.vec3(-1.0e30, -1.0e30, -1.0e30)


@wp.kernel
def body_creases(body_edge_start: wp.array(dtype=wp.int32), sharp: wp.array(dtype=wp.int32),
                 body_crease: wp.array(dtype=wp.int32)):
    """1 where body ``b`` has some crease or border edge this step (``sharp``,
    :func:`edge_geometry`), else 0: an edge pair needs one of those (:func:`edge_edge`), so a
    smooth edge need not query the edges of a body without any (the candy's Jell-O top against
    six of its eight candies)."""
    b = wp.tid()
    crease = int(0)
    for e in range(body_edge_start[b], body_edge_start[b + 1]):
        if sharp[e] != 0:
            crease = 1
            break
    body_crease[b] = crease


@wp.func
def edge_pair_covered(e: int, a: int, j: int, b: int, edges: wp.array2d(dtype=wp.int32),
                      sharp: wp.array(dtype=wp.int32), hit: wp.array2d(dtype=wp.int32)) -> bool:
    """Whether the pair of edges ``e`` (of body ``a``) and ``j`` (of body ``b``) lies on a patch
    the vertex-triangle contacts already hold: both ends of one edge meet the other edge's body
    (``hit``, :func:`vertex_triangle`) and the other edge is no crease (``sharp``), so the other
    surface is flat across it. An edge moves as the interpolation of its ends, so kept off a flat surface
    at both ends it is kept off it between them: the pair's row is nearly a combination of those
    contacts' rows, and such nearly dependent rows on one touching patch are what the sweeps
    converge on slowly (issue 16: one contact per touching feature pair)."""
    held_a = hit[edges[e, 0], b] != 0 and hit[edges[e, 1], b] != 0 and sharp[j] == 0
    held_b = hit[edges[j, 0], a] != 0 and hit[edges[j, 1], a] != 0 and sharp[e] == 0
    return held_a or held_b


@wp.kernel
def edge_edge(edges: wp.array2d(dtype=wp.int32), edge_body: wp.array(dtype=wp.int32),
              body_edge_start: wp.array(dtype=wp.int32), point_x32: wp.array(dtype=wp.vec3),
              point_u: wp.array(dtype=wp.vec3d), body_mean_u: wp.array(dtype=wp.vec3d),
              near: wp.array2d(dtype=wp.float32), relative: wp.array2d(dtype=wp.float64),
              near_list: wp.array2d(dtype=wp.int32), near_len: wp.array(dtype=wp.int32),
              reach_lower: wp.array2d(dtype=wp.vec3), reach_upper: wp.array2d(dtype=wp.vec3),
              bvh_ids: wp.array(dtype=wp.uint64), crease_bvh_ids: wp.array(dtype=wp.uint64),
              body_lower: wp.array(dtype=wp.vec3), body_upper: wp.array(dtype=wp.vec3),
              normal: wp.array(dtype=wp.vec3), sharp: wp.array(dtype=wp.int32),
              body_crease: wp.array(dtype=wp.int32), margin: float, dt: float,
              min_sine: float, min_alignment: float, pairs_per_edge: int, hit: wp.array2d(dtype=wp.int32),
              pair_edge: wp.array2d(dtype=wp.int32),
              pair_st: wp.array2d(dtype=wp.vec3d), pair_normal: wp.array2d(dtype=wp.vec3d),
              pair_gap: wp.array2d(dtype=wp.float64), found: wp.array(dtype=wp.int32),
              found_before: wp.array(dtype=wp.int32), block: int, offset: int):
    """Edge ``i`` of body a against the edges of every body b > a it may meet, in b's edge BVH
    (:func:`softvr.collision.edges_vs_edges`: the reach is the margin plus the edge's largest
    vertex motion relative to b [m]); up to ``pairs_per_edge`` pairs per body, in slots
    ``pairs_per_edge * b + k`` (-1: none; found pairs fill a body's slots from its first).
    Pairs deeper than the margin are seen from the wrong side and dropped, and so are pairs the
    vertex-triangle contacts already hold (``hit``, of :func:`vertex_triangle`, which runs
    first: :func:`edge_pair_covered`), before they take a slot.

    A query box off body b's box (``body_lower``, ``body_upper``: the union of its edges'
    boxes, :func:`body_bounds`) finds nothing in b's BVH, so it is not made; and the
    reach is first bounded by margin + dt (the ends' largest speed relative to a's mean +
    ``relative[a, b]``, :func:`near_bodies`) (|u - b's mean| <= |u - a's mean| + |a's mean -
    b's mean|), so that the far bodies (most pairs on the
    candy: 746 of 240 504 reach a body's box) cost a few float compares, not two lengths and
    a query. A body's slots are written only where they may change (its first slot not -1:
    last step found a pair), not 2 B slots an edge every step; ``found[i]`` (1: a pair in some
    slot) tells whether any may be, and last step's goes to ``found_before[i]`` (for
    :func:`gather_contacts`), so that the slots of an edge without pairs (most) are not read.
    Bodies b <= a are not visited (their slots are never set), and bodies whose ``near`` bound
    (:func:`near_bodies`: a's box towards b's) the edge's box misses get no box test of their
    own: an edge without pairs last step that no body passes is done there. A smooth edge
    queries b's crease BVH (``crease_bvh_ids``: b's creases and borders only, :func:`edge_geometry`),
    a crease b's full one. A thread takes ``block`` edges, from (thread +
    ``offset``) x ``block`` (:data:`softvr.device.ITEMS_A_CPU_THREAD`)."""
    begin = (wp.tid() + offset) * block
    for i in range(begin, wp.min(begin + block, edges.shape[0])):
        a = edge_body[i]
        before = found[i]
        found_before[i] = before
        p1 = point_x32[edges[i, 0]]
        q1 = point_x32[edges[i, 1]]
        box_lo = wp.min(p1, q1)
        box_hi = wp.max(p1, q1)
        if before == 0 and near_count(a, a + 1, box_lo, box_hi, near, near_list, near_len, reach_lower, reach_upper,
                                      body_lower, body_upper) == 0:
            found[i] = 0  # no slot to clear, no body to query (most edges)
            continue
        u0 = point_u[edges[i, 0]]
        u1 = point_u[edges[i, 1]]
        own = body_mean_u[a]
        speed = wp.max(wp.length(u0 - own), wp.length(u1 - own))
        any_found = int(0)
        for b in range(a + 1, bvh_ids.shape[0]):
            close = False
            # Every pair needs a crease edge (the query's own test below): a smooth edge against a
            # body without any (``body_crease``, :func:`body_creases`) finds none.
            if near[a, b] >= 0.0 and (sharp[i] != 0 or body_crease[b] != 0):
                # 1.001 and 1e-6 m cover the rounding of both bounds (relative ~1e-7 in float32).
                bound = (margin + dt * float(speed + relative[a, b])) * 1.001 + 1.0e-6
                close = not _off_box(box_lo, box_hi, bound, body_lower[b], body_upper[b])
            if close or (before != 0 and pair_edge[i, pairs_per_edge * b] >= 0):
                for k in range(pairs_per_edge):
                    pair_edge[i, pairs_per_edge * b + k] = -1
            if close:
                mean = body_mean_u[b]
                travel = wp.max(wp.length(u0 - mean), wp.length(u1 - mean))
                reach = margin + dt * float(travel)
                if not _off_box(box_lo, box_hi, reach, body_lower[b], body_upper[b]):
                    grow = wp.vec3(reach, reach, reach)
                    # A smooth edge pairs only with b's creases: b's crease BVH yields those of the
                    # full BVH's leaves, in its order (the same tree), without walking b's smooth
                    # surface (the candy's Jell-O top against a candy: 594 of 4 834 leaves).
                    tree = bvh_ids[b]
                    if sharp[i] == 0:
                        tree = crease_bvh_ids[b]
                    query = wp.bvh_query_aabb(tree, box_lo - grow, box_hi + grow)
                    j = int(0)
                    taken = int(0)
                    while wp.bvh_query_next(query, j):
                        jg = body_edge_start[b] + j
                        if taken < pairs_per_edge and (sharp[i] != 0 or sharp[jg] != 0) and not edge_pair_covered(
                                i, a, jg, b, edges, sharp, hit):
                            aligned, s, t, n, gap = edge_pair(p1, q1, point_x32[edges[jg, 0]], point_x32[edges[jg, 1]],
                                                              normal[i], normal[jg], reach, min_sine, min_alignment)
                            if aligned != 0 and gap >= -margin:
                                slot = pairs_per_edge * b + taken
                                pair_edge[i, slot] = jg
                                pair_st[i, slot] = wp.vec3d(wp.float64(s), wp.float64(t), wp.float64(0.0))
                                pair_normal[i, slot] = wp.vec3d(wp.float64(n[0]), wp.float64(n[1]), wp.float64(n[2]))
                                pair_gap[i, slot] = wp.float64(gap)
                                taken += 1
                    any_found = any_found + taken
        found[i] = wp.min(any_found, 1)


@wp.func
def add_node(c: int, node: int, w: wp.float64, count: wp.array(dtype=wp.int32),
             nodes: wp.array2d(dtype=wp.int32), weights: wp.array2d(dtype=wp.float64)):
    """Add ``w`` times node ``node`` to contact ``c``'s stencil (summed if already in it)."""
    n = count[c]
    for k in range(n):
        if nodes[c, k] == node:
            weights[c, k] = weights[c, k] + w
            return
    nodes[c, n] = node
    weights[c, n] = w
    count[c] = n + 1


@wp.func
def add_point(c: int, p: int, scale: wp.float64, point_nodes: wp.array2d(dtype=wp.int32),
              point_weights: wp.array2d(dtype=wp.float64), count: wp.array(dtype=wp.int32),
              nodes: wp.array2d(dtype=wp.int32), weights: wp.array2d(dtype=wp.float64)):
    for k in range(STENCIL):
        node = point_nodes[p, k]
        if node >= 0:
            add_node(c, node, scale * point_weights[p, k], count, nodes, weights)


@wp.struct
class NodeContactOut:
    """The arrays of :class:`softvr.sim.NodeContacts` the gather writes a contact to (one
    argument instead of fourteen)."""

    kind: wp.array(dtype=wp.int32)
    column: wp.array(dtype=wp.int32)
    point: wp.array(dtype=wp.int32)
    other: wp.array(dtype=wp.int32)
    face: wp.array(dtype=wp.int32)
    bary: wp.array(dtype=wp.vec3d)
    frame: wp.array(dtype=wp.mat33d)
    gap: wp.array(dtype=wp.float64)
    friction: wp.array(dtype=wp.float64)
    impulse: wp.array(dtype=wp.vec3d)
    stencil_count: wp.array(dtype=wp.int32)
    stencil_nodes: wp.array2d(dtype=wp.int32)
    stencil_weights: wp.array2d(dtype=wp.float64)


def contact_out(contacts) -> NodeContactOut:
    """The :class:`NodeContactOut` of ``contacts`` (a :class:`softvr.sim.NodeContacts`)."""
    out = NodeContactOut()
    for name in ("kind", "column", "point", "other", "face", "bary", "frame", "gap", "friction", "impulse",
                 "stencil_count", "stencil_nodes", "stencil_weights"):
        setattr(out, name, getattr(contacts, name))
    return out


@wp.func
def start_contact(out: NodeContactOut, c: int, kind: int, column: int, point: int, other: int, face: int,
                  bary: wp.vec3d, normal: wp.vec3d, gap: wp.float64, friction: wp.float64, last: wp.vec3d):
    """Write contact ``c`` with an empty stencil, warm-started from ``last`` (world [N s]):
    a pushing contact only, so the warm start's normal impulse is clamped to >= 0."""
    f = plane_frame(normal)
    out.kind[c] = kind
    out.column[c] = column
    out.point[c] = point
    out.other[c] = other
    out.face[c] = face
    out.bary[c] = bary
    out.frame[c] = f
    out.gap[c] = gap
    out.friction[c] = friction
    lam = f * last
    out.impulse[c] = wp.vec3d(wp.max(lam[0], wp.float64(0.0)), lam[1], lam[2])
    out.stencil_count[c] = 0


@wp.func
def point_contact(out: NodeContactOut, c: int, kind: int, column: int, p: int, other: int, normal: wp.vec3d,
                  gap: wp.float64, friction: wp.float64, carried: wp.array2d(dtype=wp.vec3d),
                  point_nodes: wp.array2d(dtype=wp.int32), point_weights: wp.array2d(dtype=wp.float64)):
    """Contact ``c`` of collision point ``p`` with a static (plane, sphere or mesh ``other``),
    warm-started from ``carried[p, column]``."""
    start_contact(out, c, kind, column, p, other, -1, wp.vec3d(), normal, gap, friction, carried[p, column])
    add_point(c, p, wp.float64(1.0), point_nodes, point_weights, out.stencil_count, out.stencil_nodes,
              out.stencil_weights)


@wp.func
def reaches(g: wp.float64, normal: wp.vec3d, u: wp.vec3d, dt: wp.float64, margin: wp.float64) -> bool:
    """Whether a point at gap ``g`` [m] along ``normal``, moving at ``u`` [m/s], is within
    ``margin`` [m] now or after ``dt`` [s] of its approach."""
    reach = g + dt * wp.min(wp.dot(u, normal), wp.float64(0.0))
    return wp.min(g, reach) < margin


@wp.func
def try_plane(s: int, p: int, n_out: int, write: int, capacity: int, point_x: wp.array(dtype=wp.vec3d),
              point_u: wp.array(dtype=wp.vec3d), plane_normal: wp.array(dtype=wp.vec3d),
              plane_offset: wp.array(dtype=wp.float64), plane_margin: wp.array(dtype=wp.float64),
              plane_friction: wp.array(dtype=wp.float64), dt: wp.float64, carried: wp.array2d(dtype=wp.vec3d),
              point_nodes: wp.array2d(dtype=wp.int32), point_weights: wp.array2d(dtype=wp.float64),
              out: NodeContactOut) -> int:
    """1 where point ``p`` meets plane ``s`` (within its ``plane_margin`` [m], now or over its
    motion in ``dt``), else 0; where ``write`` and ``n_out`` < ``capacity`` the contact is
    written as contact ``n_out``."""
    normal = plane_normal[s]
    g = wp.dot(normal, point_x[p]) - plane_offset[s]
    if reaches(g, normal, point_u[p], dt, plane_margin[p]):
        if write != 0 and n_out < capacity:
            point_contact(out, n_out, PLANE, s, p, s, normal, g, plane_friction[s], carried, point_nodes,
                          point_weights)
        return 1
    return 0


@wp.func
def try_sphere(k: int, p: int, column: int, n_out: int, write: int, capacity: int, point_x: wp.array(dtype=wp.vec3d),
               point_u: wp.array(dtype=wp.vec3d), point_margin: wp.array(dtype=wp.float64),
               sphere_center: wp.array(dtype=wp.vec3d), sphere_radius: wp.array(dtype=wp.float64),
               sphere_friction: wp.array(dtype=wp.float64), dt: wp.float64, carried: wp.array2d(dtype=wp.vec3d),
               point_nodes: wp.array2d(dtype=wp.int32), point_weights: wp.array2d(dtype=wp.float64),
               out: NodeContactOut) -> int:
    """:func:`try_plane` for point ``p`` and static sphere ``k`` (carried ``column``): gap and
    normal along the radius through the point (:func:`softvr.collision.points_vs_sphere`)."""
    d = point_x[p] - sphere_center[k]
    dist = wp.length(d)
    normal = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(1.0))
    if dist > wp.float64(1e-12):
        normal = d / dist
    g = dist - sphere_radius[k]
    if reaches(g, normal, point_u[p], dt, point_margin[p]):
        if write != 0 and n_out < capacity:
            point_contact(out, n_out, SPHERE, column, p, k, normal, g, sphere_friction[k], carried, point_nodes,
                          point_weights)
        return 1
    return 0


@wp.func
def try_mesh(k: int, p: int, column: int, n_out: int, write: int, capacity: int,
             static_hit: wp.array2d(dtype=wp.int32), static_normal: wp.array2d(dtype=wp.vec3),
             static_gap: wp.array2d(dtype=wp.float32), mesh_friction: wp.array(dtype=wp.float64),
             carried: wp.array2d(dtype=wp.vec3d), point_nodes: wp.array2d(dtype=wp.int32),
             point_weights: wp.array2d(dtype=wp.float64), out: NodeContactOut) -> int:
    """:func:`try_plane` for point ``p`` and static mesh ``k`` (carried ``column``), from
    :func:`point_static_mesh`'s hit."""
    if static_hit[p, k] != 0:
        if write != 0 and n_out < capacity:
            fn = static_normal[p, k]
            normal = wp.normalize(wp.vec3d(wp.float64(fn[0]), wp.float64(fn[1]), wp.float64(fn[2])))
            point_contact(out, n_out, MESH, column, p, k, normal, wp.float64(static_gap[p, k]), mesh_friction[k],
                          carried, point_nodes, point_weights)
        return 1
    return 0


@wp.func
def try_vertex(p: int, b: int, planes: int, n_out: int, write: int, capacity: int, hit: wp.array2d(dtype=wp.int32),
               hit_face: wp.array2d(dtype=wp.int32), hit_bary: wp.array2d(dtype=wp.vec3d),
               hit_normal: wp.array2d(dtype=wp.vec3d), hit_gap: wp.array2d(dtype=wp.float64),
               triangles: wp.array2d(dtype=wp.int32), body_triangle_start: wp.array(dtype=wp.int32),
               surface_friction: wp.float64, carried: wp.array2d(dtype=wp.vec3d),
               point_nodes: wp.array2d(dtype=wp.int32), point_weights: wp.array2d(dtype=wp.float64),
               out: NodeContactOut) -> int:
    """:func:`try_plane` for vertex ``p`` and body ``b``'s surface, from :func:`vertex_triangle`'s
    hit: the vertex's stencil minus the triangle's at its barycentric weights."""
    if hit[p, b] != 0:
        if write != 0 and n_out < capacity:
            t = body_triangle_start[b] + hit_face[p, b]
            w = hit_bary[p, b]
            start_contact(out, n_out, VERTEX_TRIANGLE, planes + b, p, b, t, w, hit_normal[p, b], hit_gap[p, b],
                          surface_friction, carried[p, planes + b])
            add_point(n_out, p, wp.float64(1.0), point_nodes, point_weights, out.stencil_count,
                      out.stencil_nodes, out.stencil_weights)
            for v in range(3):
                add_point(n_out, triangles[t, v], -w[v], point_nodes, point_weights, out.stencil_count,
                          out.stencil_nodes, out.stencil_weights)
        return 1
    return 0


@wp.func
def first_slot(e: int, edges: wp.array2d(dtype=wp.int32), point_body: wp.array(dtype=wp.int32),
               slots: int, bodies: int) -> int:
    """Edge ``e``'s first slot that can hold a pair: its body a queries bodies b > a only
    (:func:`edge_edge`: 2 B slots, pairs_per_edge a body), so the slots of bodies <= a are never set."""
    return slots // bodies * (point_body[edges[e, 0]] + 1)


@wp.func
def try_edge_slot(e: int, k: int, n_out: int, write: int, capacity: int, point_body: wp.array(dtype=wp.int32),
                  edges: wp.array2d(dtype=wp.int32), pair_edge: wp.array2d(dtype=wp.int32),
                  pair_st: wp.array2d(dtype=wp.vec3d), pair_normal: wp.array2d(dtype=wp.vec3d),
                  pair_gap: wp.array2d(dtype=wp.float64), edge_carried: wp.array2d(dtype=wp.vec3d),
                  edge_partner: wp.array2d(dtype=wp.int32), surface_friction: wp.float64,
                  point_nodes: wp.array2d(dtype=wp.int32), point_weights: wp.array2d(dtype=wp.float64),
                  out: NodeContactOut) -> int:
    """:func:`try_plane` for slot ``k`` of edge ``e`` (:func:`edge_edge`'s pair there, if any).
    Where ``write``, the slot's carried impulse is also taken and cleared (with its partner),
    contact or not: a slot without a partner holds no impulse anyone reads (a new pair there
    starts cold, carried_out reads partnered slots only), so it is left as it is (24 of the 26
    bytes a slot, 2 B slots an edge)."""
    last = wp.vec3d()
    partner = edge_partner[e, k]
    if partner >= 0 and write != 0:
        last = edge_carried[e, k]
        edge_carried[e, k] = wp.vec3d()
        edge_partner[e, k] = -1
    j = pair_edge[e, k]
    if j >= 0:
        if write != 0 and n_out < capacity:
            st = pair_st[e, k]
            if partner != j:  # the slot held another pair last step: start cold
                last = wp.vec3d()
            start_contact(out, n_out, EDGE_EDGE, k, e, point_body[edges[j, 0]], j, st, pair_normal[e, k],
                          pair_gap[e, k], surface_friction, last)
            one = wp.float64(1.0)
            # Side a's ends weighted (1 - s, s), side b's -(1 - t, t).
            sc, sn, sw = out.stencil_count, out.stencil_nodes, out.stencil_weights
            add_point(n_out, edges[e, 0], one - st[0], point_nodes, point_weights, sc, sn, sw)
            add_point(n_out, edges[e, 1], st[0], point_nodes, point_weights, sc, sn, sw)
            add_point(n_out, edges[j, 0], st[1] - one, point_nodes, point_weights, sc, sn, sw)
            add_point(n_out, edges[j, 1], -st[1], point_nodes, point_weights, sc, sn, sw)
        return 1
    return 0


@wp.kernel
def gather_contacts(point_x: wp.array(dtype=wp.vec3d), point_u: wp.array(dtype=wp.vec3d),
                    point_nodes: wp.array2d(dtype=wp.int32), point_weights: wp.array2d(dtype=wp.float64),
                    point_margin: wp.array(dtype=wp.float64), plane_margin: wp.array(dtype=wp.float64),
                    point_body: wp.array(dtype=wp.int32), triangles: wp.array2d(dtype=wp.int32), body_triangle_start: wp.array(dtype=wp.int32),
                    plane_normal: wp.array(dtype=wp.vec3d), plane_offset: wp.array(dtype=wp.float64),
                    plane_friction: wp.array(dtype=wp.float64), sphere_center: wp.array(dtype=wp.vec3d),
                    sphere_radius: wp.array(dtype=wp.float64), sphere_friction: wp.array(dtype=wp.float64),
                    static_hit: wp.array2d(dtype=wp.int32), static_normal: wp.array2d(dtype=wp.vec3),
                    static_gap: wp.array2d(dtype=wp.float32), mesh_friction: wp.array(dtype=wp.float64),
                    surface_friction: wp.float64, hit: wp.array2d(dtype=wp.int32), hit_face: wp.array2d(dtype=wp.int32),
                    hit_bary: wp.array2d(dtype=wp.vec3d), hit_normal: wp.array2d(dtype=wp.vec3d),
                    hit_gap: wp.array2d(dtype=wp.float64), point_hit: wp.array(dtype=wp.int32),
                    edges: wp.array2d(dtype=wp.int32), pair_edge: wp.array2d(dtype=wp.int32), pair_st: wp.array2d(dtype=wp.vec3d),
                    pair_normal: wp.array2d(dtype=wp.vec3d), pair_gap: wp.array2d(dtype=wp.float64),
                    edge_carried: wp.array2d(dtype=wp.vec3d), edge_partner: wp.array2d(dtype=wp.int32),
                    edge_found: wp.array(dtype=wp.int32), edge_found_before: wp.array(dtype=wp.int32),
                    dt: wp.float64, capacity: int, carried: wp.array2d(dtype=wp.vec3d),
                    count: wp.array(dtype=wp.int32), out: NodeContactOut):
    """One thread, so that contacts come out in the same order on every device: every (point,
    plane) pair by plane, then point (the per-object path's order), then every (point, static
    sphere) pair the same way (:func:`softvr.collision.points_vs_sphere`: gap and normal along
    the radius through the point), then every (point, static mesh) hit (``static_*``, from
    :func:`point_static_mesh`), then every (vertex, body) hit (of the vertices ``point_hit``
    marks) by vertex, then body, then every
    edge pair by edge a, then slot; a point meets the planes within its ``plane_margin`` [m]
    (-inf: never, a rigid primitive's point), the statics within its ``point_margin`` [m].
    ``other`` is the plane, sphere or mesh, or the body whose
    triangle ``face`` (global) the vertex meets at barycentric ``bary``, or whose edge
    ``face`` (global) edge ``point`` meets at (s, t, 0) = ``bary``; ``carried[p, column]``
    (planes first, then bodies, spheres, meshes) and ``edge_carried[e, column]`` (with the
    edge met, ``edge_partner``) hold the pair's world impulse [N s] of the last step (an edge's
    slots only read where :func:`edge_edge` found pairs this step or the last, ``edge_found``,
    ``edge_found_before``): ``carried``
    is only read, at the pairs in contact, since it holds last step's pairs only
    (:func:`carry_impulses` clears the step before's), not read and cleared at every (point,
    column) (12 674 x 9 on the candy). :func:`gather_pairs` gives the same contacts in the same order with a
    thread per candidate pair (a GPU's form)."""
    planes = plane_normal.shape[0]
    n_out = int(0)
    for s in range(planes):
        for p in range(point_nodes.shape[0]):
            found = try_plane(s, p, n_out, 1, capacity, point_x, point_u, plane_normal, plane_offset, plane_margin,
                              plane_friction, dt, carried, point_nodes, point_weights, out)
            if n_out < capacity:
                n_out += found
    for k in range(sphere_radius.shape[0]):
        column = planes + hit.shape[1] + k
        for p in range(point_nodes.shape[0]):
            found = try_sphere(k, p, column, n_out, 1, capacity, point_x, point_u, point_margin, sphere_center,
                               sphere_radius, sphere_friction, dt, carried, point_nodes, point_weights, out)
            if n_out < capacity:
                n_out += found
    for k in range(mesh_friction.shape[0]):
        column = planes + hit.shape[1] + sphere_radius.shape[0] + k
        for p in range(point_nodes.shape[0]):
            found = try_mesh(k, p, column, n_out, 1, capacity, static_hit, static_normal, static_gap, mesh_friction,
                             carried, point_nodes, point_weights, out)
            if n_out < capacity:
                n_out += found
    for p in range(hit.shape[0]):
        if point_hit[p] == 0:  # (most vertices: their row of B bodies is not read)
            continue
        for b in range(hit.shape[1]):
            found = try_vertex(p, b, planes, n_out, 1, capacity, hit, hit_face, hit_bary, hit_normal, hit_gap,
                               triangles, body_triangle_start, surface_friction, carried, point_nodes, point_weights,
                               out)
            if n_out < capacity:
                n_out += found
    for e in range(edges.shape[0]):  # (pair_edge keeps one row of -1 where there are no edges)
        # A partner (last step's contact) sits in a slot last step's edge_edge set: an edge whose
        # slots were empty then and now (edge_found, edge_found_before) has nothing to read.
        if edge_found[e] == 0 and edge_found_before[e] == 0:
            continue
        for k in range(first_slot(e, edges, point_body, pair_edge.shape[1], hit.shape[1]), pair_edge.shape[1]):
            found = try_edge_slot(e, k, n_out, 1, capacity, point_body, edges, pair_edge, pair_st, pair_normal,
                                  pair_gap, edge_carried, edge_partner, surface_friction, point_nodes, point_weights,
                                  out)
            if n_out < capacity:
                n_out += found
    count[0] = n_out


@wp.func
def gather_candidate(i: int, n_out: int, write: int, point_x: wp.array(dtype=wp.vec3d),
                     point_u: wp.array(dtype=wp.vec3d), point_nodes: wp.array2d(dtype=wp.int32),
                     point_weights: wp.array2d(dtype=wp.float64), point_margin: wp.array(dtype=wp.float64),
                     plane_margin: wp.array(dtype=wp.float64), point_body: wp.array(dtype=wp.int32),
                     triangles: wp.array2d(dtype=wp.int32), body_triangle_start: wp.array(dtype=wp.int32),
                     plane_normal: wp.array(dtype=wp.vec3d), plane_offset: wp.array(dtype=wp.float64),
                     plane_friction: wp.array(dtype=wp.float64), sphere_center: wp.array(dtype=wp.vec3d),
                     sphere_radius: wp.array(dtype=wp.float64), sphere_friction: wp.array(dtype=wp.float64),
                     static_hit: wp.array2d(dtype=wp.int32), static_normal: wp.array2d(dtype=wp.vec3),
                     static_gap: wp.array2d(dtype=wp.float32), mesh_friction: wp.array(dtype=wp.float64),
                     surface_friction: wp.float64, hit: wp.array2d(dtype=wp.int32),
                     hit_face: wp.array2d(dtype=wp.int32), hit_bary: wp.array2d(dtype=wp.vec3d),
                     hit_normal: wp.array2d(dtype=wp.vec3d), hit_gap: wp.array2d(dtype=wp.float64),
                     point_hit: wp.array(dtype=wp.int32), edges: wp.array2d(dtype=wp.int32),
                     pair_edge: wp.array2d(dtype=wp.int32), pair_st: wp.array2d(dtype=wp.vec3d),
                     pair_normal: wp.array2d(dtype=wp.vec3d), pair_gap: wp.array2d(dtype=wp.float64),
                     edge_carried: wp.array2d(dtype=wp.vec3d), edge_partner: wp.array2d(dtype=wp.int32),
                     edge_found: wp.array(dtype=wp.int32), edge_found_before: wp.array(dtype=wp.int32),
                     dt: wp.float64, capacity: int, carried: wp.array2d(dtype=wp.vec3d), out: NodeContactOut) -> int:
    """Candidate pair ``i`` of :func:`gather_contacts`' order (points x planes, x static spheres,
    x static meshes, each static-major; vertices x bodies, vertex-major; edges x slots,
    edge-major: :func:`gather_candidates`), tried (:func:`try_plane` and the others)."""
    points = point_nodes.shape[0]
    planes = plane_normal.shape[0]
    spheres = sphere_radius.shape[0]
    bodies = hit.shape[1]
    first = i
    if first < planes * points:
        return try_plane(first // points, first % points, n_out, write, capacity, point_x, point_u, plane_normal,
                         plane_offset, plane_margin, plane_friction, dt, carried, point_nodes, point_weights, out)
    first = first - planes * points
    if first < spheres * points:
        k = first // points
        return try_sphere(k, first % points, planes + bodies + k, n_out, write, capacity, point_x, point_u,
                          point_margin, sphere_center, sphere_radius, sphere_friction, dt, carried, point_nodes,
                          point_weights, out)
    first = first - spheres * points
    if first < mesh_friction.shape[0] * points:
        k = first // points
        return try_mesh(k, first % points, planes + bodies + spheres + k, n_out, write, capacity, static_hit,
                        static_normal, static_gap, mesh_friction, carried, point_nodes, point_weights, out)
    first = first - mesh_friction.shape[0] * points
    if first < hit.shape[0] * bodies:
        p = first // bodies
        if point_hit[p] == 0:
            return 0
        return try_vertex(p, first % bodies, planes, n_out, write, capacity, hit, hit_face, hit_bary, hit_normal,
                          hit_gap, triangles, body_triangle_start, surface_friction, carried, point_nodes,
                          point_weights, out)
    first = first - hit.shape[0] * bodies
    slots = pair_edge.shape[1]
    e = first // slots
    k = first % slots
    if e >= edges.shape[0] or (edge_found[e] == 0 and edge_found_before[e] == 0):
        return 0
    if k < first_slot(e, edges, point_body, slots, bodies):
        return 0
    return try_edge_slot(e, k, n_out, write, capacity, point_body, edges, pair_edge, pair_st, pair_normal, pair_gap,
                         edge_carried, edge_partner, surface_friction, point_nodes, point_weights, out)


@wp.kernel
def gather_pairs(point_x: wp.array(dtype=wp.vec3d), point_u: wp.array(dtype=wp.vec3d),
                 point_nodes: wp.array2d(dtype=wp.int32), point_weights: wp.array2d(dtype=wp.float64),
                 point_margin: wp.array(dtype=wp.float64), plane_margin: wp.array(dtype=wp.float64),
                 point_body: wp.array(dtype=wp.int32), triangles: wp.array2d(dtype=wp.int32),
                 body_triangle_start: wp.array(dtype=wp.int32), plane_normal: wp.array(dtype=wp.vec3d),
                 plane_offset: wp.array(dtype=wp.float64), plane_friction: wp.array(dtype=wp.float64),
                 sphere_center: wp.array(dtype=wp.vec3d), sphere_radius: wp.array(dtype=wp.float64),
                 sphere_friction: wp.array(dtype=wp.float64), static_hit: wp.array2d(dtype=wp.int32),
                 static_normal: wp.array2d(dtype=wp.vec3), static_gap: wp.array2d(dtype=wp.float32),
                 mesh_friction: wp.array(dtype=wp.float64), surface_friction: wp.float64,
                 hit: wp.array2d(dtype=wp.int32), hit_face: wp.array2d(dtype=wp.int32),
                 hit_bary: wp.array2d(dtype=wp.vec3d), hit_normal: wp.array2d(dtype=wp.vec3d),
                 hit_gap: wp.array2d(dtype=wp.float64), point_hit: wp.array(dtype=wp.int32),
                 edges: wp.array2d(dtype=wp.int32), pair_edge: wp.array2d(dtype=wp.int32),
                 pair_st: wp.array2d(dtype=wp.vec3d), pair_normal: wp.array2d(dtype=wp.vec3d),
                 pair_gap: wp.array2d(dtype=wp.float64), edge_carried: wp.array2d(dtype=wp.vec3d),
                 edge_partner: wp.array2d(dtype=wp.int32), edge_found: wp.array(dtype=wp.int32),
                 edge_found_before: wp.array(dtype=wp.int32), dt: wp.float64, capacity: int,
                 carried: wp.array2d(dtype=wp.vec3d), out: NodeContactOut, write: int, flags: wp.array(dtype=wp.int32),
                 rows: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32)):
    """:func:`gather_contacts` with a thread per candidate pair ``i`` (:func:`gather_candidate`; a
    GPU's form), in two launches around an exclusive scan of ``flags`` into ``rows``: ``write`` 0
    sets ``flags[i]`` to 1 where the pair makes a contact (nothing else written); ``write`` 1
    writes it as contact ``rows[i]`` where it makes one below ``capacity`` and takes its edge
    slot's carried impulse either way, and the last thread writes ``count[0]``: the one-thread
    gather's contacts in its order."""
    i = wp.tid()
    found = gather_candidate(i, rows[i], write, point_x, point_u, point_nodes, point_weights, point_margin,
                             plane_margin, point_body, triangles, body_triangle_start, plane_normal, plane_offset,
                             plane_friction, sphere_center, sphere_radius, sphere_friction, static_hit, static_normal,
                             static_gap, mesh_friction, surface_friction, hit, hit_face, hit_bary, hit_normal, hit_gap,
                             point_hit, edges, pair_edge, pair_st, pair_normal, pair_gap, edge_carried, edge_partner,
                             edge_found, edge_found_before, dt, capacity, carried, out)
    if write == 0:
        flags[i] = found
    elif i == flags.shape[0] - 1:
        count[0] = wp.min(rows[i] + flags[i], capacity)


@wp.kernel
def carry_impulses(count: wp.array(dtype=wp.int32), kind: wp.array(dtype=wp.int32), column: wp.array(dtype=wp.int32),
                   point: wp.array(dtype=wp.int32), face: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.mat33d),
                   impulse: wp.array(dtype=wp.vec3d), carried: wp.array2d(dtype=wp.vec3d),
                   edge_carried: wp.array2d(dtype=wp.vec3d), edge_partner: wp.array2d(dtype=wp.int32),
                   written: wp.array(dtype=wp.int32), written_count: wp.array(dtype=wp.int32)):
    """The step's impulses (world [N s]) into the carried tables for the next step's warm start.
    ``carried`` then holds this step's pairs only: the entries the last call wrote (flat
    indices ``written[:written_count[0]]``) are cleared first, or all of it while
    ``written_count[0]`` < 0 (the first call: the table may hold warm starts put in from the
    per-object path), so that a pair no longer in contact forgets its impulse."""
    columns = carried.shape[1]
    if written_count[0] < 0:
        for p in range(carried.shape[0]):
            for k in range(columns):
                carried[p, k] = wp.vec3d()
    for i in range(written_count[0]):
        carried[written[i] // columns, written[i] % columns] = wp.vec3d()
    n = int(0)
    for c in range(count[0]):
        world = wp.transpose(frame[c]) * impulse[c]
        if kind[c] == EDGE_EDGE:
            edge_carried[point[c], column[c]] = world
            edge_partner[point[c], column[c]] = face[c]
        elif kind[c] != PRIMITIVE:  # primitive contacts start cold
            carried[point[c], column[c]] = world
            written[n] = point[c] * columns + column[c]
            n += 1
    written_count[0] = n


@wp.kernel
def clear_carried(carried: wp.array2d(dtype=wp.vec3d), written: wp.array(dtype=wp.int32),
                  written_count: wp.array(dtype=wp.int32), threads: int):
    """:func:`carry_impulses`' clearing with ``threads`` threads striding: the entries of
    ``carried`` the last :func:`carry_parallel` wrote (flat ``written[c]`` of its
    ``written_count[0]`` contacts, -1 for none), or all of it while ``written_count[0]`` < 0
    (the first call: the table may hold warm starts put in from the per-object path)."""
    columns = carried.shape[1]
    if written_count[0] < 0:
        for e in range(wp.tid(), carried.shape[0] * columns, threads):
            carried[e // columns, e % columns] = wp.vec3d()
        return
    for c in range(wp.tid(), written_count[0], threads):
        e = written[c]
        if e >= 0:
            carried[e // columns, e % columns] = wp.vec3d()


@wp.kernel
def carry_parallel(count: wp.array(dtype=wp.int32), kind: wp.array(dtype=wp.int32), column: wp.array(dtype=wp.int32),
                   point: wp.array(dtype=wp.int32), face: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.mat33d),
                   impulse: wp.array(dtype=wp.vec3d), carried: wp.array2d(dtype=wp.vec3d),
                   edge_carried: wp.array2d(dtype=wp.vec3d), edge_partner: wp.array2d(dtype=wp.int32),
                   written: wp.array(dtype=wp.int32), written_count: wp.array(dtype=wp.int32), threads: int):
    """:func:`carry_impulses`' writing with ``threads`` threads striding over the contacts (after
    :func:`clear_carried`): each contact's world impulse [N s] into its entry, which goes to
    ``written[c]`` (-1: an edge pair's or a primitive's, not in ``carried``)."""
    columns = carried.shape[1]
    n = count[0]
    for c in range(wp.tid(), n, threads):
        world = wp.transpose(frame[c]) * impulse[c]
        written[c] = -1
        if kind[c] == EDGE_EDGE:
            edge_carried[point[c], column[c]] = world
            edge_partner[point[c], column[c]] = face[c]
        elif kind[c] != PRIMITIVE:  # primitive contacts start cold
            carried[point[c], column[c]] = world
            written[c] = point[c] * columns + column[c]
    if wp.tid() == 0:
        written_count[0] = n



# The per-body reductions of the detection with a thread per item (a GPU's form: one thread
# walking a body's points waits on every load in turn, ~5 000 of the Jell-O's), into per-body
# totals taken atomically (zeroed or filled before). A mean summed atomically has no fixed order
# on CUDA: its last bits may differ from run to run.


@wp.kernel
def point_sums(point_body: wp.array(dtype=wp.int32), point_u: wp.array(dtype=wp.vec3d),
               body_sum: wp.array(dtype=wp.vec3d), body_count: wp.array(dtype=wp.int32)):
    """:func:`body_motion`'s sums: point ``p``'s predicted velocity [m/s] into its body's
    ``body_sum``, and the body's point count."""
    p = wp.tid()
    b = point_body[p]
    wp.atomic_add(body_sum, b, point_u[p])
    wp.atomic_add(body_count, b, 1)


@wp.kernel
def body_means(body_sum: wp.array(dtype=wp.vec3d), body_count: wp.array(dtype=wp.int32),
               body_mean_u: wp.array(dtype=wp.vec3d), body_spread: wp.array(dtype=wp.float64)):
    """Body ``b``'s mean predicted velocity [m/s] from :func:`point_sums`; its spread zeroed for
    :func:`point_spread`."""
    b = wp.tid()
    u = body_sum[b]
    if body_count[b] > 0:
        u = u / wp.float64(body_count[b])
    body_mean_u[b] = u
    body_spread[b] = wp.float64(0.0)


@wp.kernel
def point_spread(point_body: wp.array(dtype=wp.int32), point_u: wp.array(dtype=wp.vec3d),
                 body_mean_u: wp.array(dtype=wp.vec3d), body_spread: wp.array(dtype=wp.float64)):
    """:func:`body_motion`'s spread: point ``p``'s speed [m/s] relative to its body's mean, the
    largest per body."""
    p = wp.tid()
    b = point_body[p]
    wp.atomic_max(body_spread, b, wp.length(point_u[p] - body_mean_u[b]))


@wp.kernel
def item_bounds(item_body: wp.array(dtype=wp.int32), lower: wp.array(dtype=wp.vec3), upper: wp.array(dtype=wp.vec3),
                body_lower: wp.array(dtype=wp.vec3), body_upper: wp.array(dtype=wp.vec3)):
    """:func:`body_bounds` with a thread per item ``e`` (of body ``item_body[e]``): its box into its
    body's (filled with +-1e30 before) by component-wise atomic min / max."""
    e = wp.tid()
    b = item_body[e]
    wp.atomic_min(body_lower, b, lower[e])
    wp.atomic_max(body_upper, b, upper[e])


@wp.kernel
def edge_creases(edge_body: wp.array(dtype=wp.int32), sharp: wp.array(dtype=wp.int32),
                 body_crease: wp.array(dtype=wp.int32)):
    """:func:`body_creases` with a thread per edge ``e`` (``body_crease`` zeroed before): 1 into its
    body's where it is sharp (every such thread writes the same 1)."""
    e = wp.tid()
    if sharp[e] != 0:
        body_crease[edge_body[e]] = 1
