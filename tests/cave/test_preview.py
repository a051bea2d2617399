"""The desktop preview unfolds a display like a polyhedron's net.

Truths: a hinge keeps the shared edge fixed, so an unfolded neighbour's corners on that edge
coincide with the placed screen's and the rest lies on the far side at the screen's own size;
the RAVE's screens are 3.75 x 3.12 m (the floor 3.75 x 3.75); tiles of a wall are that wall
cut in pieces, so their preview is the wall's. Layout tolerances 1e-9 m: rotations by exact
angles, rounding only. Images are compared exactly: constant colours on regions whose
boundaries fall between preview pixel centres (4 m at 16 px/m = 64 px, etc.).
"""

import numpy as np
import pytest

from softvr.cave import Display, Screen, preset, preview_image, preview_layout
from softvr.errors import InputError

W, H = 3.75, 3.12


def _check(place, origin, right, up):
    np.testing.assert_allclose(place.origin, origin, atol=1e-9)
    np.testing.assert_allclose(place.right, right, atol=1e-9)
    np.testing.assert_allclose(place.up, up, atol=1e-9)


def test_cube_walls_and_floor_adjoin_the_fronts_edges():
    """Front at the origin; the left wall opens out to x in [-3.75, 0] (its lower-right edge
    is the front's left edge), the right one to [3.75, 7.5], the floor hangs below the front's
    bottom edge (its upper edge, y in [-3.75, 0])."""
    layout = preview_layout(preset("cube"))
    _check(layout["front"], (0, 0), (W, 0), (0, H))
    _check(layout["left"], (-W, 0), (W, 0), (0, H))
    _check(layout["right"], (W, 0), (W, 0), (0, H))
    _check(layout["floor"], (0, -W), (W, 0), (0, W))
    c = {name: p.corners() for name, p in layout.items()}
    np.testing.assert_allclose(c["left"][[1, 2]], c["front"][[0, 3]], atol=1e-9)   # shared vertical edge
    np.testing.assert_allclose(c["right"][[0, 3]], c["front"][[1, 2]], atol=1e-9)
    np.testing.assert_allclose(c["floor"][[3, 2]], c["front"][[0, 1]], atol=1e-9)   # shared bottom edge


def test_amphitheatre_unfolds_into_a_flat_strip():
    """The side screens hinge at 45 degrees; unfolded they continue the front: a strip
    3 x 3.75 = 11.25 m wide and 3.12 m high, every screen upright."""
    layout = preview_layout(preset("rave-amphitheatre"))
    corners = np.concatenate([p.corners() for p in layout.values()])
    assert corners[:, 0].max() - corners[:, 0].min() == pytest.approx(3 * W, abs=1e-9)
    assert corners[:, 1].min() == pytest.approx(0.0, abs=1e-9) and corners[:, 1].max() == pytest.approx(H, abs=1e-9)
    for name, x in (("left", -W), ("front", 0.0), ("right", W)):
        _check(layout[name], (x, 0), (W, 0), (0, H))


def test_powerwall_tiles_preview_as_the_whole_wall():
    """Four constant-colour tiles give the picture of the whole 4 x 2.25 m wall showing the
    four colours in quadrants (row 0 of the tiles at the bottom): at 16 px/m, 64 x 36 pixels,
    each quadrant 32 x 18."""
    tiles = preset("powerwall-2x2")
    colours = {"wall_00": (200, 0, 0), "wall_10": (0, 200, 0), "wall_01": (0, 0, 200), "wall_11": (200, 200, 0)}
    images = {name: np.full((9, 16, 3), c, np.uint8) for name, c in colours.items()}
    tiled = preview_image(tiles, images, pixels_per_metre=16)
    whole_image = np.empty((36, 64, 3), np.uint8)
    whole_image[:18, :32], whole_image[:18, 32:] = colours["wall_01"], colours["wall_11"]
    whole_image[18:, :32], whole_image[18:, 32:] = colours["wall_00"], colours["wall_10"]
    wall = Display([Screen("wall", (-2.0, 2.0, 0.5), (2.0, 2.0, 0.5), (-2.0, 2.0, 2.75), (3840, 2160))])
    np.testing.assert_array_equal(tiled, whole_image)
    np.testing.assert_array_equal(preview_image(wall, {"wall": whole_image}, pixels_per_metre=16), tiled)
    for interpolation in ("nearest", "bilinear"):  # a constant image samples to itself either way
        again = preview_image(tiles, images, pixels_per_metre=16, interpolation=interpolation)
        np.testing.assert_array_equal(again, whole_image)


def test_cube_preview_places_and_orients_every_image():
    """Each screen shows a 2 x 2 image (its quadrants distinct). The net is 11.25 m wide (three
    walls) and 3.12 + 3.75 m high (walls over the floor): 45 x 28 px at 4 px/m. The top-left
    quadrant of each image is at its unfolded screen's upper left; beside the floor is
    background; screens without an image are grey; ``gap`` draws background inside every
    screen's border."""
    display = preset("cube")
    images = {name: np.array([[[k, 10, 0], [k, 20, 0]], [[k, 30, 0], [k, 40, 0]]], np.uint8)
              for k, name in enumerate(("left", "front", "right"), start=1)}
    ppm = 4.0
    out = preview_image(display, images, pixels_per_metre=ppm, background=(5, 5, 5), missing=(90, 90, 90))
    assert out.shape == (int(np.ceil((W + H) * ppm)), int(np.ceil(3 * W * ppm)), 3)

    def at(x, y):  # the preview pixel at layout point (x, y) [m]; the net's top is y = 3.12, its left x = -3.75
        return out[int((H - y) * ppm), int((x + W) * ppm)]

    for k, x0 in ((1, -W), (2, 0.0), (3, W)):
        np.testing.assert_array_equal(at(x0 + 0.25 * W, 0.75 * H), [k, 10, 0])   # top-left quadrant
        np.testing.assert_array_equal(at(x0 + 0.75 * W, 0.25 * H), [k, 40, 0])   # bottom-right
    np.testing.assert_array_equal(at(0.5 * W, -0.5 * W), [90, 90, 90])             # the floor, no image
    np.testing.assert_array_equal(at(-0.5 * W, -0.5 * W), [5, 5, 5])               # beside the floor
    framed = preview_image(display, images, pixels_per_metre=ppm, gap=1, background=(5, 5, 5))
    np.testing.assert_array_equal(framed[0, int(W * ppm) + 5], [5, 5, 5])  # the front's top row is border now
    np.testing.assert_array_equal(out[0, int(W * ppm) + 5], [2, 10, 0])


def test_unconnected_screens_go_to_the_right_and_bad_images_are_refused():
    """A screen sharing no edge with the others (a wall 10 m away, facing elsewhere) is laid
    right of the net, at its own size, on the root's floor line (y from 0)."""
    front = Screen("front", (-1, 1, 0), (1, 1, 0), (-1, 1, 1.5))
    apart = Screen("apart", (10, 0, 0), (10, 3, 0), (10, 0, 1), node="apart")
    layout = preview_layout(Display([front, apart]))
    _check(layout["front"], (0, 0), (2, 0), (0, 1.5))
    assert layout["apart"].origin[0] > 2.0 and layout["apart"].origin[1] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(np.linalg.norm(layout["apart"].right), 3.0, atol=1e-9)
    np.testing.assert_allclose(layout["apart"].up, (0, 1), atol=1e-9)
    display = preset("cube")
    with pytest.raises(InputError, match="a screen of the display"):
        preview_image(display, {"ceiling": np.zeros((2, 2, 3), np.uint8)})
    with pytest.raises(InputError, match="RGB uint8"):
        preview_image(display, {"front": np.zeros((2, 2), np.uint8)})
