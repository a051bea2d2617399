"""Off-screen surface rendering checked against geometry computed by hand.

Truths: an orthographic camera with parallel scale s shows ``height / (2 s)`` pixels per world
unit, so a unit square facing it covers that many pixels squared (each edge may land up to
1 px off: between (L - 2)^2 and (L + 2)^2 pixels); moving the mesh by d moves its pixel
centroid by d times that scale; a tet mesh's boundary is closed and outward (its enclosed
volume by the divergence theorem equals the sum of the tet volumes); a CT ball's disc has the
radius the perspective camera fit predicts, and ball and surfaces composite by depth as renders of
each alone say they must.
"""

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.render import Camera, SurfaceRenderer
from softvr.volume import Volume

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



# ------------------------------------------------------------------------------------ volumes
# A CT-like ball in metres: 40^3 int16 voxels of 1 mm, 1000 HU within 12 voxels of the grid
# centre (the world origin), -1000 HU (air, transparent in the "ct" preset) elsewhere.
VN, VS, VR = 40, 1e-3, 12
VW = VH = 96
FLAT = dict(background=(0.2, 0.3, 0.4), background_top=(0.2, 0.3, 0.4), antialias=False)
FLAT_RGB = np.round(np.array(FLAT["background"]) * 255).astype(int)
HALF = (VN - 1) / 2 * VS  # the grid's bounds (voxel centres) are +-HALF on every axis
CENTRE = (VH // 2, VW // 2)  # (row, col) of the pixel the ball's centre projects to


def ct_ball(inside: int = 1000) -> Volume:
    c = (VN - 1) / 2
    i = np.arange(VN) - c
    x, y, z = np.meshgrid(i, i, i, indexing="ij")
    data = np.where(x**2 + y**2 + z**2 <= VR**2, inside, -1000).astype(np.int16)
    return Volume(data, spacing=(VS, VS, VS), origin=(-c * VS,) * 3)


def not_background(image: np.ndarray) -> np.ndarray:
    return (np.abs(image.astype(int) - FLAT_RGB) > 0).any(axis=2)


def test_volume_is_drawn_and_framed_by_the_camera_fit():
    """The "front" camera fitted to the grid box +-h (h = 19.5 mm; Camera.apply: 5 % margin,
    30 degree view angle, square image) sits at distance d = h (1.05 / tan 15deg + 1) from the
    centre, since the nearest corners (y = +h) must fit the frustum. A ball of radius R on the
    axis then shows as a disc of radius (H / 2) R / sqrt(d^2 - R^2) / tan 15deg pixels. The
    drawn surface of the ball is where the interpolated HU cross the preset's opacity onset
    (-500 HU), between the last voxel inside (12 voxels out) and the first outside (13), so
    R is in [12, 13] mm; each rim pixel may go either way: +-1 px."""
    with SurfaceRenderer(VW, VH, "front", **FLAT) as r:
        r.add_volume(ct_ball())
        np.testing.assert_allclose(r.scene_bounds(), [-HALF, HALF] * 3, atol=1e-12)
        image = r.render()
        eye = np.asarray(r.vtk_camera.GetPosition())
    tan = np.tan(np.radians(15.0))
    d = HALF * (1.05 / tan + 1)
    np.testing.assert_allclose(eye, [0.0, d, 0.0], atol=1e-9)

    def disc_px(radius):
        return VH / 2 * radius / np.sqrt(d**2 - radius**2) / tan

    mask = not_background(image)
    assert mask[CENTRE]
    for row, col in [(1, 1), (1, VW - 2), (VH - 2, 1), (VH - 2, VW - 2)]:
        np.testing.assert_array_equal(image[row - 1 : row + 2, col - 1 : col + 2], np.broadcast_to(FLAT_RGB, (3, 3, 3)))
    r_px = np.sqrt(mask.sum() / np.pi)  # the radius of a disc of the drawn area
    assert disc_px(12 * VS) - 1 <= r_px <= disc_px(13 * VS) + 1  # about 20 % of the image
    np.testing.assert_allclose(centroid(mask), [(VW - 1) / 2, (VH - 1) / 2], atol=1.0)


def test_volume_and_surfaces_are_composited_by_depth():
    """Truth: renders of the square alone and of the ball alone, with the same camera (fixed by
    ``bounds``). A square in front of the ball covers it exactly; the ball covers a square
    behind it, up to the light that the ray caster lets through the ball: it stops a ray once
    it is almost opaque, so up to ~2 % (5 levels of 255) of the square behind may show."""
    ball = ct_ball()
    front = SQUARE * 0.010 + (0.0, 0.016, 0.0)  # 10 mm square between the camera and the ball
    behind = SQUARE * 0.030 + (0.0, -0.016, 0.0)  # 30 mm: it sticks out around the ball

    def render(volume=True, square=None):
        with SurfaceRenderer(VW, VH, "front", bounds=[-HALF, HALF] * 3, **FLAT) as r:
            if volume:
                r.add_volume(ball)
            if square is not None:
                r.add_mesh(square, SQUARE_TRIS, color=(0.9, 0.2, 0.1))
            return r.render().astype(int)

    ball_only = render()
    ball_mask = not_background(ball_only)

    square_only = render(volume=False, square=front)
    covered_by_square = not_background(square_only)
    assert covered_by_square[CENTRE] and ball_mask[covered_by_square].all()  # it hides ball only
    both = render(square=front)
    np.testing.assert_array_equal(both[covered_by_square], square_only[covered_by_square])

    square_only = render(volume=False, square=behind)
    assert np.abs(square_only[CENTRE] - ball_only[CENTRE]).max() > 50  # the square would show
    both = render(square=behind)
    assert np.abs(both[CENTRE] - ball_only[CENTRE]).max() <= 5
    # Around the ball the square behind is seen through the air voxels (transparent).
    around = not_background(square_only) & ~ball_mask
    assert around.sum() > 100
    assert np.abs(both[around] - square_only[around]).max() <= 1


def test_gradient_background_under_a_cast_volume_is_the_one_vtk_draws():
    """Truth: VTK's own frames of a square over its gradient background (no volume: drawn as a
    whole by VTK). With a volume to ray cast, VTK clears flat and the gradient, drawn once, is
    put where no surface is (depth 1). Over a volume of air every ray composites nothing and
    the caster returns a surface colour c as round(255 (c / 255)) = c: the frames must be VTK's
    bit for bit, the first and the next (which reuses the drawn gradient)."""
    square = SQUARE * 0.010 + (0.0, 0.016, 0.0)
    gradient = dict(background=(0.1, 0.2, 0.3), background_top=(0.6, 0.5, 0.9), antialias=False)

    def frames(volume: bool) -> list:
        with SurfaceRenderer(VW, VH, "front", bounds=[-HALF, HALF] * 3, **gradient) as r:
            r.add_mesh(square, SQUARE_TRIS, color=(0.9, 0.2, 0.1))
            if volume:
                r.add_volume(ct_ball(inside=-1000), mapper="warp")
            return [r.render() for _ in range(2)]

    vtk, cast = frames(False), frames(True)
    assert len(np.unique(vtk[0][:, 0], axis=0)) > 20 and not_background(vtk[0])[CENTRE]  # a gradient, the square
    for ours, theirs in zip(cast, vtk):
        np.testing.assert_array_equal(ours, theirs)


def test_update_volume_and_volume_handles():
    with SurfaceRenderer(VW, VH, "front", **FLAT) as r:
        v = r.add_volume(ct_ball(), preset="ct-skin")
        m = r.add_mesh(SQUARE * 0.005 + (0.0, 0.0, -0.015), SQUARE_TRIS)
        assert not_background(r.render())[CENTRE]
        r.set_visible(v, False)
        assert not not_background(r.render())[CENTRE]
        r.set_visible(v, True)
        r.update_volume(v, ct_ball(inside=-1000))  # all air: nothing to see
        assert not not_background(r.render())[CENTRE]
        r.update_volume(v, ct_ball())
        assert not_background(r.render())[CENTRE]
        with pytest.raises(InputError, match="update_volume"):
            r.update(v, SQUARE)
        with pytest.raises(InputError, match="handle.*volume"):
            r.update_volume(m, ct_ball())
        with pytest.raises(InputError, match="handle"):
            r.update_volume(9, ct_ball())
        with pytest.raises(InputError, match="handle"):
            r.set_color(v, (1, 0, 0))
        with pytest.raises(InputError, match="sample_distance"):
            r.add_volume(ct_ball(), sample_distance=0)
        with pytest.raises(InputError, match="preset"):
            r.add_volume(ct_ball(), preset="bone")
        with pytest.raises(InputError, match="volume"):
            r.update_volume(v, np.zeros((4, 4, 4)))
