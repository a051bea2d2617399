"""The volume demo runs headless for a few frames, and its scripted deformation is valid."""

import json

import imageio.v3 as iio
import numpy as np
import pytest

from softvr.examples.example_volume_deform import Example, main, press_and_twist
from softvr.volume import Volume, grid_tet_mesh
from softvr.volume.tetmesh import tet_signed_volumes


def test_press_and_twist_never_inverts_a_tet():
    vol = Volume(np.zeros((256, 256, 108), np.int16), spacing=(0.957, 0.957, 1.5))
    nodes, tets = grid_tet_mesh(vol, (16, 16, 8))
    bounds = np.stack([nodes.min(0), nodes.max(0)])
    rest = tet_signed_volumes(nodes, tets)
    nose = np.array([120.6, 232.6, 34.5])  # the head CT's most anterior tissue voxel
    for point in (None, nose):
        for s in np.linspace(0, 1, 11):
            moved = press_and_twist(nodes, bounds, s, point)
            ratio = tet_signed_volumes(moved, tets) / rest
            assert ratio.min() > 0.3, (point, s)
    # The finger pushes the pressed point in -y by 12 % of the extent at full press.
    node = np.argmin(np.linalg.norm(nodes - nose, axis=1))
    dent = press_and_twist(nodes, bounds, 0.5, nodes[node])[node] - nodes[node]
    assert np.allclose(dent, [0.0, -0.12 * (bounds[1, 1] - bounds[0, 1]), 0.0])
    assert np.allclose(press_and_twist(nodes, bounds, 0.0), nodes)
    # The twist is a rotation about z: the top ring turns by 35 degrees, the bottom not at all.
    full = press_and_twist(nodes, bounds, 1.0)
    dented = press_and_twist(nodes, bounds, 0.5)
    top = np.isclose(nodes[:, 2], bounds[1, 2])
    centre = (bounds[0, :2] + bounds[1, :2]) / 2
    a0 = np.arctan2(*(dented[top, 1::-1] - centre[::-1]).T)
    a1 = np.arctan2(*(full[top, 1::-1] - centre[::-1]).T)
    assert np.allclose(np.degrees(np.angle(np.exp(1j * (a1 - a0)))), 35.0, atol=1e-6)


def test_example_steps_and_renders(device):
    rng = np.random.default_rng(0)
    vol = Volume((rng.random((40, 40, 24)) * 2000 - 1000).astype(np.int16), spacing=(1.0, 1.0, 1.5))
    ex = Example(vol, cells=(4, 4, 2), frames=3, device=device, width=96, height=72)
    try:
        for _ in range(3):
            out = ex.step()
            assert out.dtype == np.int16
            img = ex.render()
            assert img.shape == (72, 96, 3)
        assert ex.metrics[0]["voxels_written"] == vol.data.size  # frame 0 is the rest shape
    finally:
        ex.close()


@pytest.mark.slow
def test_demo_main_on_the_real_head_ct(tmp_path):
    rc = main(["--frames", "3", "--out", str(tmp_path), "--size", "160", "120", "--cells", "8", "8", "4", "--device", "cpu",
               "--quiet"])
    assert rc == 0
    frames = list(iio.imiter(tmp_path / "volume.mp4"))
    assert len(frames) == 3
    sheet = iio.imread(tmp_path / "volume_sheet.png")
    assert sheet.ndim == 3 and sheet.shape[2] == 3
    stats = json.loads((tmp_path / "volume_metrics.json").read_text())
    assert stats["tets"] == 5 * 8 * 8 * 4 and len(stats["frames"]) == 3
    assert all(f["voxels_written"] > 1e6 for f in stats["frames"])
