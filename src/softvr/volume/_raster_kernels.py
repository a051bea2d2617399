"""Warp kernels of the tetrahedral rasterizer (thesis Algorithm 1 and its span variant).

Inside/outside is decided in exact integer arithmetic so that shared faces are classified
identically by both tetrahedra (no cracks, no double writes). For face ``f`` of a tet the
host stores ``face[f] = (Sx, Sy, Sz, e, h)`` (int64) such that output voxel ``(i, j, k)``
passes that face iff ``F = Sx*i + Sy*j + Sz*k - e >= 0``; ``h`` is ``F`` at the opposite
vertex plus ``e``, used by culling. Rows run along the last (contiguous) array axis.

The value written is ``c0(A u1 + t)`` with the per-tet affine map of output to input
voxel indices stored in ``affine[tet] = (A row-major, t)`` (thesis eqs. 3.1-3.2:
``A = E0 E1^-1``, the barycentric map of the deformed tet composed with the inverse of the
rest one).
"""

from __future__ import annotations

from typing import Any

import warp as wp

# No adjoints are needed; fast-math lets the compiler fuse the trilinear lerps.
wp.set_module_options({"enable_backward": False, "fast_math": True})

#: Rasterization modes, the value of the ``mode`` kernel argument.
MODE_BBOX = wp.constant(0)
MODE_SPANS = wp.constant(1)

vec4l = wp.types.vector(length=4, dtype=wp.int64)


@wp.func
def floor_div(a: wp.int64, b: wp.int64) -> wp.int64:
    """floor(a / b) for b > 0 (Warp's integer ``/`` truncates toward zero)."""
    q = a / b
    if q * b > a:
        q = q - wp.int64(1)
    return q


@wp.func
def owner_search(offsets: wp.array(dtype=wp.int32), count: int, item: int) -> int:
    """Index t with offsets[t] <= item < offsets[t + 1] (``offsets`` exclusive prefix sums)."""
    lo = int(0)
    hi = count
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if offsets[mid] <= item:
            lo = mid
        else:
            hi = mid
    return lo


@wp.func
def axis_cell(u: wp.float32, n: int):
    """Lower sample index and weight along one axis; u is already clamped to [0, n - 1]."""
    i0 = wp.min(int(u), wp.max(n - 2, 0))
    return i0, u - wp.float32(i0)


@wp.func
def sample(
    vol: wp.array(dtype=Any), dims: wp.vec3i, strides: wp.vec3i, ux: wp.float32, uy: wp.float32, uz: wp.float32,
    nearest: int,
) -> wp.float32:
    """Trilinear (or nearest) value of the flattened volume at continuous voxel index u.

    ``strides`` are element strides, 0 along axes of size 1, so that the upper
    neighbour index never leaves the array.
    """
    cx = wp.clamp(ux, wp.float32(0.0), wp.float32(dims[0] - 1))
    cy = wp.clamp(uy, wp.float32(0.0), wp.float32(dims[1] - 1))
    cz = wp.clamp(uz, wp.float32(0.0), wp.float32(dims[2] - 1))
    if nearest != 0:
        h = wp.float32(0.5)
        return wp.float32(vol[int(cx + h) * strides[0] + int(cy + h) * strides[1] + int(cz + h) * strides[2]])
    ix, wx = axis_cell(cx, dims[0])
    iy, wy = axis_cell(cy, dims[1])
    iz, wz = axis_cell(cz, dims[2])
    p = ix * strides[0] + iy * strides[1] + iz * strides[2]
    sx = strides[0]
    sy = strides[1]
    sz = strides[2]
    one = wp.float32(1.0)
    c00 = (one - wz) * wp.float32(vol[p]) + wz * wp.float32(vol[p + sz])
    c01 = (one - wz) * wp.float32(vol[p + sy]) + wz * wp.float32(vol[p + sy + sz])
    c10 = (one - wz) * wp.float32(vol[p + sx]) + wz * wp.float32(vol[p + sx + sz])
    c11 = (one - wz) * wp.float32(vol[p + sx + sy]) + wz * wp.float32(vol[p + sx + sy + sz])
    c0 = (one - wy) * c00 + wy * c01
    c1 = (one - wy) * c10 + wy * c11
    return (one - wx) * c0 + wx * c1


@wp.func
def face_value(face: wp.array2d(dtype=wp.int64), f: int, i: int, j: int, k: int) -> wp.int64:
    return face[f, 0] * wp.int64(i) + face[f, 1] * wp.int64(j) + face[f, 2] * wp.int64(k) - face[f, 3]


@wp.func
def to_index(x: wp.float32) -> int:
    """int(x) saturated to +-2**30 (a tiny slope gives huge or infinite bounds)."""
    return int(wp.clamp(x, wp.float32(-1.0e9), wp.float32(1.0e9)))


@wp.func
def axis_range(b: wp.float32, inv_a: wp.float32, n: int, klo: int, khi: int):
    """Sub-range of [klo, khi] where u = b + a k stays within the input footprint [-0.5, n - 0.5].

    ``inv_a`` is 1 / a, or 0 when a = 0 (then u = b along the whole row).
    """
    lo_u = wp.float32(-0.5)
    hi_u = wp.float32(n) - wp.float32(0.5)
    lo = klo
    hi = khi
    if inv_a > wp.float32(0.0):
        lo = wp.max(lo, to_index(wp.ceil((lo_u - b) * inv_a)))
        hi = wp.min(hi, to_index(wp.floor((hi_u - b) * inv_a)))
    elif inv_a < wp.float32(0.0):
        lo = wp.max(lo, to_index(wp.ceil((hi_u - b) * inv_a)))
        hi = wp.min(hi, to_index(wp.floor((lo_u - b) * inv_a)))
    elif b < lo_u or b > hi_u:
        hi = lo - 1
    return lo, hi


@wp.func
def write_row(
    vol: wp.array(dtype=Any),
    dims: wp.vec3i,
    strides: wp.vec3i,
    out: wp.array3d(dtype=Any),
    counts: wp.array3d(dtype=wp.int32),
    affine: wp.array2d(dtype=wp.float64),
    t: int,
    i: int,
    j: int,
    klo: int,
    khi: int,
    params: wp.vec4f,
):
    """Write voxels (i, j, klo..khi), all inside tet t: ``out = c0(A u1 + t)`` (eqs. 3.1-3.2).

    Voxels whose rest position falls outside the input's footprint keep the background.
    ``params = (nearest, round to integer, min, max of the output type)``.
    """
    if counts.shape[0] > 0:
        for k in range(klo, khi + 1):
            wp.atomic_add(counts, i, j, k, 1)
        return
    fi = wp.float64(i)
    fj = wp.float64(j)
    bx = wp.float32(affine[t, 0] * fi + affine[t, 1] * fj + affine[t, 9])
    by = wp.float32(affine[t, 3] * fi + affine[t, 4] * fj + affine[t, 10])
    bz = wp.float32(affine[t, 6] * fi + affine[t, 7] * fj + affine[t, 11])
    ax = wp.float32(affine[t, 2])
    ay = wp.float32(affine[t, 5])
    az = wp.float32(affine[t, 8])
    lo, hi = axis_range(bx, wp.float32(affine[t, 12]), dims[0], klo, khi)
    lo, hi = axis_range(by, wp.float32(affine[t, 13]), dims[1], lo, hi)
    lo, hi = axis_range(bz, wp.float32(affine[t, 14]), dims[2], lo, hi)
    nearest = int(params[0])
    rounding = params[1] != wp.float32(0.0)
    for k in range(lo, hi + 1):
        fk = wp.float32(k)
        v = sample(vol, dims, strides, bx + ax * fk, by + ay * fk, bz + az * fk, nearest)
        if rounding:
            v = wp.clamp(wp.floor(v + wp.float32(0.5)), params[2], params[3])
        out[i, j, k] = type(vol[0])(v)


@wp.func
def inside(face: wp.array2d(dtype=wp.int64), t: int, i: int, j: int, k: int) -> bool:
    """Whether voxel (i, j, k) belongs to tet t under the exact tie rule."""
    for f in range(4):
        if face_value(face, 4 * t + f, i, j, k) < wp.int64(0):
            return False
    return True


@wp.kernel
def raster_slabs(
    vol: wp.array(dtype=Any),
    dims: wp.vec3i,
    strides: wp.vec3i,
    out: wp.array3d(dtype=Any),
    counts: wp.array3d(dtype=wp.int32),
    face: wp.array2d(dtype=wp.int64),
    affine: wp.array2d(dtype=wp.float64),
    box: wp.array2d(dtype=wp.int32),
    slab_offsets: wp.array(dtype=wp.int32),
    tet_count: int,
    mode: int,
    params: wp.vec4f,
    tested: wp.array(dtype=wp.int32),
    written: wp.array(dtype=wp.int32),
    offset: int,
):
    """One thread per (tet, x-slab of its box): bounding-box scan or exact row spans."""
    s = wp.tid() + offset
    t = owner_search(slab_offsets, tet_count, s)
    i = box[t, 0] + s - slab_offsets[t]
    n_tested = int(0)
    n_written = int(0)
    # Per face f: g(j) = Sx i + Sy j - e along the slab; q = floor(g / |Sz|), r the remainder
    # (q = g itself when Sz = 0). Rows then need no integer division.
    q = vec4l()
    r = vec4l()
    dq = vec4l()
    dr = vec4l()
    den = vec4l()
    if mode == MODE_SPANS:
        for f in range(4):
            row = 4 * t + f
            g = face[row, 0] * wp.int64(i) + face[row, 1] * wp.int64(box[t, 2]) - face[row, 3]
            d = wp.abs(face[row, 2])
            if d > wp.int64(0):
                q[f] = floor_div(g, d)
                r[f] = g - q[f] * d
                dq[f] = floor_div(face[row, 1], d)
                dr[f] = face[row, 1] - dq[f] * d
            else:
                q[f] = g
                dq[f] = face[row, 1]
            den[f] = d
    for j in range(box[t, 2], box[t, 3] + 1):
        if mode == MODE_SPANS:
            # Exact span of the row: k >= -q_f on faces with Sz > 0, k <= q_f on Sz < 0.
            klo = wp.int64(box[t, 4])
            khi = wp.int64(box[t, 5])
            for f in range(4):
                sz = face[4 * t + f, 2]
                if sz > wp.int64(0):
                    klo = wp.max(klo, -q[f])
                elif sz < wp.int64(0):
                    khi = wp.min(khi, q[f])
                elif q[f] < wp.int64(0):
                    khi = klo - wp.int64(1)
            if khi >= klo:
                n = int(khi - klo) + 1
                n_tested += n
                n_written += n
                write_row(vol, dims, strides, out, counts, affine, t, i, j, int(klo), int(khi), params)
            # Step every face's floor(g / |Sz|) to the next row without dividing (a DDA).
            for f in range(4):
                q[f] = q[f] + dq[f]
                if den[f] > wp.int64(0):
                    r[f] = r[f] + dr[f]
                    if r[f] >= den[f]:
                        r[f] = r[f] - den[f]
                        q[f] = q[f] + wp.int64(1)
        else:
            n_tested += box[t, 5] - box[t, 4] + 1
            for k in range(box[t, 4], box[t, 5] + 1):
                if inside(face, t, i, j, k):
                    n_written += 1
                    write_row(vol, dims, strides, out, counts, affine, t, i, j, k, k, params)
    tested[s] = n_tested
    written[s] = n_written


@wp.kernel
def point_masks(
    face: wp.array2d(dtype=wp.int64),
    box: wp.array2d(dtype=wp.int32),
    cell_dims: wp.array2d(dtype=wp.int32),
    point_offsets: wp.array(dtype=wp.int32),
    tet_count: int,
    cell_size: int,
    masks: wp.array(dtype=wp.uint8),
    offset: int,
):
    """Thesis 3.2.1: 8-bit half-space mask of each coarse grid point of each tet.

    Bit 2f is set when the point is strictly outside face f (b_f < 0), bit 2f+1 when it is
    strictly beyond the plane of the opposite vertex (b_f > 1).
    """
    p = wp.tid() + offset
    t = owner_search(point_offsets, tet_count, p)
    local = p - point_offsets[t]
    py = cell_dims[t, 1] + 1
    pz = cell_dims[t, 2] + 1
    a = local / (py * pz)
    b = (local / pz) % py
    c = local % pz
    i = box[t, 0] + a * cell_size
    j = box[t, 2] + b * cell_size
    k = box[t, 4] + c * cell_size
    m = int(0)
    for f in range(4):
        v = face_value(face, 4 * t + f, i, j, k)
        if v < wp.int64(0):
            m = m | (1 << (2 * f))
        if v > face[4 * t + f, 4]:
            m = m | (1 << (2 * f + 1))
    masks[p] = wp.uint8(m)


@wp.kernel
def cell_masks(
    cell_dims: wp.array2d(dtype=wp.int32),
    point_offsets: wp.array(dtype=wp.int32),
    cell_offsets: wp.array(dtype=wp.int32),
    tet_count: int,
    masks: wp.array(dtype=wp.uint8),
    keep: wp.array(dtype=wp.uint8),
    offset: int,
):
    """Thesis 3.2.2: AND of a cell's 8 corner masks; the cell is culled when it is non-zero."""
    q = wp.tid() + offset
    t = owner_search(cell_offsets, tet_count, q)
    local = q - cell_offsets[t]
    cy = cell_dims[t, 1]
    cz = cell_dims[t, 2]
    a = local / (cy * cz)
    b = (local / cz) % cy
    c = local % cz
    py = cy + 1
    pz = cz + 1
    base = point_offsets[t]
    m = int(255)
    for da in range(2):
        for db in range(2):
            for dc in range(2):
                m = m & int(masks[base + ((a + da) * py + (b + db)) * pz + (c + dc)])
    if m == 0:
        keep[q] = wp.uint8(1)
    else:
        keep[q] = wp.uint8(0)


@wp.kernel
def raster_cells(
    vol: wp.array(dtype=Any),
    dims: wp.vec3i,
    strides: wp.vec3i,
    out: wp.array3d(dtype=Any),
    counts: wp.array3d(dtype=wp.int32),
    face: wp.array2d(dtype=wp.int64),
    affine: wp.array2d(dtype=wp.float64),
    box: wp.array2d(dtype=wp.int32),
    cell_dims: wp.array2d(dtype=wp.int32),
    cell_offsets: wp.array(dtype=wp.int32),
    kept_cells: wp.array(dtype=wp.int32),
    tet_count: int,
    cell_size: int,
    params: wp.vec4f,
    tested: wp.array(dtype=wp.int32),
    written: wp.array(dtype=wp.int32),
    offset: int,
):
    """One thread per (kept cell, x-slab of the cell): per-voxel test and write (Algorithm 1)."""
    s = wp.tid() + offset
    q = kept_cells[s / cell_size]
    t = owner_search(cell_offsets, tet_count, q)
    local = q - cell_offsets[t]
    cy = cell_dims[t, 1]
    cz = cell_dims[t, 2]
    i = box[t, 0] + (local / (cy * cz)) * cell_size + s % cell_size
    j0 = box[t, 2] + ((local / cz) % cy) * cell_size
    k0 = box[t, 4] + (local % cz) * cell_size
    j1 = wp.min(j0 + cell_size - 1, box[t, 3])
    k1 = wp.min(k0 + cell_size - 1, box[t, 5])
    n_tested = int(0)
    n_written = int(0)
    if i <= box[t, 1]:
        n_tested = (j1 - j0 + 1) * (k1 - k0 + 1)
        for j in range(j0, j1 + 1):
            for k in range(k0, k1 + 1):
                if inside(face, t, i, j, k):
                    n_written += 1
                    write_row(vol, dims, strides, out, counts, affine, t, i, j, k, k, params)
    tested[s] = n_tested
    written[s] = n_written


# Declare every voxel type up front: the module then hashes (and compiles) once, instead of
# once more each time a new dtype is first launched.
for _dtype in (wp.uint8, wp.int16, wp.uint16, wp.float32):
    _arrays = {"vol": wp.array(dtype=_dtype), "out": wp.array3d(dtype=_dtype)}
    wp.overload(raster_slabs, _arrays)
    wp.overload(raster_cells, _arrays)
