"""Compiled implicit adhesion of the node arrays' contacts (thesis ch. 4): before the sweeps,
each contact's key, materials, area, intensity and slip (:func:`prepare`); after them,
bonding / debonding (4.3.3) and what carries over to the next step, sorted by key
(:func:`evolve`). The bounds of eq. 4.16 act inside the sweeps
(:func:`softvr.contact._node_jacobi_kernels.contacts`); the shared math is in
:mod:`softvr.contact._adhesion_kernels`, as the rigid arrays use it.

Contact kinds of the node arrays (:class:`softvr.sim.NodeContacts`): 0 point vs plane, 1
surface vertex vs another body's triangle, 2 edge vs edge, 3 a rigid body's box or sphere
primitive (its key, area and side b's plane from the rigid path's detection, which numbers the
bodies among the rigid ones: the key is re-packed with the scene's), 4 point vs static sphere,
5 point vs static mesh (keyed and measured as a point on a plane, the static's index as side b).
"""

from __future__ import annotations

import warp as wp

from softvr.contact._adhesion_kernels import bond_stiffness, carry_sorted, evolve_bond, find_key, yields_patch
from softvr.contact._node_jacobi_kernels import _rigid_velocity

# softvr.collision.ContactKind of the node kinds 0, 1, 2, 4, 5, and the key's bit layout
# (softvr.collision.contact_keys: kind 4 | body a 10 | body b 10 | feature a 20 | feature b 20).
POINT_PLANE, POINT_SPHERE, POINT_MESH, VERTEX_TRIANGLE, EDGE_EDGE = 0, 1, 2, 3, 4
#: The key of a contact that does not adhere: above every real one (kinds < 15), so that it
#: never shadows one in the carried table's search.
NO_KEY = wp.constant(wp.uint64(0xFFFFFFFFFFFFFFFF))
#: The key's 10-bit body field and its low 40 bits (features a and b).
BODY_BITS = wp.constant(wp.uint64(0x3FF))
FEATURE_BITS = wp.constant(wp.uint64(0xFFFFFFFFFF))


@wp.func
def pack_key(kind: int, body_a: int, feature_a: int, body_b: int, feature_b: int) -> wp.uint64:
    """The contact's key, as :func:`softvr.collision.contact_keys` packs it."""
    return ((wp.uint64(kind) << wp.uint64(60)) | (wp.uint64(body_a) << wp.uint64(50))
            | (wp.uint64(body_b) << wp.uint64(40)) | (wp.uint64(feature_a) << wp.uint64(20)) | wp.uint64(feature_b))


@wp.func
def facing(t: int, n: wp.vec3d, point_x: wp.array(dtype=wp.vec3d), triangles: wp.array2d(dtype=wp.int32),
           two_sided: int) -> wp.float64:
    """Area [m^2] of triangle ``t`` projected on the plane of unit normal ``n`` (pointing into
    the triangle's body): ``A |n_t . n|`` on an open surface, ``A max(-n_t . n, 0)`` on a
    closed one (:meth:`softvr.collision.CollisionSurface._facing`)."""
    x0 = point_x[triangles[t, 0]]
    cross = wp.cross(point_x[triangles[t, 1]] - x0, point_x[triangles[t, 2]] - x0)
    size = wp.length(cross)
    if size <= wp.float64(0.0):
        return wp.float64(0.0)
    cosine = wp.dot(cross, n) / size
    if two_sided != 0:
        return wp.float64(0.5) * size * wp.abs(cosine)
    return wp.float64(0.5) * size * wp.max(-cosine, wp.float64(0.0))


@wp.func
def vertex_area(p: int, n: wp.vec3d, point_x: wp.array(dtype=wp.vec3d), triangles: wp.array2d(dtype=wp.int32),
                vertex_start: wp.array(dtype=wp.int32), vertex_triangles: wp.array(dtype=wp.int32),
                two_sided: int) -> wp.float64:
    """A third of every incident triangle's facing area (:meth:`CollisionSurface.facing_vertex_area`)."""
    area = wp.float64(0.0)
    for k in range(vertex_start[p], vertex_start[p + 1]):
        area += facing(vertex_triangles[k], n, point_x, triangles, two_sided) / wp.float64(3.0)
    return area


@wp.func
def edge_area(e: int, n: wp.vec3d, point_x: wp.array(dtype=wp.vec3d), triangles: wp.array2d(dtype=wp.int32),
              edge_faces: wp.array2d(dtype=wp.int32), two_sided: int) -> wp.float64:
    """A third of the edge's one or two triangles' facing areas (:meth:`CollisionSurface.facing_edge_area`)."""
    area = facing(edge_faces[e, 0], n, point_x, triangles, two_sided)
    if edge_faces[e, 1] >= 0:
        area += facing(edge_faces[e, 1], n, point_x, triangles, two_sided)
    return area / wp.float64(3.0)


@wp.func
def primitive_key(rigid_key: wp.uint64, body_a: int, body_b: int) -> wp.uint64:
    """The scene key of a primitive contact whose rigid-path key is ``rigid_key`` (bodies
    numbered among the rigid bodies): bodies ``body_a`` and ``body_b`` (scene indices; -1: side b
    is a plane, whose index the key keeps), kind and features as they are."""
    b = wp.uint64(body_b)
    if body_b < 0:
        b = (rigid_key >> wp.uint64(40)) & BODY_BITS
    return ((rigid_key >> wp.uint64(60)) << wp.uint64(60)) | (wp.uint64(body_a) << wp.uint64(50)) \
        | (b << wp.uint64(40)) | (rigid_key & FEATURE_BITS)


@wp.struct
class NodeAdhesionArrays:
    """The node arrays' adhesion (``c`` contacts' capacity, ``m`` materials): per contact its
    ``key`` (uint64), ``material_a`` / ``material_b`` (int32, -1: none), ``intensity`` beta
    (float64, -1: not tracked); the carried table of the last step's contacts, ascending by
    key: ``carried_count`` [1], ``carried_key``, ``carried_impulse`` (world [N s]),
    ``carried_intensity``, ``carried_slip`` [m]; ``materials`` [m, 7]
    (:data:`softvr.sim.model.ADHESION_COLUMNS`), ``body_material`` [bodies],
    ``plane_material`` [planes], ``sphere_material`` [static spheres], ``mesh_material``
    [static meshes], ``body_two_sided`` [bodies] (1: an open surface),
    ``vertex_start`` [p + 1] / ``vertex_triangles``: each collision point's incident
    triangles (global; none for a point that is no surface vertex); ``pair_bonded`` [bodies,
    bodies] (int32) and ``pair_bonded_area`` [bodies, bodies] [m^2]: how many of the step's
    vertex-triangle contacts of body a's vertices on body b's triangles adhere and their summed
    area (:func:`count_bonded`)."""

    key: wp.array(dtype=wp.uint64)
    material_a: wp.array(dtype=wp.int32)
    material_b: wp.array(dtype=wp.int32)
    intensity: wp.array(dtype=wp.float64)
    carried_count: wp.array(dtype=wp.int32)
    carried_key: wp.array(dtype=wp.uint64)
    carried_impulse: wp.array(dtype=wp.vec3d)
    carried_intensity: wp.array(dtype=wp.float64)
    carried_slip: wp.array(dtype=wp.vec3d)
    materials: wp.array2d(dtype=wp.float64)
    body_material: wp.array(dtype=wp.int32)
    plane_material: wp.array(dtype=wp.int32)
    sphere_material: wp.array(dtype=wp.int32)
    mesh_material: wp.array(dtype=wp.int32)
    body_two_sided: wp.array(dtype=wp.int32)
    vertex_start: wp.array(dtype=wp.int32)
    vertex_triangles: wp.array(dtype=wp.int32)
    pair_bonded: wp.array2d(dtype=wp.int32)
    pair_bonded_area: wp.array2d(dtype=wp.float64)


@wp.func
def _prepare_contact(c: int, ad: NodeAdhesionArrays, kind: wp.array(dtype=wp.int32), column: wp.array(dtype=wp.int32),
                     point: wp.array(dtype=wp.int32), other: wp.array(dtype=wp.int32), face: wp.array(dtype=wp.int32),
                     frame: wp.array(dtype=wp.mat33d), rigid_key: wp.array(dtype=wp.uint64),
                     rigid_area: wp.array(dtype=wp.float64), point_x: wp.array(dtype=wp.vec3d),
                     point_body: wp.array(dtype=wp.int32), body_point_start: wp.array(dtype=wp.int32),
                     triangles: wp.array2d(dtype=wp.int32), edge_body: wp.array(dtype=wp.int32),
                     body_edge_start: wp.array(dtype=wp.int32), edge_faces: wp.array2d(dtype=wp.int32),
                     area: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
                     slip: wp.array(dtype=wp.vec3d), impulse: wp.array(dtype=wp.vec3d)):
    """Contact ``c``'s row of :func:`prepare`."""
    n = wp.vec3d(frame[c][0, 0], frame[c][0, 1], frame[c][0, 2])
    k = kind[c]
    p = point[c]
    o = other[c]
    key = wp.uint64(0)
    ar = wp.float64(0.0)
    ma = int(-1)
    mb = int(-1)
    if k == 3:
        key = primitive_key(rigid_key[p], column[c], o)
        ar = rigid_area[p]
        ma = ad.body_material[column[c]]
        if o >= 0:
            mb = ad.body_material[o]
        else:
            mb = ad.plane_material[int((rigid_key[p] >> wp.uint64(40)) & BODY_BITS)]
    elif k == 2:
        a = edge_body[p]
        key = pack_key(EDGE_EDGE, a, p - body_edge_start[a], o, face[c] - body_edge_start[o])
        ma = ad.body_material[a]
        mb = ad.body_material[o]
        ar = wp.min(edge_area(p, n, point_x, triangles, edge_faces, ad.body_two_sided[a]),
                    edge_area(face[c], -n, point_x, triangles, edge_faces, ad.body_two_sided[o]))
    else:
        a = point_body[p]
        ma = ad.body_material[a]
        ar = vertex_area(p, n, point_x, triangles, ad.vertex_start, ad.vertex_triangles, ad.body_two_sided[a])
        if k == 0:
            key = pack_key(POINT_PLANE, a, p - body_point_start[a], o, 0)
            mb = ad.plane_material[o]
        elif k == 4:
            key = pack_key(POINT_SPHERE, a, p - body_point_start[a], o, 0)
            mb = ad.sphere_material[o]
        elif k == 5:
            key = pack_key(POINT_MESH, a, p - body_point_start[a], o, 0)
            mb = ad.mesh_material[o]
        else:
            key = pack_key(VERTEX_TRIANGLE, a, p - body_point_start[a], o, 0)
            mb = ad.body_material[o]
    ad.key[c] = key
    ad.material_a[c] = ma
    ad.material_b[c] = mb
    area[c] = ar
    m = find_key(ad.carried_key, ad.carried_count[0], key)
    beta = wp.float64(-1.0)
    u = wp.vec3d()
    if m >= 0:
        beta = ad.carried_intensity[m]
        u = ad.carried_slip[m]
    ad.intensity[c] = beta
    slip[c] = u - wp.dot(u, n) * n
    s = bond_stiffness(ad.materials, ma, mb, ar, beta)
    stiffness[c] = s
    if s > wp.float64(0.0):
        impulse[c] = frame[c] * ad.carried_impulse[m]


@wp.kernel
def prepare(ad: NodeAdhesionArrays, count: wp.array(dtype=wp.int32), kind: wp.array(dtype=wp.int32),
            column: wp.array(dtype=wp.int32), point: wp.array(dtype=wp.int32), other: wp.array(dtype=wp.int32),
            face: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.mat33d), rigid_key: wp.array(dtype=wp.uint64),
            rigid_area: wp.array(dtype=wp.float64), point_x: wp.array(dtype=wp.vec3d),
            point_body: wp.array(dtype=wp.int32), body_point_start: wp.array(dtype=wp.int32),
            triangles: wp.array2d(dtype=wp.int32), edge_body: wp.array(dtype=wp.int32),
            body_edge_start: wp.array(dtype=wp.int32), edge_faces: wp.array2d(dtype=wp.int32),
            area: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
            slip: wp.array(dtype=wp.vec3d), impulse: wp.array(dtype=wp.vec3d), threads: int, offset: int):
    """Per contact of the step (``threads`` threads striding over ``count[0]``, thread ``tid +
    offset``): its key, materials, area [m^2] (its feature's surface projected on the contact
    plane, the smaller of its two sides' for two edges, a vertex's own on a triangle, of which
    :func:`share_patches` keeps one way of a face-to-face patch; docs/adhesion.md; a
    primitive contact's (kind 3) the rigid path's ``rigid_key`` and ``rigid_area`` of its row),
    intensity and slip [m] carried by key, stiffness ``A C beta^2`` [N/m]; a bonded contact's
    warm start ``impulse`` [N s] is the last step's unclamped (it may pull). A few threads, not
    one per slot of the capacity: a CPU thread copies the struct ``ad``, and over the ~190 000
    slots of the candy that alone took 25 ms a step."""
    for c in range(wp.tid() + offset, count[0], threads):
        _prepare_contact(c, ad, kind, column, point, other, face, frame, rigid_key, rigid_area, point_x, point_body,
                         body_point_start, triangles, edge_body, body_edge_start, edge_faces, area, stiffness, slip,
                         impulse)


@wp.kernel
def clear_bonded(ad: NodeAdhesionArrays):
    """Zero ``ad.pair_bonded`` and ``ad.pair_bonded_area`` [bodies, bodies] (:func:`count_bonded`)."""
    a, b = wp.tid()
    ad.pair_bonded[a, b] = 0
    ad.pair_bonded_area[a, b] = wp.float64(0.0)


@wp.kernel
def count_bonded(ad: NodeAdhesionArrays, count: wp.array(dtype=wp.int32), kind: wp.array(dtype=wp.int32),
                 point: wp.array(dtype=wp.int32), other: wp.array(dtype=wp.int32),
                 point_body: wp.array(dtype=wp.int32), area: wp.array(dtype=wp.float64),
                 stiffness: wp.array(dtype=wp.float64), threads: int):
    """``ad.pair_bonded[a, b]``, ``ad.pair_bonded_area[a, b]`` [m^2]: the step's adhering
    vertex-triangle contacts (kind 1: tracked, with an area and adhesive materials, so a bond
    stiffness > 0 [N/m]) of body a's vertices on body b's triangles and their areas, after
    :func:`prepare` (``threads`` threads striding over ``count[0]``, adding with atomics: one
    launch, not split over CPU threads)."""
    for c in range(wp.tid(), count[0], threads):
        if kind[c] == 1 and stiffness[c] > wp.float64(0.0):
            wp.atomic_add(ad.pair_bonded, point_body[point[c]], other[c], 1)
            wp.atomic_add(ad.pair_bonded_area, point_body[point[c]], other[c], area[c])


@wp.kernel
def share_patches(ad: NodeAdhesionArrays, count: wp.array(dtype=wp.int32), kind: wp.array(dtype=wp.int32),
                  point: wp.array(dtype=wp.int32), other: wp.array(dtype=wp.int32),
                  point_body: wp.array(dtype=wp.int32), stiffness: wp.array(dtype=wp.float64), threads: int,
                  offset: int):
    """One way of a face-to-face patch's vertex-triangle contacts bonds (:func:`yields_patch`
    on :func:`count_bonded`'s tallies); the other way's stiffness [N/m] is set to 0. Its
    contacts keep their areas and intensities, so that their bonds follow the same gaps (eqs.
    4.11, 4.12) and may take over should the other way's give (``threads`` threads striding
    over ``count[0]``, thread ``tid + offset``)."""
    for c in range(wp.tid() + offset, count[0], threads):
        if kind[c] == 1:
            a = point_body[point[c]]
            o = other[c]
            if yields_patch(ad.pair_bonded[a, o], ad.pair_bonded[o, a], ad.pair_bonded_area[a, o],
                            ad.pair_bonded_area[o, a], a, o):
                stiffness[c] = wp.float64(0.0)


@wp.func
def evolve_contact(c: int, ad: NodeAdhesionArrays, frame: wp.array(dtype=wp.mat33d),
                   impulse: wp.array(dtype=wp.vec3d), gap_after: wp.array(dtype=wp.float64),
                   stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                   stencil_weights: wp.array2d(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
                   rigid_lever: wp.array2d(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
                   v: wp.array(dtype=wp.vec3d), area: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
                   slip: wp.array(dtype=wp.vec3d), dt: wp.float64):
    """Contact ``c``'s bond at the end of the step (:func:`evolve`): its slip ``u + dt v_t`` [m],
    bonding / debonding (4.3.3), into ``ad.intensity[c]`` and ``slip[c]``."""
    n = wp.vec3d(frame[c][0, 0], frame[c][0, 1], frame[c][0, 2])
    rel = wp.vec3d()
    movable = int(0)
    for k in range(stencil_count[c]):
        node = stencil_nodes[c, k]
        rel = rel + stencil_weights[c, k] * v[node]
        if fixed[node] == 0:
            movable = 1
    rel = rel + _rigid_velocity(c, v, rigid_node, rigid_lever)
    u = slip[c]
    if stiffness[c] > wp.float64(0.0):
        u = u + dt * rel
        u = u - wp.dot(u, n) * n
    beta_out = wp.float64(-1.0)
    u_out = wp.vec3d()
    ma = ad.material_a[c]
    mb = ad.material_b[c]
    if ma >= 0 and mb >= 0 and movable != 0:
        beta_out, u_out = evolve_bond(ad.materials, ma, mb, ad.intensity[c], impulse[c][0], gap_after[c], area[c],
                                      u, dt)
    ad.intensity[c] = beta_out
    slip[c] = u_out


@wp.kernel
def evolve(ad: NodeAdhesionArrays, count: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.mat33d),
           impulse: wp.array(dtype=wp.vec3d), gap_after: wp.array(dtype=wp.float64),
           stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
           stencil_weights: wp.array2d(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
           rigid_lever: wp.array2d(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
           v: wp.array(dtype=wp.vec3d), area: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
           slip: wp.array(dtype=wp.vec3d), dt: wp.float64):
    """One thread, after the sweeps (solved velocities ``v`` [n] [m/s], ``gap_after`` [m]): each
    bonded contact's slip at the end of the step ``u + dt v_t`` [m] (``v_t`` with its rigid
    sides' ``omega x lever``), bonding / debonding
    (4.3.3; a contact no impulse can move is not tracked, as the per-object path drops it),
    then the step's contacts into the carried table, ascending by key."""
    total = count[0]
    for c in range(total):
        evolve_contact(c, ad, frame, impulse, gap_after, stencil_count, stencil_nodes, stencil_weights, rigid_node,
                       rigid_lever, fixed, v, area, stiffness, slip, dt)
    for c in range(total):
        carry_sorted(c, ad.key[c], wp.transpose(frame[c]) * impulse[c], ad.intensity[c], slip[c], ad.carried_key,
                     ad.carried_impulse, ad.carried_intensity, ad.carried_slip)
    ad.carried_count[0] = total


# :func:`evolve` with a thread per contact (a GPU's form: one thread walking a step's ~3 000 contacts
# and insertion-sorting them waits on every load in turn): each contact's bond evolved and its key
# listed (rows past the count keyed last), the keys radix-sorted with their rows (stable, so the
# same table as the insertion sort), the table written in key order.
_LAST_KEY = wp.constant(wp.uint64(0xFFFFFFFFFFFFFFFF))


@wp.kernel
def evolve_parallel(ad: NodeAdhesionArrays, count: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.mat33d),
                    impulse: wp.array(dtype=wp.vec3d), gap_after: wp.array(dtype=wp.float64),
                    stencil_count: wp.array(dtype=wp.int32), stencil_nodes: wp.array2d(dtype=wp.int32),
                    stencil_weights: wp.array2d(dtype=wp.float64), rigid_node: wp.array2d(dtype=wp.int32),
                    rigid_lever: wp.array2d(dtype=wp.vec3d), fixed: wp.array(dtype=wp.int32),
                    v: wp.array(dtype=wp.vec3d), area: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
                    slip: wp.array(dtype=wp.vec3d), dt: wp.float64, sort_key: wp.array(dtype=wp.uint64),
                    sort_row: wp.array(dtype=wp.int32), threads: int):
    """:func:`evolve_contact` for each of the ``count[0]`` contacts and its key into ``sort_key``
    (row ``sort_row``) for the sort; the rows past the count keyed last. ``threads`` threads
    stride over the buffer's ``sort_key.shape[0] / 2`` rows."""
    total = count[0]
    for c in range(wp.tid(), sort_key.shape[0] // 2, threads):
        sort_row[c] = c
        if c < total:
            evolve_contact(c, ad, frame, impulse, gap_after, stencil_count, stencil_nodes, stencil_weights, rigid_node,
                           rigid_lever, fixed, v, area, stiffness, slip, dt)
            sort_key[c] = ad.key[c]
        else:
            sort_key[c] = _LAST_KEY


@wp.kernel
def carry_parallel(ad: NodeAdhesionArrays, count: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.mat33d),
                   impulse: wp.array(dtype=wp.vec3d), slip: wp.array(dtype=wp.vec3d),
                   sort_row: wp.array(dtype=wp.int32), threads: int):
    """The step's contacts into the carried table in key order (``sort_row``: the rows sorted by
    key, :func:`evolve_parallel`), ``threads`` threads striding: :func:`evolve`'s table."""
    total = count[0]
    for r in range(wp.tid(), total, threads):
        c = sort_row[r]
        ad.carried_key[r] = ad.key[c]
        ad.carried_impulse[r] = wp.transpose(frame[c]) * impulse[c]
        ad.carried_intensity[r] = ad.intensity[c]
        ad.carried_slip[r] = slip[c]
    if wp.tid() == 0:
        ad.carried_count[0] = total

