"""Off-screen volume rendering checked against geometry, not against captured output.

A sphere of radius ``R`` rendered with an orthographic camera and an opaque, unshaded
transfer function must appear as a disc of radius ``R * ppu`` pixels (``ppu`` = pixels per
world unit = ``height / (2 * parallel_scale)``).

Tolerance on the disc area: each rim pixel is classified by its centre, and the sampled
sphere surface (the 0.5 level of trilinear interpolation between voxel centres inside
and outside ``R``) lies within half a voxel of ``R``. With one voxel <= one pixel (the
finer axes) that moves the rim by at most ~1 px, so the area may be off by the rim
length times 1 px: ``|A - pi r^2| <= 2 pi r * 1 px``, i.e. a relative ``2 / r``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.render import Camera, VolumeRenderer, render_volume
from softvr.volume import Volume

W = H = 128
PPU = 2.0  # pixels per world unit (mm)
RADIUS = 15.0  # mm -> 30 px
SPACING = (0.5, 0.5, 1.0)  # anisotropic: the disc is round only if spacing is honoured
SHAPE = (72, 72, 36)
ORTHO = Camera("front", parallel=True, parallel_scale=H / (2 * PPU), focal_point=(0.0, 0.0, 0.0))

# OSMesa is checked in a subprocess: VTK cannot mix it with the viewer's X window in
# one process (see softvr.render._backend), and the viewer tests run in this one.
CONFIGS = [("cpu", "egl"), ("gpu", "egl")]


def foreground(image: np.ndarray) -> np.ndarray:
    return image.mean(axis=2) > 127


def centroid(mask: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    return np.array([cols.mean(), rows.mean()])  # (x right, y down) in pixels


@pytest.mark.parametrize(("mapper", "backend"), CONFIGS)
def test_sphere_is_a_disc_of_the_right_area(mapper, backend, make_sphere, opaque_preset):
    vol = make_sphere(RADIUS, SPACING, SHAPE)
    with VolumeRenderer(W, H, opaque_preset, ORTHO, mapper=mapper, backend=backend) as renderer:
        assert renderer.backend == backend and renderer.mapper == mapper
        image = renderer.render(vol)
    assert image.shape == (H, W, 3) and image.dtype == np.uint8
    mask = foreground(image)
    r_px = RADIUS * PPU
    expected = np.pi * r_px**2
    tolerance = 2 * np.pi * r_px * 1.0  # rim length x 1 px
    assert abs(mask.sum() - expected) <= tolerance, (mask.sum(), expected, tolerance)
    # Round (x and z extents agree although z voxels are twice as long) and centred.
    rows, cols = np.nonzero(mask)
    assert abs((cols.max() - cols.min()) - (rows.max() - rows.min())) <= 2
    assert np.allclose(centroid(mask), [(W - 1) / 2, (H - 1) / 2], atol=1.0)
    # Everything outside the disc (plus a 2 px rim) is background.
    yy, xx = np.mgrid[:H, :W]
    far = np.hypot(xx - (W - 1) / 2, yy - (H - 1) / 2) > r_px + 2
    assert not mask[far].any()


@pytest.mark.parametrize(("mapper", "backend"), [("cpu", "egl"), ("gpu", "egl")])
def test_translating_the_origin_moves_the_disc(mapper, backend, make_sphere, opaque_preset):
    d = np.array([3.0, -5.0, 2.0])  # mm; y is the viewing direction: no image motion
    with VolumeRenderer(W, H, opaque_preset, ORTHO, mapper=mapper, backend=backend) as renderer:
        c0 = centroid(foreground(renderer.render(make_sphere(RADIUS, SPACING, SHAPE))))
        moved = make_sphere(RADIUS, SPACING, SHAPE)
        moved.origin = moved.origin + d
        c1 = centroid(foreground(renderer.render(moved)))  # same renderer: camera stays put
    # Front view: world +x is screen left, world +z is screen up (rows grow downwards).
    expected = np.array([-d[0], -d[2]]) * PPU
    assert np.allclose(c1 - c0, expected, atol=1.0), (c1 - c0, expected)


def test_osmesa_backend_renders_the_same_disc():
    script = textwrap.dedent(
        f"""
        import json, sys
        import numpy as np
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from conftest import OPAQUE, sphere_volume
        from softvr.render import Camera, RenderBackendError, VolumeRenderer
        from softvr.render._backend import new_onscreen_window
        cam = Camera("front", parallel=True, parallel_scale={H / (2 * PPU)}, focal_point=(0.0, 0.0, 0.0))
        with VolumeRenderer({W}, {H}, OPAQUE, cam, backend="osmesa") as r:
            image = r.render(sphere_volume({RADIUS}, {SPACING}, {SHAPE}))
            backend = r.backend
        try:
            new_onscreen_window(8, 8)
            mixed = "allowed"
        except RenderBackendError as e:
            mixed = str(e)
        print(json.dumps({{"backend": backend, "area": int((image.mean(axis=2) > 127).sum()), "mixed": mixed}}))
        """
    )
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["backend"] == "osmesa"
    r_px = RADIUS * PPU
    assert abs(result["area"] - np.pi * r_px**2) <= 2 * np.pi * r_px
    assert "same process" in result["mixed"]


def test_shape_and_spacing_may_change_between_frames(make_sphere, opaque_preset):
    with VolumeRenderer(W, H, opaque_preset, ORTHO) as renderer:
        a = foreground(renderer.render(make_sphere(RADIUS, SPACING, SHAPE))).sum()
        b = foreground(renderer.render(make_sphere(RADIUS / 2, (0.25, 0.5, 0.5), (80, 40, 40)))).sum()
    assert abs(b - a / 4) <= 2 * np.pi * RADIUS * PPU / 2


def test_direction_matrix_rotates_the_volume(opaque_preset):
    data = np.zeros((40, 10, 10), np.float32)
    data[2:-2, 2:-2, 2:-2] = 1.0  # a bar along the volume's i axis
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # i -> world +y
    cam = Camera("front", parallel=True, parallel_scale=25.0, focal_point=(0.0, 0.0, 0.0))
    origin = -np.array([19.5, 4.5, 4.5])
    with VolumeRenderer(100, 100, opaque_preset, cam) as renderer:
        plain = foreground(renderer.render(Volume(data, origin=origin)))
        turned = foreground(renderer.render(Volume(data, origin=rot @ origin, direction=rot)))
    rows, cols = np.nonzero(plain)
    assert np.ptp(cols) > 3 * np.ptp(rows)  # the bar lies across the screen
    rows, cols = np.nonzero(turned)
    assert abs(np.ptp(cols) - np.ptp(rows)) <= 2  # now it points at the camera: a square


@pytest.mark.parametrize("view", ["front", "side", "top", "iso"])
def test_views_frame_the_volume(view, phantom):
    image = render_volume(phantom, 80, 60, preset="ct", camera=Camera(view, azimuth=10, elevation=5))
    mask = image.max(axis=2) > 20
    assert 0.05 < mask.mean() < 0.9  # something visible, not cropped to the full frame
    assert not mask[0].any() and not mask[-1].any()  # fitted with a margin


def test_presets_give_their_colours(phantom):
    ct = render_volume(phantom, 64, 48, preset="ct", camera="front")
    assert ct.max() > 150  # bone is bright
    mri = Volume(np.clip(phantom.data // 6 + 40, 0, 255).astype(np.uint8), phantom.spacing, phantom.origin)
    grey = render_volume(mri, 64, 48, preset="auto")
    fg = grey[grey.max(axis=2) > 20].astype(int)
    assert len(fg) and np.abs(fg[:, 0] - fg[:, 2]).max() <= 3  # MRI preset is grey
    labels = np.zeros((20, 20, 20), np.uint8)
    labels[2:10, 2:18, 2:18] = 1
    labels[10:18, 2:18, 2:18] = 2
    img = render_volume(Volume(labels, is_label=True), 64, 48, preset="auto", camera="front")
    colours = {tuple(c) for c in img.reshape(-1, 3)[img.reshape(-1, 3).max(axis=1) > 60] // 64}
    assert len(colours) >= 2  # two labels, two hues


def test_camera_stays_fixed_until_reset(phantom):
    with VolumeRenderer(64, 48, "ct", "front") as renderer:
        renderer.render(phantom)
        pos = renderer.vtk_camera.GetPosition()
        moved = Volume(phantom.data, phantom.spacing, phantom.origin + 30.0)
        renderer.render(moved)
        assert renderer.vtk_camera.GetPosition() == pos
        renderer.reset_camera()
        renderer.render(moved)
        assert np.allclose(np.subtract(renderer.vtk_camera.GetPosition(), pos), 30.0)


def test_bad_input_is_reported():
    with pytest.raises(InputError, match="preset"):
        VolumeRenderer(16, 16, preset="xray")
    with pytest.raises(InputError, match="Camera.view"):
        Camera("diagonal")
    with VolumeRenderer(16, 16) as renderer:
        with pytest.raises(InputError, match="at least 2 voxels"):
            renderer.render(Volume(np.zeros((4, 4, 1), np.int16)))
        with pytest.raises(InputError, match="Volume"):
            renderer.render(np.zeros((4, 4, 4)))
