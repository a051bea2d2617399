"""Floors for ``softvr bench volume``: the same voxels moved without a mesh (issue 18).

``numpy copy``
    ``np.copyto`` of the input into the output: the memory floor (every byte read and written once).
``warp trilinear``
    A plain Warp kernel, one thread per output row, that samples the input trilinearly at
    (i, j, k) + a constant offset, rounds and writes it: the resampling work of an in-place
    frame with no mesh, no spans and no per-tet set-up, split over the cores by
    :func:`softvr.device.launch` as the rasterizer is.
"""

from __future__ import annotations

from typing import no_type_check

import numpy as np
import warp as wp

from softvr.device import launch, load_kernels

__all__ = ["floor_copy", "floor_trilinear"]

wp.set_module_options({"enable_backward": False})


@wp.kernel
@no_type_check  # Warp's annotations (wp.array(dtype=...)) are not Python types
def _trilinear_rows(src: wp.array3d(dtype=wp.int16), out: wp.array3d(dtype=wp.int16), d: wp.vec3f, offset: int):
    r = wp.tid() + offset
    ny = out.shape[1]
    nz = out.shape[2]
    i = r / ny
    j = r % ny
    ux = wp.clamp(wp.float32(i) + d[0], 0.0, wp.float32(src.shape[0] - 1))
    uy = wp.clamp(wp.float32(j) + d[1], 0.0, wp.float32(src.shape[1] - 1))
    ix = wp.min(int(ux), src.shape[0] - 2)
    iy = wp.min(int(uy), src.shape[1] - 2)
    wx = ux - wp.float32(ix)
    wy = uy - wp.float32(iy)
    for k in range(nz):
        uz = wp.clamp(wp.float32(k) + d[2], 0.0, wp.float32(nz - 1))
        iz = wp.min(int(uz), nz - 2)
        wz = uz - wp.float32(iz)
        c00 = (1.0 - wz) * wp.float32(src[ix, iy, iz]) + wz * wp.float32(src[ix, iy, iz + 1])
        c01 = (1.0 - wz) * wp.float32(src[ix, iy + 1, iz]) + wz * wp.float32(src[ix, iy + 1, iz + 1])
        c10 = (1.0 - wz) * wp.float32(src[ix + 1, iy, iz]) + wz * wp.float32(src[ix + 1, iy, iz + 1])
        c11 = (1.0 - wz) * wp.float32(src[ix + 1, iy + 1, iz]) + wz * wp.float32(src[ix + 1, iy + 1, iz + 1])
        c0 = (1.0 - wy) * c00 + wy * c01
        c1 = (1.0 - wy) * c10 + wy * c11
        v = wp.floor((1.0 - wx) * c0 + wx * c1 + 0.5)
        out[i, j, k] = wp.int16(wp.clamp(v, -32768.0, 32767.0))


def floor_copy(data: np.ndarray):
    """A function copying ``data`` into a preallocated array (the memory floor)."""
    out = np.empty_like(data)
    return lambda: np.copyto(out, data)


def floor_trilinear(data: np.ndarray, device: str = "cpu"):
    """A function resampling int16 ``data`` (3-D, each axis >= 2) at a sub-voxel offset (Warp)."""
    src: wp.array = wp.array(np.ascontiguousarray(data, dtype=np.int16), device=device)
    out = wp.empty(data.shape, dtype=wp.int16, device=device)
    rows = int(data.shape[0] * data.shape[1])
    load_kernels(_trilinear_rows, device)
    args = [src, out, wp.vec3f(0.3, 0.2, 0.1)]

    def run():
        launch(_trilinear_rows, rows, args, device, min_chunk=64)
        if device != "cpu":
            wp.synchronize_device(device)

    return run
