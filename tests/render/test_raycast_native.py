"""The ray caster's CPU fast path (``_raycast_native``, C++) against the Warp kernel it ports,
which stays the reference (and the CUDA path): both evaluate every float expression in the
same order without FMA contraction, so the images and the state carried from frame to frame
(each pixel's known-empty prefix ``_empty_until``, first sample read ``_read_from`` and
sample segment) must be equal bit for bit, not merely close.

* Full casts of the head CT with the palpation trainer's view: both CT presets and a sawtooth
  one (``ct-skin``'s opacities, colour and gradient-opacity tables alternating entry by entry, so
  that a value or gradient one ulp off shows in a byte: a deliberately wrong native lerp order,
  ``value * scale - lo * scale`` for ``(value - lo) * scale``, fails it in 19 bytes and ``ct-skin``
  in one), each with shading on and off, gradient opacity on and off, smoothing across the
  thick slices on and off, the ray starts jittered and not.
* Incremental frames (the pattern of test_raycast's): a ball dented deeper frame by frame with
  a probe following the dent, a change hidden behind the skin and the probe withdrawn; each
  frame cast once by each path from the same state, which also picks the rays to cast again
  (the brick update, the changed bricks, the distance passes and the pixel marks in C++ or in
  Warp): the same count.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from softvr.datasets import HEAD_CT_PATH, head_ct
from softvr.render import PRESETS, Camera, Preset, VolumeRenderer
from softvr.render import raycast as R
from softvr.volume import Volume
from tests.render.test_raycast import _sphere_actor


def _state(renderer: VolumeRenderer) -> dict[str, np.ndarray]:
    """The caster's per-pixel state carried to the next frame, and how many rays it cast (a ray
    cast needlessly gives the same colour and state: the count shows it)."""
    caster = renderer.ray_caster
    return {"empty_until": caster._empty_until.numpy(), "read_from": caster._read_from.numpy(),
            "segment_start": caster._segments[0].numpy(), "segment_end": caster._segments[1].numpy(),
            "cast_pixels": np.array([caster.cast_pixels])}


def _render(renderer: VolumeRenderer, volume, native: bool, **kwargs):
    """The image and state of one frame cast by the C++ path (``native``) or the Warp kernel."""
    renderer.ray_caster.native = native
    image = renderer.render(volume, **kwargs)
    return image, _state(renderer)


def _assert_same(a, b, label):
    assert np.array_equal(a[0], b[0]), (label, "image", int((a[0] != b[0]).sum()))
    for key in a[1]:
        # Bit for bit: compare the float arrays' bytes (NaN-safe, -0.0 != 0.0).
        assert a[1][key].tobytes() == b[1][key].tobytes(), (label, key)


def _sawtooth(preset: Preset) -> Preset:
    """``preset`` with its colour table's entries alternating between two colours and its gradient
    opacity table's between 0.2 and 1: a colour is the lerp of two neighbouring entries, so a value
    or gradient length one ulp off moves a pixel by ~0.02 grey level and its rounding often enough
    to be seen in a frame (with smooth tables a difference that small seldom changes a byte)."""
    points = [p[0] for p in preset.colors] + [p[0] for p in preset.opacities]
    values = np.linspace(min(points), max(points), R.LUT_SIZE)
    colors = tuple((v, float(i % 2), float((i + 1) % 2), 0.5) for i, v in enumerate(values))
    return dataclasses.replace(preset, colors=colors,
                               gradient_opacities=tuple((float(g), 0.2 + 0.8 * (g % 2)) for g in range(256)))


@pytest.mark.skipif(not HEAD_CT_PATH.exists(), reason="head CT (Debian invesalius-examples) not installed")
@pytest.mark.parametrize("name", ["ct-skin", "ct", "sawtooth"])
def test_native_cast_of_the_head_ct_equals_the_warp_kernel(name, head):
    cam = Camera("front", azimuth=-40.0, elevation=5.0, zoom=1.3)  # the palpation trainer's view
    base = _sawtooth(PRESETS["ct-skin"]) if name == "sawtooth" else PRESETS[name]
    ramp = base.gradient_opacities or ((0, 0.15), (80, 1.0))
    for shade, gradient, smooth, jitter in itertools.product((True, False), repeat=4):
        preset = dataclasses.replace(base, shade=shade, gradient_opacities=ramp if gradient else None)
        label = (name, shade, gradient, smooth, jitter)
        casts = []
        for native in (True, False):
            with VolumeRenderer(96, 96, preset, cam, mapper="warp") as renderer:
                renderer.ray_caster.smooth_slices = smooth
                renderer.ray_caster.jitter = jitter
                casts.append(_render(renderer, head, native))
        _assert_same(*casts, label)
        assert (casts[0][0].max(axis=2) > 20).mean() > 0.2, label  # the head fills the frame


def test_native_incremental_frames_equal_the_warp_kernel():
    cam = Camera("front", azimuth=-30.0, elevation=10.0, zoom=1.2)
    n, size = 48, 96
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1)
    data = np.where(np.linalg.norm(ijk - 23.5, axis=-1) < 14.0, 40, -1000).astype(np.int16)
    vol = Volume(data, spacing=(1.0, 1.0, 1.5), origin=(-23.5,) * 3)  # thick slices: smoothed shading
    tip = np.array([23.5, 23.5 + 14.0, 23.5])
    radius = 3.0
    frames = []
    for depth in (1.0, 2.0, 3.0, 4.0):
        centre = tip + (radius - depth) * np.array([0.0, 1.0, 0.0])
        lo, hi = np.floor(centre - radius).astype(int), np.ceil(centre + radius).astype(int)
        frames.append((centre, (lo, hi)))
    renderers = [VolumeRenderer(size, size, "ct", cam, mapper="warp") for _ in range(2)]
    probes = [_sphere_actor(tip + (radius + 1.0) * np.array([0.0, 1.0, 0.0]) - 23.5, radius) for _ in renderers]
    try:
        for renderer, probe in zip(renderers, probes):
            renderer.vtk_renderer.AddActor(probe)
        _assert_same(*(_render(r, vol, native) for r, native in zip(renderers, (True, False))), "first")
        cast = []
        for centre, (lo, hi) in frames:
            region = tuple(slice(a, b + 1) for a, b in zip(lo, hi))
            data[region][np.linalg.norm(ijk[region] - centre, axis=-1) < radius] = -1000
            for probe in probes:
                probe.SetPosition(*(centre - 23.5 - probe.GetCenter() + probe.GetPosition()))
            _assert_same(*(_render(r, vol, native, changed=(lo, hi))
                           for r, native in zip(renderers, (True, False))), centre)
            cast.append(renderers[0].ray_caster.cast_pixels)
        data[20:28, 20:28, 20:28] = 1200  # behind the skin
        _assert_same(*(_render(r, vol, native, changed=((20, 20, 20), (27, 27, 27)))
                       for r, native in zip(renderers, (True, False))), "hidden")
        for probe in probes:
            probe.SetPosition(*(np.array(probe.GetPosition()) + (0.0, 5.0, 0.0)))
        _assert_same(*(_render(r, vol, native, changed=False)
                       for r, native in zip(renderers, (True, False))), "withdrawn")
        assert all(0 < c < size * size for c in cast), cast  # incremental: a part of the frame cast
    finally:
        for renderer in renderers:
            renderer.close()


@pytest.fixture(scope="module")
def head():
    return head_ct()
