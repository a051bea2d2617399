"""Off-axis cameras of a display against geometry and against a single wide render.

Truths: a centred eye on a symmetric screen gives the symmetric frustum of a plain
perspective camera; a world point on the seam of two cube screens projects onto the shared
edge from both (x = +1 on one, -1 on the other, the same height); a wall cut into 2 x 2 tiles
renders, tile by tile, the image of the whole wall through one frustum (up to the rasterizer's
edge pixels); corners of a screen are perpendicular or the file is refused, with every
problem named at once.
"""

import numpy as np
import pytest

from softvr.cave import Screen, frustum_matrix, load_display, preset, render_screen, screen_view, tile
from softvr.errors import InputError


def test_centred_eye_gives_the_symmetric_perspective():
    """A 2 x 1.5 m screen 1 m in front of the eye: l = -r = 1 n, b = -t = 0.75 n, i.e. the
    perspective with vertical field of view 2 atan(0.75)."""
    view = screen_view((-1, 1, -0.75), (1, 1, -0.75), (-1, 1, 0.75), (0, 0, 0), near=0.1, far=10.0)
    np.testing.assert_allclose(view.extents, (-0.1, 0.1, -0.075, 0.075), atol=1e-12)
    f = 1.0 / np.tan(np.arctan(0.75))  # gluPerspective's cot(fovy / 2)
    expected = np.array([[f / (4 / 3), 0, 0, 0], [0, f, 0, 0], [0, 0, -10.1 / 9.9, -2 / 9.9], [0, 0, -1, 0]])
    np.testing.assert_allclose(view.projection, expected, atol=1e-12)
    np.testing.assert_allclose(view.project([[1, 1, 0.75], [-1, 1, -0.75]])[:, :2], [[1, 1], [-1, -1]], atol=1e-12)


@pytest.mark.parametrize("eye", [(0.0, 0.0, 1.7), (0.6, -0.4, 1.2), (-1.1, 0.9, 2.0)])
def test_a_point_on_the_cube_seam_lands_on_the_shared_edge_from_both_screens(eye):
    display = preset("cube")
    left, front = display.screen("left"), display.screen("front")
    seam = np.asarray(front.lower_left) + 0.37 * (np.asarray(front.upper_left) - np.asarray(front.lower_left))
    on_left = left.view(eye).project(seam)[0]
    on_front = front.view(eye).project(seam)[0]
    assert on_left[0] == pytest.approx(1.0, abs=1e-9) and on_front[0] == pytest.approx(-1.0, abs=1e-9)
    assert on_left[1] == pytest.approx(on_front[1], abs=1e-9) == 2 * 0.37 - 1


def test_tiles_of_a_wall_compose_the_whole_walls_image():
    from softvr.render import SurfaceRenderer

    wall = Screen("wall", (-1.0, 2.0, 0.0), (1.0, 2.0, 0.0), (-1.0, 2.0, 1.5), (160, 120), "wall")
    eye = (0.3, 0.0, 0.9)  # off centre: every tile's frustum is asymmetric

    def scene(width, height):
        # A flat background: a gradient runs over each viewport, so tiles would differ there.
        r = SurfaceRenderer(width, height, background=(0.2, 0.2, 0.25), background_top=(0.2, 0.2, 0.25))
        for x, z, color in ((-0.5, 0.4, (0.9, 0.2, 0.2)), (0.2, 1.0, (0.2, 0.8, 0.3)), (0.6, 0.5, (0.2, 0.3, 0.9))):
            r.add_sphere((x, 3.0, z), 0.35, color=color)
        r.add_plane(point=(0.0, 0.0, 0.0), size=8.0)
        return r

    with scene(*wall.pixels) as whole:
        reference = render_screen(whole, wall, eye)
    composed = np.zeros_like(reference)
    tiles = tile(wall, 2, 2)  # row 0 at the bottom
    for t in tiles:
        i, j = int(t.name[-2]), int(t.name[-1])
        with scene(*t.pixels) as r:
            image = render_screen(r, t, eye)
        w, h = t.pixels
        rows = slice((1 - j) * h, (2 - j) * h)  # image row 0 is the top
        composed[rows, i * w:(i + 1) * w] = image
    diff = np.abs(composed.astype(int) - reference.astype(int)).max(axis=2)
    assert reference.std() > 10  # the spheres are in view
    # Equal up to edge pixels (measured: 5 of 19 200 differ by more than 8/255, at silhouettes
    # the tiles' rasterization splits differently): under 0.2 %, mean difference under 0.5/255.
    assert (diff > 8).mean() < 0.002 and diff.mean() < 0.5, ((diff > 8).mean(), diff.mean())


def test_bad_display_files_name_every_problem(tmp_path):
    path = tmp_path / "cave.toml"
    path.write_text('format = "softvr-display 1"\n'
                    '[[screen]]\nname = "front"\nlower_left = [0, 0, 0]\nlower_right = [2, 0, 0]\n'
                    'upper_left = [0.5, 0, 2]\nnode = "n1"\n'
                    '[[screen]]\nname = "left"\nlower_left = [0, 0, 0]\nlower_right = [0, 2, 0]\n'
                    'upper_left = [0, 0, 2]\nnode = "n1"\nstereo = "holographic"\n')
    with pytest.raises(InputError) as info:
        load_display(path)
    message = str(info.value)
    for fragment in ("cave.toml", "screen[0] (front).corners", "a rectangle", "screen[1].node", "'n1' twice",
                     "screen[1] (left).stereo", "holographic"):
        assert fragment in message
    front = Screen("front", (0, 0, 0), (2, 0, 0), (0, 0, 2))
    with pytest.raises(InputError, match="in front of the screen"):
        front.view((1.0, 0.0, 1.0))  # in the screen's plane
    with pytest.raises(InputError, match="preset"):
        preset("dome")


def test_presets_and_a_valid_file_load():
    for name in ("single-wall", "cube", "rave-wall", "rave-cube", "rave-amphitheatre", "powerwall-2x2"):
        d = preset(name)
        assert all(s.problems() == [] for s in d.screens)
    rave = preset("rave-amphitheatre")
    assert [s.size for s in rave.screens] == [pytest.approx((3.75, 3.12))] * 3
    left, right = rave.eyes((0, 0, 1.7), (1, 0, 0))
    np.testing.assert_allclose(right - left, [0.065, 0, 0])
    np.testing.assert_allclose(frustum_matrix(-1, 1, -1, 1, 1, 3)[2:, 2:], [[-2, -3], [-1, 0]])


def test_a_saved_display_loads_back_to_the_same_screens(tmp_path):
    from softvr.cave import save_display

    wall = preset("powerwall-2x2")
    wall.screens[0] = Screen('tile "a"', wall.screens[0].lower_left, wall.screens[0].lower_right,
                             wall.screens[0].upper_left, (640, 360), "n\\0", "anaglyph")
    path = save_display(wall, tmp_path / "wall.toml")
    again = load_display(path)
    assert again.screens == wall.screens and again.eye_separation == wall.eye_separation


# ------------------------------------------------------------------ hostile files (issue 17)
_SCREEN = ('[[screen]]\nname = "front"\nlower_left = [-1.0, 1.0, 0.0]\nlower_right = [1.0, 1.0, 0.0]\n'
           'upper_left = [-1.0, 1.0, 1.5]\npixels = [800, 600]\n')


@pytest.mark.parametrize("text, field", [
    ('screen = 3.5\n', "screen"),
    ('screen = [1, 2]\n', "screen"),
    (_SCREEN.replace("[800, 600]", '"800x600"'), "screen[0].pixels"),
    (_SCREEN.replace("[800, 600]", "[800.5, 600]"), "screen[0].pixels"),
    (_SCREEN.replace('"front"', '"' + "f" * 300 + '"'), "screen[0].name"),
    (_SCREEN.replace('"front"', '"a\\u0000b"'), "screen[0].name"),
    (_SCREEN + 'stereo = ["none"]\n', "screen[0] (front).stereo"),
    (_SCREEN.replace("[-1.0, 1.0, 0.0]", "[-1e300, 1.0, 0.0]", 1), "screen[0].lower_left"),
    (_SCREEN.replace("[800, 600]", "[16384, 16384]") * 2, "pixels"),
])
def test_a_display_file_of_the_wrong_types_or_sizes_is_refused_naming_the_field(tmp_path, text, field):
    """Truth: the requirement — an InputError naming the file and the field, never a
    TypeError / AttributeError from inside the reader."""
    path = tmp_path / "display.toml"
    path.write_text('format = "softvr-display 1"\n' + text)
    with pytest.raises(InputError) as caught:
        load_display(path)
    assert caught.value.source == str(path)
    assert field in str(caught.value), str(caught.value)


def test_a_display_file_that_is_not_utf8_or_is_a_fifo_is_refused(tmp_path):
    latin = tmp_path / "latin.toml"
    latin.write_bytes(('format = "softvr-display 1"\n' + _SCREEN.replace("front", "fr\xf6nt")).encode("latin-1"))
    with pytest.raises(InputError, match="UTF-8"):
        load_display(latin)
    import os

    os.mkfifo(tmp_path / "fifo.toml")
    with pytest.raises(InputError, match="FIFO"):
        load_display(tmp_path / "fifo.toml")


def test_two_screens_of_one_name_are_refused(tmp_path):
    """Images and views are keyed by screen name: a second screen of the same name would
    silently replace the first in a preview."""
    path = tmp_path / "display.toml"
    path.write_text('format = "softvr-display 1"\n' + _SCREEN + 'node = "a"\n' + _SCREEN + 'node = "b"\n')
    with pytest.raises(InputError, match=r"screen\[1\].name: expected a name no other screen has"):
        load_display(path)


def test_an_eye_behind_a_screen_of_a_file_names_the_file(tmp_path):
    """A screen read from a file carries it: the error its geometry causes later (an eye in
    its plane) names the file as well as the screen."""
    path = tmp_path / "display.toml"
    path.write_text('format = "softvr-display 1"\n' + _SCREEN)
    screen = load_display(path).screens[0]
    with pytest.raises(InputError) as caught:
        screen.view((0.0, 1.0, 0.5))  # in the screen's plane y = 1
    assert caught.value.source == str(path) and "front eye" in str(caught.value)
    assert screen == Screen("front", screen.lower_left, screen.lower_right, screen.upper_left, (800, 600))
