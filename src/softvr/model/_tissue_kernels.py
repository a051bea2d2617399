"""Warp kernels of :mod:`softvr.model.tissue`."""

import warp as wp


@wp.kernel
def voxel_owner_kernel(nodes: wp.array(dtype=wp.vec3d), tets: wp.array2d(dtype=wp.int32), dims: wp.vec3i,
                  shift: wp.vec3d, owner: wp.array(dtype=wp.int32)):
    """Each voxel centre (shifted by ``shift`` voxels) inside tet t gets owner t; one thread
    per tet over its bounding box of voxel indices (``nodes`` in voxel index space)."""
    t = wp.tid()
    a = nodes[tets[t, 0]]
    b = nodes[tets[t, 1]]
    c = nodes[tets[t, 2]]
    d = nodes[tets[t, 3]]
    lo = wp.min(wp.min(a, b), wp.min(c, d)) - shift
    hi = wp.max(wp.max(a, b), wp.max(c, d)) - shift
    i0 = wp.max(int(wp.ceil(lo[0])), 0)
    j0 = wp.max(int(wp.ceil(lo[1])), 0)
    k0 = wp.max(int(wp.ceil(lo[2])), 0)
    i1 = wp.min(int(wp.floor(hi[0])), dims[0] - 1)
    j1 = wp.min(int(wp.floor(hi[1])), dims[1] - 1)
    k1 = wp.min(int(wp.floor(hi[2])), dims[2] - 1)
    inv = wp.inverse(wp.matrix_from_cols(b - a, c - a, d - a))
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for k in range(k0, k1 + 1):
                p = wp.vec3d(wp.float64(i), wp.float64(j), wp.float64(k)) + shift
                l = inv @ (p - a)
                if l[0] >= wp.float64(0.0) and l[1] >= wp.float64(0.0) and l[2] >= wp.float64(0.0):
                    if l[0] + l[1] + l[2] <= wp.float64(1.0):
                        owner[(i * dims[1] + j) * dims[2] + k] = t
