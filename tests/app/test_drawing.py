"""What the player's views draw: a body lying on a plane is drawn over the plane (no z-fighting),
and the live window's collision layer (``k``) frames the bodies when it starts with the render
surfaces hidden.

Truths: a surface in front of or on a plane covers, in the image, exactly the pixels it covers
with no plane behind it (the depth test decides nothing else); the collision surface of a body
is its drawn shape here, so its edges span the part of the image the camera fits the body into.
"""

import numpy as np
import pytest

from softvr.app import play_window
from softvr.render.surfaces import SurfaceRenderer
from softvr.scene import load_scene

SQUARE = np.array([[-0.3, -0.3, 0.0], [0.3, -0.3, 0.0], [0.3, 0.3, 0.0], [-0.3, 0.3, 0.0]])


def _red_pixels(lift: float, elevation: float, plane: bool) -> int:
    """Red pixels of a red square [m] at height ``lift`` [m] over a blue ground plane at z = 0
    (or over nothing), seen from ``elevation`` [deg] above the horizon."""
    with SurfaceRenderer(160, 120, camera="front", bounds=(-0.5, 0.5, -0.5, 0.5, -0.05, 0.05),
                         antialias=False) as r:
        if plane:
            r.add_plane(size=2.0, tiles=1, color=(0.2, 0.2, 0.9))
        r.add_mesh(SQUARE + (0.0, 0.0, lift), [[0, 1, 2], [0, 2, 3]], color=(1.0, 0.0, 0.0))
        r.set_camera(elevation=elevation)
        image = r.render().astype(int)
    return int((image[..., 0] > 2 * image[..., 2]).sum())


@pytest.mark.parametrize("elevation", [10.0, 30.0, 80.0])
@pytest.mark.parametrize("lift", [0.0, -1e-4])
def test_a_body_lying_on_a_plane_is_drawn_over_it(lift, elevation):
    """On the plane (lift 0) or sunk into it by what a resting contact overlaps (g dt^2 = 0.1 mm
    at dt = 3 ms), the square is drawn whole: as many red pixels as with no plane at all. Without
    the plane's depth offset a grazing view shows ~15 % of it as plane, and a sunk one none."""
    alone = _red_pixels(lift, elevation, plane=False)
    assert alone > 500
    assert _red_pixels(lift, elevation, plane=True) == alone


def test_the_collision_layer_alone_frames_the_bodies(display, tmp_path):
    """``softvr view SCENE --hide render --show collision``: a scene without render bounds, its
    render surfaces hidden from the start; the camera still fits the body, whose collision
    edges (cyan) then span over a third of the window's width (fitted into it with a 5 %
    margin, a 10 cm cube seen from the front fills most of it)."""
    scene = tmp_path / "cube.toml"
    scene.write_text('format = "softvr-scene 1"\n[simulation]\ndt = 0.01\nsteps_per_frame = 1\nframes = 2\n'
                     'gravity = [0.0, 0.0, 0.0]\n[render]\nsize = [160, 120]\ncamera = "front"\n'
                     '[material.gel]\nyoung = 1e4\npoisson = 0.3\ndensity = 1000.0\n'
                     '[[body]]\nname = "cube"\ntype = "fem"\nbox = [0.1, 0.1, 0.1]\ncells = 2\nmaterial = "gel"\n')
    shot = tmp_path / "shot.png"
    with load_scene(scene) as player:
        play_window(player, timeout_s=2.0, screenshot=shot, overlays=("collision",))
    import imageio.v3 as iio

    image = iio.imread(shot)[..., :3].astype(int)
    cyan = (image[..., 2] > 180) & (image[..., 1] > 150) & (image[..., 0] < 150)
    columns = np.flatnonzero(cyan.any(axis=0))
    assert len(columns) and columns[-1] - columns[0] > image.shape[1] / 3, columns
