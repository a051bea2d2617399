"""The CPU fast path of the ray caster's kernel (:func:`softvr.render._raycast_kernels.raycast`).

The Warp kernel stays the reference (and the CUDA path); on the CPU it hands its block of rays
to :func:`raycast_native`, a C++ port of its per-ray loop that evaluates every float expression
of the kernel in the same order, without FMA contraction (Warp compiles CPU kernels without it,
and without fast-math), so the images and the per-pixel state are the same bit for bit
(tests/render/test_raycast_native.py).

What it saves is Warp's code generation around the loop, not work: the palpation trainer's raycast
launch takes ~16 % less CPU (0.33-0.35 against 0.39-0.44 us a ray, ~41 K rays a frame). The rays
are short (a few samples) and their samples' chains of loads and arithmetic already overlap:
batches of four samples a ray (1.15x the kernel), two rays in flight (1.02x) and a 16-lane gradient
(1.03x, its loads go lane by lane) took more CPU than this plain loop (1.18x), and lanes across
rays would shade at ~30 % lane use (8 lanes; smoothing ~17 %).
"""

from __future__ import annotations

import typing
from collections.abc import Callable

import warp as wp

__all__ = ["NATIVE_VOXEL_CODES", "raycast_native", "voxel_cases"]

#: The voxel dtypes the C++ forms read in place, by the code the kernels take (0: Warp's code).
NATIVE_VOXEL_CODES = {"int16": 1, "uint8": 2, "uint16": 3, "float32": 4}
_C_TYPES = {"int16": "short", "uint8": "unsigned char", "uint16": "unsigned short", "float32": "float"}


def voxel_cases(code: str, body: Callable[[str], str]) -> str:
    """A C++ ``switch`` on the variable ``code`` (a :data:`NATIVE_VOXEL_CODES` code) whose case
    for each dtype runs ``body(c_type)``, ``c_type`` its C++ type (``"short"`` for int16, ...)."""
    cases = "".join(f"case {NATIVE_VOXEL_CODES[name]}: {{\n{body(c_type)}\nbreak; }}\n"
                    for name, c_type in _C_TYPES.items())
    return f"switch ({code}) {{\n{cases}default: break;\n}}\n"


# The C++ (CPU only: on CUDA the function is empty and never called). Warp's own builtins (wp::lerp,
# wp::clamp, wp::normalize, matrix products, ...) where the kernel calls them, so that their order
# of evaluation is the kernel's; plain float expressions written in the kernel's order, with FMA
# contraction off as in Warp's CPU build. Constants are double literals cast to float, as Warp
# emits them.
_SNIPPET = r"""
#if !defined(__CUDA_ARCH__)
{
#pragma clang fp contract(off)
    typedef unsigned char u8;
    typedef unsigned long long u64;
    const int n0 = n[0], n1 = n[1], n2 = n[2];
    const int s0 = strides[0], s1 = strides[1], s2 = strides[2];
    const float fn0 = (float)(n0 - 1), fn1 = (float)(n1 - 1), fn2 = (float)(n2 - 1);
    const int size = lut.shape[0];
    const int glut_size = gradient_lut.shape[0];
    const wp::vec4* __restrict__ L = (const wp::vec4*)lut.data;
    const float* __restrict__ G = (const float*)gradient_lut.data;
    const int nb0 = distance.shape[0], nb1 = distance.shape[1], nb2 = distance.shape[2];
    const u8* __restrict__ D = (const u8*)distance.data;
    const long long d0s = distance.strides[0], d1s = distance.strides[1], d2s = distance.strides[2];
    const u8* __restrict__ C = (const u8*)cells.data;
    const long long c0s = cells.strides[0], c1s = cells.strides[1], c2s = cells.strides[2];
    const float opaque = (float)0.99;
    const float smooth_from = (float)0.5, smooth_full = (float)0.8;
    const float tiny = (float)1.0e-12, huge = (float)1.0e30, small = (float)1.0e-6;
    // Bricks of BRICK = 4 voxels a side (shifts by 2, masks of 3): the kernels module refuses another.
    const float bs = 4.0f;

    auto slab = [](float o, float d, float lo, float hi, float t0, float t1) -> wp::vec2 {
        if (wp::abs(d) < (float)1.0e-12) {
            if (o < lo || o > hi)
                return wp::vec2(1.0f, 0.0f);
            return wp::vec2(t0, t1);
        }
        const float a = (lo - o) / d;
        const float b = (hi - o) / d;
        return wp::vec2(wp::max(t0, wp::min(a, b)), wp::min(t1, wp::max(a, b)));
    };
    auto brick_at = [&](const wp::vec3& p) -> wp::vec3i {
        return wp::vec3i(wp::clamp(((int)p[0]) >> 2, 0, nb0 - 1), wp::clamp(((int)p[1]) >> 2, 0, nb1 - 1),
                         wp::clamp(((int)p[2]) >> 2, 0, nb2 - 1));
    };
    auto gained_at = [&](int i, int j, int k) -> u8 {
        return *((const u8*)gained.data + i * (long long)gained.strides[0] + j * (long long)gained.strides[1]
                 + k * (long long)gained.strides[2]);
    };
    auto none_gained = [&](const wp::vec3& a, const wp::vec3& b) -> bool {
        const wp::vec3i ca = brick_at(a);
        const wp::vec3i cb = brick_at(b);
        if (ca[0] == cb[0] && ca[1] == cb[1] && ca[2] == cb[2])
            return gained_at(ca[0], ca[1], ca[2]) == 0;
        if (wp::abs(ca[0] - cb[0]) > 1 || wp::abs(ca[1] - cb[1]) > 1 || wp::abs(ca[2] - cb[2]) > 1)
            return false;
        u8 flagged = 0;
        for (int c = 0; c < 8; ++c)
            flagged = flagged | gained_at((c & 1) ? cb[0] : ca[0], (c & 2) ? cb[1] : ca[1], (c & 4) ? cb[2] : ca[2]);
        return flagged == 0;
    };
    auto exit_along = [](float o, float inv_d, float lo, float hi) -> float {
        return ((inv_d > 0.0f ? hi : lo) - o) * inv_d;
    };
    auto noise = [](int x, int y) -> float {
        unsigned int state = (unsigned int)x * 747796405u + (unsigned int)y * 1597334677u + 1u;
        unsigned int word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
        word = (word >> 22u) ^ word;
        return (float)(word >> 8u) * (1.0f / 16777216.0f);
    };
    auto lerp = [](float a, float b, float t) -> float { return a * (1.0f - t) + b * t; };

    auto run = [&](const auto* __restrict__ V) {
        auto at = [&](int a) -> float { return (float)V[a]; };
        // The gradient (central differences, trilinear weights) at the cell with lower corner
        // (i, j, k), address a, fractions fx, fy, fz: the Warp ``gradient``'s sums in its order.
        auto gradient = [&](int i, int j, int k, int a, float fx, float fy, float fz) -> wp::vec3 {
            const int xm = (i - wp::max(i - 1, 0)) * s0;
            const int xp = (wp::min(i + 2, n0 - 1) - i) * s0;
            const int ym = (j - wp::max(j - 1, 0)) * s1;
            const int yp = (wp::min(j + 2, n1 - 1) - j) * s1;
            const int zm = (k - wp::max(k - 1, 0)) * s2;
            const int zp = (wp::min(k + 2, n2 - 1) - k) * s2;
            float gx = 0.0f, gy = 0.0f, gz = 0.0f;
            #pragma unroll
            for (int c = 0; c < 4; ++c) {
                const int u = c & 1, v = c >> 1;
                int r = a + u * s1 + v * s2;
                float w = (u == 1 ? fy : 1.0f - fy) * (v == 1 ? fz : 1.0f - fz);
                gx = gx + w * lerp(at(r + s0) - at(r - xm), at(r + xp) - at(r), fx);
                r = a + u * s0 + v * s2;
                w = (u == 1 ? fx : 1.0f - fx) * (v == 1 ? fz : 1.0f - fz);
                gy = gy + w * lerp(at(r + s1) - at(r - ym), at(r + yp) - at(r), fy);
                r = a + u * s0 + v * s1;
                w = (u == 1 ? fx : 1.0f - fx) * (v == 1 ? fy : 1.0f - fy);
                gz = gz + w * lerp(at(r + s2) - at(r - zm), at(r + zp) - at(r), fz);
            }
            return wp::vec3(0.5f * gx, 0.5f * gy, 0.5f * gz);
        };
        // The gradient at index-space point p (Warp ``gradient``: clamped, its cell).
        auto gradient_at = [&](const wp::vec3& p) -> wp::vec3 {
            const float q0 = wp::clamp(p[0], 0.0f, fn0), q1 = wp::clamp(p[1], 0.0f, fn1);
            const float q2 = wp::clamp(p[2], 0.0f, fn2);
            const int i = wp::min((int)q0, n0 - 2), j = wp::min((int)q1, n1 - 2), k = wp::min((int)q2, n2 - 2);
            return gradient(i, j, k, i * s0 + j * s1 + k * s2, q0 - (float)i, q1 - (float)j, q2 - (float)k);
        };

        for (int idx = first_ray; idx < last_ray; ++idx) {
            const int tid = ((const int*)pixels.data)[idx];
            const int px = tid % width;
            const int row = tid / width;
            const int py = height - 1 - row;
            wp::vec3 o, d, dw;
            wp::vec2 inside;
            wp::vec4 at_depth;
            if (store_rays != 0) {
                const float nx = 2.0f * ((float)px + 0.5f) / (float)width - 1.0f;
                const float ny = 2.0f * ((float)py + 0.5f) / (float)height - 1.0f;
                const wp::vec4 near4 = wp::mul(ndc_to_world, wp::vec4(nx, ny, -1.0f, 1.0f));
                const wp::vec4 far4 = wp::mul(ndc_to_world, wp::vec4(nx, ny, 1.0f, 1.0f));
                const wp::vec3 near_ = wp::div(wp::vec3(near4[0], near4[1], near4[2]), near4[3]);
                const wp::vec3 far_ = wp::div(wp::vec3(far4[0], far4[1], far4[2]), far4[3]);
                dw = wp::normalize(wp::sub(far_, near_));
                const wp::vec4 mid = wp::mul(ndc_to_world, wp::vec4(nx, ny, 0.0f, 1.0f));
                const wp::vec4 column = wp::mul(ndc_to_world, wp::vec4(0.0f, 0.0f, 1.0f, 0.0f));
                at_depth = wp::vec4(wp::dot(wp::vec3(mid[0], mid[1], mid[2]), dw),
                                    wp::dot(wp::vec3(column[0], column[1], column[2]), dw), mid[3], wp::dot(near_, dw));
                const wp::vec4 o4 = wp::mul(world_to_index, wp::vec4(near_[0], near_[1], near_[2], 1.0f));
                o = wp::vec3(o4[0], o4[1], o4[2]);
                const wp::vec4 d4 = wp::mul(world_to_index, wp::vec4(dw[0], dw[1], dw[2], 0.0f));
                d = wp::vec3(d4[0], d4[1], d4[2]);
                inside = wp::vec2(0.0f, (float)3.0e38);
                inside = slab(o[0], d[0], 0.0f, (float)(n0 - 1), inside[0], inside[1]);
                inside = slab(o[1], d[1], 0.0f, (float)(n1 - 1), inside[0], inside[1]);
                inside = slab(o[2], d[2], 0.0f, (float)(n2 - 1), inside[0], inside[1]);
                wp::index(ray_origin, tid) = o;
                wp::index(ray_direction, tid) = d;
                wp::index(ray_world, tid) = dw;
                wp::index(ray_span, tid) = inside;
                wp::index(ray_depth, tid) = at_depth;
            } else {
                o = wp::index(ray_origin, tid);
                d = wp::index(ray_direction, tid);
                dw = wp::index(ray_world, tid);
                inside = wp::index(ray_span, tid);
                at_depth = wp::index(ray_depth, tid);
            }
            const float z = 2.0f * wp::index(depth, py, px) - 1.0f;
            const float t_surface = (at_depth[0] + z * at_depth[1]) / (at_depth[2] + z * ndc_to_world.data[3][2])
                                    - at_depth[3];
            const float span0 = inside[0], span1 = wp::min(inside[1], t_surface);
            float r_ = 0.0f, g_ = 0.0f, b_ = 0.0f;
            float alpha = 0.0f;
            if (span0 < span1) {
                const float t0 = span0;
                float shift = 0.5f;
                if (jitter != 0)
                    shift = noise(px, row);
                const wp::vec3 view = wp::neg(dw);
                const wp::vec3 half = wp::normalize(wp::add(light, view));
                const float o0 = o[0], o1 = o[1], o2 = o[2], e0 = d[0], e1 = d[1], e2 = d[2];
                const float i0 = wp::abs(e0) > tiny ? 1.0f / e0 : huge;
                const float i1 = wp::abs(e1) > tiny ? 1.0f / e1 : huge;
                const float i2 = wp::abs(e2) > tiny ? 1.0f / e2 : huge;
                const float inv_step = 1.0f / step;
                float known = wp::index(empty_until, tid);
                if (known > 0.0f && flips != 0) {
                    wp::vec2 on_ray = slab(o0, e0, flip_lo[0], flip_hi[0], t0, t0 + (known + shift) * step);
                    on_ray = slab(o1, e1, flip_lo[1], flip_hi[1], on_ray[0], on_ray[1]);
                    on_ray = slab(o2, e2, flip_lo[2], flip_hi[2], on_ray[0], on_ray[1]);
                    if (on_ray[0] <= on_ray[1])
                        known = 0.0f;
                }
                float k = known;
                float first = -1.0f;
                if (known > 0.0f && skip_ok != 0) {
                    const float read = wp::index(read_from, tid);
                    if (read > known) {
                        if (none_gained(wp::add(o, wp::mul(t0 + (known + shift) * step, d)),
                                        wp::add(o, wp::mul(t0 + (read - 1.0f + shift) * step, d)))) {
                            first = known;
                            k = read;
                        }
                    }
                }
                float first_read = -1.0f;
                int l0 = -1, l1 = -1, l2 = -1;
                while (alpha < opaque) {
                    const float t = t0 + (k + shift) * step;
                    if (t > span1)
                        break;
                    const float p0 = o0 + t * e0, p1 = o1 + t * e1, p2 = o2 + t * e2;
                    const int b0 = wp::clamp(((int)p0) >> 2, 0, nb0 - 1);
                    const int b1 = wp::clamp(((int)p1) >> 2, 0, nb1 - 1);
                    const int b2 = wp::clamp(((int)p2) >> 2, 0, nb2 - 1);
                    int r = 0;
                    if (b0 != l0 || b1 != l1 || b2 != l2) {
                        r = (int)D[b0 * d0s + b1 * d1s + b2 * d2s];
                        if (r == 0) {
                            l0 = b0; l1 = b1; l2 = b2;
                            if (first < 0.0f)
                                first = k;
                        }
                    }
                    if (r > 0) {
                        const float leave = wp::min(
                            wp::min(exit_along(o0, i0, (float)(b0 - r + 1) * bs, (float)(b0 + r) * bs),
                                    exit_along(o1, i1, (float)(b1 - r + 1) * bs, (float)(b1 + r) * bs)),
                            exit_along(o2, i2, (float)(b2 - r + 1) * bs, (float)(b2 + r) * bs));
                        k = wp::max(k + 1.0f, wp::ceil((leave - t0) * inv_step - shift));
                        continue;
                    }
                    // The cell once, for its mask, the trilinear weights and the gradient (the kernel
                    // works it out for each from the same point: the same cell).
                    const float q0 = wp::clamp(p0, 0.0f, fn0), q1 = wp::clamp(p1, 0.0f, fn1);
                    const float q2 = wp::clamp(p2, 0.0f, fn2);
                    const int ci = wp::min((int)q0, n0 - 2), cj = wp::min((int)q1, n1 - 2);
                    const int ck = wp::min((int)q2, n2 - 2);
                    const u64 mask = *(const u64*)(C + (ci >> 2) * c0s + (cj >> 2) * c1s + (ck >> 2) * c2s);
                    const int bit = ((ci & 3) << 4) | ((cj & 3) << 2) | (ck & 3);
                    if (((mask >> (u64)bit) & 1ull) == 0ull) {
                        k = k + 1.0f;
                        continue;
                    }
                    if (first_read < 0.0f)
                        first_read = k;
                    const float fx = q0 - (float)ci, fy = q1 - (float)cj, fz = q2 - (float)ck;
                    const int a = ci * s0 + cj * s1 + ck * s2;
                    const float c00 = lerp(at(a), at(a + s0), fx);
                    const float c10 = lerp(at(a + s1), at(a + s0 + s1), fx);
                    const float c01 = lerp(at(a + s2), at(a + s0 + s2), fx);
                    const float c11 = lerp(at(a + s1 + s2), at(a + s0 + s1 + s2), fx);
                    const float value = lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz);
                    const float u = wp::clamp((value - lut_lo) * lut_scale, 0.0f, (float)(size - 1));
                    const int li = wp::min((int)u, size - 2);
                    const wp::vec4 c = wp::lerp(L[li], L[li + 1], u - (float)li);
                    float sa = c[3];
                    if (sa > 0.0f) {
                        wp::vec3 color(c[0], c[1], c[2]);
                        if (shade != 0 || gradient_scale >= 0.0f) {
                            const wp::vec3 gi = gradient(ci, cj, ck, a, fx, fy, fz);
                            wp::vec3 gw = wp::mul(index_gradient_to_world, gi);
                            float gl = wp::length(gw);
                            if (gradient_scale >= 0.0f) {
                                const float gu = wp::clamp(gl * gradient_scale, 0.0f, (float)(glut_size - 1));
                                const int gj = wp::min((int)gu, glut_size - 2);
                                sa = sa * lerp(G[gj], G[gj + 1], gu - (float)gj);
                            }
                            if (shade != 0) {
                                if (smooth_axis >= 0 && gl > small) {
                                    const float across = wp::abs(wp::dot(gw, slice_normal)) / gl;
                                    const float blend = wp::clamp((across - smooth_from) / (smooth_full - smooth_from),
                                                                  0.0f, 1.0f);
                                    if (blend > 0.0f) {
                                        const wp::vec3 p(p0, p1, p2);
                                        wp::vec3 e(0.0f);
                                        e[smooth_axis] = 1.0f;
                                        const wp::vec3 smooth = wp::mul(
                                            0.25f, wp::add(wp::add(gradient_at(wp::sub(p, e)), wp::mul(2.0f, gi)),
                                                           gradient_at(wp::add(p, e))));
                                        gw = wp::mul(index_gradient_to_world,
                                                     wp::add(gi, wp::mul(blend, wp::sub(smooth, gi))));
                                        gl = wp::length(gw);
                                    }
                                }
                                float lit = shading[0];
                                if (gl > small) {
                                    wp::vec3 nrm = wp::div(gw, gl);
                                    if (wp::dot(nrm, view) < 0.0f)
                                        nrm = wp::neg(nrm);
                                    lit = lit + shading[1] * wp::max(wp::dot(nrm, light), 0.0f);
                                    const float h1 = wp::max(wp::dot(nrm, half), 0.0f);
                                    const float h4 = (h1 * h1) * (h1 * h1);
                                    const float h16 = (h4 * h4) * (h4 * h4);
                                    color = wp::add(wp::mul(color, lit), wp::vec3(shading[2] * h16 * h4));
                                } else {
                                    color = wp::mul(color, lit);
                                }
                            }
                        }
                        const float wgt = (1.0f - alpha) * sa;
                        r_ = r_ + wgt * color[0];
                        g_ = g_ + wgt * color[1];
                        b_ = b_ + wgt * color[2];
                        alpha = alpha + (1.0f - alpha) * sa;
                    }
                    k = k + 1.0f;
                }
                wp::index(empty_until, tid) = first >= 0.0f ? first : k;
                wp::index(read_from, tid) = first_read >= 0.0f ? first_read : k;
                wp::index(segment_start, tid) = wp::add(o, wp::mul(t0, d));
                wp::index(segment_end, tid) = wp::add(o, wp::mul(wp::min(t0 + (k + shift) * step, span1), d));
            } else {
                wp::index(segment_start, tid) = wp::vec3((float)-1.0e9);
                wp::index(segment_end, tid) = wp::vec3((float)-1.0e9);
                wp::index(empty_until, tid) = 0.0f;
                wp::index(read_from, tid) = 0.0f;
            }
            const float rgb[3] = {r_, g_, b_};
            for (int ch = 0; ch < 3; ++ch) {
                const float value = rgb[ch] + (1.0f - alpha) * (float)wp::index(surface, row, px, ch) / 255.0f;
                wp::index(image, row, px, ch) = wp::uint8(wp::clamp(value * 255.0f + 0.5f, 0.0f, 255.0f));
            }
        }
    };
""" + voxel_cases("vol_code", lambda c_type: f"run((const {c_type}*)vol_ptr);") + r"""}
#endif
"""


# Warp's annotations (wp.array(dtype=...)) are no Python types.
@typing.no_type_check
@wp.func_native(_SNIPPET)
def raycast_native(
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
    first_ray: int,
    last_ray: int,
):
    """The CPU fast path of ``raycast`` for its rays ``pixels[first_ray:last_ray]`` (same
    arguments; the voxels at address ``vol_ptr``, dtype by ``NATIVE_VOXEL_CODES`` ``vol_code``):
    the kernel's per-ray loop in C++, every expression evaluated in the kernel's order
    (thesis 3.3 front-to-back compositing, the kernels' module docstring's equation)."""
    ...
