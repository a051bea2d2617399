"""A fixed scene compared with a stored reference image (catches look regressions).

The scene: the 40^3 CT phantom of ``conftest.ct_phantom`` with the ``"ct"`` preset from
the ``"iso"`` view, next to a three-label volume with the ``"labels"`` preset from the
``"front"`` view, each 160 x 120 px, side by side (``contact_sheet``, no labels).

Tolerance: mean absolute difference <= 2.0 grey levels over all pixels and channels,
and fewer than 1 % of pixels off by more than 48. The default CPU ray caster
(``vtkFixedPointVolumeRayCastMapper``) computes the image on the CPU in VTK's own code,
so different OpenGL drivers give (nearly) identical images; the tolerance absorbs
rounding changes between VTK releases, while a changed preset, camera or geometry
moves far more pixels than that.

Regenerate the reference after an intended change of look, then inspect it:

    SOFTVR_UPDATE_REFERENCE=1 .venv/bin/python -m pytest tests/render/test_render_reference.py
"""

from __future__ import annotations

import os
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from softvr.render import Camera, VolumeRenderer, contact_sheet, save_png
from softvr.volume import Volume

REFERENCE = Path(__file__).parent / "reference" / "phantom_ct_iso_labels_front.png"
MEAN_ABS_TOLERANCE = 2.0
BIG_DIFF, BIG_DIFF_FRACTION = 48, 0.01


def label_phantom() -> Volume:
    n = 32
    x, y, z = np.meshgrid(*(np.arange(n) - (n - 1) / 2,) * 3, indexing="ij")
    r = np.sqrt(x**2 + y**2 + z**2)
    data = np.zeros((n, n, n), np.uint8)
    data[r < 14] = 1
    data[(r < 14) & (x > 3)] = 2
    data[r < 6] = 3
    return Volume(data, spacing=(1.0, 1.0, 1.0), origin=(-15.5, -15.5, -15.5), is_label=True)


def render_scene(phantom: Volume) -> np.ndarray:
    with VolumeRenderer(160, 120, "ct", Camera("iso")) as renderer:
        ct = renderer.render(phantom)
    with VolumeRenderer(160, 120, "labels", Camera("front", elevation=20)) as renderer:
        labels = renderer.render(label_phantom())
    return contact_sheet([ct, labels], columns=2, gap=0)


def test_scene_matches_reference(phantom):
    image = render_scene(phantom)
    if os.environ.get("SOFTVR_UPDATE_REFERENCE"):
        save_png(image, REFERENCE)
        pytest.skip(f"reference rewritten: {REFERENCE}")
    reference = iio.imread(REFERENCE)
    assert reference.shape == image.shape
    diff = np.abs(image.astype(np.int16) - reference.astype(np.int16))
    assert diff.mean() <= MEAN_ABS_TOLERANCE, f"mean |difference| {diff.mean():.2f} > {MEAN_ABS_TOLERANCE}"
    assert (diff.max(axis=2) > BIG_DIFF).mean() < BIG_DIFF_FRACTION
    # The reference is not blank: both panels show something.
    assert reference[:, :160].max() > 150 and reference[:, 160:].max() > 100
