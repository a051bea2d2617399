"""Warp kernels of the volume ray caster (one source for CPU and CUDA).

Rays are cast in the volume's continuous index space (voxel centres at integer
coordinates, as VTK's point data), parametrised by the world distance ``t`` from the
near clipping plane, so the step, the opacity correction and the surface depth are all in
world units. Front-to-back emission-absorption compositing (thesis 3.3: the deformed
volume is drawn like the rest one)::

    C += (1 - A) a_i c_i,    A += (1 - A) a_i,    a_i = 1 - (1 - a_tf(v_i)) ** (dt / d_unit)

with the opacity ``a_tf`` per unit length ``d_unit`` (the smallest voxel spacing, as
VTK's scalar-opacity unit distance) already corrected for the step ``dt`` in the table.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from softvr.render._raycast_native import NATIVE_VOXEL_CODES, raycast_native, voxel_cases

wp.set_module_options({"enable_backward": False})

#: Voxels per brick edge of the empty-space-skipping grid (a power of two: the ray loop finds
#: a sample's brick by a shift, not a division).
BRICK_SHIFT = wp.constant(2)
BRICK = wp.constant(1 << 2)
#: Stop a ray once its accumulated opacity reaches this (the rest can change a pixel by < 1 %).
OPAQUE_ENOUGH = wp.constant(0.99)
#: Share of the gradient across the slices (cosine of the angle between surface and slices)
#: from which the shading normal is smoothed across them, and from which in full: terraces
#: lie Δ / tan(angle) apart for slices Δ thick, so at 60 degrees they are finer than a slice
#: and at 37 degrees and below 1.3 slices and more apart.
SMOOTH_FROM = wp.constant(0.5)
SMOOTH_FULL = wp.constant(0.8)
#: The sample segment of a ray that missed the volume [index coordinates]: outside any box.
MISSED = wp.constant(-1.0e9)
#: How far [voxels] beyond a changed voxel a sample can read it: trilinear weights reach one
#: voxel, the central differences of the gradient one more; plus a margin for rounding (one
#: more along the axis of the smoothing across slices, :func:`slice_smoothed`).
READ_REACH = wp.constant(2.5)


@wp.func
def fetch(vol: wp.array(dtype=Any), s: wp.vec3i, i: int, j: int, k: int) -> float:
    """Voxel (i, j, k) of the flat voxel array ``vol`` with element strides ``s``."""
    return float(vol[i * s[0] + j * s[1] + k * s[2]])


@wp.func
def clamped(n: wp.vec3i, p: wp.vec3) -> wp.vec3:
    """Index-space point ``p`` clamped to a grid of ``n`` voxels (VTK's edge behaviour)."""
    return wp.vec3(wp.clamp(p[0], 0.0, float(n[0] - 1)), wp.clamp(p[1], 0.0, float(n[1] - 1)),
                   wp.clamp(p[2], 0.0, float(n[2] - 1)))


@wp.func
def cell(n: wp.vec3i, q: wp.vec3) -> wp.vec3i:
    """The lower corner voxel of the cell holding the clamped point ``q``: the last cell on the
    far faces, so that its upper corners are voxels too."""
    return wp.vec3i(wp.min(int(q[0]), n[0] - 2), wp.min(int(q[1]), n[1] - 2), wp.min(int(q[2]), n[2] - 2))


@wp.func
def trilinear(vol: wp.array(dtype=Any), n: wp.vec3i, s: wp.vec3i, p: wp.vec3) -> float:
    """The volume at index-space point ``p``, clamped to the grid (VTK's edge behaviour)."""
    q = clamped(n, p)
    corner = cell(n, q)
    i = corner[0]
    j = corner[1]
    k = corner[2]
    fx = q[0] - float(i)
    fy = q[1] - float(j)
    fz = q[2] - float(k)
    # One address, then the 8 corners at fixed offsets from it.
    a = i * s[0] + j * s[1] + k * s[2]
    c00 = wp.lerp(float(vol[a]), float(vol[a + s[0]]), fx)
    c10 = wp.lerp(float(vol[a + s[1]]), float(vol[a + s[0] + s[1]]), fx)
    c01 = wp.lerp(float(vol[a + s[2]]), float(vol[a + s[0] + s[2]]), fx)
    c11 = wp.lerp(float(vol[a + s[1] + s[2]]), float(vol[a + s[0] + s[1] + s[2]]), fx)
    return wp.lerp(wp.lerp(c00, c10, fy), wp.lerp(c01, c11, fy), fz)


@wp.func
def gradient(vol: wp.array(dtype=Any), n: wp.vec3i, s: wp.vec3i, p: wp.vec3) -> wp.vec3:
    """Central differences of the interpolated volume one voxel either side of ``p``, per
    index axis [value units per voxel]. A shift by a whole voxel keeps the trilinear
    weights, so ``(f(p + e) - f(p - e)) / 2`` is the trilinear interpolation of the voxels'
    own central differences: one set of weights for all three axes (edges clamped). Along
    x, the cell's corners i, i + 1 take differences over voxels i - 1 .. i + 2, so the 32
    voxels of the cell and its six neighbouring faces are each read once (the 48 reads of
    eight separate central differences share 16)."""
    q = clamped(n, p)
    corner = cell(n, q)
    i = corner[0]
    j = corner[1]
    k = corner[2]
    fx = q[0] - float(i)
    fy = q[1] - float(j)
    fz = q[2] - float(k)
    a = i * s[0] + j * s[1] + k * s[2]
    # Offsets to the neighbouring faces, clamped at the grid's edges (the corners are inside: cell()).
    xm = (i - wp.max(i - 1, 0)) * s[0]
    xp = (wp.min(i + 2, n[0] - 1) - i) * s[0]
    ym = (j - wp.max(j - 1, 0)) * s[1]
    yp = (wp.min(j + 2, n[1] - 1) - j) * s[1]
    zm = (k - wp.max(k - 1, 0)) * s[2]
    zp = (wp.min(k + 2, n[2] - 1) - k) * s[2]
    gx = float(0.0)
    gy = float(0.0)
    gz = float(0.0)
    for c in range(4):
        # Along x: the 4 rows (j + u, k + v); their weight in y, z.
        u = c & 1
        v = c >> 1
        r = a + u * s[1] + v * s[2]
        w = wp.where(u == 1, fy, 1.0 - fy) * wp.where(v == 1, fz, 1.0 - fz)
        gx = gx + w * wp.lerp(float(vol[r + s[0]]) - float(vol[r - xm]), float(vol[r + xp]) - float(vol[r]), fx)
        # Along y: the rows (i + u, k + v).
        r = a + u * s[0] + v * s[2]
        w = wp.where(u == 1, fx, 1.0 - fx) * wp.where(v == 1, fz, 1.0 - fz)
        gy = gy + w * wp.lerp(float(vol[r + s[1]]) - float(vol[r - ym]), float(vol[r + yp]) - float(vol[r]), fy)
        # Along z: the rows (i + u, j + v).
        r = a + u * s[0] + v * s[1]
        w = wp.where(u == 1, fx, 1.0 - fx) * wp.where(v == 1, fy, 1.0 - fy)
        gz = gz + w * wp.lerp(float(vol[r + s[2]]) - float(vol[r - zm]), float(vol[r + zp]) - float(vol[r]), fz)
    return 0.5 * wp.vec3(gx, gy, gz)


@wp.func
def slice_smoothed(vol: wp.array(dtype=Any), n: wp.vec3i, s: wp.vec3i, p: wp.vec3, axis: int, plain: wp.vec3) -> wp.vec3:
    """The gradient at ``p`` (``plain``, :func:`gradient`) smoothed along index ``axis`` by the
    weights (1, 2, 1) / 4 at -1, 0, +1 voxel: the trilinear interpolation of the voxels' central
    differences smoothed along that axis (rows past the grid's ends clamped to it). Across thick
    slices the gradient of the trilinear field turns at every slice, which a shaded surface
    almost parallel to them shows as bands (terraces), one per slice; smoothing spreads each
    turn over three slices, as a Gaussian prefilter of 0.7 slice would. A shift by a whole voxel
    keeps the trilinear weights, so the smoothed interpolant is (g(p - e) + 2 g(p) + g(p + e)) / 4
    of the gradient g; at the grid's ends the shifted point, clamped to the grid, reads the end
    row, as the clamped rows do. (Two more gradients cost less than one pass over the four
    columns' twelve rows of differences.)"""
    e = wp.vec3(0.0)
    e[axis] = 1.0
    return 0.25 * (gradient(vol, n, s, p - e) + 2.0 * plain + gradient(vol, n, s, p + e))


@wp.func
def lut_position(v: float, lo: float, scale: float, size: int) -> float:
    return wp.clamp((v - lo) * scale, 0.0, float(size - 1))


@wp.func
def lut_rgba(lut: wp.array(dtype=wp.vec4), u: float) -> wp.vec4:
    """Linear interpolation in a table at fractional position ``u``."""
    i = wp.min(int(u), lut.shape[0] - 2)
    return wp.lerp(lut[i], lut[i + 1], u - float(i))


@wp.func
def lut_scalar(lut: wp.array(dtype=float), u: float) -> float:
    i = wp.min(int(u), lut.shape[0] - 2)
    return wp.lerp(lut[i], lut[i + 1], u - float(i))


@wp.func
def pixel_noise(x: int, y: int) -> float:
    """A per-pixel offset in [0, 1) from an integer hash (PCG, O'Neill 2014) of the pixel:
    uncorrelated between pixels, so the jittered ray starts spread the sampling error over
    all spatial frequencies (fine noise) instead of concentrating it in stripes. (A
    quasi-periodic pattern such as interleaved gradient noise leaves a spectral peak of its
    own.)"""
    state = wp.uint32(x) * wp.uint32(747796405) + wp.uint32(y) * wp.uint32(1597334677) + wp.uint32(1)
    word = ((state >> ((state >> wp.uint32(28)) + wp.uint32(4))) ^ state) * wp.uint32(277803737)
    word = (word >> wp.uint32(22)) ^ word
    return float(word >> wp.uint32(8)) * (1.0 / 16777216.0)


@wp.func
def slab(o: float, d: float, lo: float, hi: float, t0: float, t1: float) -> wp.vec2:
    """Narrow the ray interval [t0, t1] to where ``o + t d`` lies in [lo, hi] on one axis."""
    if wp.abs(d) < 1.0e-12:
        if o < lo or o > hi:
            return wp.vec2(1.0, 0.0)
        return wp.vec2(t0, t1)
    a = (lo - o) / d
    b = (hi - o) / d
    return wp.vec2(wp.max(t0, wp.min(a, b)), wp.min(t1, wp.max(a, b)))


@wp.func
def segment_in_box(a: wp.vec3, d: wp.vec3, lo: wp.vec3, hi: wp.vec3) -> wp.vec2:
    """The part [u0, u1] of the segment ``a + u d``, u in [0, 1], inside the box ``lo`` ..
    ``hi`` (empty: u0 > u1)."""
    # Most segments tested lie wholly to one side of the box: their ends tell it, without
    # the slabs' six divisions.
    e = a + d
    for axis in range(3):
        if wp.max(a[axis], e[axis]) < lo[axis] or wp.min(a[axis], e[axis]) > hi[axis]:
            return wp.vec2(1.0, 0.0)
    u = wp.vec2(0.0, 1.0)
    for axis in range(3):
        u = slab(a[axis], d[axis], lo[axis], hi[axis], u[0], u[1])
    return u


@wp.func
def brick_at(nb: wp.vec3i, p: wp.vec3) -> wp.vec3i:
    """The brick holding index-space point ``p`` (clamped to the ``nb`` bricks), as the ray loop finds it."""
    return wp.vec3i(wp.clamp(int(p[0]) >> BRICK_SHIFT, 0, nb[0] - 1), wp.clamp(int(p[1]) >> BRICK_SHIFT, 0, nb[1] - 1),
                    wp.clamp(int(p[2]) >> BRICK_SHIFT, 0, nb[2] - 1))


@wp.func
def none_gained(a: wp.vec3, b: wp.vec3, gained: wp.array3d(dtype=wp.uint8)) -> bool:
    """Whether no brick between those holding the index-space points ``a`` and ``b`` (the box
    of bricks they span, as :func:`brick_at` finds them) is flagged in ``gained``
    (:func:`brick_minmax`); False also where the box is more than two bricks long along an
    axis (rare: not looked at). A ray's samples from ``a`` to ``b`` lie in that box: their
    positions rise or fall monotonically along it, rounding included."""
    nb = wp.vec3i(gained.shape[0], gained.shape[1], gained.shape[2])
    ca = brick_at(nb, a)
    cb = brick_at(nb, b)
    if ca[0] == cb[0] and ca[1] == cb[1] and ca[2] == cb[2]:  # most often
        return gained[ca[0], ca[1], ca[2]] == wp.uint8(0)
    if wp.abs(ca[0] - cb[0]) > 1 or wp.abs(ca[1] - cb[1]) > 1 or wp.abs(ca[2] - cb[2]) > 1:
        return False
    # A box at most 2 x 2 x 2: its bricks are the 8 picks of either end's index per axis
    # (unrolled: a loop over the box's extent costs more than the samples it saves).
    flagged = wp.uint8(0)
    for c in range(8):
        flagged = flagged | gained[wp.where((c & 1) != 0, cb[0], ca[0]), wp.where((c & 2) != 0, cb[1], ca[1]),
                                   wp.where((c & 4) != 0, cb[2], ca[2])]
    return flagged == wp.uint8(0)


@wp.func
def exit_along(o: float, inv_d: float, lo: float, hi: float) -> float:
    """Ray parameter where ``o + t / inv_d`` leaves [lo, hi] on one axis (going forwards)."""
    return (wp.where(inv_d > 0.0, hi, lo) - o) * inv_d


@wp.func
def crosses_marked(a: wp.vec3, d: wp.vec3, u0: float, u1: float, distance: wp.array3d(dtype=wp.uint8)) -> bool:
    """Whether the segment ``a + u d``, u in [u0, u1], inside the grid [index coordinates],
    passes through a marked brick (``BRICK`` voxels a side, as the ray loop's): ``distance``
    holds each brick's Chebyshev distance [bricks] to the nearest marked one (0: marked),
    so the walk jumps out of the unmarked cube of bricks around each point it reaches (as
    the ray loop skips empty space), a hundredth of a voxel past its face."""
    nb = wp.vec3i(distance.shape[0], distance.shape[1], distance.shape[2])
    bs = float(BRICK)
    inv_d = wp.vec3(0.0)
    past = float(0.0)
    u = u0
    found = bool(False)
    # Each jump crosses at least one brick face: at most the bricks a line can cross.
    for step in range(nb[0] + nb[1] + nb[2]):
        if u > u1:
            break
        p = a + u * d
        c = wp.vec3i(wp.clamp(int(wp.floor(p[0] / bs)), 0, nb[0] - 1),
                     wp.clamp(int(wp.floor(p[1] / bs)), 0, nb[1] - 1),
                     wp.clamp(int(wp.floor(p[2] / bs)), 0, nb[2] - 1))
        r = int(distance[c[0], c[1], c[2]])
        if r == 0:
            found = True
            break
        if step == 0:  # most walks end at their first brick: the divisions only for those that jump
            inv_d = wp.vec3(wp.where(wp.abs(d[0]) > 1.0e-12, 1.0 / d[0], 1.0e30),
                            wp.where(wp.abs(d[1]) > 1.0e-12, 1.0 / d[1], 1.0e30),
                            wp.where(wp.abs(d[2]) > 1.0e-12, 1.0 / d[2], 1.0e30))
            past = 0.01 / wp.max(wp.length(d), 1.0e-6)
        u = u + past + wp.min(wp.min(exit_along(p[0], inv_d[0], float(c[0] - r + 1) * bs, float(c[0] + r) * bs),
                                     exit_along(p[1], inv_d[1], float(c[1] - r + 1) * bs, float(c[1] + r) * bs)),
                              exit_along(p[2], inv_d[2], float(c[2] - r + 1) * bs, float(c[2] + r) * bs))
    return found


#: The voxels of one slab of a brick (brick_minmax).
Slab = wp.types.matrix(shape=(BRICK + 1, BRICK + 1), dtype=wp.float32)


@wp.func
def cell_bit(i: int, j: int, k: int) -> int:
    """The bit of cell (i, j, k) (its lower corner voxel) in its brick's cell mask."""
    return ((i & (BRICK - 1)) << (2 * BRICK_SHIFT)) | ((j & (BRICK - 1)) << BRICK_SHIFT) | (k & (BRICK - 1))


@wp.func
def brick_of(tid: int, first: wp.vec3i, count: wp.vec3i) -> wp.vec3i:
    """Brick ``tid`` of the block of bricks ``first .. first + count`` (last index fastest)."""
    return wp.vec3i(first[0] + tid / (count[1] * count[2]), first[1] + (tid / count[2]) % count[1],
                    first[2] + tid % count[2])


# The CPU form of :func:`update_brick`: per brick, each voxel's table positions floor / ceil
# once (monotone in the value, so a cell's least floor is the floor at its least value: the
# same integers as the Warp code's per-cell positions), in plain loops the compiler vectorizes.
# The C++ of this module is written for BRICK = 4 (a brick's 5 x 5 x 5 voxels, its 64 cells'
# bits (x << 4) | (y << 2) | z, rows of 4 voxels as 64-bit words).
if BRICK != 4:
    raise ImportError("softvr.render._raycast_kernels: the C++ brick kernels are written for BRICK = 4")
_BRICK_SNIPPET = r"""
#if !defined(__CUDA_ARCH__)
{
#pragma clang fp contract(off)
    const int nb0 = changed.shape[0], nb1 = changed.shape[1], nb2 = changed.shape[2];
    const unsigned char* ch = (const unsigned char*)changed.data;
    const int* vis = (const int*)visible.data;
    unsigned char* sd = (unsigned char*)seed.data;
    unsigned char* fl = (unsigned char*)flips.data;
    unsigned long long* cm = (unsigned long long*)cells.data;
    unsigned char* gn = (unsigned char*)gained.data;
    const int size = visible.shape[0] - 1;
    const float top = (float)(size - 1);
    const int total = count[0] * count[1] * count[2];
    const int end = start + block < total ? start + block : total;
    auto position = [&](float v) {  // lut_position
        float p = (v - lut_lo) * lut_scale;
        return p < 0.0f ? 0.0f : (p > top ? top : p);
    };
    for (int t = start; t < end; ++t) {
        const int bx = first[0] + t / (count[1] * count[2]);
        const int by = first[1] + (t / count[2]) % count[1];
        const int bz = first[2] + t % count[2];
        if (every == 0) {
            int touched = 0;
            for (int c = 0; c < 8; ++c) {
                const int i = bx + (c & 1) < nb0 - 1 ? bx + (c & 1) : nb0 - 1;
                const int j = by + ((c >> 1) & 1) < nb1 - 1 ? by + ((c >> 1) & 1) : nb1 - 1;
                const int k = bz + ((c >> 2) & 1) < nb2 - 1 ? bz + ((c >> 2) & 1) : nb2 - 1;
                touched += ch[((long long)i * nb1 + j) * nb2 + k];
            }
            if (touched == 0) continue;
        }
        // The brick's 5 x 5 x 5 voxels, indices clamped to the grid (repeats change no range).
        long long at[3][5];
        for (int u = 0; u < 5; ++u) {
            at[0][u] = (long long)(bx * 4 + u < n[0] - 1 ? bx * 4 + u : n[0] - 1) * strides[0];
            at[1][u] = (long long)(by * 4 + u < n[1] - 1 ? by * 4 + u : n[1] - 1) * strides[1];
            at[2][u] = (long long)(bz * 4 + u < n[2] - 1 ? bz * 4 + u : n[2] - 1) * strides[2];
        }
        float v[125];
        for (int x = 0; x < 5; ++x)
            for (int y = 0; y < 5; ++y)
                for (int z = 0; z < 5; ++z)
                    v[(x * 5 + y) * 5 + z] = (float)VOXEL[at[0][x] + at[1][y] + at[2][z]];
        float vmin = v[0], vmax = v[0];
        for (int q = 1; q < 125; ++q) {
            vmin = v[q] < vmin ? v[q] : vmin;
            vmax = v[q] > vmax ? v[q] : vmax;
        }
        const int fmin = (int)__builtin_floorf(position(vmin)), cmax = (int)__builtin_ceilf(position(vmax));
        const bool occupied = vis[cmax + 1] - vis[fmin] > 0;
        const long long b = ((long long)bx * nb1 + by) * nb2 + bz;
        const unsigned char value = occupied ? 0 : (unsigned char)reach;
        const bool turned = occupied && sd[b] != 0;
        const unsigned long long old = cm[b];
        if (value != sd[b]) { sd[b] = value; fl[t] = 1; }
        const int u0 = fmin - 1 > 0 ? fmin - 1 : 0, u1 = cmax + 1 < size - 1 ? cmax + 1 : size - 1;
        const int shown = vis[u1 + 1] - vis[u0];
        unsigned long long bits = 0;
        if (shown == 0 || shown == u1 - u0 + 1) {
            bits = shown > 0 ? ~0ull : 0ull;
        } else {
            int f[125], c[125];
            for (int q = 0; q < 125; ++q) {
                const float p = position(v[q]);
                f[q] = (int)__builtin_floorf(p);
                c[q] = (int)__builtin_ceilf(p);
            }
            // The least floor / greatest ceil over each 2 x 2 face of a slab, then over a cell's two faces.
            int flo[5][16], chi[5][16];
            for (int x = 0; x < 5; ++x)
                for (int y = 0; y < 4; ++y)
                    for (int z = 0; z < 4; ++z) {
                        const int q = (x * 5 + y) * 5 + z;
                        int a = f[q] < f[q + 1] ? f[q] : f[q + 1];
                        int e = f[q + 5] < f[q + 6] ? f[q + 5] : f[q + 6];
                        flo[x][y * 4 + z] = a < e ? a : e;
                        a = c[q] > c[q + 1] ? c[q] : c[q + 1];
                        e = c[q + 5] > c[q + 6] ? c[q + 5] : c[q + 6];
                        chi[x][y * 4 + z] = a > e ? a : e;
                    }
            for (int x = 0; x < 4; ++x)
                for (int yz = 0; yz < 16; ++yz) {
                    const int lo = flo[x][yz] < flo[x + 1][yz] ? flo[x][yz] : flo[x + 1][yz];
                    const int hi = chi[x][yz] > chi[x + 1][yz] ? chi[x][yz] : chi[x + 1][yz];
                    const int c0 = lo - 1 > 0 ? lo - 1 : 0, c1 = hi + 1 < size - 1 ? hi + 1 : size - 1;
                    if (vis[c1 + 1] - vis[c0] > 0) bits |= 1ull << ((x << 4) | yz);
                }
        }
        cm[b] = bits;
        if (turned || (bits & ~old) != 0ull) gn[b] = 1;
    }
}
#endif
"""

# The snippet once per voxel type (VOXEL: the voxels as that type).
_VOXEL_SWITCH = ("#if !defined(__CUDA_ARCH__)\n"
                 + voxel_cases("code", lambda t: f"#define VOXEL ((const {t}*)vol_ptr)\n{_BRICK_SNIPPET}#undef VOXEL")
                 + "#endif\n")


@wp.func_native(_VOXEL_SWITCH)
def update_bricks_native(
    start: int,
    block: int,
    vol_ptr: wp.uint64,
    code: int,
    n: wp.vec3i,
    strides: wp.vec3i,
    changed: wp.array3d(dtype=wp.uint8),
    every: int,
    visible: wp.array(dtype=wp.int32),
    lut_lo: float,
    lut_scale: float,
    reach: int,
    first: wp.vec3i,
    count: wp.vec3i,
    seed: wp.array3d(dtype=wp.uint8),
    flips: wp.array(dtype=wp.uint8),
    cells: wp.array3d(dtype=wp.uint64),
    gained: wp.array3d(dtype=wp.uint8),
):
    """:func:`update_brick` on the bricks ``start .. start + block`` of the block (CPU, C++; the
    voxels at ``vol_ptr``, of the type of ``NATIVE_VOXEL_CODES`` ``code``, element strides
    ``strides``), the same integers and bits as the Warp code."""
    ...


@wp.func
def update_brick(
    vol: wp.array(dtype=Any),
    n: wp.vec3i,
    strides: wp.vec3i,
    changed: wp.array3d(dtype=wp.uint8),
    every: int,
    visible: wp.array(dtype=wp.int32),
    lut_lo: float,
    lut_scale: float,
    reach: int,
    b: wp.vec3i,
    t: int,
    seed: wp.array3d(dtype=wp.uint8),
    flips: wp.array(dtype=wp.uint8),
    cells: wp.array3d(dtype=wp.uint64),
    gained: wp.array3d(dtype=wp.uint8),
):
    """From the value range of the voxels a sample inside each brick can read (brick ``b`` spans
    index coordinates [b * BRICK, (b + 1) * BRICK], so trilinear interpolation there reads
    voxels b * BRICK .. (b + 1) * BRICK inclusive): the seed of the distance field, 0 for a
    brick with a value of non-zero opacity in its range, else ``reach``; ``flips[t]`` (brick ``b`` is the
    block's ``t``-th; start zeroed) set to 1 where brick t's seed changed (a
    flag per thread, not a shared box grown with atomics: Warp's CPU atomics are plain
    read-modify-write, and the launch is split over threads).
    ``visible`` holds the running count of table entries with opacity > 0, so a range is empty
    iff the counts at its ends are equal (``lut_lo``, ``lut_scale``: the table's position of a
    value). And which of the brick's cells (the unit cubes between voxels, at most BRICK^3 = 64)
    can hold a sample of non-zero opacity: bit ``cell_bit`` of ``cells`` is set iff the table
    has such an entry between the positions of its 8 corner voxels' least and greatest value,
    one entry either side for rounding (a trilinear value lies between its corners'); 1 in
    ``gained`` (start zeroed) where the brick turned occupied or a cell's bit was set that was
    clear (a sample there skipped before may be read now: :func:`raycast`'s ``read_from``). Updates
    bricks ``first .. first + count``: all if ``every`` != 0, else those holding a voxel of a
    ``changed`` brick (:func:`brick_changes`: bricks b .. b + 1 per axis own them)."""
    bx = b[0]
    by = b[1]
    bz = b[2]
    if every == 0:
        nb = wp.vec3i(changed.shape[0], changed.shape[1], changed.shape[2])
        touched = int(0)
        for c in range(8):
            i = wp.min(bx + (c & 1), nb[0] - 1)
            j = wp.min(by + ((c >> 1) & 1), nb[1] - 1)
            k = wp.min(bz + ((c >> 2) & 1), nb[2] - 1)
            touched = touched + int(changed[i, j, k])
        if touched == 0:
            return
    vmin = float(3.0e38)
    vmax = float(-3.0e38)
    for i in range(bx * BRICK, wp.min((bx + 1) * BRICK, n[0] - 1) + 1):
        for j in range(by * BRICK, wp.min((by + 1) * BRICK, n[1] - 1) + 1):
            for k in range(bz * BRICK, wp.min((bz + 1) * BRICK, n[2] - 1) + 1):
                v = fetch(vol, strides, i, j, k)
                vmin = wp.min(vmin, v)
                vmax = wp.max(vmax, v)
    size = visible.shape[0] - 1
    occupied = visible[int(wp.ceil(lut_position(vmax, lut_lo, lut_scale, size))) + 1] - visible[
        int(wp.floor(lut_position(vmin, lut_lo, lut_scale, size)))] > 0
    value = wp.uint8(wp.where(occupied, 0, reach))
    # A sample of the brick is skipped where it was empty or the sample's cell bit was clear:
    # it may be read now if the brick turned occupied or the bit was set (gained).
    turned = occupied and seed[bx, by, bz] != wp.uint8(0)
    old = cells[bx, by, bz]
    if value != seed[bx, by, bz]:
        seed[bx, by, bz] = value
        flips[t] = wp.uint8(1)
    bits = wp.uint64(0)
    u0 = wp.max(int(wp.floor(lut_position(vmin, lut_lo, lut_scale, size))) - 1, 0)
    u1 = wp.min(int(wp.ceil(lut_position(vmax, lut_lo, lut_scale, size))) + 1, size - 1)
    shown = visible[u1 + 1] - visible[u0]
    # Most bricks are all empty (air) or all visible (tissue): each of their cells is too.
    if shown == 0 or shown == u1 - u0 + 1:
        if shown > 0:
            bits = ~bits
        cells[bx, by, bz] = bits
        if turned or (bits & ~old) != wp.uint64(0):
            gained[bx, by, bz] = wp.uint8(1)
        return
    # Cell (x, y, z) of the brick lies between its voxels x .. x + 1 (and y, z). Separable: each
    # slab of voxels x gives the least and greatest value over the 2 x 2 voxels of each cell face
    # in it, and a cell takes those of its two slabs (reads past the grid's far faces are
    # clamped: cells there are never sampled, cell()).
    last_lo = wp.mat44(0.0)
    last_hi = wp.mat44(0.0)
    for x in range(BRICK + 1):
        i = wp.min(bx * BRICK + x, n[0] - 1)
        slab_values = Slab()
        for y in range(BRICK + 1):
            for z in range(BRICK + 1):
                slab_values[y, z] = fetch(vol, strides, i, wp.min(by * BRICK + y, n[1] - 1),
                                          wp.min(bz * BRICK + z, n[2] - 1))
        face_lo = wp.mat44(0.0)
        face_hi = wp.mat44(0.0)
        for y in range(BRICK):
            for z in range(BRICK):
                v00 = slab_values[y, z]
                v01 = slab_values[y, z + 1]
                v10 = slab_values[y + 1, z]
                v11 = slab_values[y + 1, z + 1]
                face_lo[y, z] = wp.min(wp.min(v00, v01), wp.min(v10, v11))
                face_hi[y, z] = wp.max(wp.max(v00, v01), wp.max(v10, v11))
        if x > 0:
            for y in range(BRICK):
                for z in range(BRICK):
                    c0 = wp.max(int(wp.floor(lut_position(wp.min(last_lo[y, z], face_lo[y, z]), lut_lo, lut_scale,
                                                          size))) - 1, 0)
                    c1 = wp.min(int(wp.ceil(lut_position(wp.max(last_hi[y, z], face_hi[y, z]), lut_lo, lut_scale,
                                                         size))) + 1, size - 1)
                    if visible[c1 + 1] - visible[c0] > 0:
                        bits = bits | (wp.uint64(1) << wp.uint64(cell_bit(x - 1, y, z)))
        last_lo = face_lo
        last_hi = face_hi
    cells[bx, by, bz] = bits
    if turned or (bits & ~old) != wp.uint64(0):
        gained[bx, by, bz] = wp.uint8(1)


@wp.kernel
def brick_minmax(
    vol: wp.array(dtype=Any),
    n: wp.vec3i,
    strides: wp.vec3i,
    changed: wp.array3d(dtype=wp.uint8),
    every: int,
    visible: wp.array(dtype=wp.int32),
    lut_lo: float,
    lut_scale: float,
    reach: int,
    vol_ptr: wp.uint64,
    voxel_code: int,
    first: wp.vec3i,
    count: wp.vec3i,
    seed: wp.array3d(dtype=wp.uint8),
    flips: wp.array(dtype=wp.uint8),
    cells: wp.array3d(dtype=wp.uint64),
    gained: wp.array3d(dtype=wp.uint8),
    block: int,
    offset: int,
):
    """:func:`update_brick` on the bricks ``first .. first + count`` (last index fastest),
    ``block`` a thread; ``voxel_code`` != 0 (CPU): in C++ (:func:`update_bricks_native`, the
    voxels at ``vol_ptr``), else in Warp."""
    start = (wp.tid() + offset) * block
    if voxel_code != 0:
        update_bricks_native(start, block, vol_ptr, voxel_code, n, strides, changed, every, visible, lut_lo, lut_scale,
                             reach, first, count, seed, flips, cells, gained)
        return
    for t in range(start, wp.min(start + block, count[0] * count[1] * count[2])):
        update_brick(vol, n, strides, changed, every, visible, lut_lo, lut_scale, reach, brick_of(t, first, count), t,
                     seed, flips, cells, gained)


@wp.func
def brick_changed(
    vol: wp.array(dtype=Any),
    n: wp.vec3i,
    strides: wp.vec3i,
    b: wp.vec3i,
    known: wp.array(dtype=Any),
    rows: wp.array(dtype=wp.int64),
    known_rows: wp.array(dtype=wp.int64),
    packed: int,
    changed: wp.array3d(dtype=wp.uint8),
):
    """1 in ``changed`` for brick ``b`` if its own voxels (b * BRICK .. b * BRICK + BRICK - 1;
    the last brick also owns the grid's far voxels) differ from ``known``, the voxels as last
    cast (brought up to date), else 0. Owning splits the voxels between bricks: no two
    bricks write one voxel of ``known``. ``packed`` != 0: ``rows`` and ``known_rows`` are
    ``vol`` and ``known`` read as 64-bit words, each an inner brick's row of BRICK voxels
    along the last axis (2-byte voxels, rows contiguous and aligned), compared a row at once."""
    nb = wp.vec3i(changed.shape[0], changed.shape[1], changed.shape[2])
    flag = wp.uint8(0)
    if b[0] < nb[0] - 1 and b[1] < nb[1] - 1 and b[2] < nb[2] - 1:
        # An inner brick owns BRICK^3 voxels: fixed loops, unrolled (no bounds per row).
        base = b[0] * BRICK * strides[0] + b[1] * BRICK * strides[1] + b[2] * BRICK * strides[2]
        if packed != 0:
            for i in range(BRICK):
                for j in range(BRICK):
                    w = (base + i * strides[0] + j * strides[1]) / BRICK
                    if rows[w] != known_rows[w]:
                        known_rows[w] = rows[w]
                        flag = wp.uint8(1)
            changed[b[0], b[1], b[2]] = flag
            return
        for i in range(BRICK):
            for j in range(BRICK):
                for k in range(BRICK):
                    a = base + i * strides[0] + j * strides[1] + k * strides[2]
                    if vol[a] != known[a]:
                        known[a] = vol[a]
                        flag = wp.uint8(1)
        changed[b[0], b[1], b[2]] = flag
        return
    end = wp.vec3i(0)
    for axis in range(3):
        end[axis] = wp.where(b[axis] == nb[axis] - 1, n[axis], (b[axis] + 1) * BRICK)
    for i in range(b[0] * BRICK, end[0]):
        for j in range(b[1] * BRICK, end[1]):
            for k in range(b[2] * BRICK, end[2]):
                a = i * strides[0] + j * strides[1] + k * strides[2]
                if vol[a] != known[a]:
                    known[a] = vol[a]
                    flag = wp.uint8(1)
    changed[b[0], b[1], b[2]] = flag



# :func:`brick_changed` for 2-byte voxels read as 64-bit words (``packed``), on the CPU: the
# inner bricks of a column along the last axis compared as 16 contiguous rows of words (a
# word a brick), the memory streamed once in order; an edge brick voxel by voxel.
_CHANGES_SNIPPET = r"""
#if !defined(__CUDA_ARCH__)
{
    typedef unsigned long long u64;
    typedef unsigned short u16;
    const u64* now = (const u64*)rows.data;
    u64* was = (u64*)known_rows.data;
    const u16* now16 = (const u16*)rows.data;
    u16* was16 = (u16*)known_rows.data;
    unsigned char* out = (unsigned char*)changed.data;
    const int nb0 = changed.shape[0], nb1 = changed.shape[1], nb2 = changed.shape[2];
    const long long s0 = strides[0], s1 = strides[1];  // strides[2] == 1
    const int total = count[0] * count[1] * count[2];
    const int end = start + block < total ? start + block : total;
    int t = start;
    while (t < end) {
        const int bx = first[0] + t / (count[1] * count[2]);
        const int by = first[1] + (t / count[2]) % count[1];
        const int bz = first[2] + t % count[2];
        unsigned char* flag = out + ((long long)bx * nb1 + by) * nb2 + bz;
        if (bx < nb0 - 1 && by < nb1 - 1 && bz < nb2 - 1) {
            int len = first[2] + count[2] - bz;  // the run of inner bricks left in this column and block
            len = len < end - t ? len : end - t;
            len = len < nb2 - 1 - bz ? len : nb2 - 1 - bz;
            len = len < 64 ? len : 64;
            unsigned char differ[64];
            for (int k = 0; k < len; ++k) differ[k] = 0;
            for (int i = 0; i < 4; ++i)
                for (int j = 0; j < 4; ++j) {
                    const long long w = ((bx * 4 + i) * s0 + (by * 4 + j) * s1 + bz * 4) / 4;
                    const u64* a = now + w;
                    u64* b = was + w;
                    for (int k = 0; k < len; ++k) {
                        const bool d = a[k] != b[k];
                        differ[k] |= d;
                        if (d) b[k] = a[k];
                    }
                }
            for (int k = 0; k < len; ++k) flag[k] = differ[k];
            t += len;
        } else {
            const int i1 = bx == nb0 - 1 ? n[0] : bx * 4 + 4;
            const int j1 = by == nb1 - 1 ? n[1] : by * 4 + 4;
            const int k1 = bz == nb2 - 1 ? n[2] : bz * 4 + 4;
            unsigned char f = 0;
            for (int i = bx * 4; i < i1; ++i)
                for (int j = by * 4; j < j1; ++j)
                    for (int k = bz * 4; k < k1; ++k) {
                        const long long a = i * s0 + j * s1 + k;
                        if (now16[a] != was16[a]) { was16[a] = now16[a]; f = 1; }
                    }
            *flag = f;
            ++t;
        }
    }
}
#endif
"""


@wp.func_native(_CHANGES_SNIPPET)
def brick_changes_native(
    start: int,
    block: int,
    n: wp.vec3i,
    strides: wp.vec3i,
    first: wp.vec3i,
    count: wp.vec3i,
    rows: wp.array(dtype=wp.int64),
    known_rows: wp.array(dtype=wp.int64),
    changed: wp.array3d(dtype=wp.uint8),
):
    """:func:`brick_changed` on the bricks ``start .. start + block`` of the block, ``packed``
    (CPU, C++; element strides ``strides``, the last 1, the others multiples of BRICK)."""
    ...


@wp.kernel
def brick_changes(
    vol: wp.array(dtype=Any),
    n: wp.vec3i,
    strides: wp.vec3i,
    first: wp.vec3i,
    count: wp.vec3i,
    known: wp.array(dtype=Any),
    rows: wp.array(dtype=wp.int64),
    known_rows: wp.array(dtype=wp.int64),
    packed: int,
    changed: wp.array3d(dtype=wp.uint8),
    block: int,
    offset: int,
):
    """:func:`brick_changed` on the bricks ``first .. first + count`` (last index fastest),
    ``block`` a thread; ``packed`` != 0 (CPU) in C++ (:func:`brick_changes_native`)."""
    start = (wp.tid() + offset) * block
    if packed != 0:
        brick_changes_native(start, block, n, strides, first, count, rows, known_rows, changed)
        return
    for t in range(start, wp.min(start + block, count[0] * count[1] * count[2])):
        brick_changed(vol, n, strides, brick_of(t, first, count), known, rows, known_rows, packed, changed)


@wp.kernel
def brick_distance_pass(
    src: wp.array3d(dtype=wp.uint8),
    axis: int,
    reach: int,
    first: wp.vec3i,
    count: wp.vec3i,
    dst: wp.array3d(dtype=wp.uint8),
    offset: int,
):
    """One axis of the Chebyshev distance transform [bricks], capped at ``reach``:
    ``dst(b) = min_o max(|o|, src(b + o e_axis))``. The L-infinity distance
    ``min_c max_i |b_i - c_i|`` to the occupied bricks c nests into one such pass per axis,
    so three passes from the seed give it exactly."""
    b = brick_of(wp.tid() + offset, first, count)
    n = src.shape[axis]
    best = int(src[b[0], b[1], b[2]])
    for o in range(1, reach):
        for sgn in range(2):
            c = wp.vec3i(b[0], b[1], b[2])
            c[axis] = b[axis] + wp.where(sgn == 0, o, -o)
            if c[axis] >= 0 and c[axis] < n:
                best = wp.min(best, wp.max(o, int(src[c[0], c[1], c[2]])))
    dst[b[0], b[1], b[2]] = wp.uint8(best)


# :func:`brick_distance_pass` three times in C++ (the CPU): the boxes of bricks a few thousand,
# where three Warp launches cost more than the passes. A brick's offsets stop at its best so
# far (max(o, v) >= o cannot lower a best <= o): the same minimum.
_DISTANCE_SNIPPET = r"""
#if !defined(__CUDA_ARCH__)
{
    unsigned char* field[4] = {(unsigned char*)seed.data, (unsigned char*)pass1.data, (unsigned char*)pass2.data,
                               (unsigned char*)distance.data};
    const int nb[3] = {seed.shape[0], seed.shape[1], seed.shape[2]};
    const long long step[3] = {(long long)nb[1] * nb[2], nb[2], 1};
    int lo[3] = {first[0], first[1], first[2]}, hi[3] = {last[0], last[1], last[2]};
    for (int axis = 0; axis < 3; ++axis) {
        lo[axis] = lo[axis] - reach + 1 > 0 ? lo[axis] - reach + 1 : 0;
        hi[axis] = hi[axis] + reach - 1 < nb[axis] - 1 ? hi[axis] + reach - 1 : nb[axis] - 1;
        const unsigned char* src = field[axis];
        unsigned char* dst = field[axis + 1];
        const long long s = step[axis];
        for (int i = lo[0]; i <= hi[0]; ++i)
            for (int j = lo[1]; j <= hi[1]; ++j)
                for (int k = lo[2]; k <= hi[2]; ++k) {
                    const long long at = i * step[0] + j * step[1] + k;
                    const int pos = axis == 0 ? i : (axis == 1 ? j : k);
                    int best = src[at];
                    for (int o = 1; o < reach && o < best; ++o) {
                        if (pos + o < nb[axis]) {
                            const int v = src[at + o * s] > o ? src[at + o * s] : o;
                            best = v < best ? v : best;
                        }
                        if (pos - o >= 0) {
                            const int v = src[at - o * s] > o ? src[at - o * s] : o;
                            best = v < best ? v : best;
                        }
                    }
                    dst[at] = (unsigned char)best;
                }
    }
}
#endif
"""


@wp.func_native(_DISTANCE_SNIPPET)
def distance_passes_native(
    seed: wp.array3d(dtype=wp.uint8),
    pass1: wp.array3d(dtype=wp.uint8),
    pass2: wp.array3d(dtype=wp.uint8),
    distance: wp.array3d(dtype=wp.uint8),
    reach: int,
    first: wp.vec3i,
    last: wp.vec3i,
):
    """:func:`brick_distance_passes` in C++ (CPU; C-contiguous fields)."""
    ...


@wp.kernel
def brick_distance_passes(
    seed: wp.array3d(dtype=wp.uint8),
    pass1: wp.array3d(dtype=wp.uint8),
    pass2: wp.array3d(dtype=wp.uint8),
    distance: wp.array3d(dtype=wp.uint8),
    reach: int,
    first: wp.vec3i,
    last: wp.vec3i,
    offset: int,
):
    """The Chebyshev distance [bricks] to the occupied bricks, capped at ``reach``, brought up to
    date in ``distance`` after ``seed`` changed in the bricks ``first .. last`` (inclusive): the
    three :func:`brick_distance_pass` es seed -> ``pass1`` -> ``pass2`` -> ``distance``, each over
    the box grown by ``reach - 1`` along its axis and the axes before it (as far as a changed
    seed moves their values), one after the other on one CPU thread (C++; launch 1 thread)."""
    distance_passes_native(seed, pass1, pass2, distance, reach, first, last)


@wp.kernel
def raycast(
    vol: wp.array(dtype=Any),
    vol_ptr: wp.uint64,
    vol_code: int,
    n: wp.vec3i,
    strides: wp.vec3i,
    world_to_index: wp.mat44,
    index_gradient_to_world: wp.mat33,
    ndc_to_world: wp.mat44,
    width: int,
    height: int,
    step: float,
    jitter: int,
    lut: wp.array(dtype=wp.vec4),
    lut_lo: float,
    lut_scale: float,
    gradient_lut: wp.array(dtype=float),
    gradient_scale: float,
    shading: wp.vec3,
    light: wp.vec3,
    shade: int,
    smooth_axis: int,
    slice_normal: wp.vec3,
    distance: wp.array3d(dtype=wp.uint8),
    cells: wp.array3d(dtype=wp.uint64),
    flips: int,
    flip_lo: wp.vec3,
    flip_hi: wp.vec3,
    empty_until: wp.array(dtype=float),
    read_from: wp.array(dtype=float),
    gained: wp.array3d(dtype=wp.uint8),
    skip_ok: int,
    depth: wp.array2d(dtype=float),
    surface: wp.array3d(dtype=wp.uint8),
    pixels: wp.array(dtype=wp.int32),
    image: wp.array3d(dtype=wp.uint8),
    segment_start: wp.array(dtype=wp.vec3),
    segment_end: wp.array(dtype=wp.vec3),
    store_rays: int,
    ray_origin: wp.array(dtype=wp.vec3),
    ray_direction: wp.array(dtype=wp.vec3),
    ray_world: wp.array(dtype=wp.vec3),
    ray_span: wp.array(dtype=wp.vec2),
    ray_depth: wp.array(dtype=wp.vec4),
    block: int,
    offset: int,
):
    """One ray per pixel, composited over the surfaces' colour and stopped at their depth;
    ``block`` rays a thread (those of ``pixels[t * block ...]``: on the CPU a thread starts by
    unpacking the kernel's 43 arguments, which a ray of a few samples through the skin notices,
    :func:`softvr.device.blocked_launch`).

    ``depth`` [height, width] is the OpenGL depth buffer in [0, 1] (row 0 at the bottom);
    ``surface`` and ``image`` [height, width, 3] are RGB with row 0 at the top. ``shading``
    is (ambient, diffuse, specular), with the specular power 20 (as VTK's mappers here);
    ``light`` the unit direction towards the (head) light. ``gradient_scale`` < 0 disables
    gradient opacity. ``smooth_axis`` >= 0: where the surface lies at a shallow angle to the
    slices across that index axis (world unit normal ``slice_normal``), the shading normal
    is the gradient smoothed along it by (1, 2, 1) / 4 over neighbouring voxels
    (:func:`slice_smoothed`), blended in as the gradient's component across the slices
    rises from ``SMOOTH_FROM`` to ``SMOOTH_FULL`` of its length; -1: the gradient itself.
    Gradient opacity always takes the gradient itself.

    ``empty_until`` [height * width] carries from frame to frame, per pixel, the index of the
    first ray sample not known to lie in an empty brick (same camera, grid and table). It
    stays valid unless a brick that turned occupied since (inside the index box
    ``flip_lo .. flip_hi`` when ``flips`` != 0) lies on the ray before that sample; then the
    ray starts over from its entry point.

    ``read_from`` [height * width] carries the index of the first sample read (not skipped
    for its brick or cell; if none, where the ray stopped). If ``skip_ok`` != 0, a ray whose
    prefix ``empty_until`` holds starts there when no brick holding a sample in between is
    flagged in ``gained`` [bricks] (:func:`brick_minmax`: it turned occupied or a cell's bit
    was set since the last cast, :func:`none_gained`): those samples are skipped again. The
    cells' masks and occupancy hold the table's zero-opacity ranges exactly (with a margin),
    so a skipped sample is transparent, as it would be read. (``skip_ok`` = 0 where
    ``gained`` was not written since the last cast.)

    ``distance`` [bricks] holds each brick's Chebyshev distance to the nearest occupied one
    (capped; the empty-space jumps), ``cells`` each brick's mask of the cells that can hold a
    visible sample (:func:`brick_minmax`): a sample in any other cell is skipped unread.

    ``vol_code`` != 0 (CPU): the rays go to :func:`raycast_native` (this loop in C++, the same
    results bit for bit; ``vol_ptr`` the voxels' address, ``vol_code`` their dtype), else to this
    loop (the reference, and the CUDA path).

    Only the pixels listed in ``pixels`` [count] (row-major indices, row 0 at the top) are
    cast; the rest of ``image`` keeps what it holds. Each cast pixel's ``segment_start`` ..
    ``segment_end`` [index coordinates] bound where its samples lie, up to where the ray
    stopped (:func:`stale_pixels` reads them next frame); far outside the grid if it missed.

    Each pixel's ray, the same for every frame of one view, is worked out if ``store_rays`` != 0
    and kept, else read back [per pixel]: ``ray_origin`` and ``ray_direction`` (its start on the
    near plane and its unit world direction, in index coordinates), ``ray_world`` (that
    direction in the world), ``ray_span`` (where it lies in the grid [world units from the near
    plane]) and ``ray_depth`` (a, b, c, e: the surface at OpenGL depth z in [0, 1] lies at
    t = (a + z' b) / (c + z' ndc_to_world[3, 2]) - e, z' = 2 z - 1).
    """
    first_ray = (wp.tid() + offset) * block
    if vol_code != 0:
        raycast_native(vol_ptr, vol_code, n, strides, world_to_index, index_gradient_to_world, ndc_to_world, width,
                       height, step, jitter, lut, lut_lo, lut_scale, gradient_lut, gradient_scale, shading, light,
                       shade, smooth_axis, slice_normal, distance, cells, flips, flip_lo, flip_hi, empty_until, read_from,
                       gained, skip_ok, depth, surface, pixels, image, segment_start, segment_end, store_rays,
                       ray_origin, ray_direction, ray_world, ray_span, ray_depth, first_ray,
                       wp.min(first_ray + block, pixels.shape[0]))
        return
    for idx in range(first_ray, wp.min(first_ray + block, pixels.shape[0])):
        tid = pixels[idx]
        px = tid % width
        row = tid / width
        py = height - 1 - row  # OpenGL rows run up
        o = wp.vec3(0.0)
        d = wp.vec3(0.0)
        dw = wp.vec3(0.0)
        inside = wp.vec2(0.0)
        at_depth = wp.vec4(0.0)
        if store_rays != 0:
            nx = 2.0 * (float(px) + 0.5) / float(width) - 1.0
            ny = 2.0 * (float(py) + 0.5) / float(height) - 1.0
            near4 = ndc_to_world @ wp.vec4(nx, ny, -1.0, 1.0)
            far4 = ndc_to_world @ wp.vec4(nx, ny, 1.0, 1.0)
            near = wp.vec3(near4[0], near4[1], near4[2]) / near4[3]
            far = wp.vec3(far4[0], far4[1], far4[2]) / far4[3]
            dw = wp.normalize(far - near)
            # The surface point at depth z' is ndc_to_world (nx, ny, z', 1) = mid + z' column 2.
            mid = ndc_to_world @ wp.vec4(nx, ny, 0.0, 1.0)
            column = ndc_to_world @ wp.vec4(0.0, 0.0, 1.0, 0.0)
            at_depth = wp.vec4(wp.dot(wp.vec3(mid[0], mid[1], mid[2]), dw),
                               wp.dot(wp.vec3(column[0], column[1], column[2]), dw), mid[3], wp.dot(near, dw))
            o4 = world_to_index @ wp.vec4(near[0], near[1], near[2], 1.0)
            o = wp.vec3(o4[0], o4[1], o4[2])
            d4 = world_to_index @ wp.vec4(dw[0], dw[1], dw[2], 0.0)
            d = wp.vec3(d4[0], d4[1], d4[2])
            inside = wp.vec2(0.0, 3.0e38)
            inside = slab(o[0], d[0], 0.0, float(n[0] - 1), inside[0], inside[1])
            inside = slab(o[1], d[1], 0.0, float(n[1] - 1), inside[0], inside[1])
            inside = slab(o[2], d[2], 0.0, float(n[2] - 1), inside[0], inside[1])
            ray_origin[tid] = o
            ray_direction[tid] = d
            ray_world[tid] = dw
            ray_span[tid] = inside
            ray_depth[tid] = at_depth
        else:
            o = ray_origin[tid]
            d = ray_direction[tid]
            dw = ray_world[tid]
            inside = ray_span[tid]
            at_depth = ray_depth[tid]
        z = 2.0 * depth[py, px] - 1.0
        t_surface = (at_depth[0] + z * at_depth[1]) / (at_depth[2] + z * ndc_to_world[3, 2]) - at_depth[3]
        span = wp.vec2(inside[0], wp.min(inside[1], t_surface))
        rgb = wp.vec3(0.0)
        alpha = float(0.0)
        if span[0] < span[1]:
            t0 = span[0]
            shift = float(0.5)
            if jitter != 0:
                shift = pixel_noise(px, row)
            view = -dw
            half = wp.normalize(light + view)
            size = lut.shape[0]
            nb = wp.vec3i(distance.shape[0], distance.shape[1], distance.shape[2])
            # Reciprocals once per ray: the empty-space jumps multiply (a zero component never exits).
            inv_d = wp.vec3(wp.where(wp.abs(d[0]) > 1.0e-12, 1.0 / d[0], 1.0e30),
                            wp.where(wp.abs(d[1]) > 1.0e-12, 1.0 / d[1], 1.0e30),
                            wp.where(wp.abs(d[2]) > 1.0e-12, 1.0 / d[2], 1.0e30))
            inv_step = 1.0 / step
            known = empty_until[tid]
            if known > 0.0 and flips != 0:
                on_ray = slab(o[0], d[0], flip_lo[0], flip_hi[0], t0, t0 + (known + shift) * step)
                on_ray = slab(o[1], d[1], flip_lo[1], flip_hi[1], on_ray[0], on_ray[1])
                on_ray = slab(o[2], d[2], flip_lo[2], flip_hi[2], on_ray[0], on_ray[1])
                if on_ray[0] <= on_ray[1]:
                    known = 0.0
            k = known
            first = float(-1.0)  # the first sample found in an occupied brick
            if known > 0.0 and skip_ok != 0:
                read = read_from[tid]
                if read > known:
                    if none_gained(o + (t0 + (known + shift) * step) * d, o + (t0 + (read - 1.0 + shift) * step) * d,
                                   gained):
                        first = known
                        k = read
            first_read = float(-1.0)  # the first sample read
            last = wp.vec3i(-1, -1, -1)  # the occupied brick the ray is in (no need to look again)
            while alpha < OPAQUE_ENOUGH:
                t = t0 + (k + shift) * step
                if t > span[1]:
                    break
                p = o + t * d
                b = brick_at(nb, p)
                r = int(0)
                if b[0] != last[0] or b[1] != last[1] or b[2] != last[2]:
                    r = int(distance[b[0], b[1], b[2]])
                    if r == 0:
                        last = b
                        if first < 0.0:
                            first = k
                if r > 0:
                    # Empty space: jump to where the ray leaves the empty cube of bricks around
                    # this one, staying on the ray's sample lattice t0 + (k + shift) step so
                    # that skipping changes no sample.
                    bs = float(BRICK)
                    leave = wp.min(wp.min(exit_along(o[0], inv_d[0], float(b[0] - r + 1) * bs, float(b[0] + r) * bs),
                                          exit_along(o[1], inv_d[1], float(b[1] - r + 1) * bs, float(b[1] + r) * bs)),
                                   exit_along(o[2], inv_d[2], float(b[2] - r + 1) * bs, float(b[2] + r) * bs))
                    k = wp.max(k + 1.0, wp.ceil((leave - t0) * inv_step - shift))
                    continue
                # A sample in a cell whose corners hold no value of non-zero opacity between them is
                # transparent (brick_minmax): skipped without reading the voxels.
                q = cell(n, clamped(n, p))
                if ((cells[q[0] >> BRICK_SHIFT, q[1] >> BRICK_SHIFT, q[2] >> BRICK_SHIFT]
                     >> wp.uint64(cell_bit(q[0], q[1], q[2]))) & wp.uint64(1)) == wp.uint64(0):
                    k = k + 1.0
                    continue
                if first_read < 0.0:
                    first_read = k
                v = trilinear(vol, n, strides, p)
                c = lut_rgba(lut, lut_position(v, lut_lo, lut_scale, size))
                a = c[3]
                if a > 0.0:
                    color = wp.vec3(c[0], c[1], c[2])
                    if shade != 0 or gradient_scale >= 0.0:
                        gi = gradient(vol, n, strides, p)
                        gw = index_gradient_to_world @ gi
                        gl = wp.length(gw)
                        if gradient_scale >= 0.0:
                            a = a * lut_scalar(gradient_lut, wp.clamp(gl * gradient_scale, 0.0,
                                                                      float(gradient_lut.shape[0] - 1)))
                        if shade != 0:
                            if smooth_axis >= 0 and gl > 1.0e-6:
                                # Only a surface at a shallow angle to the slices shows their terraces:
                                # smoothed in full from 37 degrees down, not at all from 60 up.
                                across = wp.abs(wp.dot(gw, slice_normal)) / gl
                                blend = wp.clamp((across - SMOOTH_FROM) / (SMOOTH_FULL - SMOOTH_FROM), 0.0, 1.0)
                                if blend > 0.0:
                                    smooth = slice_smoothed(vol, n, strides, p, smooth_axis, gi)
                                    gw = index_gradient_to_world @ (gi + blend * (smooth - gi))
                                    gl = wp.length(gw)
                            lit = shading[0]
                            if gl > 1.0e-6:
                                nrm = gw / gl
                                if wp.dot(nrm, view) < 0.0:  # two-sided lighting
                                    nrm = -nrm
                                lit = lit + shading[1] * wp.max(wp.dot(nrm, light), 0.0)
                                # cos ** 20 by squaring: 5 products instead of an exp and a log (pow).
                                h1 = wp.max(wp.dot(nrm, half), 0.0)
                                h4 = (h1 * h1) * (h1 * h1)
                                h16 = (h4 * h4) * (h4 * h4)
                                color = color * lit + wp.vec3(shading[2] * h16 * h4)
                            else:
                                color = color * lit
                    rgb = rgb + (1.0 - alpha) * a * color
                    alpha = alpha + (1.0 - alpha) * a
                k = k + 1.0
            empty_until[tid] = wp.where(first >= 0.0, first, k)
            read_from[tid] = wp.where(first_read >= 0.0, first_read, k)
            # The sample at k was not taken: the samples read lie before it (and before the span's end).
            segment_start[tid] = o + t0 * d
            segment_end[tid] = o + wp.min(t0 + (k + shift) * step, span[1]) * d
        else:
            segment_start[tid] = wp.vec3(MISSED)
            segment_end[tid] = wp.vec3(MISSED)
            empty_until[tid] = 0.0  # no segment is kept to check the prefix against later flips
            read_from[tid] = 0.0
        for ch in range(3):
            value = rgb[ch] + (1.0 - alpha) * float(surface[row, px, ch]) / 255.0
            image[row, px, ch] = wp.uint8(wp.clamp(value * 255.0 + 0.5, 0.0, 255.0))


@wp.func_native(r"""
#if !defined(__CUDA_ARCH__)
for (int row = r0; row <= r1; ++row)
    __builtin_memset((unsigned char*)mask.data + (long long)row * width + c0, 1, c1 - c0 + 1);
#endif
""")
def fill_rect_native(mask: wp.array(dtype=wp.uint8), width: int, c0: int, c1: int, r0: int, r1: int):
    """1 in ``mask`` [height * width] over columns ``c0 .. c1`` of rows ``r0 .. r1`` (CPU: a
    memset a row, where a store a pixel cost most of :func:`mark_pixels`)."""
    ...


@wp.kernel
def mark_pixels(
    lo: wp.array(dtype=wp.vec3),
    hi: wp.array(dtype=wp.vec3),
    index_to_ndc: wp.mat44,
    width: int,
    height: int,
    mark: int,
    native: int,
    mask: wp.array(dtype=wp.uint8),
    rects: wp.array(dtype=wp.vec4i),
    offset: int,
):
    """The pixels whose rays may meet the index-space box ``lo[b] .. hi[b]``: the bounds of
    its corners projected by ``index_to_ndc`` (to clip space), a pixel wider for rounding
    (every pixel if a corner lies behind the camera). A ray meets a box only where its pixel
    centre lies in the box's projection, the convex hull of the projected corners. Set 1 in
    ``mask`` [height * width] (row-major, row 0 at the top) over them if ``mark`` != 0, and
    write their rectangle to ``rects[b]`` (first column, last column, first row, last row;
    ``(width, -1, height, -1)`` if none); the caller takes the union, as a shared rectangle
    grown with atomics would lose updates on the CPU (Warp's CPU atomics are plain
    read-modify-write, and the launch is split over threads). ``native`` != 0 (CPU): the
    rows filled in C++ (:func:`fill_rect_native`)."""
    b = wp.tid() + offset
    x0 = float(1.0e30)
    x1 = float(-1.0e30)
    y0 = float(1.0e30)
    y1 = float(-1.0e30)
    behind = bool(False)
    for c in range(8):
        p = wp.vec3(wp.where((c & 4) != 0, hi[b][0], lo[b][0]), wp.where((c & 2) != 0, hi[b][1], lo[b][1]),
                    wp.where((c & 1) != 0, hi[b][2], lo[b][2]))
        q = index_to_ndc @ wp.vec4(p[0], p[1], p[2], 1.0)
        if q[3] <= 0.0:
            behind = True
        else:
            # Pixel (px, py) looks along NDC ((2 px + 1) / width - 1, (2 py + 1) / height - 1).
            px = (q[0] / q[3] + 1.0) * 0.5 * float(width) - 0.5
            py = (q[1] / q[3] + 1.0) * 0.5 * float(height) - 0.5
            x0 = wp.min(x0, px)
            x1 = wp.max(x1, px)
            y0 = wp.min(y0, py)
            y1 = wp.max(y1, py)
    c0 = int(0)
    c1 = width - 1
    r0 = int(0)
    r1 = height - 1
    if not behind:
        c0 = wp.max(int(wp.floor(x0)) - 1, 0)
        c1 = wp.min(int(wp.ceil(x1)) + 1, width - 1)
        r0 = wp.max(height - 1 - (int(wp.ceil(y1)) + 1), 0)  # rows run down
        r1 = wp.min(height - 1 - (int(wp.floor(y0)) - 1), height - 1)
    if c0 > c1 or r0 > r1:
        rects[b] = wp.vec4i(width, -1, height, -1)
        return
    rects[b] = wp.vec4i(c0, c1, r0, r1)
    if mark != 0 and native != 0:
        fill_rect_native(mask, width, c0, c1, r0, r1)
    elif mark != 0:
        for row in range(r0, r1 + 1):
            for column in range(c0, c1 + 1):
                mask[row * width + column] = wp.uint8(1)


@wp.kernel
def stale_pixels(
    width: int,
    boxed: int,
    box_lo: wp.vec3,
    box_hi: wp.vec3,
    reach: wp.vec3,
    read_distance: wp.array3d(dtype=wp.uint8),
    candidates: wp.array(dtype=wp.uint8),
    rect: wp.vec4i,
    segment_start: wp.array(dtype=wp.vec3),
    segment_end: wp.array(dtype=wp.vec3),
    flips: int,
    flip_lo: wp.vec3,
    flip_hi: wp.vec3,
    empty_until: wp.array(dtype=float),
    stale: wp.array(dtype=wp.bool),
    block: int,
    offset: int,
):
    """Set True in ``stale`` (row-major pixels, row 0 at the top; 1 already where the surfaces'
    colour or depth changed) for each pixel of ``rect`` (first column, last column, first
    row, last row; ``block`` pixels a thread, in row-major order) whose ray must be cast again (same camera,
    tables and grid as the last frame): its last segment of samples (:func:`raycast`) meets
    the index box ``box_lo .. box_hi`` of rewritten voxels grown by ``reach`` [3] (if
    ``boxed`` != 0; else no voxel changed) and, in it, a brick whose samples may read a
    changed voxel (``read_distance``: the bricks' distance to one, :meth:`RayCaster._read_distance`).
    Any other pixel reads the same voxels with the same weights as last frame, so its colour
    is the same bit for bit; a ray that stopped (opaque) before the change keeps stopping there.

    A ray not cast again whose segment meets ``flip_lo .. flip_hi`` (:func:`raycast`'s flipped
    bricks, if ``flips`` != 0) forgets its known-empty prefix: a brick on it may have filled
    through a voxel it does not read, and a later change there flips no brick.

    Only the pixels in ``rect`` can have a segment that meets either box (every point of a
    ray is seen in its pixel), and only those set in ``candidates`` [height * width] a marked
    brick (:func:`mark_pixels`): the others are not walked."""
    columns = rect[1] - rect[0] + 1
    first = (wp.tid() + offset) * block
    for t in range(first, wp.min(first + block, columns * (rect[3] - rect[2] + 1))):
        tid = (rect[2] + t / columns) * width + rect[0] + t % columns
        if stale[tid]:
            continue
        walk = boxed != 0 and candidates[tid] != 0
        if not walk and flips == 0:
            continue
        a = segment_start[tid]
        d = segment_end[tid] - a
        if walk:
            u = segment_in_box(a, d, box_lo - reach, box_hi + reach)
            # Walked from the ray's end: the changes are mostly where rays stop (the skin), so a
            # ray to cast again is found in a brick or two.
            if u[0] <= u[1]:
                if crosses_marked(a + d, -d, 1.0 - u[1], 1.0 - u[0], read_distance):
                    stale[tid] = True
                    continue
        if flips != 0:
            u = segment_in_box(a, d, flip_lo, flip_hi)
            if u[0] <= u[1]:
                empty_until[tid] = 0.0


#: Voxel dtypes read in place; others are converted to float32 once per upload.
VOXEL_TYPES = {"int16": wp.int16, "uint8": wp.uint8, "uint16": wp.uint16, "float32": wp.float32}

#: The voxel kernels' overloads by voxel dtype name (keys of VOXEL_TYPES), launched as they are:
#: a launch of the generic kernel infers its argument types and looks the overload up each
#: time (~0.2 ms of Python a launch).
RAYCAST: dict[str, wp.Kernel] = {}
BRICK_MINMAX: dict[str, wp.Kernel] = {}
BRICK_CHANGES: dict[str, wp.Kernel] = {}
for _name, _t in VOXEL_TYPES.items():
    RAYCAST[_name] = wp.overload(raycast, {"vol": wp.array(dtype=_t)})
    BRICK_MINMAX[_name] = wp.overload(brick_minmax, {"vol": wp.array(dtype=_t)})
    BRICK_CHANGES[_name] = wp.overload(brick_changes, {"vol": wp.array(dtype=_t), "known": wp.array(dtype=_t)})
