"""Compiled contact generation over a whole rigid scene, one launch per pair kind: collision
points, box corners and spheres against planes, sphere against sphere, box against box.

Each kernel is the array form of its per-pair NumPy function (:func:`points_vs_plane` with
:meth:`CollisionSurface.facing_vertex_area`, :func:`box_vs_plane`, :func:`sphere_vs_plane`,
:func:`sphere_vs_sphere`, :func:`box_vs_box`): the same gaps, speculative approach, areas and
keys, so that the two paths make the same contacts. Contacts are appended to a
:class:`~softvr.collision.contact_buffer.ContactBuffer` through an atomic counter.
"""

from __future__ import annotations

import warp as wp

# ContactKind values (collision.contacts): the first field of a key.
POINT_PLANE = wp.constant(wp.uint64(0))
SPHERE_PLANE = wp.constant(wp.uint64(5))
SPHERE_SPHERE = wp.constant(wp.uint64(6))
BOX_PLANE = wp.constant(wp.uint64(7))
BOX_BOX = wp.constant(wp.uint64(8))


@wp.func
def contact_key(kind: wp.uint64, body_a: int, feature_a: int, body_b: int, feature_b: int) -> wp.uint64:
    """The bits of :func:`~softvr.collision.contacts.contact_keys`: kind 4 | body a 10 |
    body b 10 | feature a 20 | feature b 20."""
    return ((kind << wp.uint64(60)) | (wp.uint64(body_a) << wp.uint64(50)) | (wp.uint64(body_b) << wp.uint64(40))
            | (wp.uint64(feature_a) << wp.uint64(20)) | wp.uint64(feature_b))


@wp.func
def body_rotation(orientation: wp.vec4d) -> wp.mat33d:
    """Rotation matrix of softvr's (w, x, y, z) quaternion (Warp's quaternions are x, y, z, w)."""
    return wp.quat_to_matrix(wp.quatd(orientation[1], orientation[2], orientation[3], orientation[0]))


@wp.func
def linear(v: wp.spatial_vectord) -> wp.vec3d:
    return wp.vec3d(v[0], v[1], v[2])


@wp.func
def angular(v: wp.spatial_vectord) -> wp.vec3d:
    return wp.vec3d(v[3], v[4], v[5])


@wp.func
def point_velocity(v: wp.spatial_vectord, offset: wp.vec3d) -> wp.vec3d:
    """``v_lin + omega x r`` [m/s] of a body point at world offset ``r`` from the centre."""
    return linear(v) + wp.cross(angular(v), offset)


@wp.func
def emit(count: wp.array(dtype=wp.int32), key: wp.array(dtype=wp.uint64), body_a: wp.array(dtype=wp.int32),
         body_b: wp.array(dtype=wp.int32), offset_a: wp.array(dtype=wp.vec3d), offset_b: wp.array(dtype=wp.vec3d),
         point_a: wp.array(dtype=wp.vec3d), point_b: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d),
         gap: wp.array(dtype=wp.float64), area: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
         material_a: wp.array(dtype=wp.int32), material_b: wp.array(dtype=wp.int32),
         k: wp.uint64, a: int, b: int, ra: wp.vec3d, rb: wp.vec3d, pa: wp.vec3d, pb: wp.vec3d, n: wp.vec3d,
         g: wp.float64, ar: wp.float64, mu: wp.float64, ma: int, mb: int):
    slot = wp.atomic_add(count, 0, 1)
    if slot < key.shape[0]:
        key[slot] = k
        body_a[slot] = a
        body_b[slot] = b
        offset_a[slot] = ra
        offset_b[slot] = rb
        point_a[slot] = pa
        point_b[slot] = pb
        normal[slot] = n
        gap[slot] = g
        area[slot] = ar
        friction[slot] = mu
        material_a[slot] = ma
        material_b[slot] = mb


@wp.kernel
def points_plane(position: wp.array(dtype=wp.vec3d), orientation: wp.array(dtype=wp.vec4d),
                 velocity: wp.array(dtype=wp.spatial_vectord), point_body: wp.array(dtype=wp.int32),
                 point_feature: wp.array(dtype=wp.int32), point_local: wp.array(dtype=wp.vec3d),
                 point_margin: wp.array(dtype=wp.float64), point_material: wp.array(dtype=wp.int32),
                 point_two_sided: wp.array(dtype=wp.int32), point_triangles: wp.array(dtype=wp.int32),
                 triangle_normal: wp.array(dtype=wp.vec3d), triangle_area: wp.array(dtype=wp.float64),
                 plane_point: wp.array(dtype=wp.vec3d), plane_normal: wp.array(dtype=wp.vec3d),
                 plane_friction: wp.array(dtype=wp.float64), plane_material: wp.array(dtype=wp.int32),
                 dt: wp.float64,
                 count: wp.array(dtype=wp.int32), key: wp.array(dtype=wp.uint64), body_a: wp.array(dtype=wp.int32),
                 body_b: wp.array(dtype=wp.int32), offset_a: wp.array(dtype=wp.vec3d),
                 offset_b: wp.array(dtype=wp.vec3d), point_a: wp.array(dtype=wp.vec3d),
                 point_b: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d), gap: wp.array(dtype=wp.float64),
                 area: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
                 material_a: wp.array(dtype=wp.int32), material_b: wp.array(dtype=wp.int32)):
    """Thread (point i, plane k): :func:`points_vs_plane` with the vertex's projected area
    (:meth:`CollisionSurface.facing_vertex_area`)."""
    i, k = wp.tid()
    b = point_body[i]
    rot = body_rotation(orientation[b])
    r = rot * point_local[i]
    p = position[b] + r
    n = plane_normal[k]
    g = wp.dot(p - plane_point[k], n)
    approach = dt * wp.min(wp.dot(point_velocity(velocity[b], r), n), wp.float64(0.0))
    if wp.min(g, g + approach) < point_margin[i]:
        ar = wp.float64(0.0)
        for t in range(point_triangles[i], point_triangles[i + 1]):
            cosine = wp.dot(rot * triangle_normal[t], n)
            facing = wp.max(-cosine, wp.float64(0.0))
            if point_two_sided[i] != 0:
                facing = wp.abs(cosine)
            ar += triangle_area[t] * facing / wp.float64(3.0)
        emit(count, key, body_a, body_b, offset_a, offset_b, point_a, point_b, normal, gap, area, friction,
             material_a, material_b, contact_key(POINT_PLANE, b, point_feature[i], k, 0), b, -1, r, wp.vec3d(),
             p, p - g * n, n, g, ar, plane_friction[k], point_material[i], plane_material[k])


@wp.func
def corner_sign(corner: int, axis: int) -> wp.float64:
    """Sign (-1 or 1) of box corner ``corner`` (feature id 4 [x > 0] + 2 [y > 0] + [z > 0])."""
    if (corner >> (2 - axis)) & 1 == 1:
        return wp.float64(1.0)
    return wp.float64(-1.0)


@wp.func
def corner_offset(corner: int, half: wp.vec3d) -> wp.vec3d:
    return wp.vec3d(corner_sign(corner, 0) * half[0], corner_sign(corner, 1) * half[1], corner_sign(corner, 2) * half[2])


@wp.kernel
def boxes_plane(position: wp.array(dtype=wp.vec3d), orientation: wp.array(dtype=wp.vec4d),
                velocity: wp.array(dtype=wp.spatial_vectord), box_body: wp.array(dtype=wp.int32),
                box_half: wp.array(dtype=wp.vec3d), box_material: wp.array(dtype=wp.int32),
                box_plane_margin: wp.array2d(dtype=wp.float64),
                plane_point: wp.array(dtype=wp.vec3d), plane_normal: wp.array(dtype=wp.vec3d),
                plane_friction: wp.array(dtype=wp.float64), plane_material: wp.array(dtype=wp.int32),
                dt: wp.float64,
                count: wp.array(dtype=wp.int32), key: wp.array(dtype=wp.uint64), body_a: wp.array(dtype=wp.int32),
                body_b: wp.array(dtype=wp.int32), offset_a: wp.array(dtype=wp.vec3d),
                offset_b: wp.array(dtype=wp.vec3d), point_a: wp.array(dtype=wp.vec3d),
                point_b: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d), gap: wp.array(dtype=wp.float64),
                area: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
                material_a: wp.array(dtype=wp.int32), material_b: wp.array(dtype=wp.int32)):
    """Thread (box j, plane k): :func:`box_vs_plane`, the face turned to the plane sharing its
    area among its corners in contact."""
    j, k = wp.tid()
    b = box_body[j]
    h = box_half[j]
    rot = body_rotation(orientation[b])
    n = plane_normal[k]
    margin = box_plane_margin[j, k]
    local = wp.transpose(rot) * n
    axis = int(0)
    if wp.abs(local[1]) > wp.abs(local[axis]):
        axis = 1
    if wp.abs(local[2]) > wp.abs(local[axis]):
        axis = 2
    facing = wp.float64(1.0)  # -sign(local[axis]): the face turned to the plane
    if local[axis] > wp.float64(0.0):
        facing = wp.float64(-1.0)
    on_face = int(0)
    for c in range(8):
        r = rot * corner_offset(c, h)
        g = wp.dot(position[b] + r - plane_point[k], n)
        approach = dt * wp.min(wp.dot(point_velocity(velocity[b], r), n), wp.float64(0.0))
        if wp.min(g, g + approach) < margin and corner_sign(c, axis) == facing:
            on_face += 1
    face_area = wp.float64(4.0) * h[(axis + 1) % 3] * h[(axis + 2) % 3] / wp.float64(wp.max(on_face, 1))
    for c in range(8):
        r = rot * corner_offset(c, h)
        p = position[b] + r
        g = wp.dot(p - plane_point[k], n)
        approach = dt * wp.min(wp.dot(point_velocity(velocity[b], r), n), wp.float64(0.0))
        if wp.min(g, g + approach) < margin:
            ar = wp.float64(0.0)
            if corner_sign(c, axis) == facing:
                ar = face_area
            emit(count, key, body_a, body_b, offset_a, offset_b, point_a, point_b, normal, gap, area, friction,
                 material_a, material_b, contact_key(BOX_PLANE, b, c, k, 0), b, -1, r, wp.vec3d(), p, p - g * n, n,
                 g, ar, plane_friction[k], box_material[j], plane_material[k])


@wp.func
def cap_area(radius: wp.float64, margin: wp.float64) -> wp.float64:
    """2 pi R h, the cap within ``margin`` of a tangent plane (:func:`sphere_vs_plane`)."""
    return wp.float64(2.0 * wp.pi) * radius * wp.min(wp.max(margin, wp.float64(0.0)), wp.float64(2.0) * radius)


@wp.kernel
def spheres_plane(position: wp.array(dtype=wp.vec3d), velocity: wp.array(dtype=wp.spatial_vectord),
                  sphere_body: wp.array(dtype=wp.int32), sphere_radius: wp.array(dtype=wp.float64),
                  sphere_material: wp.array(dtype=wp.int32), sphere_plane_margin: wp.array2d(dtype=wp.float64),
                  plane_point: wp.array(dtype=wp.vec3d), plane_normal: wp.array(dtype=wp.vec3d),
                  plane_friction: wp.array(dtype=wp.float64), plane_material: wp.array(dtype=wp.int32),
                  dt: wp.float64,
                  count: wp.array(dtype=wp.int32), key: wp.array(dtype=wp.uint64), body_a: wp.array(dtype=wp.int32),
                  body_b: wp.array(dtype=wp.int32), offset_a: wp.array(dtype=wp.vec3d),
                  offset_b: wp.array(dtype=wp.vec3d), point_a: wp.array(dtype=wp.vec3d),
                  point_b: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d),
                  gap: wp.array(dtype=wp.float64), area: wp.array(dtype=wp.float64),
                  friction: wp.array(dtype=wp.float64), material_a: wp.array(dtype=wp.int32),
                  material_b: wp.array(dtype=wp.int32)):
    """Thread (sphere j, plane k): :func:`sphere_vs_plane`."""
    j, k = wp.tid()
    b = sphere_body[j]
    radius = sphere_radius[j]
    margin = sphere_plane_margin[j, k]
    n = plane_normal[k]
    g = wp.dot(position[b] - plane_point[k], n) - radius
    approach = dt * wp.min(wp.dot(linear(velocity[b]), n), wp.float64(0.0))
    if wp.min(g, g + approach) < margin:
        r = -radius * n
        p = position[b] + r
        emit(count, key, body_a, body_b, offset_a, offset_b, point_a, point_b, normal, gap, area, friction,
             material_a, material_b, contact_key(SPHERE_PLANE, b, 0, k, 0), b, -1, r, wp.vec3d(), p, p - g * n, n,
             g, cap_area(radius, margin), plane_friction[k], sphere_material[j], plane_material[k])


@wp.kernel
def sphere_pairs(position: wp.array(dtype=wp.vec3d), velocity: wp.array(dtype=wp.spatial_vectord),
                 sphere_body: wp.array(dtype=wp.int32), sphere_radius: wp.array(dtype=wp.float64),
                 sphere_material: wp.array(dtype=wp.int32), pairs: wp.array2d(dtype=wp.int32),
                 pair_margin: wp.array(dtype=wp.float64), mu: wp.float64, dt: wp.float64,
                 count: wp.array(dtype=wp.int32), key: wp.array(dtype=wp.uint64), body_a: wp.array(dtype=wp.int32),
                 body_b: wp.array(dtype=wp.int32), offset_a: wp.array(dtype=wp.vec3d),
                 offset_b: wp.array(dtype=wp.vec3d), point_a: wp.array(dtype=wp.vec3d),
                 point_b: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d),
                 gap: wp.array(dtype=wp.float64), area: wp.array(dtype=wp.float64),
                 friction: wp.array(dtype=wp.float64), material_a: wp.array(dtype=wp.int32),
                 material_b: wp.array(dtype=wp.int32)):
    """Thread (sphere pair q): :func:`sphere_vs_sphere`, both sides acting at the midpoint."""
    q = wp.tid()
    ja = pairs[q, 0]
    jb = pairs[q, 1]
    a = sphere_body[ja]
    b = sphere_body[jb]
    ra = sphere_radius[ja]
    rb = sphere_radius[jb]
    d = position[a] - position[b]
    dist = wp.length(d)
    n = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(1.0))
    if dist > wp.float64(1e-12):
        n = d / dist
    g = dist - ra - rb
    approach = dt * wp.min(wp.dot(linear(velocity[a]) - linear(velocity[b]), n), wp.float64(0.0))
    margin = pair_margin[q]
    if wp.min(g, g + approach) < margin:
        pa = position[a] - ra * n
        pb = position[b] + rb * n
        mid = wp.float64(0.5) * (pa + pb)
        emit(count, key, body_a, body_b, offset_a, offset_b, point_a, point_b, normal, gap, area, friction,
             material_a, material_b, contact_key(SPHERE_SPHERE, a, 0, b, 0), a, b, mid - position[a],
             mid - position[b], pa, pb, n, g, cap_area(wp.min(ra, rb), margin), mu, sphere_material[ja],
             sphere_material[jb])
