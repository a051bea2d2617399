"""Warp kernels of the tetrahedral rasterizer (thesis Algorithm 1 and its span variant).

Inside/outside is decided in exact integer arithmetic so that shared faces are classified
identically by both tetrahedra (no cracks, no double writes). For face ``f`` of a tet the
host stores ``face[f] = (Sx, Sy, Sz, e, h)`` (int64) such that output voxel ``(i, j, k)``
passes that face iff ``F = Sx*i + Sy*j + Sz*k - e >= 0``; ``h`` is ``F`` at the opposite
vertex plus ``e``, used by culling. Rows run along the last (contiguous) array axis.

The value written is ``c0(A u1 + t)`` with the per-tet affine map of output to input
voxel indices stored in ``affine[tet] = (A row-major, t, 1 / A[:, 2], rest tet inside input)`` (thesis eqs. 3.1-3.2:
``A = E0 E1^-1``, the barycentric map of the deformed tet composed with the inverse of the
rest one).
"""

from __future__ import annotations

from typing import Any

import warp as wp

# No adjoints are needed. No fast-math: the CPU row loop and the Warp reference must round alike.
wp.set_module_options({"enable_backward": False})

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




# C++ shared by the two CPU snippets below: constants of the input, and the sampling of
# ``sample`` + ``write_row`` (clamp to the voxel range, trilinear or nearest, round) written
# as plain expressions in the reference's order.
_CPP_INPUT = r"""
    const float* __restrict__ v = (const float*)volf.data;
    const int nx1 = dims[0] - 1, ny1 = dims[1] - 1, nz1 = dims[2] - 1;
    const int mx = nx1 > 1 ? nx1 - 1 : 0, my = ny1 > 1 ? ny1 - 1 : 0, mz = nz1 > 1 ? nz1 - 1 : 0;
    const int sx = strides[0], sy = strides[1], sz = strides[2];
    const float fx1 = (float)nx1, fy1 = (float)ny1, fz1 = (float)nz1;
    const float lo_v = params[2], hi_v = params[3];
    const bool nearest = params[0] != 0.0f, rounding = params[1] != 0.0f;
    auto clampf_ = [](float x, float h) { return x < 0.0f ? 0.0f : (x > h ? h : x); };
    // z-neighbour pairs (v[p], v[p + 1]) in one load (see _cpp_trilinear's ``source``).
    auto pair_i16 = [](const short* s, int p, float& a, float& b) {
        unsigned int w; __builtin_memcpy(&w, s + p, 4);
        a = (float)(short)(w & 0xffffu); b = (float)(short)(w >> 16);
    };
    auto pair_u16 = [](const short* s, int p, float& a, float& b) {
        unsigned int w; __builtin_memcpy(&w, s + p, 4);
        a = (float)(w & 0xffffu); b = (float)(w >> 16);
    };
    (void)pair_i16; (void)pair_u16;
"""


def _cpp_nearest(ux: str, uy: str, uz: str) -> str:
    """C++ statements declaring ``val``, the nearest input value at continuous index (ux, uy, uz)."""
    return f"""
                const int ix = (int)(clampf_({ux}, fx1) + 0.5f);
                const int iy = (int)(clampf_({uy}, fy1) + 0.5f);
                const int iz = (int)(clampf_({uz}, fz1) + 0.5f);
                const float val = v[ix * sx + iy * sy + iz * sz];"""


def _cpp_trilinear(ux: str, uy: str, uz: str, rounding: str = "rounding", source: str = "float") -> str:
    """C++ statements declaring ``val``, the trilinear input value at (ux, uy, uz), rounded if asked.

    ``rounding`` is a C++ boolean expression (a literal ``true`` / ``false`` lets clang drop the
    branch and vectorize the loop). ``source`` says where the 8 corner values come from:
    ``"float"`` the float32 array ``v`` (any strides), or, where the z stride is 1, the int16 /
    uint16 input itself (pointer ``s16``) read as z-neighbour pairs, one 32-bit load per pair,
    which halves the gathers. Both give the same floats (16-bit -> float32 is exact), so every
    variant rounds alike.
    """
    head = f"""
                const float ux = clampf_({ux}, fx1);
                const float uy = clampf_({uy}, fy1);
                const float uz = clampf_({uz}, fz1);
                int ix = (int)ux; ix = ix < mx ? ix : mx;
                int iy = (int)uy; iy = iy < my ? iy : my;
                int iz = (int)uz; iz = iz < mz ? iz : mz;
                const float wx = ux - (float)ix, wy = uy - (float)iy, wz = uz - (float)iz;
                const int p = ix * sx + iy * sy + iz * sz;"""
    if source == "float":
        corners = """
                const float c00 = (1.0f - wz) * v[p] + wz * v[p + sz];
                const float c01 = (1.0f - wz) * v[p + sy] + wz * v[p + sy + sz];
                const float c10 = (1.0f - wz) * v[p + sx] + wz * v[p + sx + sz];
                const float c11 = (1.0f - wz) * v[p + sx + sy] + wz * v[p + sx + sy + sz];"""
    else:
        load = {"int16": "pair_i16(s16, ", "uint16": "pair_u16(s16, "}[source]
        corners = "".join(
            f"""
                float a{n}, b{n}; {load}{off}, a{n}, b{n});
                const float c{n} = (1.0f - wz) * a{n} + wz * b{n};"""
            for n, off in (("00", "p"), ("01", "p + sy"), ("10", "p + sx"), ("11", "p + sx + sy"))
        )
    tail = f"""
                const float c0 = (1.0f - wy) * c00 + wy * c01;
                const float c1 = (1.0f - wy) * c10 + wy * c11;
                float val = (1.0f - wx) * c0 + wx * c1;
                if ({rounding}) {{
                    val = __builtin_floorf(val + 0.5f);
                    val = val < lo_v ? lo_v : val;
                    val = val > hi_v ? hi_v : val;
                }}"""
    return head + corners + tail


# The CPU fast path: one output row written by a plain C++ loop that clang vectorizes
# (AVX2 / AVX-512 gathers) over a float32 copy of the input. It evaluates exactly the
# expressions of ``sample`` + ``write_row`` below, which stay the reference (and the CUDA
# path); tests check the two agree. Output types: 1 uint8, 2 int16, 3 uint16, 4 float32.
_ROW_SNIPPET = (
    r"""
#if !defined(__CUDA_ARCH__)
{
#pragma clang fp contract(off)
"""
    + _CPP_INPUT
    + r"""
    auto run = [&](auto* __restrict__ o, auto zero) {
        using T = decltype(zero);
        if (nearest) {
            for (int k = klo; k <= khi; ++k) {
                const float fk = (float)k;"""
    + _cpp_nearest("bx + ax * fk", "by + ay * fk", "bz + az * fk")
    + r"""
                o[k] = (T)val;
            }
            return;
        }
        if (rounding) {
            #pragma clang loop vectorize(enable) interleave(enable)
            for (int k = klo; k <= khi; ++k) {
                const float fk = (float)k;"""
    + _cpp_trilinear("bx + ax * fk", "by + ay * fk", "bz + az * fk", "true")
    + r"""
                o[k] = (T)val;
            }
        } else {
            #pragma clang loop vectorize(enable) interleave(enable)
            for (int k = klo; k <= khi; ++k) {
                const float fk = (float)k;"""
    + _cpp_trilinear("bx + ax * fk", "by + ay * fk", "bz + az * fk", "false")
    + r"""
                o[k] = (T)val;
            }
        }
    };
    switch (out_code) {
        case 1: run((unsigned char*)out_ptr + row_offset, (unsigned char)0); break;
        case 2: run((short*)out_ptr + row_offset, (short)0); break;
        case 3: run((unsigned short*)out_ptr + row_offset, (unsigned short)0); break;
        case 4: run((float*)out_ptr + row_offset, 0.0f); break;
        default: break;
    }
}
#endif
"""
)


@wp.func_native(_ROW_SNIPPET)
def write_row_native(
    volf: wp.array(dtype=wp.float32),
    dims: wp.vec3i,
    strides: wp.vec3i,
    out_ptr: wp.uint64,
    out_code: int,
    row_offset: wp.int64,
    klo: int,
    khi: int,
    bx: wp.float32,
    by: wp.float32,
    bz: wp.float32,
    ax: wp.float32,
    ay: wp.float32,
    az: wp.float32,
    params: wp.vec4f,
):
    """CPU row writer (vectorized C++): output voxels row_offset + [klo, khi] of a C-order array."""
    ...



# The CPU fast path for exact spans: a run of x-slabs of one tet in C++. Rows of a small tet are
# short (a few voxels), so voxels of many rows are queued and sampled in one vectorized loop.
# Every expression (DDA, spans, footprint clipping, positions, trilinear, rounding) is the
# one the Warp reference evaluates, in the same order without FMA contraction.
_TET_SNIPPET = (
    r"""
#if !defined(__CUDA_ARCH__)
{
#pragma clang fp contract(off)
    typedef long long i64;
    const i64* F = (const i64*)face.data + (i64)(4 * t) * 5;
    const double* A = (const double*)affine.data + (i64)t * 16;
    const int* B = (const int*)box.data + (i64)t * 6;
"""
    + _CPP_INPUT
    + r"""
    const short* __restrict__ s16 = (const short*)src_ptr;
    (void)s16;
    const bool clip = A[15] == 0.0;
    const float ax = (float)A[2], ay = (float)A[5], az = (float)A[8];
    double px = 0.0, py = 0.0, pz = 0.0;
    auto floor_div = [](i64 a, i64 b) { i64 q = a / b; if (q * b > a) q -= 1; return q; };
    auto to_index = [](float x) { return (int)(x < -1.0e9f ? -1.0e9f : (x > 1.0e9f ? 1.0e9f : x)); };
    auto axis_range = [&](float b, float inv_a, int n, int& lo, int& hi) {
        const float lo_u = -0.5f, hi_u = (float)n - 0.5f;
        if (inv_a > 0.0f) {
            int c = to_index(__builtin_ceilf((lo_u - b) * inv_a)); lo = lo > c ? lo : c;
            int f = to_index(__builtin_floorf((hi_u - b) * inv_a)); hi = hi < f ? hi : f;
        } else if (inv_a < 0.0f) {
            int c = to_index(__builtin_ceilf((hi_u - b) * inv_a)); lo = lo > c ? lo : c;
            int f = to_index(__builtin_floorf((lo_u - b) * inv_a)); hi = hi < f ? hi : f;
        } else if (b < lo_u || b > hi_u) {
            hi = lo - 1;
        }
    };
    // Per face f: g(i, j) = Sx i + Sy j - e; q = floor(g / |Sz|) with remainder r (q = g when
    // Sz = 0), stepped along j (dq, dr) and i (dqi, dri) without dividing: a 2-D DDA.
    i64 qi[4], ri[4], dqi[4], dri[4], dq[4], dr[4], den[4], szs[4];
    for (int f = 0; f < 4; ++f) {
        const i64* Ff = F + 5 * f;
        const i64 g = Ff[0] * (i64)i_first + Ff[1] * (i64)B[2] - Ff[3];
        const i64 d = Ff[2] < 0 ? -Ff[2] : Ff[2];
        if (d > 0) {
            qi[f] = floor_div(g, d); ri[f] = g - qi[f] * d;
            dq[f] = floor_div(Ff[1], d); dr[f] = Ff[1] - dq[f] * d;
            dqi[f] = floor_div(Ff[0], d); dri[f] = Ff[0] - dqi[f] * d;
        } else {
            qi[f] = g; ri[f] = 0; dq[f] = Ff[1]; dr[f] = 0; dqi[f] = Ff[0]; dri[f] = 0;
        }
        den[f] = d; szs[f] = Ff[2];
    }
    // Room for a whole grid-cube tet (~700 voxels in place on the head CT): one flush a work item.
    // At 512 most items flushed twice, each flush a call plus up to 7 voxels in the scalar loop
    // (~1.3 ms of a 52 ms frame at one thread).
    const int QUEUE = 1024;
    int kq[QUEUE + 8];
    // Output offsets counted from the item's first slab, in int32 (the host sizes items so that
    // they fit: rasterize._span_item_slabs): against int64, one store a queue block fewer and a
    // smaller queue, ~4 % of a frame.
    int oq[QUEUE + 8];
    float bxq[QUEUE + 8], byq[QUEUE + 8], bzq[QUEUE + 8];
    int queued = 0, written = 0;
    // Whether every position this run samples lies in [m, n - 1 - m] on each axis, from the image
    // of its output box under the affine map in double; the float positions the loops compute
    // differ from it by a few float roundings, far less than the margin m (1e-4 of the terms'
    // magnitudes). There clamping to [0, n - 1] and capping the cell index at n - 2 change
    // nothing, and the AVX2 loop skips them (~4 % of a frame). NaN anywhere makes it false.
    bool interior = true;
    {
        const double lo_o[3] = {(double)i_first, (double)B[2], (double)B[4]};
        const double hi_o[3] = {(double)i_last, (double)B[3], (double)B[5]};
        for (int a = 0; a < 3; ++a) {
            double mn = A[9 + a], mx_ = A[9 + a], mag = 1.0 + __builtin_fabs(A[9 + a]);
            for (int c = 0; c < 3; ++c) {
                const double m = A[3 * a + c];
                mn += m * (m < 0.0 ? hi_o[c] : lo_o[c]);
                mx_ += m * (m < 0.0 ? lo_o[c] : hi_o[c]);
                mag += __builtin_fabs(m) * __builtin_fmax(__builtin_fabs(lo_o[c]), __builtin_fabs(hi_o[c]));
            }
            const double margin = 1e-4 * mag;
            interior = interior && mn >= margin && mx_ <= (double)(dims[a] - 1) - margin;
        }
    }
    // Sample the queued voxels into the output: one vectorized loop per (source, rounding), chosen
    // outside the loop so that clang vectorizes each (a branch inside kept it scalar). Not
    // inlined: the copy inlined where the queue is full (trip count 512) stayed scalar.
    // Everything the loops read is captured by value: through references (stack slots that
    // the output might alias) clang kept a runtime alias check that sent every voxel down the scalar loop.
    const int* const kqp = kq;
    const float* const bxp = bxq;
    const float* const byp = byq;
    const float* const bzp = bzq;
    const int* const oqp = oq;
    auto sample_queue = [kqp, bxp, byp, bzp, oqp, v, s16, mx, my, mz, sx, sy, sz, fx1, fy1, fz1,
                         lo_v, hi_v, nearest, rounding, src_code, ax, ay, az, clampf_, pair_i16, pair_u16, interior](
                            const int cnt, auto* __restrict__ o, auto zero) __attribute__((noinline)) {
        using T = decltype(zero);
        constexpr bool is_float = (T)0.5f != (T)0;
        const int* __restrict__ K = kqp;
        const float* __restrict__ BX = bxp;
        const float* __restrict__ BY = byp;
        const float* __restrict__ BZ = bzp;
        const int* __restrict__ O = oqp;
        int n0 = 0;  // voxels [0, n0) done by the explicit 8-lane code, the rest by the loops below
#if defined(__AVX2__)
        // 8 voxels at a time with AVX2 gathers: the expressions of _cpp_trilinear lane by lane
        // (clang left the loops below scalar). Same IEEE operations in the same order, no
        // contraction: bit-identical to the scalar loops and the Warp reference.
        if (!nearest && (src_code == 2 || src_code == 3 || src_code == 0)) {
            typedef float f8 __attribute__((ext_vector_type(8)));
            typedef int i8 __attribute__((ext_vector_type(8)));
            auto splat = [](float x) { return (f8)x; };
            auto isplat = [](int x) { return (i8)x; };
            auto sel = [](i8 m, f8 a, f8 b) { return (f8)((m & (i8)a) | (~m & (i8)b)); };
            auto isel = [](i8 m, i8 a, i8 b) { return (m & a) | (~m & b); };
            auto clampv = [&](f8 x, f8 h) { return sel(x < splat(0.0f), splat(0.0f), sel(x > h, h, x)); };
            const f8 vax = splat(ax), vay = splat(ay), vaz = splat(az), one = splat(1.0f);
            const f8 hx = splat(fx1), hy = splat(fy1), hz = splat(fz1);
            const i8 imx = isplat(mx), imy = isplat(my), imz = isplat(mz), all = isplat(-1);
            const i8 vsx = isplat(sx), vsy = isplat(sy), vsz = isplat(sz);
            // One copy of the loop per source (src a constant at each call below): the source's
            // tests leave the loop, and the z stride, 1 for the 16-bit sources, its multiply.
            auto loop8 = [&](const int src) __attribute__((always_inline)) {
            // Software prefetch of the 4 corner lines of the cell of queue entry n (clamped as the
            // sampling clamps; the address is computed in integers, a hint that never faults):
            // the entry AHEAD on, lane 0 of a later block, each block, and the first AHEAD
            // entries before the loop. A queue's voxels read ~11 lines a block, from a footprint
            // (with the queue itself) beyond L1; the stride prefetchers miss it (8 lanes, 4
            // lines, rows of a few voxels). In place on the head CT: -3 to -6 % of a frame's CPU
            // time at one thread (AHEAD 32: -1 %, 64: -4 %, 96-128: -5.5 %, 192: -3.5 %; the
            // output voxels' line as well: no better; lanes 0 and 4: worse). From the 16-bit
            // inputs only where rows run near the input's z axis (|ax|, |ay| <= 1/4: a block's
            // lanes then mostly share lane 0's cells): under the benchmark's 45-degree rotation it
            // cost 1-2.5 % (10 240 tets) and 4-8 % (40 big tets) there. From the float32 copy
            // (gathers, twice the bytes) it paid rotated too: MRI, 1 080 tets, -4 to -5 %.
            constexpr int AHEAD = 96;
            const bool prefetch = src == 0 || (__builtin_fabsf(ax) <= 0.25f && __builtin_fabsf(ay) <= 0.25f);
            const __UINTPTR_TYPE__ src_base = src == 0 ? (__UINTPTR_TYPE__)v : (__UINTPTR_TYPE__)s16;
            const __UINTPTR_TYPE__ es = src == 0 ? 4 : 2;
            auto prefetch_cell = [&](int n) __attribute__((always_inline)) {
                n = n < cnt ? n : cnt - 1;
                const float fk = (float)K[n];
                const int pc = (int)clampf_(BX[n] + ax * fk, fx1) * sx + (int)clampf_(BY[n] + ay * fk, fy1) * sy
                    + (int)clampf_(BZ[n] + az * fk, fz1) * sz;
                const __UINTPTR_TYPE__ at = src_base + (__UINTPTR_TYPE__)pc * es;
                __builtin_prefetch((const void*)at, 0, 3);
                __builtin_prefetch((const void*)(at + (__UINTPTR_TYPE__)sy * es), 0, 3);
                __builtin_prefetch((const void*)(at + (__UINTPTR_TYPE__)sx * es), 0, 3);
                __builtin_prefetch((const void*)(at + (__UINTPTR_TYPE__)(sx + sy) * es), 0, 3);
            };
            for (int n = n0; prefetch && n < n0 + AHEAD && n < cnt; n += 8) prefetch_cell(n);
            for (; n0 < cnt; n0 += 8) {
                if (prefetch) prefetch_cell(n0 + AHEAD);
                i8 kk; f8 bx8, by8, bz8;
                __builtin_memcpy(&kk, K + n0, 32); __builtin_memcpy(&bx8, BX + n0, 32);
                __builtin_memcpy(&by8, BY + n0, 32); __builtin_memcpy(&bz8, BZ + n0, 32);
                const f8 fk = __builtin_convertvector(kk, f8);
                f8 ux = bx8 + vax * fk, uy = by8 + vay * fk, uz = bz8 + vaz * fk;
                i8 ix, iy, iz;
                if (interior) {  // the clamps below are identities here
                    ix = __builtin_convertvector(ux, i8);
                    iy = __builtin_convertvector(uy, i8);
                    iz = __builtin_convertvector(uz, i8);
                } else {
                    ux = clampv(ux, hx); uy = clampv(uy, hy); uz = clampv(uz, hz);
                    ix = __builtin_convertvector(ux, i8); ix = isel(ix < imx, ix, imx);
                    iy = __builtin_convertvector(uy, i8); iy = isel(iy < imy, iy, imy);
                    iz = __builtin_convertvector(uz, i8); iz = isel(iz < imz, iz, imz);
                }
                const f8 wx = ux - __builtin_convertvector(ix, f8);
                const f8 wy = uy - __builtin_convertvector(iy, f8);
                const f8 wz = uz - __builtin_convertvector(iz, f8);
                const i8 p = ix * vsx + iy * vsy + (src == 0 ? iz * vsz : iz);
                f8 a00, b00, a01, b01, a10, b10, a11, b11;
                if (src == 0) {
                    auto g = [&](i8 idx) {
                        return (f8)__builtin_ia32_gatherd_ps256(splat(0.0f), v, idx, (f8)all, 4);
                    };
                    a00 = g(p); b00 = g(p + vsz); a01 = g(p + vsy); b01 = g(p + vsy + vsz);
                    a10 = g(p + vsx); b10 = g(p + vsx + vsz); a11 = g(p + vsx + vsy); b11 = g(p + vsx + vsy + vsz);
                } else {
                    // The 8 pairs of a corner line by plain 32-bit loads into lanes, not a gather:
                    // on this Zen 3 VM that cut the frame's CPU time by ~8 % (a gather is
                    // microcoded there and blocks dispatch); the 8 indices are extracted once
                    // for the 4 corner lines.
                    const bool sgn = src == 2;
                    int at[8];
                    __builtin_memcpy(at, &p, 32);
                    auto pairs = [&](const short* base, f8& a, f8& b) {
                        unsigned int t[8];
                        #pragma unroll
                        for (int l = 0; l < 8; ++l) __builtin_memcpy(t + l, base + at[l], 4);
                        const i8 w = (i8){(int)t[0], (int)t[1], (int)t[2], (int)t[3], (int)t[4], (int)t[5], (int)t[6], (int)t[7]};
                        typedef unsigned int u8v __attribute__((ext_vector_type(8)));
                        const u8v uw = (u8v)w;
                        if (sgn) {
                            a = __builtin_convertvector((w << 16) >> 16, f8);
                            b = __builtin_convertvector(w >> 16, f8);
                        } else {
                            a = __builtin_convertvector((i8)(uw & 0xffffu), f8);
                            b = __builtin_convertvector((i8)(uw >> 16), f8);
                        }
                    };
                    pairs(s16, a00, b00); pairs(s16 + sy, a01, b01); pairs(s16 + sx, a10, b10); pairs(s16 + sx + sy, a11, b11);
                }
                const f8 c00 = (one - wz) * a00 + wz * b00;
                const f8 c01 = (one - wz) * a01 + wz * b01;
                const f8 c10 = (one - wz) * a10 + wz * b10;
                const f8 c11 = (one - wz) * a11 + wz * b11;
                const f8 c0 = (one - wy) * c00 + wy * c01;
                const f8 c1 = (one - wy) * c10 + wy * c11;
                f8 val = (one - wx) * c0 + wx * c1;
                if (rounding) {
                    // No clamp to the type's range: the output has the input's integer type, and
                    // the weights lie in [0, 1], so the mix lies within its corners' range up to
                    // float32 round-off (< 0.03 at 32767), which the floor below takes back inside.
                    val = (f8)__builtin_ia32_roundps256(val + splat(0.5f), 9);  // floor
                }
                // Each lane straight to its output voxel: a float queue flushed in a second pass
                // cost ~3 % more of a frame. An integer T takes the lane's int32 truncation, as
                // (T)val does (the values lie in T's range).
                const i8 vi = __builtin_convertvector(val, i8);
                if (n0 + 8 <= cnt) {
                    #pragma unroll
                    for (int l = 0; l < 8; ++l) o[O[n0 + l]] = is_float ? (T)val[l] : (T)vi[l];
                } else {  // the queue's last, partial block: its other lanes are padding
                    for (int l = 0; l < cnt - n0; ++l) o[O[n0 + l]] = is_float ? (T)val[l] : (T)vi[l];
                }
            }
            };
            if (src_code == 2) loop8(2); else if (src_code == 3) loop8(3); else loop8(0);
        }
#endif
        if (nearest) {
            for (int n = 0; n < cnt; ++n) {
                const float fk = (float)K[n];"""
    + _cpp_nearest("BX[n] + ax * fk", "BY[n] + ay * fk", "BZ[n] + az * fk")
    + r"""
                o[O[n]] = (T)val;
            }
            return;
        }"""
    + "".join(
        f"""
        if ({cond}) {{
            for (int n = n0; n < cnt; ++n) {{
                const float fk = (float)K[n];"""
        + _cpp_trilinear("BX[n] + ax * fk", "BY[n] + ay * fk", "BZ[n] + az * fk", rnd, src)
        + """
                o[O[n]] = (T)val;
            }
            return;
        }"""
        for cond, rnd, src in (
            ("src_code == 2 && rounding", "true", "int16"),
            ("src_code == 3 && rounding", "true", "uint16"),
            ("rounding", "true", "float"),
            ("true", "false", "float"),
        )
    )
    + r"""
    };
    const i64 item_base = (i64)i_first * out_ny * out_nz;
    auto flush_any = [&]() {
        // The 8-lane loop samples the queue's last, partial block whole and stores its used lanes
        // (through the scalar loops below, those voxels cost 0.3-0.9 % of a frame in place): its
        // unused lanes repeat the first queued voxel, so they read only where that one does.
        for (int l = queued; l < queued + 8; ++l) {
            kq[l] = kq[0]; bxq[l] = bxq[0]; byq[l] = byq[0]; bzq[l] = bzq[0];
        }
        switch (out_code) {
            case 1: sample_queue(queued, (unsigned char*)out_ptr + item_base, (unsigned char)0); break;
            case 2: sample_queue(queued, (short*)out_ptr + item_base, (short)0); break;
            case 3: sample_queue(queued, (unsigned short*)out_ptr + item_base, (unsigned short)0); break;
            case 4: sample_queue(queued, (float*)out_ptr + item_base, 0.0f); break;
            default: break;
        }
        queued = 0;
    };
    // Row loop without data-dependent branches: the 4 faces' DDA state is one 4-lane int64
    // vector (q, r per face), the carry of each remainder is a compare mask, a face with Sz = 0
    // gets a divisor its remainder never reaches, and each face's part in the span is a select
    // on its sign, reduced over the lanes (the scalar form mispredicted on every other row).
    typedef long long l4 __attribute__((ext_vector_type(4)));
    const i64 NOCARRY = (i64)1 << 62, NONE = (i64)1 << 62;
    auto sel4 = [](l4 m, l4 a, l4 b) { return (a & m) | (b & ~m); };
    // Whole-vector loads: lane by lane, each insert went through the stack and stalled the
    // reload (a failed store forward), 44 per work item (~5 % of a frame).
    const l4 inf4 = (l4)NONE, zero4 = (l4)0;
    l4 qi4, ri4, dqi4, dri4, dq4, dr4, den_f, sz4;
    __builtin_memcpy(&qi4, qi, 32); __builtin_memcpy(&ri4, ri, 32);
    __builtin_memcpy(&dqi4, dqi, 32); __builtin_memcpy(&dri4, dri, 32);
    __builtin_memcpy(&dq4, dq, 32); __builtin_memcpy(&dr4, dr, 32);
    __builtin_memcpy(&den_f, den, 32); __builtin_memcpy(&sz4, szs, 32);
    const l4 den4 = sel4((l4)(den_f > zero4), den_f, (l4)NOCARRY), dn4 = den4;
    const l4 pos4 = (l4)(sz4 > zero4), neg4 = (l4)(sz4 < zero4), flat4 = (l4)(sz4 == zero4);
    const l4 box_lo4 = (l4)(i64)B[4], box_nhi4 = (l4)(-(i64)B[5]);
    typedef int i8q __attribute__((ext_vector_type(8)));
    typedef float f8q __attribute__((ext_vector_type(8)));
    const i8q iota8 = {0, 1, 2, 3, 4, 5, 6, 7};
    // Rows are walked in two passes of up to ROWS rows: the first steps the DDA and keeps the
    // non-empty spans, the second queues them. With the queue's flush (a call) inside the DDA
    // loop, clang kept the DDA state in stack slots, and every row waited on a store-to-load
    // round trip; this loop has no call, and no branch on whether a row is empty.
    const int ROWS = 64;
    typedef double d4q __attribute__((ext_vector_type(4)));
    typedef float f4q __attribute__((ext_vector_type(4)));
    const d4q aj4 = {A[1], A[4], A[7], 0.0}, at4 = {A[9], A[10], A[11], 0.0};
    i64 span_lo[ROWS], span_hi[ROWS];
    int span_j[ROWS];
    for (int i = i_first; i <= i_last; ++i) {
        const double fi = (double)i;
        px = A[0] * fi; py = A[3] * fi; pz = A[6] * fi;
        const d4q p4 = {px, py, pz, 0.0};
        l4 q4 = qi4, r4 = ri4;
        for (int j0 = B[2]; j0 <= B[3]; j0 += ROWS) {
            const int j1 = B[3] - j0 < ROWS ? B[3] : j0 + ROWS - 1;
            int rows = 0;
            i64 total = 0;
            for (int j = j0; j <= j1; ++j) {
                // Both ends by one max reduction over 2 x 4 lanes: klo = max(box, -q on faces with
                // Sz > 0), -khi = max(-box, -q on Sz < 0, +inf on Sz = 0 where q < 0). A tet's
                // Sz sum to 0 and are not all 0, so each half has a lane for the box bound. (As
                // scalar selects after the reductions, clang made the box clamps branches,
                // mispredicted on about every other row.)
                const l4 w = -q4;
                const l4 a = sel4(pos4, w, box_lo4);
                const l4 b = sel4(neg4, w, sel4(flat4 & (l4)(q4 < zero4), inf4, box_nhi4));
                l4 x = __builtin_shufflevector(a, b, 0, 1, 4, 5), y = __builtin_shufflevector(a, b, 2, 3, 6, 7);
                x = sel4((l4)(x > y), x, y);
                y = __builtin_shufflevector(x, x, 1, 0, 3, 2);
                x = sel4((l4)(x > y), x, y);
                const i64 klo = x[0], khi = -x[2];
                r4 += dr4;
                const l4 carry = (l4)(r4 >= dn4);  // -1 where the remainder wraps
                r4 -= dn4 & carry;
                q4 += dq4 - carry;
                span_lo[rows] = klo; span_hi[rows] = khi; span_j[rows] = j;
                rows += khi >= klo ? 1 : 0;
                total += khi >= klo ? khi - klo + 1 : 0;
            }
            // Where the chunk's kept voxels fit in the queue (always for tets of a few thousand
            // voxels), flush once before it and queue its rows with no call inside the loop: the
            // call made clang keep the loop's state in stack slots, reloaded on every row.
            auto queue_rows = [&](const bool may_flush) __attribute__((always_inline)) {
                for (int r = 0; r < rows; ++r) {
                    const i64 klo = span_lo[r], khi = span_hi[r];
                    const int j = span_j[r];
                    int lo = (int)klo, hi = (int)khi;
                    const double fj = (double)j;
                    const f4q b4 = __builtin_convertvector(p4 + aj4 * (d4q)fj + at4, f4q);
                    const float bx = b4[0], by = b4[1], bz = b4[2];
                    if (clip) {
                        axis_range(bx, (float)A[12], dims[0], lo, hi);
                        axis_range(by, (float)A[13], dims[1], lo, hi);
                        axis_range(bz, (float)A[14], dims[2], lo, hi);
                    }
                    const int row = (int)(((i64)(i - i_first) * out_ny + j) * out_nz);
                    // 8 entries at a time, five 32-byte stores (clang kept most of the plain loop's 40
                    // stores scalar), with no branch on the row's length below 9 voxels. A block may
                    // run past the row into spare slots, overwritten next; queued <= QUEUE - 8 at each
                    // block keeps its stores inside the queue.
                    const f8q bx8 = (f8q)bx, by8 = (f8q)by, bz8 = (f8q)bz;
                    const int n = hi - lo + 1;  // < 1 where clipping emptied the row
                    int e0 = 0;
                    do {
                        const i8q k8 = (i8q)(lo + e0) + iota8;
                        const i8q o8 = (i8q)(row + lo + e0) + iota8;
                        __builtin_memcpy(kq + queued, &k8, 32);
                        __builtin_memcpy(oq + queued, &o8, 32);
                        __builtin_memcpy(bxq + queued, &bx8, 32);
                        __builtin_memcpy(byq + queued, &by8, 32);
                        __builtin_memcpy(bzq + queued, &bz8, 32);
                        const int m = n - e0 < 8 ? n - e0 : 8;
                        queued += m > 0 ? m : 0;
                        e0 += 8;
                        if (may_flush && queued > QUEUE - 8) flush_any();
                    } while (e0 < n);
                }
            };
            written += (int)total;
            if (total <= QUEUE - 8) {
                if (queued + total > QUEUE - 8) flush_any();
                queue_rows(false);
            } else {
                queue_rows(true);
            }
        }
        ri4 += dri4;
        const l4 carry = (l4)(ri4 >= den4);
        ri4 -= den4 & carry;
        qi4 += dqi4 - carry;
    }
    if (queued > 0) flush_any();
    return written;
}
#else
    return 0;
#endif
"""
)


@wp.func_native(_TET_SNIPPET)
def write_tet_native(
    volf: wp.array(dtype=wp.float32),
    src_ptr: wp.uint64,
    src_code: int,
    dims: wp.vec3i,
    strides: wp.vec3i,
    out_ptr: wp.uint64,
    out_code: int,
    out_ny: wp.int64,
    out_nz: wp.int64,
    face: wp.array2d(dtype=wp.int64),
    affine: wp.array2d(dtype=wp.float64),
    box: wp.array2d(dtype=wp.int32),
    t: int,
    i_first: int,
    i_last: int,
    params: wp.vec4f,
) -> int:
    """CPU exact-span rasterization of slabs x = i_first..i_last of tet t; returns the voxels inside."""
    ...

@wp.func
def write_row(
    vol: wp.array(dtype=Any),
    volf: wp.array(dtype=wp.float32),
    out_ptr: wp.uint64,
    out_code: int,
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
    ``params = (nearest, round to integer, min, max of the output type)``. With
    ``out_code != 0`` (CPU) the row goes to :func:`write_row_native`, else this Warp loop.
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
    lo = klo
    hi = khi
    if affine[t, 15] == wp.float64(0.0):  # the rest tet pokes out of the input's footprint
        lo, hi = axis_range(bx, wp.float32(affine[t, 12]), dims[0], lo, hi)
        lo, hi = axis_range(by, wp.float32(affine[t, 13]), dims[1], lo, hi)
        lo, hi = axis_range(bz, wp.float32(affine[t, 14]), dims[2], lo, hi)
    if out_code != 0:
        row = (wp.int64(i) * wp.int64(out.shape[1]) + wp.int64(j)) * wp.int64(out.shape[2])
        write_row_native(volf, dims, strides, out_ptr, out_code, row, lo, hi, bx, by, bz, ax, ay, az, params)
        return
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
def raster_tets_cpu(
    volf: wp.array(dtype=wp.float32),
    src_ptr: wp.uint64,
    src_code: int,
    dims: wp.vec3i,
    strides: wp.vec3i,
    out_ptr: wp.uint64,
    out_code: int,
    out_shape: wp.vec3i,
    face: wp.array2d(dtype=wp.int64),
    affine: wp.array2d(dtype=wp.float64),
    box: wp.array2d(dtype=wp.int32),
    item_offsets: wp.array(dtype=wp.int32),
    tet_count: int,
    slabs_per_item: int,
    params: wp.vec4f,
    written: wp.array(dtype=wp.int32),
    offset: int,
):
    """CPU exact spans (:func:`write_tet_native`), one thread per run of ``slabs_per_item``
    x-slabs of a tet: small tets are one item, big ones several (load balance)."""
    s = wp.tid() + offset
    t = owner_search(item_offsets, tet_count, s)
    i_first = box[t, 0] + (s - item_offsets[t]) * slabs_per_item
    i_last = wp.min(i_first + slabs_per_item - 1, box[t, 1])
    written[s] = write_tet_native(
        volf, src_ptr, src_code, dims, strides, out_ptr, out_code, wp.int64(out_shape[1]), wp.int64(out_shape[2]),
        face, affine, box, t, i_first, i_last, params,
    )


@wp.func
def inside_run(face: wp.array2d(dtype=wp.int64), t: int, i: int, j: int, k0: int, k1: int):
    """First and last k in [k0, k1] whose voxel passes the inside test (last < first if none)."""
    first = int(0)
    last = int(-1)
    found = bool(False)
    for k in range(k0, k1 + 1):
        if inside(face, t, i, j, k):
            if not found:
                first = k
                found = True
            last = k
    if not found:
        first = k0
        last = k0 - 1
    return first, last


@wp.kernel
def raster_slabs(
    vol: wp.array(dtype=Any),
    volf: wp.array(dtype=wp.float32),
    out_ptr: wp.uint64,
    out_code: int,
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
                write_row(vol, volf, out_ptr, out_code, dims, strides, out, counts, affine, t, i, j, int(klo), int(khi), params)
            # Step every face's floor(g / |Sz|) to the next row without dividing (a DDA).
            for f in range(4):
                q[f] = q[f] + dq[f]
                if den[f] > wp.int64(0):
                    r[f] = r[f] + dr[f]
                    if r[f] >= den[f]:
                        r[f] = r[f] - den[f]
                        q[f] = q[f] + wp.int64(1)
        else:
            # Thesis Algorithm 1: test every voxel of the box row. A tet is convex, so the
            # voxels that pass form one run, written in one go.
            n_tested += box[t, 5] - box[t, 4] + 1
            first, last = inside_run(face, t, i, j, box[t, 4], box[t, 5])
            if last >= first:
                n_written += last - first + 1
                write_row(vol, volf, out_ptr, out_code, dims, strides, out, counts, affine, t, i, j, first, last, params)
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
    volf: wp.array(dtype=wp.float32),
    out_ptr: wp.uint64,
    out_code: int,
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
            first, last = inside_run(face, t, i, j, k0, k1)
            if last >= first:
                n_written += last - first + 1
                write_row(vol, volf, out_ptr, out_code, dims, strides, out, counts, affine, t, i, j, first, last, params)
    tested[s] = n_tested
    written[s] = n_written


# Declare every voxel type up front: the module then hashes (and compiles) once, instead of
# once more each time a new dtype is first launched.
for _dtype in (wp.uint8, wp.int16, wp.uint16, wp.float32):
    _arrays = {"vol": wp.array(dtype=_dtype), "out": wp.array3d(dtype=_dtype)}
    wp.overload(raster_slabs, _arrays)
    wp.overload(raster_cells, _arrays)


@wp.func
def snap(u: wp.vec3d, sub: wp.float64) -> wp.vec3l:
    """Node position in 1/sub voxel units, rounded half up (exact integers from here on)."""
    h = wp.float64(0.5)
    return wp.vec3l(
        wp.int64(wp.floor(u[0] * sub + h)), wp.int64(wp.floor(u[1] * sub + h)), wp.int64(wp.floor(u[2] * sub + h))
    )


@wp.func
def cross_l(a: wp.vec3l, b: wp.vec3l) -> wp.vec3l:
    return wp.vec3l(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@wp.func
def dot_l(a: wp.vec3l, b: wp.vec3l) -> wp.int64:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@wp.func
def write_face(face: wp.array2d(dtype=wp.int64), row: int, pa: wp.vec3l, pb: wp.vec3l, pc: wp.vec3l,
               pv: wp.vec3l, sub: wp.int64) -> bool:
    """Exact plane of face (a, b, c) oriented towards vertex v; False if v lies on it.

    Stores (sub n, d + tau, h - tau): a voxel (i, j, k) passes iff sub n.(i, j, k) - (d + tau)
    >= 0, where tau = 0 when n is positive in (z, y, x) lexicographic order (ties go to that
    side) and 1 otherwise; h = n.(v - a) > 0 is the plane value at the opposite vertex.
    """
    n = cross_l(pb - pa, pc - pa)
    d = dot_l(n, pa)
    h = dot_l(n, pv) - d
    if h < wp.int64(0):
        n = -n
        d = -d
        h = -h
    zero = wp.int64(0)
    lexpos = n[2] > zero or (n[2] == zero and (n[1] > zero or (n[1] == zero and n[0] > zero)))
    tau = wp.int64(1)
    if lexpos:
        tau = zero
    face[row, 0] = n[0] * sub
    face[row, 1] = n[1] * sub
    face[row, 2] = n[2] * sub
    face[row, 3] = d + tau
    face[row, 4] = h - tau
    return h != zero


@wp.kernel
def tet_setup(
    rest: wp.array(dtype=wp.vec3d),
    moved: wp.array(dtype=wp.vec3d),
    tets: wp.array2d(dtype=wp.int32),
    sub: int,
    out_shape: wp.vec3i,
    in_shape: wp.vec3i,
    face: wp.array2d(dtype=wp.int64),
    affine: wp.array2d(dtype=wp.float64),
    box: wp.array2d(dtype=wp.int32),
    det: wp.array(dtype=wp.float64),
    offset: int,
):
    """Per tet: exact face planes, clipped voxel box, the output->input affine map, and
    ``det[t]``, the determinant of the deformed edge matrix in output voxel indices (the host's
    inverted / degenerate check).

    ``rest``: rest nodes in input voxel indices [node_count]; ``moved``: deformed nodes in
    output voxel indices. ``affine[t] = (A row-major, t, 1 / A[:, 2] or 0, rest tet inside
    the input's footprint)`` with ``u0 = A u1 + t`` (thesis eqs. 3.1-3.2: A = E0 E1^-1).
    """
    t = wp.tid() + offset
    i0 = tets[t, 0]
    i1 = tets[t, 1]
    i2 = tets[t, 2]
    i3 = tets[t, 3]
    s = wp.float64(sub)
    p0 = snap(moved[i0], s)
    p1 = snap(moved[i1], s)
    p2 = snap(moved[i2], s)
    p3 = snap(moved[i3], s)
    sl = wp.int64(sub)
    ok = write_face(face, 4 * t + 0, p1, p2, p3, p0, sl)
    ok = write_face(face, 4 * t + 1, p0, p2, p3, p1, sl) and ok
    ok = write_face(face, 4 * t + 2, p0, p1, p3, p2, sl) and ok
    ok = write_face(face, 4 * t + 3, p0, p1, p2, p3, sl) and ok
    for a in range(3):
        lo = wp.min(wp.min(p0[a], p1[a]), wp.min(p2[a], p3[a]))
        hi = wp.max(wp.max(p0[a], p1[a]), wp.max(p2[a], p3[a]))
        blo = wp.max(-floor_div(-lo, sl), wp.int64(0))  # ceil(lo / sub), clipped to the grid
        bhi = wp.min(floor_div(hi, sl), wp.int64(out_shape[a] - 1))
        if not ok:
            bhi = blo - wp.int64(1)  # a tet flattened by snapping covers no voxel
        box[t, 2 * a] = int(blo)
        box[t, 2 * a + 1] = int(bhi)

    r0 = rest[i0]
    e0 = wp.matrix_from_cols(rest[i1] - r0, rest[i2] - r0, rest[i3] - r0)
    m0 = moved[i0]
    e1 = wp.matrix_from_cols(moved[i1] - m0, moved[i2] - m0, moved[i3] - m0)
    det[t] = wp.determinant(e1)
    am = e0 * wp.inverse(e1)
    tv = r0 - am * m0
    for r in range(3):
        for c in range(3):
            affine[t, 3 * r + c] = am[r, c]
        affine[t, 9 + r] = tv[r]
        slope = wp.float32(am[r, 2])
        inv = wp.float64(0.0)
        if slope != wp.float32(0.0):
            inv = wp.float64(wp.float32(1.0) / slope)
        affine[t, 12 + r] = inv
    lim = wp.vec3d(wp.float64(in_shape[0]), wp.float64(in_shape[1]), wp.float64(in_shape[2])) - wp.vec3d(
        wp.float64(0.5), wp.float64(0.5), wp.float64(0.5)
    )
    inside = wp.float64(1.0)
    for v in range(4):
        rv = rest[tets[t, v]]
        for a in range(3):
            if rv[a] < wp.float64(-0.5) or rv[a] > lim[a]:
                inside = wp.float64(0.0)
    affine[t, 15] = inside
