"""``softvr.volume.deform`` reuses its set-up across calls on the same volume and mesh (issue 18)."""

import numpy as np
import pytest

from softvr.volume import Rasterizer, Volume, deform, grid_tet_mesh
from softvr.volume import rasterize as R


def _case(dtype=np.int16):
    rng = np.random.default_rng(3)
    vol = Volume((rng.random((20, 18, 16)) * 1000).astype(dtype), np.array([1.0, 1.2, 0.9]), np.zeros(3))
    nodes, tets = grid_tet_mesh(vol, 3)
    moved = nodes + 0.4 * np.sin(nodes[:, [1, 2, 0]] / 5.0)
    return vol, nodes, tets, moved


@pytest.mark.parametrize("dtype", [np.int16, np.uint8, np.float32])
def test_repeated_calls_reuse_the_setup_and_equal_the_rasterizer(dtype):
    vol, nodes, tets, moved = _case(dtype)
    ref = Rasterizer(vol, nodes, tets, device="cpu").deform(moved, vol).data
    first = deform(vol, nodes, tets, moved, device="cpu", out_grid=vol).data
    cached = R._ONE_SHOT[0][3]
    second = deform(vol, nodes, tets, moved, device="cpu", out_grid=vol).data
    assert R._ONE_SHOT[0][3] is cached
    np.testing.assert_array_equal(first, ref)
    np.testing.assert_array_equal(second, ref)


def test_a_new_mesh_or_options_or_edited_data_are_seen():
    vol, nodes, tets, moved = _case()
    deform(vol, nodes, tets, moved, device="cpu", out_grid=vol)
    cached = R._ONE_SHOT[0][3]
    other_nodes = nodes.copy()
    other_nodes[0] += 0.25
    deform(vol, other_nodes, tets, moved, device="cpu", out_grid=vol)
    assert R._ONE_SHOT[0][3] is not cached
    cached = R._ONE_SHOT[0][3]
    deform(vol, other_nodes, tets, moved, device="cpu", out_grid=vol, culling="bbox")
    assert R._ONE_SHOT[0][3] is not cached
    # Data edited in place (and a new minimum, the default background) show in the next call.
    vol.data[...] = vol.data[::-1]
    vol.data[0, 0, 0] = -5
    again = deform(vol, other_nodes, tets, moved, device="cpu", out_grid=vol, culling="bbox").data
    fresh = Rasterizer(vol, other_nodes, tets, culling="bbox", device="cpu").deform(moved, vol).data
    np.testing.assert_array_equal(again, fresh)
