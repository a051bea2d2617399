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
_TWO_PI = wp.constant(wp.float64(6.283185307179586))  # wp.pi is a float32


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


@wp.struct
class ContactOut:
    """The arrays of a :class:`~softvr.collision.contact_buffer.ContactBuffer` a detection
    kernel appends to (one argument instead of fourteen)."""

    count: wp.array(dtype=wp.int32)
    key: wp.array(dtype=wp.uint64)
    body_a: wp.array(dtype=wp.int32)
    body_b: wp.array(dtype=wp.int32)
    offset_a: wp.array(dtype=wp.vec3d)
    offset_b: wp.array(dtype=wp.vec3d)
    point_a: wp.array(dtype=wp.vec3d)
    point_b: wp.array(dtype=wp.vec3d)
    normal: wp.array(dtype=wp.vec3d)
    gap: wp.array(dtype=wp.float64)
    area: wp.array(dtype=wp.float64)
    friction: wp.array(dtype=wp.float64)
    material_a: wp.array(dtype=wp.int32)
    material_b: wp.array(dtype=wp.int32)


@wp.func
def emit(out: ContactOut, k: wp.uint64, a: int, b: int, ra: wp.vec3d, rb: wp.vec3d, pa: wp.vec3d, pb: wp.vec3d,
         n: wp.vec3d, g: wp.float64, ar: wp.float64, mu: wp.float64, ma: int, mb: int):
    """Append one contact (dropped past the capacity; the count still tells how many there were)."""
    slot = wp.atomic_add(out.count, 0, 1)
    if slot < out.key.shape[0]:
        out.key[slot] = k
        out.body_a[slot] = a
        out.body_b[slot] = b
        out.offset_a[slot] = ra
        out.offset_b[slot] = rb
        out.point_a[slot] = pa
        out.point_b[slot] = pb
        out.normal[slot] = n
        out.gap[slot] = g
        out.area[slot] = ar
        out.friction[slot] = mu
        out.material_a[slot] = ma
        out.material_b[slot] = mb


@wp.kernel
def points_plane(position: wp.array(dtype=wp.vec3d), orientation: wp.array(dtype=wp.vec4d),
                 velocity: wp.array(dtype=wp.spatial_vectord), point_body: wp.array(dtype=wp.int32),
                 point_feature: wp.array(dtype=wp.int32), point_local: wp.array(dtype=wp.vec3d),
                 point_margin: wp.array(dtype=wp.float64), point_material: wp.array(dtype=wp.int32),
                 point_two_sided: wp.array(dtype=wp.int32), point_triangles: wp.array(dtype=wp.int32),
                 triangle_normal: wp.array(dtype=wp.vec3d), triangle_area: wp.array(dtype=wp.float64),
                 plane_point: wp.array(dtype=wp.vec3d), plane_normal: wp.array(dtype=wp.vec3d),
                 plane_friction: wp.array(dtype=wp.float64), plane_material: wp.array(dtype=wp.int32),
                 dt: wp.float64, out: ContactOut):
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
        emit(out, contact_key(POINT_PLANE, b, point_feature[i], k, 0), b, -1, r, wp.vec3d(),
             p, p - g * n, n, g, ar, plane_friction[k], point_material[i], plane_material[k])


@wp.func
def corner_sign(corner: int, axis: int) -> wp.float64:
    """Sign (-1 or 1) of box corner ``corner`` (feature id 4 [x > 0] + 2 [y > 0] + [z > 0])."""
    if (corner >> (2 - axis)) & 1 == 1:
        return wp.float64(1.0)
    return wp.float64(-1.0)


@wp.func
def corner_offset(corner: int, half: wp.vec3d) -> wp.vec3d:
    return wp.vec3d(corner_sign(corner, 0) * half[0], corner_sign(corner, 1) * half[1],
                    corner_sign(corner, 2) * half[2])


@wp.kernel
def boxes_plane(position: wp.array(dtype=wp.vec3d), orientation: wp.array(dtype=wp.vec4d),
                velocity: wp.array(dtype=wp.spatial_vectord), box_body: wp.array(dtype=wp.int32),
                box_half: wp.array(dtype=wp.vec3d), box_material: wp.array(dtype=wp.int32),
                box_plane_margin: wp.array2d(dtype=wp.float64),
                plane_point: wp.array(dtype=wp.vec3d), plane_normal: wp.array(dtype=wp.vec3d),
                plane_friction: wp.array(dtype=wp.float64), plane_material: wp.array(dtype=wp.int32),
                dt: wp.float64, out: ContactOut):
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
            emit(out, contact_key(BOX_PLANE, b, c, k, 0), b, -1, r, wp.vec3d(), p, p - g * n, n,
                 g, ar, plane_friction[k], box_material[j], plane_material[k])


@wp.func
def cap_area(radius: wp.float64, margin: wp.float64) -> wp.float64:
    """2 pi R h, the cap within ``margin`` of a tangent plane (:func:`sphere_vs_plane`)."""
    return _TWO_PI * radius * wp.min(wp.max(margin, wp.float64(0.0)), wp.float64(2.0) * radius)


@wp.kernel
def spheres_plane(position: wp.array(dtype=wp.vec3d), velocity: wp.array(dtype=wp.spatial_vectord),
                  sphere_body: wp.array(dtype=wp.int32), sphere_radius: wp.array(dtype=wp.float64),
                  sphere_material: wp.array(dtype=wp.int32), sphere_plane_margin: wp.array2d(dtype=wp.float64),
                  plane_point: wp.array(dtype=wp.vec3d), plane_normal: wp.array(dtype=wp.vec3d),
                  plane_friction: wp.array(dtype=wp.float64), plane_material: wp.array(dtype=wp.int32),
                  dt: wp.float64, out: ContactOut):
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
        emit(out, contact_key(SPHERE_PLANE, b, 0, k, 0), b, -1, r, wp.vec3d(), p, p - g * n, n,
             g, cap_area(radius, margin), plane_friction[k], sphere_material[j], plane_material[k])


@wp.kernel
def sphere_pairs(position: wp.array(dtype=wp.vec3d), velocity: wp.array(dtype=wp.spatial_vectord),
                 sphere_body: wp.array(dtype=wp.int32), sphere_radius: wp.array(dtype=wp.float64),
                 sphere_material: wp.array(dtype=wp.int32), pairs: wp.array2d(dtype=wp.int32),
                 pair_margin: wp.array(dtype=wp.float64), mu: wp.float64, dt: wp.float64, out: ContactOut):
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
        emit(out, contact_key(SPHERE_SPHERE, a, 0, b, 0), a, b, mid - position[a],
             mid - position[b], pa, pb, n, g, cap_area(wp.min(ra, rb), margin), mu, sphere_material[ja],
             sphere_material[jb])


# ------------------------------------------------------------------ box against box
# Local polygon storage of the clipped incident face: at most 4 + 4 vertices (a clipping pass
# adds at most one to a convex polygon); 16 leaves room to spare.
vec16d = wp.types.vector(length=16, dtype=wp.float64)
vec16i = wp.types.vector(length=16, dtype=wp.int32)
vec8i = wp.types.vector(length=8, dtype=wp.int32)
_NONE = wp.constant(wp.float64(-1.0e300))  # the separation of a degenerate (parallel) edge axis


@wp.func
def column(m: wp.mat33d, k: int) -> wp.vec3d:
    return wp.vec3d(m[0, k], m[1, k], m[2, k])


@wp.func
def sat_raw_axis(k: int, ra: wp.mat33d, rb: wp.mat33d) -> wp.vec3d:
    """Candidate axis k of the separating-axis test (unnormalized): a's face normals 0-2, b's
    3-5, a_i x b_j at 6 + 3 i + j (:func:`box._separation`)."""
    if k < 3:
        return column(ra, k)
    if k < 6:
        return column(rb, k - 3)
    return wp.cross(column(ra, (k - 6) // 3), column(rb, (k - 6) % 3))


@wp.func
def sat_axis(k: int, ra: wp.mat33d, rb: wp.mat33d, d: wp.vec3d) -> wp.vec3d:
    """Unit axis k pointing from b to a (0 for a degenerate edge axis)."""
    axis = sat_raw_axis(k, ra, rb)
    length = wp.length(axis)
    if k >= 6:
        if length < wp.float64(1e-6):
            return wp.vec3d()
    axis = axis / length
    if wp.dot(axis, d) < wp.float64(0.0):
        axis = -axis
    return axis


@wp.func
def sat_separation(k: int, ra: wp.mat33d, ha: wp.vec3d, rb: wp.mat33d, hb: wp.vec3d, d: wp.vec3d) -> wp.float64:
    """Separation [m] of the boxes' projections on axis k (< 0: overlap)."""
    axis = sat_axis(k, ra, rb, d)
    if wp.length(axis) == wp.float64(0.0):
        return _NONE
    sep = wp.abs(wp.dot(axis, d))
    for i in range(3):
        sep -= wp.abs(wp.dot(axis, column(ra, i))) * ha[i] + wp.abs(wp.dot(axis, column(rb, i))) * hb[i]
    return sep


@wp.func
def edge_feature(axis: int, sign_first: wp.float64, sign_second: wp.float64) -> int:
    """Feature id 8 + 4 axis + 2 [first other axis > 0] + [second > 0] of a box edge."""
    f = int(8 + 4 * axis)
    if sign_first > wp.float64(0.0):
        f += 2
    if sign_second > wp.float64(0.0):
        f += 1
    return f


@wp.func
def edge_feature_of(axis: int, signs: wp.vec3d) -> int:
    first = int(0)
    second = int(1)
    if axis == 0:
        first = 1
        second = 2
    if axis == 1:
        second = 2
    return edge_feature(axis, signs[first], signs[second])


@wp.func
def corner_of(signs: wp.vec3d) -> int:
    c = int(0)
    if signs[0] > wp.float64(0.0):
        c += 4
    if signs[1] > wp.float64(0.0):
        c += 2
    if signs[2] > wp.float64(0.0):
        c += 1
    return c


@wp.func
def cyclic_sign(i: int, which: int) -> wp.float64:
    """Signs (j, l) of face corner i in the cyclic order (-,-), (+,-), (+,+), (-,+)."""
    if which == 0:
        if i == 1 or i == 2:
            return wp.float64(1.0)
        return wp.float64(-1.0)
    if i >= 2:
        return wp.float64(1.0)
    return wp.float64(-1.0)


@wp.func
def face_signs(f: int, i: int) -> wp.vec3d:
    """Signs [3] of corner i of face f = 2 k + [outward along +k] (box._face_tables)."""
    k = f // 2
    s = wp.float64(2 * (f % 2) - 1)
    j = (k + 1) % 3
    l = (k + 2) % 3
    signs = wp.vec3d()
    signs[k] = s
    signs[j] = cyclic_sign(i, 0)
    signs[l] = cyclic_sign(i, 1)
    return signs


@wp.func
def face_corner(f: int, i: int) -> int:
    return corner_of(face_signs(f, i))


@wp.func
def face_edge(f: int, i: int) -> int:
    """Edge i of face f, from its corner i to corner i + 1: along j where the l sign is fixed
    (i even), along l where the j sign is (i odd)."""
    k = f // 2
    j = (k + 1) % 3
    l = (k + 2) % 3
    signs = face_signs(f, i)
    axis = l
    if i % 2 == 0:
        axis = j
    signs[axis] = wp.float64(0.0)
    return edge_feature_of(axis, signs)


@wp.func
def corner_between(first: int, second: int) -> int:
    """Face corner 0-3 between adjacent face edges or side planes ``first`` and ``second``."""
    if second == (first + 1) % 4:
        return second
    return first


@wp.func
def side_axis(side: int) -> int:
    return (side + 1) % 2  # (1, 0, 1, 0)


@wp.func
def side_sign(side: int) -> wp.float64:
    if side == 1 or side == 2:  # (-1, 1, 1, -1)
        return wp.float64(1.0)
    return wp.float64(-1.0)


@wp.kernel
def box_pairs(position: wp.array(dtype=wp.vec3d), orientation: wp.array(dtype=wp.vec4d),
              velocity: wp.array(dtype=wp.spatial_vectord), box_body: wp.array(dtype=wp.int32),
              box_half: wp.array(dtype=wp.vec3d), box_material: wp.array(dtype=wp.int32),
              pairs: wp.array2d(dtype=wp.int32), pair_margin: wp.array(dtype=wp.float64), mu: wp.float64,
              dt: wp.float64, cand_point: wp.array2d(dtype=wp.vec3d), cand_gap: wp.array2d(dtype=wp.float64),
              cand_fa: wp.array2d(dtype=wp.int32), cand_fb: wp.array2d(dtype=wp.int32), out: ContactOut):
    """Thread (box pair q): :func:`box_vs_box` -- the separating-axis test over 15 axes, then
    the clipped face manifold or one edge-edge contact (collision/box.py says how and why).
    ``cand_*`` [q, 8] hold each pair's candidate points, gaps and features (scratch)."""
    q = wp.tid()
    ja = pairs[q, 0]
    jb = pairs[q, 1]
    a = box_body[ja]
    b = box_body[jb]
    ha = box_half[ja]
    hb = box_half[jb]
    ra = body_rotation(orientation[a])
    rb = body_rotation(orientation[b])
    pa = position[a]
    pb = position[b]
    va = velocity[a]
    vb = velocity[b]
    margin = pair_margin[q]
    zero = wp.float64(0.0)
    size_a = wp.length(ha)
    size_b = wp.length(hb)
    reach = margin + dt * (wp.length(linear(va) - linear(vb)) + wp.length(angular(va)) * size_a
                           + wp.length(angular(vb)) * size_b)
    d = pa - pb
    if wp.dot(d, d) >= (size_a + size_b + reach) * (size_a + size_b + reach):
        return
    most = _NONE
    for k in range(15):
        most = wp.max(most, sat_separation(k, ra, ha, rb, hb, d))
    if most >= reach:
        return
    slack = wp.float64(1e-3) * wp.min(wp.min(wp.min(ha[0], ha[1]), ha[2]), wp.min(wp.min(hb[0], hb[1]), hb[2]))
    k_a = int(0)
    k_b = int(3)
    k_e = int(6)
    for k in range(1, 3):
        if sat_separation(k, ra, ha, rb, hb, d) > sat_separation(k_a, ra, ha, rb, hb, d):
            k_a = k
        if sat_separation(3 + k, ra, ha, rb, hb, d) > sat_separation(k_b, ra, ha, rb, hb, d):
            k_b = 3 + k
    for k in range(7, 15):
        if sat_separation(k, ra, ha, rb, hb, d) > sat_separation(k_e, ra, ha, rb, hb, d):
            k_e = k
    sep_a = sat_separation(k_a, ra, ha, rb, hb, d)
    sep_b = sat_separation(k_b, ra, ha, rb, hb, d)
    face = k_a
    if sep_a <= sep_b + wp.float64(0.05) * wp.abs(sep_b) + slack:
        face = k_b
    sep_face = sat_separation(face, ra, ha, rb, hb, d)
    best = face
    if sat_separation(k_e, ra, ha, rb, hb, d) > sep_face + wp.float64(0.05) * wp.abs(sep_face) + slack:
        best = k_e
    n = sat_axis(best, ra, rb, d)
    # Candidates (cand_*): points, gaps, features on a and b; their shared area.
    m = int(0)
    shared = zero
    if best >= 6:
        i = (best - 6) // 3
        j = (best - 6) % 3
        sa = wp.vec3d()
        sb = wp.vec3d()
        for ax in range(3):
            sa[ax] = wp.float64(1.0)
            if wp.dot(column(ra, ax), n) > zero:
                sa[ax] = wp.float64(-1.0)
            sb[ax] = wp.float64(-1.0)
            if wp.dot(column(rb, ax), n) > zero:
                sb[ax] = wp.float64(1.0)
        sa[i] = zero
        sb[j] = zero
        ca = pa + ra * wp.cw_mul(sa, ha)
        cb = pb + rb * wp.cw_mul(sb, hb)
        da = column(ra, i)
        db = column(rb, j)
        # Minimise |ca + t da - cb - s db|: (1 - cos^2) t = cos e - f, e = db.w, f = da.w.
        w = ca - cb
        cosine = wp.dot(da, db)
        e = wp.dot(db, w)
        f = wp.dot(da, w)
        ta = wp.clamp((cosine * e - f) / (wp.float64(1.0) - cosine * cosine), -ha[i], ha[i])
        tb = wp.clamp(e + ta * cosine, -hb[j], hb[j])
        qa = ca + ta * da
        qb = cb + tb * db
        cand_point[q, 0] = wp.float64(0.5) * (qa + qb)
        cand_gap[q, 0] = wp.dot(qa - qb, n)
        cand_fa[q, 0] = edge_feature_of(i, sa)
        cand_fb[q, 0] = edge_feature_of(j, sb)
        m = 1
    else:
        # The reference face and the box it belongs to; the other box's most opposed face is clipped.
        ref_rot = rb
        ref_pos = pb
        ref_h = hb
        inc_rot = ra
        inc_pos = pa
        inc_h = ha
        f_ref = int(0)
        if best >= 3:
            f_ref = 2 * (best - 3)
            if wp.dot(column(rb, best - 3), n) > zero:
                f_ref += 1
        else:
            ref_rot = ra
            ref_pos = pa
            ref_h = ha
            inc_rot = rb
            inc_pos = pb
            inc_h = hb
            f_ref = 2 * best
            if wp.dot(column(ra, best), n) < zero:
                f_ref += 1
        k_ref = f_ref // 2
        n_ref = wp.float64(2 * (f_ref % 2) - 1) * column(ref_rot, k_ref)
        along = wp.transpose(inc_rot) * n_ref
        k_inc = int(0)
        if wp.abs(along[1]) > wp.abs(along[k_inc]):
            k_inc = 1
        if wp.abs(along[2]) > wp.abs(along[k_inc]):
            k_inc = 2
        f_inc = 2 * k_inc
        if along[k_inc] < zero:
            f_inc += 1
        jr = (k_ref + 1) % 3
        lr = (k_ref + 2) % 3
        ej = column(ref_rot, jr)
        el = column(ref_rot, lr)
        centre = ref_pos + ref_h[k_ref] * n_ref
        x = vec16d()
        y = vec16d()
        z = vec16d()
        labels = vec16i()
        first = vec16i()
        second = vec16i()
        for i in range(4):
            at = inc_pos + inc_rot * wp.cw_mul(face_signs(f_inc, i), inc_h) - centre
            x[i] = wp.dot(at, ej)
            y[i] = wp.dot(at, el)
            z[i] = wp.dot(at, n_ref)
            labels[i] = i
            first[i] = (i + 3) % 4
            second[i] = i
        m = 4
        for side in range(4):
            # One Sutherland-Hodgman pass (box._clip): vertices within ``slack`` outside stay.
            bound = ref_h[lr]
            if side_axis(side) == 0:
                bound = ref_h[jr]
            nx = vec16d()
            ny = vec16d()
            nz = vec16d()
            nlabels = vec16i()
            nfirst = vec16i()
            nsecond = vec16i()
            kept = int(0)
            line = 4 + side
            for i in range(m):
                nxt = (i + 1) % m
                coord_i = y[i]
                coord_n = y[nxt]
                if side_axis(side) == 0:
                    coord_i = x[i]
                    coord_n = x[nxt]
                d_i = side_sign(side) * coord_i - bound
                d_n = side_sign(side) * coord_n - bound
                inside_i = d_i <= slack
                inside_n = d_n <= slack
                crossing = False
                if inside_i != inside_n:
                    if inside_i:
                        crossing = d_i <= zero
                    else:
                        crossing = d_n <= zero
                if inside_i:
                    nx[kept] = x[i]
                    ny[kept] = y[i]
                    nz[kept] = z[i]
                    nlabels[kept] = labels[i]
                    if (not inside_n) and (not crossing):
                        nlabels[kept] = line
                    nfirst[kept] = first[i]
                    nsecond[kept] = second[i]
                    kept += 1
                if crossing:
                    t = d_i / (d_i - d_n)
                    nx[kept] = x[i] + t * (x[nxt] - x[i])
                    ny[kept] = y[i] + t * (y[nxt] - y[i])
                    nz[kept] = z[i] + t * (z[nxt] - z[i])
                    nlabels[kept] = labels[i]
                    if inside_i:
                        nlabels[kept] = line
                    nfirst[kept] = labels[i]
                    nsecond[kept] = line
                    kept += 1
            x = nx
            y = ny
            z = nz
            labels = nlabels
            first = nfirst
            second = nsecond
            m = kept
        twice = zero
        for i in range(m):
            nxt = (i + 1) % m
            twice += x[i] * y[nxt] - y[i] * x[nxt]
        shared = wp.float64(0.5) * wp.abs(twice)
        for i in range(m):
            cand_point[q, i] = centre + x[i] * ej + y[i] * el + z[i] * n_ref
            cand_gap[q, i] = z[i]
            f1 = first[i]
            s1 = second[i]
            corner = corner_between(f1 % 4, s1 % 4)
            feature_inc = 20 + f_inc
            feature_ref = 20 + f_ref
            if f1 < 4 and s1 >= 4:  # an incident edge crossing a side
                feature_inc = face_edge(f_inc, f1 % 4)
                feature_ref = face_edge(f_ref, s1 % 4)
            else:
                if s1 < 4:
                    feature_inc = face_corner(f_inc, corner)
                if f1 >= 4:
                    feature_ref = face_corner(f_ref, corner)
            feature_a = feature_ref
            feature_b = feature_inc
            if best >= 3:
                feature_a = feature_inc
                feature_b = feature_ref
            cand_fa[q, i] = feature_a
            cand_fb[q, i] = feature_b
    # The candidates within the margin (or reaching it over the step), in feature order.
    hits = vec8i()
    c = int(0)
    for i in range(m):
        p = cand_point[q, i]
        rel = wp.dot(point_velocity(va, p - pa) - point_velocity(vb, p - pb), n)
        g = cand_gap[q, i]
        if wp.min(g, g + dt * wp.min(rel, zero)) < margin and c < 8:
            hits[c] = i
            c += 1
    for i in range(1, c):
        h = hits[i]
        j = i - 1
        while j >= 0 and (cand_fa[q, hits[j]] > cand_fa[q, h] or (
                cand_fa[q, hits[j]] == cand_fa[q, h] and cand_fb[q, hits[j]] > cand_fb[q, h])):
            hits[j + 1] = hits[j]
            j -= 1
        hits[j + 1] = h
    for i in range(c):
        h = hits[i]
        p = cand_point[q, h]
        emit(out, contact_key(BOX_BOX, a, cand_fa[q, h], b, cand_fb[q, h]), a, b, p - pa, p - pb,
             p, p, n, cand_gap[q, h], shared / wp.float64(wp.max(c, 1)), mu, box_material[ja], box_material[jb])
