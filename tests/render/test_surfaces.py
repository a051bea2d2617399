"""Off-screen surface rendering checked against geometry computed by hand.

Truths: an orthographic camera with parallel scale s shows ``height / (2 s)`` pixels per world
unit, so a unit square facing it covers that many pixels squared (each edge may land up to
1 px off: between (L - 2)^2 and (L + 2)^2 pixels); moving the mesh by d moves its pixel
centroid by d times that scale; a tet mesh's boundary is closed and outward (its enclosed
volume by the divergence theorem equals the sum of the tet volumes).
"""

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.render import Camera, SurfaceRenderer

W, H = 200, 160
SCALE = 1.0  # half the image height in world units
PPU = H / (2 * SCALE)  # 80 pixels per metre
BLACK = dict(background=(0, 0, 0), background_top=(0, 0, 0), antialias=False)

# A unit square in the x-z plane centred on the origin, facing +y (the "front" camera).
SQUARE = np.array([[-0.5, 0, -0.5], [0.5, 0, -0.5], [0.5, 0, 0.5], [-0.5, 0, 0.5]], float)
SQUARE_TRIS = np.array([[0, 2, 1], [0, 3, 2]])  # normal +y, towards the camera


def ortho_front():
    return Camera("front", parallel=True, parallel_scale=SCALE, focal_point=(0.0, 0.0, 0.0))


def covered(image: np.ndarray) -> np.ndarray:
    return image.max(axis=2) > 15


def centroid(mask: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    return np.array([cols.mean(), rows.mean()])


def test_unit_square_covers_its_area_in_pixels():
    with SurfaceRenderer(W, H, ortho_front(), **BLACK) as r:
        r.add_mesh(SQUARE, SQUARE_TRIS, color=(1, 1, 1))
        mask = covered(r.render())
    side = PPU * 1.0
    assert (side - 2) ** 2 <= mask.sum() <= (side + 2) ** 2
    rows, cols = np.nonzero(mask)
    assert abs((cols.max() - cols.min() + 1) - side) <= 2 and abs((rows.max() - rows.min() + 1) - side) <= 2
    # Centred in the image (the focal point is the origin).
    np.testing.assert_allclose(centroid(mask), [(W - 1) / 2, (H - 1) / 2], atol=1.0)


def test_moving_the_mesh_moves_its_image_by_d_times_pixels_per_unit():
    d = np.array([0.3, 0.0, 0.2])
    with SurfaceRenderer(W, H, ortho_front(), **BLACK) as r:
        h = r.add_mesh(SQUARE * 0.5, SQUARE_TRIS, color=(0.9, 0.6, 0.3))
        before = centroid(covered(r.render()))
        r.update(h, SQUARE * 0.5 + d)
        after = centroid(covered(r.render()))
    # Screen x follows world -x for the front view (+x on the left), rows grow downwards with -z.
    expected = np.array([-d[0] * PPU, -d[2] * PPU])
    np.testing.assert_allclose(after - before, expected, atol=1.0)


def test_surfaces_are_lit_by_their_normals():
    """A sphere is bright where it faces the lights and dark at its rim; a crease stays a crease."""
    with SurfaceRenderer(W, H, ortho_front(), **BLACK) as r:
        r.add_sphere((0, 0, 0), 0.6, color=(0.8, 0.8, 0.8))
        image = r.render().max(axis=2).astype(int)
    disc = image > 15
    radius_px = 0.6 * PPU
    assert abs(disc.sum() - np.pi * radius_px**2) < 2 * np.pi * radius_px + 10  # +- one rim pixel
    inside = image[disc]
    assert inside.max() - inside.min() > 80  # shading varies across the sphere

    # A roof of two squares meeting at 90 degrees: each half is flat-shaded (splitting at the
    # crease) and the two halves differ in brightness.
    roof = np.array([[-0.5, 0, -0.5], [0, 0.5, -0.5], [0, 0.5, 0.5], [-0.5, 0, 0.5], [0.5, 0, -0.5], [0.5, 0, 0.5]])
    tris = np.array([[0, 2, 1], [0, 3, 2], [1, 5, 4], [1, 2, 5]])
    with SurfaceRenderer(W, H, Camera("front", parallel=True, parallel_scale=SCALE, focal_point=(0, 0, 0),
                                      azimuth=30), **BLACK) as r:
        r.add_mesh(roof, tris, color=(0.8, 0.8, 0.8))
        img = r.render().max(axis=2).astype(int)
    mask = img > 15
    cols = np.nonzero(mask.any(axis=0))[0]
    mid_row = img[H // 2, cols.min() : cols.max() + 1]
    # One flat shade per face (to 1 level of rounding), one step at the crease.
    assert np.count_nonzero(np.abs(np.diff(mid_row)) > 1) == 1
    assert abs(int(mid_row[0]) - int(mid_row[-1])) > 10


def test_default_camera_frames_the_meshes_wherever_they_are():
    far = SQUARE * 0.2 + (50.0, -20.0, 7.0)
    with SurfaceRenderer(120, 90, "iso", **BLACK) as r:
        r.add_mesh(far, SQUARE_TRIS, color=(1, 1, 1))
        mask = covered(r.render())
    assert mask.sum() > 0.05 * mask.size
    np.testing.assert_allclose(centroid(mask), [59.5, 44.5], atol=6)


def test_ground_plane_and_image_format():
    with SurfaceRenderer(64, 48, Camera("front", elevation=30), bounds=(-1, 1, -1, 1, 0, 1)) as r:
        r.add_plane(size=4.0, tiles=4, color=(0.6, 0.6, 0.6))
        image = r.render()
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8
    bottom, top = image[-5:].mean(), image[:5].mean()
    assert bottom != pytest.approx(top, abs=5)  # the ground fills the lower part, the sky the upper


def test_bad_input_is_rejected_by_name():
    with SurfaceRenderer(32, 24) as r:
        h = r.add_mesh(SQUARE, SQUARE_TRIS)
        p = r.add_plane()
        with pytest.raises(InputError, match=r"vertices.*\[4, 3\]"):
            r.update(h, SQUARE[:3])
        with pytest.raises(InputError, match="handle"):
            r.update(p, SQUARE)
        with pytest.raises(InputError, match="handle"):
            r.update(7, SQUARE)
        with pytest.raises(InputError, match="triangles"):
            r.add_mesh(SQUARE, [[0, 1, 4]])
        with pytest.raises(InputError, match="color"):
            r.add_sphere((0, 0, 0), 1.0, color=(2, 0, 0))
        with pytest.raises(InputError, match=r"vertices\[1\]"):
            r.update(h, SQUARE + [[0, 0, 0], [np.nan, 0, 0], [0, 0, 0], [0, 0, 0]])
    with pytest.raises(InputError, match="closed"):
        r.render()


