"""Stereo pairs of a screen against the geometry of parallax.

Truths: two eyes a separation ``e`` apart, both at distance ``d`` from a screen, see a point
at distance ``D`` (along the screen's normal) at screen positions ``e (D - d) / D`` apart,
horizontally, whatever the point's lateral offset (similar triangles); a point in the screen's
plane (D = d) has zero parallax. The screen here is 0.6 x 0.45 m drawn on 96 x 72 pixels
(160 px/m), so a parallax of ``p`` metres is ``160 p`` pixels and ``2 p / 0.6`` in NDC.
"""

import numpy as np
import pytest

from softvr.cave import HeadPose, Screen, render_screen, render_stereo
from softvr.cave.stereo import _render_into_stereo_buffers
from softvr.cave.rig import world_view
from softvr.errors import InputError

SCREEN = Screen("s", (-0.3, 0.6, 1.475), (0.3, 0.6, 1.475), (-0.3, 0.6, 1.925), (96, 72))
HEAD = HeadPose((0.0, 0.0, 1.7))  # 0.6 m in front of the screen's centre
SEPARATION = 0.065
PX_PER_M = 160.0


@pytest.mark.parametrize("lateral", [(0.0, 0.0), (0.4, -0.3), (-2.0, 1.1)])
def test_parallax_is_separation_times_depth_ratio(lateral):
    """NDC x of the right eye minus the left: 2 e (D - d) / (D w); NDC y equal. Points in the
    screen plane, behind it and in front of it (negative, crossed parallax). Tolerance 1e-12:
    rounding only."""
    left, right = (SCREEN.view(e) for e in HEAD.eyes(SEPARATION))
    d = 0.6
    for depth in (0.6, 1.0, 3.0, 25.0, 0.3):
        scale = depth / d  # keep the point in the screen's field for the lateral offsets
        point = np.array([lateral[0] * scale * 0.1, depth, 1.7 + lateral[1] * scale * 0.1])
        a, b = left.project(point)[0], right.project(point)[0]
        parallax = SEPARATION * (depth - d) / depth  # [m] on the screen
        assert b[0] - a[0] == pytest.approx(2 * parallax / 0.6, abs=1e-12)
        assert b[1] == pytest.approx(a[1], abs=1e-12)


def _scene():
    from softvr.render import SurfaceRenderer

    r = SurfaceRenderer(96, 72, background=(0.2, 0.2, 0.2), background_top=(0.2, 0.2, 0.2), antialias=False)
    r.add_sphere((-0.1, 0.6, 1.62), 0.03, color=(1.0, 0.0, 0.0))  # centred in the screen's plane
    r.add_sphere((0.5, 6.0, 2.3), 0.3, color=(0.0, 1.0, 0.0))  # D = 6 m
    return r


def _column(image, channel):
    """Mean column [px] of the pixels where ``channel`` dominates (the sphere of that colour)."""
    others = [c for c in range(3) if c != channel]
    mask = image[:, :, channel].astype(int) > image[:, :, others].max(axis=2).astype(int) + 40
    assert mask.sum() > 20, "the sphere is in view"
    return np.nonzero(mask)[1].mean()


def test_rendered_parallax_matches_the_prediction():
    """Side-by-side halves: the sphere in the screen plane sits at the same column in both
    (0 px), the sphere 6 m away is 0.065 * (6 - 0.6) / 6 * 160 = 9.36 px further right in the
    right eye's image. Tolerance 1 px: each centroid is of a rasterized disc (about 70 pixels
    for both spheres, edge quantization well under 0.5 px each) and the image of a sphere is an
    ellipse whose centre is off the projected centre by (r / D)^2 of its offset (< 0.01 px here)."""
    with _scene() as r:
        pair = render_stereo(r, SCREEN, HEAD, SEPARATION, "side-by-side")
    assert pair.shape == (72, 192, 3)
    left, right = pair[:, :96], pair[:, 96:]
    assert _column(right, 0) - _column(left, 0) == pytest.approx(0.0, abs=1.0)
    predicted = SEPARATION * (6.0 - 0.6) / 6.0 * PX_PER_M
    assert _column(right, 1) - _column(left, 1) == pytest.approx(predicted, abs=1.0)


def test_modes_are_made_of_the_per_eye_renders():
    """Side-by-side is [left | right]; the anaglyph is the left render's red and the right
    render's green and blue, exactly; "none" is the head's mono render; the quad-buffer path's
    per-eye camera swap, run one eye at a time (VTK's Left / Right stereo types work
    off-screen), draws exactly the per-eye renders. Renders are deterministic, so equality is
    exact."""
    eyes = HEAD.eyes(SEPARATION)
    with _scene() as r:
        left, right = (render_screen(r, SCREEN, e) for e in eyes)
        mono = render_screen(r, SCREEN, HEAD.position)
        np.testing.assert_array_equal(render_stereo(r, SCREEN, HEAD, SEPARATION, "side-by-side"),
                                      np.concatenate([left, right], axis=1))
        anaglyph = render_stereo(r, SCREEN, HEAD, SEPARATION, "anaglyph")
        np.testing.assert_array_equal(anaglyph[:, :, 0], left[:, :, 0])
        np.testing.assert_array_equal(anaglyph[:, :, 1:], right[:, :, 1:])
        np.testing.assert_array_equal(render_stereo(r, SCREEN, HEAD, SEPARATION, "none"), mono)
        views = [world_view(SCREEN, e) for e in eyes]
        np.testing.assert_array_equal(_render_into_stereo_buffers(r, *views, "Left"), left)
        np.testing.assert_array_equal(_render_into_stereo_buffers(r, *views, "Right"), right)
        assert (left != right).any()


def test_quad_buffer_needs_a_stereo_window():
    """Off-screen renderers have no stereo buffers: the error says what is needed and names the
    alternatives; unknown modes and separations are refused."""
    with _scene() as r:
        with pytest.raises(InputError) as info:
            render_stereo(r, SCREEN, HEAD, SEPARATION, "quad-buffer")
        message = str(info.value)
        for fragment in ("quad-buffer", "stereo-capable on-screen", "side-by-side", "anaglyph", "off-screen"):
            assert fragment in message
        with pytest.raises(InputError, match="stereo mode"):
            render_stereo(r, SCREEN, HEAD, SEPARATION, "interlaced")
        with pytest.raises(InputError, match="separation"):
            render_stereo(r, SCREEN, HEAD, -0.01, "anaglyph")
