"""The palpation trainer's frame of the head CT compared with a stored golden image
(catches look regressions of the Warp ray caster; the correctness truths are in
``test_raycast.py``).

The scene: the head CT at rest, the trainer's ``ct-skin`` preset, camera (front, azimuth -40,
elevation 5, zoom 1.3) and sample distance (1 voxel), 128 x 128 px, ``mapper="warp"``.
Tolerance as in ``test_render_reference.py``: mean absolute difference <= 2.0 grey levels,
fewer than 1 % of pixels off by more than 48. The jitter is a hash of the pixel, so the image
is deterministic; the tolerance absorbs floating-point differences between compilers and
devices, while a changed preset, camera, shading or sampling moves far more pixels.

Regenerate after an intended change of look, then inspect it:

    SOFTVR_UPDATE_REFERENCE=1 .venv/bin/python -m pytest tests/render/test_raycast_reference.py
"""

from __future__ import annotations

import os
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from softvr.datasets import HEAD_CT_PATH
from softvr.render import Camera, VolumeRenderer, save_png

REFERENCE = Path(__file__).parent / "reference" / "palpation_frame_warp.png"


@pytest.mark.skipif(not HEAD_CT_PATH.exists(), reason="head CT (Debian invesalius-examples) not installed")
def test_palpation_frame_matches_golden_image():
    from softvr.datasets import head_ct

    cam = Camera("front", azimuth=-40.0, elevation=5.0, zoom=1.3)
    with VolumeRenderer(128, 128, "ct-skin", cam, mapper="warp", sample_distance=1.0) as renderer:
        image = renderer.render(head_ct())
    if os.environ.get("SOFTVR_UPDATE_REFERENCE"):
        save_png(image, REFERENCE)
        pytest.skip(f"reference rewritten: {REFERENCE}")
    diff = np.abs(image.astype(int) - iio.imread(REFERENCE)[..., :3].astype(int))
    assert diff.mean() <= 2.0 and (diff.max(axis=2) > 48).mean() < 0.01, (diff.mean(), (diff.max(axis=2) > 48).mean())
