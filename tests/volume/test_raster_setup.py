"""The per-tet set-up kernel against an obviously-correct numpy reference.

The reference builds the same exact integer planes with numpy int64 cross products and the
affine maps with ``numpy.linalg.inv`` (thesis eqs. 3.1-3.2: u0 = E0 E1^-1 (u1 - x1_0) + x0_0).
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from softvr.volume import Rasterizer, Volume, grid_tet_mesh
from softvr.volume.rasterize import subvoxel_factor

FACES = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def reference_setup(u0, u1, tets, sub, shape, in_shape):
    p = np.floor(u1 * sub + 0.5).astype(np.int64)[tets]
    m = len(tets)
    face = np.empty((m, 4, 5), np.int64)
    flat = np.zeros(m, bool)
    for f, (a, b, c) in enumerate(FACES):
        pa = p[:, a]
        n = np.cross(p[:, b] - pa, p[:, c] - pa)
        d = np.einsum("ij,ij->i", n, pa)
        h = np.einsum("ij,ij->i", n, p[:, f]) - d
        sign = np.where(h < 0, -1, 1)
        n, d, h = n * sign[:, None], d * sign, h * sign
        flat |= h == 0
        lexpos = (n[:, 2] > 0) | ((n[:, 2] == 0) & ((n[:, 1] > 0) | ((n[:, 1] == 0) & (n[:, 0] > 0))))
        tau = np.where(lexpos, 0, 1)
        face[:, f] = np.column_stack([n * sub, d + tau, h - tau])
    lo = np.maximum(-((-p.min(axis=1)) // sub), 0)
    hi = np.minimum(p.max(axis=1) // sub, np.asarray(shape) - 1)
    hi[flat] = lo[flat] - 1
    box = np.empty((m, 6), np.int64)
    box[:, 0::2], box[:, 1::2] = lo, hi
    r = u0[tets]
    e0 = (r[:, 1:] - r[:, :1]).transpose(0, 2, 1)
    x = u1[tets]
    e1 = (x[:, 1:] - x[:, :1]).transpose(0, 2, 1)
    a = e0 @ np.linalg.inv(e1)
    t = r[:, 0] - np.einsum("mij,mj->mi", a, x[:, 0])
    inside = np.all((r >= -0.5) & (r <= np.asarray(in_shape) - 0.5), axis=(1, 2))
    return face.reshape(-1, 5), np.column_stack([a.reshape(m, 9), t]), box, inside


@pytest.mark.parametrize("scale", [1.0, 700.0])
def test_setup_kernel_matches_numpy_reference(device, scale):
    """scale 1 snaps to 1/256 voxel; scale 700 pushes nodes ~2e4 voxels out (coarser snapping)."""
    vol = Volume(np.zeros((30, 26, 22), np.int16), spacing=(0.8, 1.1, 1.7), origin=(3, -2, 5))
    nodes, tets = grid_tet_mesh(vol, (5, 4, 3))
    rng = np.random.default_rng(4)
    rot = Rotation.from_euler("xyz", [20, 45, -30], degrees=True).as_matrix()
    moved = (nodes - nodes.mean(0)) @ rot.T * 1.2 + nodes.mean(0) + rng.normal(scale=0.3, size=nodes.shape)
    r = Rasterizer(vol, nodes, tets, device=device)
    u1 = (vol.world_to_index(moved) + 1.5) * scale
    shape = (40, 44, 38)
    sub = subvoxel_factor(u1, shape)
    assert sub == (256 if scale == 1.0 else 2)
    face, affine, box = r._setup(u1, shape)  # noqa: SLF001 - the fast path under test
    ref_face, ref_affine, ref_box, ref_inside = reference_setup(vol.world_to_index(nodes), u1, tets, sub, shape, vol.shape)
    np.testing.assert_array_equal(face.numpy(), ref_face)
    np.testing.assert_array_equal(box.numpy(), ref_box)
    np.testing.assert_allclose(affine.numpy()[:, :12], ref_affine, rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_array_equal(affine.numpy()[:, 15] == 1.0, ref_inside)
    slope = ref_affine[:, [2, 5, 8]].astype(np.float32)
    np.testing.assert_allclose(affine.numpy()[:, 12:15], np.where(slope != 0, 1 / slope, 0), rtol=1e-6)
