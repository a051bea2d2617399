"""The Warp ray caster (``VolumeRenderer(mapper="warp")``) against independent truths.

* Transmittance of a constant volume: emission-absorption with opacity ``a`` per unit
  length ``d`` gives ``A = 1 - (1 - a) ** (L / d)`` over a path ``L``; the pixel is
  ``255 A`` (white emission over black). The ray's samples cover ``L`` to within one step,
  so ``A`` may be off by one sample's opacity ``a_s = 1 - (1 - a) ** (dt / d)``: tolerance
  ``255 a_s + 0.5`` (rounding).
* Phong shading of a plane (headlight, parallel projection: light = view = h):
  ``I = ka + kd cos(theta) + ks cos(theta) ** 20`` for a plane whose normal is ``theta``
  off the view axis. The field is linear, so trilinear interpolation and central
  differences reproduce it exactly; the ray stops once its opacity reaches 0.99, so the
  pixel is ``255 I A`` with ``0.99 <= A <= 1``: tolerance ``0.01 * 255 I + 0.5``.
* The head CT equals VTK's GPU ray caster (which also takes gradients on the fly) at a
  sample distance of 0.1 voxel, same transfer function (the demos' ``ct-skin`` and
  ``ct`` presets, shading off: the two use different lighting conventions) and camera.
  Both integrate the same emission-absorption model; at a step of 0.1 voxel their
  discretisation errors are < 1 % of a grey level per unit of opacity rise (the steepest
  preset ramp rises 0.9 over 200 HU, i.e. over >= 0.2 voxel at the skin), so inside the
  silhouette they agree to within rounding plus VTK's 8-bit transfer-function texture
  (<= 1 grey level). On the silhouette a ray grazing the skin may take a sub-step path
  through it in one caster and miss it in the other: the rim is ~2 % of the pixels. Hence:
  mean absolute difference <= 1.0 grey level, 97th percentile <= 4.
* Banding: a flat skin patch seen by the palpation trainer's preset must show no stripes. The
  patch is a tilted plane whose HU rise 520 per voxel (air to soft tissue within two voxels,
  as on the head CT) with no clipping, so trilinear interpolation and the gradients are
  exact and any periodic pattern comes from where the samples fall. After removing a
  quadratic trend (smooth shading), the 64 x 64 patch's power spectrum above 2.5 cycles has
  its strongest bin at < 16 x the mean bin. For white noise (jittered sampling error) the
  N = 2040 bins are independent exponentials: P(max > t mean) ~ N exp(-t) = 2e-4 at t = 16,
  while a stripe puts its power into one bin (VTK's fixed-point ray caster, today's
  renderer: 130-370; the Warp caster without jitter: 70-790). The same for the scenes'
  renderer (``SurfaceRenderer.add_volume``, the volume demo) with the demo's ``ct`` preset:
  its default (the Warp caster, 6-10) against VTK's fixed-point caster it used before (130-150).
* Slice bands (the volume demo's skull top): a flat bone surface tilted 7 degrees off 1.5 mm
  slices, drawn by the scenes' renderer, keeps its luminance within 5.5 grey levels (std)
  of a quadratic trend, where 0.5 mm slices give 0.6-0.8 (noise) and VTK's fixed-point
  caster 28-40. The shading gradient smoothed across slices equals SciPy's gradient of the
  voxels smoothed by (1, 2, 1) / 4, interpolated trilinearly.
* Frame-to-frame state (brick grid updated in the changed box only, each ray's known-empty
  prefix): equal to a fresh renderer's image, bit for bit.
* Incremental frames (same camera: only the rays through a moved surface or near rewritten
  voxels are cast, the rest keep last frame's colour): a ball dented deeper frame by frame with
  a probe following the dent, and a change hidden behind the opaque skin. The kernel is
  deterministic per pixel (the jitter is a hash of the pixel), so every frame must equal a
  fresh renderer's full cast bit for bit; and the rays cast must be the few that can see a
  change (a dent of a few voxels seen by < 15 % of the pixels; the hidden change by none but
  the probe's). Air rewritten but transparent in both frames, in front of the ball, casts
  no ray (its bricks stay empty, so no sample there is seen in either frame).
* A ray cast again starts past the cells it skipped last frame unless one of them may now be
  seen: a layer grown there (in a brick that was already occupied) must be read, its pixels
  255 (1 - (1 - a) ** L) over the slab and layer's thickness L (emission-absorption, as above).
* The walk that finds which rays pass a brick whose voxels changed (jumps over a distance
  field) against brute force: a segment's points sampled every 1/2000 of its length, away from
  brick faces by more than the walk's 0.01-voxel step past a face (0.02), must never show a
  marked brick the walk missed.
* The pixels marked as those whose rays may meet a box (``mark_pixels``: only those are walked
  by the stale-ray test) against NumPy ray-box intersection: every pixel whose ray meets it.
* The bricks found changed (``brick_changes``) against NumPy: a brick is flagged iff a voxel
  it owns differs from the kept copy, for single-voxel changes anywhere in inner and edge bricks,
  voxel by voxel and with inner bricks' rows compared as 64-bit words (the CPU's C++ form).
* The empty-space distance field against SciPy's chessboard distance transform after partial
  updates, and the cell masks against NumPy's cell ranges: Warp's code and the CPU's C++ forms.
* A cast through air returns the surfaces' colour exactly (RGB or RGBA input): nothing is
  composited, and 255 (c / 255) rounds back to c.
* Depth: a probe sphere in front of the skin shows exactly as VTK draws it alone; one behind
  the (opaque) skin is hidden (the pixel changes by at most the 1 % of light that early
  termination lets through: 0.01 * 255 + 0.5 < 3 grey levels).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import warp as wp
from scipy import ndimage

from softvr.datasets import HEAD_CT_PATH
from softvr.errors import InputError
from softvr.device import launch
from softvr.render import PRESETS, Camera, Preset, SurfaceRenderer, VolumeRenderer
from softvr.render import _raycast_kernels as K
from softvr.render import raycast as R
from softvr.volume import Volume

WHITE = ((-1000.0, 1.0, 1.0, 1.0), (1000.0, 1.0, 1.0, 1.0))
SAMPLE = 0.5  # the default ray step [smallest voxel spacing]


def test_constant_volume_has_transmittance_exp_of_opacity_length():
    a = 0.02  # opacity per unit length (the smallest spacing, 1 mm)
    n, spacing = 24, (1.0, 1.0, 2.0)
    vol = Volume(np.full((n, n, n), 0.5, np.float32), spacing=spacing, origin=(-11.5, -11.5, -23.0))
    preset = Preset("slab", colors=((0.0, 1.0, 1.0, 1.0), (1.0, 1.0, 1.0, 1.0)), opacities=((0.0, a), (1.0, a)),
                    shade=False)
    cam = Camera("top", parallel=True, parallel_scale=20.0, focal_point=(0.0, 0.0, 0.0))
    with VolumeRenderer(64, 64, preset, cam, mapper="warp") as renderer:
        image = renderer.render(vol).astype(float)
    length = (n - 1) * spacing[2]  # voxel centres span (n - 1) spacings along the view axis
    expected = 255.0 * (1.0 - (1.0 - a) ** (length / 1.0))
    tolerance = 255.0 * (1.0 - (1.0 - a) ** SAMPLE) + 0.5
    inside = image[16:48, 16:48]  # rays through the whole box (its footprint is +-11.5 mm = +-18 px)
    assert np.abs(inside - expected).max() <= tolerance, (inside.min(), inside.max(), expected, tolerance)
    assert image[0, 0].max() == 0  # outside the footprint: background


@pytest.mark.parametrize("theta_deg", [0.0, 40.0])
def test_plane_is_phong_shaded(theta_deg):
    ka, kd, ks = 0.2, 0.5, 0.25  # I <= 0.95: no saturation at theta = 0
    preset = Preset("plane", colors=WHITE, opacities=((-1000.0, 0.0), (0.0, 0.0), (10.0, 1.0), (1000.0, 1.0)),
                    ambient=ka, diffuse=kd, specular=ks)
    theta = np.radians(theta_deg)
    normal = np.array([np.sin(theta), np.cos(theta), 0.0])  # towards the camera (+y, "front")
    n = 40
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1) - (n - 1) / 2
    vol = Volume((-100.0 * (ijk @ normal)).astype(np.float32), spacing=(1.0, 1.0, 1.0),
                 origin=(-(n - 1) / 2,) * 3)
    cam = Camera("front", parallel=True, parallel_scale=25.0, focal_point=(0.0, 0.0, 0.0))
    with VolumeRenderer(48, 48, preset, cam, mapper="warp") as renderer:
        image = renderer.render(vol).astype(float)
    c = np.cos(theta)
    intensity = 255.0 * (ka + kd * c + ks * c**20)
    patch = image[18:30, 18:30]
    assert np.all(patch <= intensity + 0.5) and np.all(patch >= 0.99 * intensity - 0.5), (
        patch.min(), patch.max(), intensity)


@pytest.mark.skipif(not HEAD_CT_PATH.exists(), reason="head CT (Debian invesalius-examples) not installed")
@pytest.mark.parametrize("name", ["ct-skin", "ct"])
def test_head_ct_equals_vtk_gpu_ray_caster(name, head):
    preset = dataclasses.replace(PRESETS[name], shade=False)
    cam = Camera("front", azimuth=-40.0, elevation=5.0, zoom=1.3)  # the palpation trainer's view
    images = {}
    for mapper in ("warp", "gpu"):
        with VolumeRenderer(96, 96, preset, cam, mapper=mapper, sample_distance=0.1) as renderer:
            images[mapper] = renderer.render(head).astype(int)
    diff = np.abs(images["warp"] - images["gpu"])
    assert (images["gpu"].max(axis=2) > 20).mean() > 0.2  # the head fills the frame
    assert diff.mean() <= 1.0 and np.percentile(diff, 97) <= 4, (diff.mean(), np.percentile(diff, 97))


def tilted_skin(n: int = 64, slope: float = 520.0) -> Volume:
    """A flat skin patch: HU ``-400 - slope * d`` at signed distance ``d`` [voxels] from a
    plane tilted off the front view (tissue behind it), unclipped: a linear field."""
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1) - (n - 1) / 2
    normal = np.array([0.25, 1.0, 0.35]) / np.linalg.norm([0.25, 1.0, 0.35])
    return Volume(np.round(-400.0 - slope * (ijk @ normal)).astype(np.int16), spacing=(1.0, 1.0, 1.0))


def band_peak(image: np.ndarray) -> float:
    """Strongest / mean power of the central 64 x 64 patch's luminance spectrum, after
    removing a quadratic trend and the frequencies below 2.5 cycles per patch."""
    h, w = image.shape[:2]
    lum = image[h // 2 - 32:h // 2 + 32, w // 2 - 32:w // 2 + 32].astype(float).mean(axis=2)
    y, x = np.mgrid[:64, :64].astype(float)
    basis = np.column_stack([np.ones(x.size), x.ravel(), y.ravel(), x.ravel() ** 2, y.ravel() ** 2, (x * y).ravel()])
    residual = lum.ravel() - basis @ np.linalg.lstsq(basis, lum.ravel(), rcond=None)[0]
    power = np.abs(np.fft.rfft2(residual.reshape(64, 64))) ** 2
    fy = np.fft.fftfreq(64)[:, None] * 64
    fx = np.arange(power.shape[1])[None, :]
    kept = power[np.hypot(fy, fx) > 2.5]
    return float(kept.max() / kept.mean())


@pytest.mark.parametrize("sample_distance", [0.5, 1.0])  # the renderer's default, the palpation trainer's
@pytest.mark.parametrize("azimuth", [0.0, -40.0])
def test_flat_skin_shows_no_banding_where_vtk_does(sample_distance, azimuth):
    skin = tilted_skin()
    peak = {}
    for mapper in ("warp", "cpu"):
        with VolumeRenderer(128, 128, "ct-skin", Camera("front", azimuth=azimuth, elevation=5.0, zoom=1.6),
                            mapper=mapper, sample_distance=sample_distance) as renderer:
            peak[mapper] = band_peak(renderer.render(skin))
    assert peak["warp"] < 16.0, peak
    assert peak["cpu"] > 16.0, peak  # the measure sees today's wood grain


@pytest.mark.parametrize("azimuth", [0.0, -40.0])
def test_scene_volume_shows_no_banding_where_vtk_did(azimuth):
    """The scenes' volume (SurfaceRenderer.add_volume: the volume demo's skull and headrest) at
    its default mapper and step, with the volume demo's preset, against VTK's fixed-point
    caster that drew it before (sample distance 1 voxel, rays sampled in step)."""
    skin = tilted_skin()
    peak = {}
    for mapper in ("auto", "cpu"):
        with SurfaceRenderer(128, 128, Camera("front", azimuth=azimuth, elevation=5.0, zoom=1.6), background=(0, 0, 0),
                             background_top=(0, 0, 0), antialias=False) as renderer:
            renderer.add_volume(skin, "ct", **({} if mapper == "auto" else {"mapper": mapper}))
            image = renderer.render()
            assert (image[32:96, 32:96].max(axis=2) > 20).all()  # the patch is all skin
            peak[mapper] = band_peak(image)
    assert peak["auto"] < 16.0, peak
    assert peak["cpu"] > 16.0, peak  # the measure sees the wood grain the demo showed


def _sphere_actor(centre, radius):
    from vtkmodules.vtkFiltersSources import vtkSphereSource
    from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper

    src = vtkSphereSource()
    src.SetCenter(*centre)
    src.SetRadius(radius)
    src.SetThetaResolution(32)
    src.SetPhiResolution(32)
    mapper = vtkPolyDataMapper()
    mapper.SetInputConnection(src.GetOutputPort())
    actor = vtkActor()
    actor.SetMapper(mapper)
    actor.GetProperty().SetColor(0.2, 0.4, 1.0)
    return actor


def test_probe_in_front_of_the_skin_hides_it_and_behind_is_hidden(ball):
    cam = Camera("front", zoom=1.2)
    bounds_air = Volume(np.full(ball.shape, -1000, np.int16), ball.spacing, ball.origin)
    in_front, behind = (0.0, 17.0, 0.0), (0.0, 4.0, 0.0)  # the skin's front is at y = 14 mm
    with VolumeRenderer(64, 64, "ct-skin", cam, mapper="cpu") as vtk_only:
        vtk_only.vtk_renderer.AddActor(_sphere_actor(in_front, 2.0))
        probe_alone = vtk_only.render(bounds_air).astype(int)  # VTK draws the probe (the air is invisible)
    with VolumeRenderer(64, 64, "ct-skin", cam, mapper="warp") as renderer:
        skin_alone = renderer.render(ball).astype(int)
        actor = _sphere_actor(in_front, 2.0)
        renderer.vtk_renderer.AddActor(actor)
        front = renderer.render(ball).astype(int)
        renderer.vtk_renderer.RemoveActor(actor)
        renderer.vtk_renderer.AddActor(_sphere_actor(behind, 2.0))
        back = renderer.render(ball).astype(int)
    probe = probe_alone.max(axis=2) > 0  # where VTK drew the probe over the black background
    assert 20 < probe.sum() < 400 and (skin_alone[probe].max(axis=1) > 40).all()  # in front of the skin
    assert np.abs(front - probe_alone)[probe].max() <= 1
    assert np.abs(back - skin_alone).max() <= 3


def test_frame_to_frame_updates_match_a_fresh_render():
    """Only the bricks in each changed box are re-derived and each ray skips the prefix it
    found empty last frame; a fresh renderer (no state) must give the same image after a
    bump on the skin, a blob appearing in the air in front of it (on the rays' empty
    prefixes) and the blob removed again."""
    cam = Camera("front", azimuth=-30.0, zoom=1.2)
    n = 48
    r = np.linalg.norm(np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1) - 23.5, axis=-1)
    data = np.where(r < 12.0, 40, -1000).astype(np.int16)  # a ball with 12 mm of air in front (+y)
    vol = Volume(data, spacing=(1.0, 1.0, 1.0), origin=(-23.5,) * 3)
    changes = [((10, 30, 20), (16, 36, 27), 40), ((20, 41, 20), (27, 45, 27), 40), ((20, 41, 20), (27, 45, 27), -1000)]
    with VolumeRenderer(64, 64, "ct-skin", cam, mapper="warp") as renderer:
        previous = renderer.render(vol).astype(int)
        for lo, hi, value in changes:
            data[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1] = value
            image = renderer.render(vol, changed=(lo, hi))
            with VolumeRenderer(64, 64, "ct-skin", cam, mapper="warp") as fresh:
                assert np.array_equal(image, fresh.render(vol))
            assert np.abs(image.astype(int) - previous).max() > 40  # each change shows
            previous = image.astype(int)


def test_incremental_frames_equal_a_fresh_cast_and_cast_only_what_changed():
    cam = Camera("front", azimuth=-30.0, elevation=10.0, zoom=1.2)
    n, size = 48, 96
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1)
    data = np.where(np.linalg.norm(ijk - 23.5, axis=-1) < 14.0, 40, -1000).astype(np.int16)
    vol = Volume(data, spacing=(1.0, 1.0, 1.0), origin=(-23.5,) * 3)
    tip = np.array([23.5, 23.5 + 14.0, 23.5])  # where the ball's front (+y, towards the camera) is pressed
    probe_radius = 3.0

    def press(depth: float):
        """Dent the ball by a sphere of the probe's radius reaching ``depth`` voxels in; its box."""
        centre = tip + (probe_radius - depth) * np.array([0.0, 1.0, 0.0])
        lo = np.floor(centre - probe_radius).astype(int)
        hi = np.ceil(centre + probe_radius).astype(int)
        region = tuple(slice(a, b + 1) for a, b in zip(lo, hi))
        inside = np.linalg.norm(ijk[region] - centre, axis=-1) < probe_radius
        data[region][inside] = -1000
        return centre - 23.5, (lo, hi)  # the probe's centre [world, mm]

    def fresh(centre):
        with VolumeRenderer(size, size, "ct-skin", cam, mapper="warp") as renderer:
            renderer.vtk_renderer.AddActor(_sphere_actor(centre, probe_radius))
            return renderer.render(vol)

    total = size * size
    with VolumeRenderer(size, size, "ct-skin", cam, mapper="warp") as renderer:
        probe = _sphere_actor(tip + (probe_radius + 1.0) * np.array([0.0, 1.0, 0.0]) - 23.5, probe_radius)
        renderer.vtk_renderer.AddActor(probe)
        previous = renderer.render(vol)
        assert renderer.ray_caster.cast_pixels == total
        casts = []
        for depth in (1.0, 2.0, 3.0, 4.0):
            centre, box = press(depth)
            probe.SetPosition(*(centre - probe.GetCenter() + probe.GetPosition()))
            image = renderer.render(vol, changed=box)
            assert np.array_equal(image, fresh(centre)), depth
            assert np.abs(image.astype(int) - previous).max() > 40  # the dent shows
            casts.append(renderer.ray_caster.cast_pixels)
            previous = image
        # Behind the skin, under the dent: no ray reaches it.
        data[20:28, 20:28, 20:28] = 1200
        image = renderer.render(vol, changed=((20, 20, 20), (27, 27, 27)))
        hidden = renderer.ray_caster.cast_pixels
        assert np.array_equal(image, fresh(centre))
        # The probe withdraws (no voxel changes; it stays inside the volume's bounds, which
        # fix the clipping range): only the pixels it left or covers now are cast.
        away = centre + np.array([0.0, 5.0, 0.0])
        probe.SetPosition(*(away - centre + probe.GetPosition()))
        image = renderer.render(vol, changed=False)
        assert np.array_equal(image, fresh(away))
        casts.append(renderer.ray_caster.cast_pixels)
    assert all(0 < c < 0.15 * total for c in casts), casts
    assert hidden == 0, hidden


def test_rays_through_air_that_changed_but_stayed_transparent_are_not_cast_again():
    """Rewritten air (-1000 -> -990 HU, transparent in ``ct-skin`` either way) in front of a ball:
    the rays cross it, but no sample there can be seen in either frame (its bricks stay empty),
    so none is cast again and the image still equals a fresh cast."""
    cam = Camera("front", azimuth=-30.0, elevation=10.0, zoom=1.2)
    n, size = 64, 64
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1)
    data = np.where(np.linalg.norm(ijk - 31.5, axis=-1) < 14.0, 40, -1000).astype(np.int16)
    vol = Volume(data, spacing=(1.0, 1.0, 1.0), origin=(-31.5,) * 3)
    with VolumeRenderer(size, size, "ct-skin", cam, mapper="warp") as renderer:
        renderer.render(vol)
        # The ball's front is at y = 45.5 (brick 11); bricks 13 .. 15 are air.
        lo, hi = (16, 53, 16), (47, 63, 47)
        data[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1] = -990
        image = renderer.render(vol, changed=(lo, hi))
        with VolumeRenderer(size, size, "ct-skin", cam, mapper="warp") as fresh:
            assert np.array_equal(image, fresh.render(vol))
        assert renderer.ray_caster.cast_pixels == 0


def test_a_ray_not_cast_again_still_learns_that_a_brick_on_its_empty_prefix_filled():
    """Rays next to a changed voxel, but not reading it, are not cast again; yet the empty-space
    brick they cross fills, so the next change on them (in that brick, which no longer flips)
    must not be skipped as known-empty air. Some of them are hidden by a surface in front of
    the volume meanwhile (no samples at all), which then moves away."""
    n = 40
    data = np.full((n, n, n), -1000, np.int16)
    vol = Volume(data, spacing=(1.0, 1.0, 1.0), origin=(-19.5,) * 3)
    cam = Camera("front", parallel=True, parallel_scale=20.0, focal_point=(0.0, 0.0, 0.0))  # rays along y
    aside = (-12.0, 0.0, 0.0)  # over rays at x = 1.5 .. 7.5 voxels; moved along x, the clipping range (along y) stays
    with VolumeRenderer(64, 64, "ct-skin", cam, mapper="warp") as renderer:
        cover = _sphere_actor((-3.0, 25.0, 0.0), 3.0)  # in front of the volume, over the rays at x = 13.5 .. 19.5
        renderer.vtk_renderer.AddActor(cover)
        cover.SetPosition(*aside)
        renderer.render(vol)  # all air: every ray's whole path is a known-empty prefix
        # Brick 4 holds voxels 16 .. 20: the first change fills it, the second is on it.
        for x, offset in ((20, (0.0, 0.0, 0.0)), (17, aside)):
            cover.SetPosition(*offset)
            data[x, 8:32, 8:32] = 40
            image = renderer.render(vol, changed=((x, 8, 8), (x, 31, 31)))
            with VolumeRenderer(64, 64, "ct-skin", cam, mapper="warp") as fresh:
                shown = _sphere_actor((-3.0, 25.0, 0.0), 3.0)
                shown.SetPosition(*offset)
                fresh.vtk_renderer.AddActor(shown)
                assert np.array_equal(image, fresh.render(vol)), x
            assert renderer.ray_caster.cast_pixels < 64 * 64 / 2


def test_a_ray_cast_again_reads_a_layer_grown_where_it_skipped_cells_last_frame():
    """A ray cast again starts at its first sample read last frame, past the cells it skipped
    (air between voxels, in a brick holding tissue), unless such a cell on the way may now be
    seen. A slab of tissue (y = 14 .. 17 voxels) seen along -y, of opacity ``a`` per unit length
    where the value is >= 0 HU (white, unshaded, over black): brick 4 (voxels 16 .. 20) holds
    its front face and the air cells y = 18 .. 20 before it. Then a layer y = 18 .. 19 is added
    in that brick (no brick turns occupied): the rays through it must read it. Emission-absorption
    truth: the value is >= 0 from 40 / 1040 voxel before the first tissue voxel to as far past
    the last, so a pixel over the layer is 255 (1 - (1 - a) ** L), L = 5 + 2 * 40 / 1040 voxels,
    within one sample's opacity (+ 0.5 rounding), where starting at last frame's first sample
    read (y < 18) would give L ~ 4 (18 grey levels darker); and it equals a fresh cast."""
    a, step = 0.3, 0.1
    preset = Preset("layer", colors=WHITE, opacities=((-1000.0, 0.0), (-1.0, 0.0), (0.0, a), (1000.0, a)),
                    shade=False)
    n = 40
    data = np.full((n, n, n), -1000, np.int16)
    data[:, 14:18, :] = 40
    vol = Volume(data, spacing=(1.0, 1.0, 1.0), origin=(-19.5,) * 3)
    cam = Camera("front", parallel=True, parallel_scale=20.0, focal_point=(0.0, 0.0, 0.0))  # rays along -y
    with VolumeRenderer(64, 64, preset, cam, mapper="warp", sample_distance=step) as renderer:
        renderer.render(vol)
        data[8:32, 18:20, 8:32] = 40
        image = renderer.render(vol, changed=((8, 18, 8), (31, 19, 31)))
        assert renderer.ray_caster.cast_pixels > 0
        with VolumeRenderer(64, 64, preset, cam, mapper="warp", sample_distance=step) as fresh:
            assert np.array_equal(image, fresh.render(vol))
    length = 5.0 + 2.0 * 40.0 / 1040.0
    expected = 255.0 * (1.0 - (1.0 - a) ** length)
    tolerance = 255.0 * (1.0 - (1.0 - a) ** step) + 0.5
    over = image[20:44, 20:44].astype(float)  # the layer spans +-11.5 mm = +-18.4 px about the centre
    assert np.abs(over - expected).max() <= tolerance, (over.min(), over.max(), expected, tolerance)


@wp.kernel
def _walk(start: wp.array(dtype=wp.vec3), end: wp.array(dtype=wp.vec3), distance: wp.array3d(dtype=wp.uint8),
          found: wp.array(dtype=wp.int32)):
    i = wp.tid()
    found[i] = wp.where(K.crosses_marked(start[i], end[i] - start[i], 0.0, 1.0, distance), 1, 0)


def test_brick_walk_finds_every_marked_brick_a_segment_crosses():
    rng = np.random.default_rng(7)
    nb, reach, brick = np.array([10, 9, 8]), 4, int(K.BRICK)
    marks = rng.integers(0, nb, size=(30, 3))
    grid = np.stack(np.meshgrid(*[np.arange(n) for n in nb], indexing="ij"), -1)
    chebyshev = np.abs(grid[..., None, :] - marks).max(axis=-1).min(axis=-1)
    distance = np.minimum(chebyshev, reach).astype(np.uint8)
    a, b = (rng.uniform(0.0, 1.0, (1000, 3)) * nb * brick for _ in range(2))
    found = wp.zeros(len(a), dtype=wp.int32, device="cpu")
    wp.launch(_walk, dim=len(a), inputs=[wp.array(a.astype(np.float32), dtype=wp.vec3, device="cpu"),
                                         wp.array(b.astype(np.float32), dtype=wp.vec3, device="cpu"),
                                         wp.array(distance, dtype=wp.uint8, device="cpu"), found], device="cpu")
    walked = found.numpy().astype(bool)
    u = np.linspace(0.0, 1.0, 2001)
    points = a[:, None, :] + u[None, :, None] * (b - a)[:, None, :]  # [segment, sample, 3] index coordinates
    cells = np.clip(np.floor(points / brick).astype(int), 0, nb - 1)
    inside = np.abs(points / brick - np.round(points / brick)) * brick > 0.02  # off every brick face
    marked = distance[cells[..., 0], cells[..., 1], cells[..., 2]] == 0
    truth = np.any(marked & inside.all(axis=-1), axis=1)
    assert 0.2 < truth.mean() < 0.8  # both kinds of segment are tested
    assert not np.any(truth & ~walked), np.flatnonzero(truth & ~walked)
    assert (walked == truth).mean() > 0.99  # and the walk is not merely cautious


def _perspective(width: int, height: int) -> np.ndarray:
    """An index-to-clip-space matrix [4, 4]: OpenGL's perspective (30 degrees, near 10, far 400)
    of a camera at (-40, -90, 70) looking at (20, 25, 15), over voxels of (0.9, 1.1, 1.5)."""
    eye, centre, up = np.array([-40.0, -90.0, 70.0]), np.array([20.0, 25.0, 15.0]), np.array([0.0, 0.0, 1.0])
    f = (centre - eye) / np.linalg.norm(centre - eye)
    s = np.cross(f, up) / np.linalg.norm(np.cross(f, up))
    view = np.eye(4)
    view[:3, :3] = np.stack([s, np.cross(s, f), -f])
    view[:3, 3] = -view[:3, :3] @ eye
    near, far, c = 10.0, 400.0, 1.0 / np.tan(np.radians(15.0))
    projection = np.array([[c * height / width, 0, 0, 0], [0, c, 0, 0],
                           [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)], [0, 0, -1, 0]])
    return projection @ view @ np.diag([0.9, 1.1, 1.5, 1.0])


def test_cast_through_air_returns_the_surfaces_colour_rgb_or_rgba():
    """Over a volume of air nothing is composited (opacity 0 everywhere: C = 0, A = 0 in the
    module's compositing), so a cast frame is the surfaces' colour c: round(255 (c / 255)) = c.
    An RGBA frame gives its RGB channels (its alpha is not read); the next frame, with some
    pixels' colour changed and others' alpha only, gives the new colours (those rays cast
    again: a change of alpha alone shows nothing). A surface of two channels is refused by name."""
    width, height = 40, 30
    world_to_clip = _perspective(width, height) @ np.diag([1 / 0.9, 1 / 1.1, 1 / 1.5, 1.0])
    air = Volume(np.full((40, 50, 30), -1000, np.int16), spacing=(1.0, 1.0, 1.0))
    rng = np.random.default_rng(4)
    surface = rng.integers(0, 256, (height, width, 4), dtype=np.uint8)
    depth = rng.uniform(0.5, 1.0, (height, width)).astype(np.float32)
    depth[::3] = 1.0  # nothing drawn: the whole ray
    caster = R.RayCaster(PRESETS["ct"], device="cpu")

    def cast(rgba, changed):
        return caster.cast(air, np.linalg.inv(world_to_clip), (0.0, 0.0, 1.0), rgba, depth, changed=changed)

    np.testing.assert_array_equal(cast(surface[:, :, :3], True), surface[:, :, :3])
    np.testing.assert_array_equal(cast(surface, True), surface[:, :, :3])
    again = surface.copy()
    again[rng.random((height, width)) < 0.1, :3] = 7
    again[rng.random((height, width)) < 0.1, 3] ^= 1
    np.testing.assert_array_equal(cast(again, False), again[:, :, :3])
    with pytest.raises(InputError, match="surface"):
        cast(surface[:, :, :2], False)


@pytest.mark.parametrize("native", [0, 1], ids=["warp", "cpp"])
def test_pixels_marked_for_a_box_are_those_whose_rays_may_meet_it(monkeypatch, native):
    """``mark_pixels`` against NumPy ray-box intersection (float64): every pixel whose ray
    through its centre, from the near to the far plane, meets a box must be marked (the stale
    test walks only those), and within the rectangle it reports; the marks lie within 3 pixels
    of those rays' pixels: a pixel of margin for rounding, one from rounding the projected
    corners outwards, one where the projection's tip falls between pixel centres.
    A box with a corner behind the camera marks every pixel. Rows filled by Warp's loop and by
    the C++ fill the CPU uses."""
    width, height = 72, 56
    to_clip = _perspective(width, height)
    rng = np.random.default_rng(3)
    lo = rng.uniform(0.0, 40.0, (40, 3))
    boxes = [(a, a + rng.uniform(0.5, 12.0, 3)) for a in lo]
    px, py = np.meshgrid(np.arange(width), np.arange(height))  # py: OpenGL rows, running up
    ndc = np.stack([(2.0 * px + 1.0) / width - 1.0, (2.0 * py + 1.0) / height - 1.0], -1).reshape(-1, 2)
    back = np.linalg.inv(to_clip)
    ends = [np.column_stack([ndc, np.full(len(ndc), z), np.ones(len(ndc))]) @ back.T for z in (-1.0, 1.0)]
    near, far = (e[:, :3] / e[:, 3:] for e in ends)
    rows = (height - 1 - py).ravel()  # the mask's rows run down
    tested = 0
    rects = []
    for box_lo, box_hi in boxes:
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = (box_lo - near) / (far - near), (box_hi - near) / (far - near)
        enter = np.nanmax(np.minimum(a, b), axis=1).clip(0.0, None)
        leave = np.nanmin(np.maximum(a, b), axis=1).clip(None, 1.0)
        truth = (enter <= leave).reshape(height, width)[::-1]
        mask = wp.zeros(width * height, dtype=wp.uint8, device="cpu")
        rect = wp.empty(1, dtype=wp.vec4i, device="cpu")
        wp.launch(K.mark_pixels, dim=1, device="cpu",
                  inputs=[wp.array(box_lo[None].astype(np.float32), dtype=wp.vec3, device="cpu"),
                          wp.array(box_hi[None].astype(np.float32), dtype=wp.vec3, device="cpu"),
                          wp.mat44(*to_clip.ravel()), width, height, 1, native, mask, rect, 0])
        marked = mask.numpy().reshape(height, width).astype(bool)
        assert not np.any(truth & ~marked), np.argwhere(truth & ~marked)
        c0, c1, r0, r1 = rect.numpy()[0]
        ys, xs = np.nonzero(marked)
        assert (c0, c1, r0, r1) == ((xs.min(), xs.max(), ys.min(), ys.max()) if len(xs) else (width, -1, height, -1))
        rects.append((c0, c1, r0, r1))
        if truth.any():
            tested += 1
            ty, tx = np.nonzero(truth)
            assert c0 >= tx.min() - 3 and c1 <= tx.max() + 3 and r0 >= ty.min() - 3 and r1 <= ty.max() + 3
    assert tested > 10
    # All the boxes in one launch split over two threads (as the renderer launches them): each
    # box's rectangle as launched alone, none lost to the other thread.
    monkeypatch.setenv("SOFTVR_NUM_THREADS", "2")
    together = wp.empty(len(boxes), dtype=wp.vec4i, device="cpu")
    launch(K.mark_pixels, len(boxes),
           [wp.array(np.array([a for a, _ in boxes], np.float32), dtype=wp.vec3, device="cpu"),
            wp.array(np.array([b for _, b in boxes], np.float32), dtype=wp.vec3, device="cpu"),
            wp.mat44(*to_clip.ravel()), width, height, 0, native,
            wp.zeros(width * height, dtype=wp.uint8, device="cpu"), together], "cpu", min_chunk=4)
    np.testing.assert_array_equal(together.numpy(), np.array(rects))
    behind = wp.zeros(width * height, dtype=wp.uint8, device="cpu")
    eye_index = np.linalg.inv(np.diag([0.9, 1.1, 1.5]))  @ np.array([-40.0, -90.0, 70.0])
    wp.launch(K.mark_pixels, dim=1, device="cpu",
              inputs=[wp.array(eye_index[None].astype(np.float32) - 5.0, dtype=wp.vec3, device="cpu"),
                      wp.array(eye_index[None].astype(np.float32) + 5.0, dtype=wp.vec3, device="cpu"),
                      wp.mat44(*to_clip.ravel()), width, height, 1, native, behind,
                      wp.empty(1, dtype=wp.vec4i, device="cpu"), 0])
    assert behind.numpy().all()


@pytest.fixture(scope="module")
def ball() -> Volume:
    """Soft tissue (40 HU) of radius 14 mm in air, 1 mm voxels, centred at the origin."""
    n = 40
    ijk = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1)
    r = np.linalg.norm(ijk - 19.5, axis=-1)
    return Volume(np.where(r < 14.0, 40, -1000).astype(np.int16), spacing=(1.0, 1.0, 1.0), origin=(-19.5,) * 3)


@pytest.fixture(scope="module")
def head():
    from softvr.datasets import head_ct

    return head_ct()


@wp.kernel
def _smoothed_gradient(vol: wp.array(dtype=wp.float32), n: wp.vec3i, strides: wp.vec3i, points: wp.array(dtype=wp.vec3),
                       axis: int, out: wp.array(dtype=wp.vec3), gradient: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    p = points[i]
    plain = K.gradient(vol, n, strides, p)
    out[i] = K.slice_smoothed(vol, n, strides, p, axis, plain)
    gradient[i] = plain


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_slice_smoothed_gradient_is_the_gradient_of_the_volume_smoothed_across_slices(axis):
    """slice_smoothed (and the gradient it smooths) against SciPy's route: smooth the voxels along ``axis`` by (1, 2, 1) / 4, take central
    differences (numpy.gradient), interpolate them trilinearly (map_coordinates, order 1) at
    points away from the edges (no clamping there). Float32 sums of values ~1: 1e-4."""
    rng = np.random.default_rng(3)
    n = np.array([9, 10, 11])
    vol = rng.uniform(-1.0, 1.0, n).astype(np.float32)
    points = rng.uniform(2.0, n - 3.0, (200, 3))
    smoothed = ndimage.correlate1d(vol.astype(float), [0.25, 0.5, 0.25], axis=axis, mode="nearest")
    truth = np.stack([ndimage.map_coordinates(g, points.T, order=1) for g in np.gradient(smoothed)], axis=1)
    plain = np.stack([ndimage.map_coordinates(g, points.T, order=1) for g in np.gradient(vol.astype(float))], axis=1)
    out, gradient = (wp.zeros(len(points), dtype=wp.vec3, device="cpu") for _ in range(2))
    wp.launch(_smoothed_gradient, dim=len(points), device="cpu",
              inputs=[wp.array(vol.ravel(), dtype=wp.float32, device="cpu"), wp.vec3i(*n),
                      wp.vec3i(*(s // 4 for s in vol.strides)), wp.array(points.astype(np.float32), dtype=wp.vec3,
                                                                          device="cpu"), axis, out, gradient])
    np.testing.assert_allclose(out.numpy(), truth, atol=1e-4)
    np.testing.assert_allclose(gradient.numpy(), plain, atol=1e-4)  # and the gradient itself


def test_changed_bricks_are_those_owning_a_changed_voxel():
    """``brick_changes`` against NumPy: brick b owns voxels b * BRICK .. b * BRICK + BRICK - 1 per
    axis (the last brick also the grid's far voxels); it is flagged iff one of them differs from
    the kept copy, which it then brings up to date. Single-voxel changes at every position within
    a brick (inner and edge bricks, a grid not a multiple of BRICK, C and F memory orders), and
    with inner bricks' rows compared as 64-bit words (a C-order last axis a multiple of BRICK)."""
    rng = np.random.default_rng(11)
    b = K.BRICK
    for order, last_axis in (("C", 5 * b + 2), ("F", 5 * b + 2), ("C", 5 * b)):
        shape = (4 * b + 3, 3 * b + 1, last_axis)
        known = np.asarray(rng.integers(-1000, 1000, shape), np.int16, order=order)
        vol = known.copy(order=order)
        nb = np.array([-(-(s - 1) // b) for s in shape])
        # One changed voxel in ~ a third of the bricks, each at a random position it owns.
        truth = np.zeros(nb, np.uint8)
        for brick in np.argwhere(rng.random(nb) < 0.35):
            last = np.where(brick == nb - 1, np.array(shape) - 1, brick * b + b - 1)
            voxel = tuple(rng.integers(brick * b, last + 1))
            vol[voxel] += 1
            truth[tuple(brick)] = 1
        strides = wp.vec3i(*(st // 2 for st in vol.strides))
        host = [a.ravel(order="K") for a in (vol, known)]
        flat = [wp.array(a, dtype=wp.int16, device="cpu", copy=False) for a in host]
        packed = int(last_axis % b == 0)
        rows = [wp.array(a.view(np.int64) if packed else np.zeros(1, np.int64), dtype=wp.int64, device="cpu",
                         copy=False) for a in host]
        changed = wp.zeros(tuple(nb), dtype=wp.uint8, device="cpu")
        wp.launch(K.brick_changes, dim=-(-int(np.prod(nb)) // 5), device="cpu",
                  inputs=[flat[0], wp.vec3i(*shape), strides, wp.vec3i(0, 0, 0), wp.vec3i(*nb), flat[1], *rows, packed,
                          changed, 5, 0])  # 5 bricks a thread: a short last block
        np.testing.assert_array_equal(changed.numpy(), truth, err_msg=order)
        np.testing.assert_array_equal(flat[1].numpy(), flat[0].numpy(), err_msg=order)  # the copy is up to date


@pytest.mark.parametrize("native", [False, True], ids=["warp", "cpp"])
def test_empty_space_distance_is_scipy_chessboard_distance_after_each_partial_update(native):
    """The empty-space jumps' field against SciPy: each brick's Chebyshev (chessboard) distance
    [bricks] to the nearest occupied one (seed 0), capped at the reach (what the seed holds
    for an empty brick), ``distance_transform_cdt`` on the whole grid. Brought up to date
    after seeds flip inside a box by passes over that box only (grown as far as a flip moves
    the distances), from a field that was right before: the three Warp passes, and the C++
    form ``RayCaster`` runs on the CPU. Boxes at the grid's corner, edge and inside."""
    rng = np.random.default_rng(8)
    nb, reach = (13, 11, 17), int(R.REACH)
    seed = np.where(rng.random(nb) < 0.004, 0, reach).astype(np.uint8)
    fields = [wp.array(seed, dtype=wp.uint8, device="cpu")] + [wp.empty(nb, dtype=wp.uint8, device="cpu")
                                                               for _ in range(3)]

    def update(first, last):
        if native:
            wp.launch(K.brick_distance_passes, dim=1, device="cpu",
                      inputs=[*fields, reach, wp.vec3i(*first), wp.vec3i(*last), 0])
            return
        first, last = np.array(first), np.array(last)
        for axis in range(3):
            first[axis], last[axis] = max(first[axis] - reach + 1, 0), min(last[axis] + reach - 1, nb[axis] - 1)
            count = last - first + 1
            wp.launch(K.brick_distance_pass, dim=int(np.prod(count)), device="cpu",
                      inputs=[fields[axis], axis, reach, wp.vec3i(*first), wp.vec3i(*count), fields[axis + 1], 0])

    update((0, 0, 0), np.array(nb) - 1)
    for first, last in (((0, 0, 0), (2, 3, 1)), ((4, 0, 9), (6, 10, 12)), ((12, 10, 16), (12, 10, 16))):
        box = tuple(slice(a, b + 1) for a, b in zip(first, last))
        truth = np.minimum(ndimage.distance_transform_cdt(seed != 0, metric="chessboard"), reach)
        np.testing.assert_array_equal(fields[3].numpy(), truth, err_msg=f"before {first} .. {last}")
        seed[box] = np.where(rng.random(seed[box].shape) < 0.1, 0, reach)
        fields[0].assign(seed)
        update(first, last)
    truth = np.minimum(ndimage.distance_transform_cdt(seed != 0, metric="chessboard"), reach)
    assert len(np.unique(truth)) >= 6  # near and far from occupied bricks, the cap among them
    np.testing.assert_array_equal(fields[3].numpy(), truth)


def test_stale_walk_distance_is_scipy_chessboard_distance_to_the_read_bricks():
    """The stale-ray walk's field (:meth:`RayCaster._read_distance`) against SciPy: a brick is
    marked iff it is occupied before or after the change (seed 0) and a brick within 1 of it
    changed (``ndimage.maximum_filter`` of size 3); the field is ``distance_transform_cdt``
    (chessboard) to the marked bricks, capped at ``_READ_REACH``, and the cap where none is,
    over the changed bricks' box grown by one (all the marked bricks lie there, and the walk
    runs only there). Random changes in boxes at the grid's corners, its middle and a single
    brick."""
    rng = np.random.default_rng(5)
    nb = (23, 17, 29)
    caster = R.RayCaster(PRESETS["ct"], device="cpu")
    for box in (((3, 2, 4), (12, 9, 20)), ((10, 5, 0), (22, 16, 8)), ((0, 0, 0), (4, 3, 5)), ((6, 6, 6), (6, 6, 6))):
        lo, hi = np.array(box[0]), np.array(box[1])
        changed = np.zeros(nb, np.uint8)
        changed[tuple(slice(a, b + 1) for a, b in zip(lo, hi))] = rng.random(hi - lo + 1) < 0.08
        seed = np.where(rng.random(nb) < 0.5, 0, R.REACH).astype(np.uint8)
        caster._occupied_before = rng.random(nb) < 0.3
        caster._changed_bricks, caster._seed = (wp.array(a, dtype=wp.uint8, device="cpu") for a in (changed, seed))
        caster._changed_box = (lo, hi)
        field, marked = caster._read_distance()
        truth = ndimage.maximum_filter(changed != 0, size=3, mode="constant") & ((seed == 0) | caster._occupied_before)
        got = np.zeros(nb, bool)
        got[tuple(np.asarray(marked, int).T)] = True
        np.testing.assert_array_equal(got, truth, err_msg=str(box))
        distance = np.minimum(ndimage.distance_transform_cdt(~truth, metric="chessboard"), R._READ_REACH) \
            if truth.any() else np.full(nb, R._READ_REACH)
        walked = tuple(slice(max(a - 1, 0), b + 2) for a, b in zip(lo, hi))
        np.testing.assert_array_equal(field[walked], distance[walked], err_msg=str(box))


@pytest.mark.parametrize("dtype", ["float32", "int16"])
@pytest.mark.parametrize("native", [False, True], ids=["warp", "cpp"])
def test_cell_masks_hold_every_cell_where_a_sample_can_be_visible(native, dtype):
    """``brick_minmax``'s cell masks against NumPy (float64): the ray loop skips a sample whose
    cell's bit is clear, so every cell where a trilinear sample's table opacity can be non-zero
    must have it. A sample's value lies between its cell's 8 corners, and the table is read at
    entries floor(u) and floor(u) + 1 of its position u: the cell can be visible iff an entry in
    floor(u(min)) .. ceil(u(max)) is (``visible``: their running count); the kernel adds one entry
    either side for rounding and no more. Bit layout: (i % BRICK) * BRICK^2 + (j % BRICK) * BRICK
    + k % BRICK in brick (i, j, k) // BRICK. A table with two visible bands (not an upper set), a
    grid not a multiple of BRICK (partial far bricks), all-air and all-tissue bricks (the
    kernel's shortcut) among mixed ones; and samples at random points (SciPy's trilinear
    interpolation, the table interpolated) never visible in a cleared cell. The same launch's
    seeds of the distance field: a brick is occupied iff its voxels' range holds a visible entry.
    Both forms of the kernel on the CPU (Warp's, and the C++ one ``RayCaster`` uses there), for
    float32 and int16 voxels."""
    rng = np.random.default_rng(5)
    b = int(K.BRICK)
    shape = np.array([4 * b + 3, 3 * b + 2, 2 * b + 1])
    ijk = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1)
    vol = (40.0 * (ijk @ np.array([1.0, 0.7, -0.4])) + rng.normal(0.0, 60.0, shape)).astype(np.float32)
    vol[: b + 1] = -1000.0  # all air
    vol[-b - 2:, : 2 * b + 1] = 300.0  # all tissue
    vol = vol.astype(dtype)
    size, lo, hi = 64, -1000.0, 1000.0
    opaque = np.zeros(size, bool)
    opaque[40:44] = opaque[52:58] = True
    visible = np.concatenate([[0], np.cumsum(opaque)]).astype(np.int32)
    scale = (size - 1) / (hi - lo)
    nb = np.array([-(-(s - 1) // b) for s in shape])
    cells = wp.zeros(tuple(nb), dtype=wp.uint64, device="cpu")
    seed = wp.full(tuple(nb), 255, dtype=wp.uint8, device="cpu")
    flips = wp.zeros(int(np.prod(nb)), dtype=wp.uint8, device="cpu")

    def minmax() -> np.ndarray:
        """One launch over every brick; the bricks flagged gained."""
        gained = wp.zeros(tuple(nb), dtype=wp.uint8, device="cpu")
        voxels = wp.array(vol.ravel(), dtype=K.VOXEL_TYPES[dtype], device="cpu")
        wp.launch(K.BRICK_MINMAX[dtype], dim=-(-int(np.prod(nb)) // 7), device="cpu",
                  inputs=[voxels, wp.vec3i(*shape), wp.vec3i(*(s // vol.itemsize for s in vol.strides)),
                          wp.zeros(tuple(nb), dtype=wp.uint8, device="cpu"), 1,
                          wp.array(visible, dtype=wp.int32, device="cpu"), lo, scale, 8, wp.uint64(voxels.ptr),
                          K.NATIVE_VOXEL_CODES[dtype] if native else 0, wp.vec3i(0, 0, 0), wp.vec3i(*nb), seed, flips,
                          cells, gained, 7, 0])  # 7 bricks a thread: a short last block
        return gained.numpy()

    minmax()
    masks = cells.numpy().view(np.uint64)
    c = np.stack(np.meshgrid(*[np.arange(s - 1) for s in shape], indexing="ij"), -1).reshape(-1, 3)
    bit = ((c[:, 0] % b) * b * b + (c[:, 1] % b) * b + c[:, 2] % b).astype(np.uint64)
    got = (masks[tuple((c // b).T)] >> bit) & np.uint64(1)
    corners = np.stack([vol[tuple((c + [x, y, z]).T)] for x in (0, 1) for y in (0, 1) for z in (0, 1)], -1).astype(float)
    position = lambda v: np.clip((v - lo) * scale, 0.0, size - 1)  # noqa: E731
    u0 = np.floor(position(corners.min(-1))).astype(int)
    u1 = np.ceil(position(corners.max(-1))).astype(int)
    may_show = lambda a, z: visible[np.minimum(z + 1, size)] - visible[np.maximum(a, 0)] > 0  # noqa: E731
    need, allowed = may_show(u0, u1), may_show(u0 - 1, u1 + 1)
    assert need.any() and (~allowed).any() and (got == 0).any() and (got == 1).any()
    assert np.all(got[need] == 1), f"{np.sum(got[need] == 0)} cells that can be visible are cleared"
    assert np.all(got[~allowed] == 0), f"{np.sum(got[~allowed] == 1)} cells far from a visible entry are set"
    points = rng.uniform(0.0, shape - 1.0, (20000, 3))
    alpha = np.interp(position(ndimage.map_coordinates(vol.astype(float), points.T, order=1)), np.arange(size),
                      opaque.astype(float))
    cell = np.minimum(points.astype(int), shape - 2)
    cell_bit = ((cell[:, 0] % b) * b * b + (cell[:, 1] % b) * b + cell[:, 2] % b).astype(np.uint64)
    shown = (masks[tuple((cell // b).T)] >> cell_bit) & np.uint64(1)
    assert (alpha > 0).sum() > 1000 and np.all(shown[alpha > 0] == 1)
    # The same launch seeds the distance field: 0 for a brick whose voxels b * BRICK .. (b + 1) * BRICK
    # hold a visible value in their range (no margin), else the reach; every seed changed from 255.
    occupied = np.zeros(nb, bool)
    for brick in np.ndindex(*nb):
        block = vol[tuple(slice(i * b, min((i + 1) * b, s - 1) + 1) for i, s in zip(brick, shape))].astype(float)
        occupied[brick] = may_show(int(np.floor(position(block.min()))), int(np.ceil(position(block.max()))))
    assert occupied.any() and (~occupied).any()
    np.testing.assert_array_equal(seed.numpy(), np.where(occupied, 0, 8))
    # Gained: a brick that turned occupied or whose mask took a bit since the last launch. The
    # same voxels again: none; one voxel of the all-air block set to a visible value: the only
    # brick whose voxel range holds it (voxel (1, 5, 5): brick (0, 1, 1), 4 .. 8 along y and z).
    assert not minmax().any()
    vol[1, 5, 5] = 300.0
    np.testing.assert_array_equal(np.argwhere(minmax()), [[0, 1, 1]])
    np.testing.assert_array_equal(flips.numpy(), np.ones(int(np.prod(nb)), np.uint8))


@wp.kernel
def _plain_gradient(vol: wp.array(dtype=wp.float32), n: wp.vec3i, strides: wp.vec3i, points: wp.array(dtype=wp.vec3),
                    out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = K.gradient(vol, n, strides, points[i])


def test_shading_gradient_is_the_trilinear_interpolation_of_edge_clamped_central_differences():
    """``gradient`` (the shading and gradient-opacity gradient) against NumPy and SciPy: the
    voxels' central differences (v[i + 1] - v[i - 1]) / 2 with indices clamped to the grid
    (an edge-padded copy), interpolated trilinearly (map_coordinates, order 1), at points
    anywhere in the grid, its faces and corners included. Float32 sums of values ~1: 1e-4."""
    rng = np.random.default_rng(5)
    n = np.array([7, 8, 9])
    vol = rng.uniform(-1.0, 1.0, n).astype(np.float32)
    points = np.concatenate([rng.uniform(0.0, n - 1.0, (300, 3)),
                             np.array([[0.0, 0.0, 0.0], n - 1.0, [0.0, 3.5, 8.0], [6.0, 0.25, 4.5]])])
    padded = np.pad(vol.astype(float), 1, mode="edge")
    centre = (slice(1, -1),) * 3
    differences = []
    for axis in range(3):
        up, down = list(centre), list(centre)
        up[axis], down[axis] = slice(2, None), slice(None, -2)
        differences.append((padded[tuple(up)] - padded[tuple(down)]) / 2.0)
    truth = np.stack([ndimage.map_coordinates(g, points.T, order=1) for g in differences], axis=1)
    out = wp.zeros(len(points), dtype=wp.vec3, device="cpu")
    wp.launch(_plain_gradient, dim=len(points), device="cpu",
              inputs=[wp.array(vol.ravel(), dtype=wp.float32, device="cpu"), wp.vec3i(*n),
                      wp.vec3i(*(s // 4 for s in vol.strides)),
                      wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu"), out])
    np.testing.assert_allclose(out.numpy(), truth, atol=1e-4)


def thick_slices_skull(dz: float) -> Volume:
    """A flat bone surface (HU -1000 to 1000 over 1.4 mm) tilted 7 degrees off slices
    ``dz`` [mm] thick under 1 mm pixels: the top of a skull on a head CT."""
    n, nz = 64, int(round(60.0 / dz))
    i, j, k = np.meshgrid(np.arange(n), np.arange(n), np.arange(nz), indexing="ij")
    normal = np.array([-0.12, -0.05, 1.0]) / np.linalg.norm([-0.12, -0.05, 1.0])
    d = (i - (n - 1) / 2) * normal[0] + (j - (n - 1) / 2) * normal[1] + (k - (nz - 1) / 2) * dz * normal[2]
    return Volume(np.clip(np.round(-1400.0 * d), -1000, 1000).astype(np.int16), spacing=(1.0, 1.0, dz))


def ripple(image: np.ndarray) -> float:
    """Standard deviation [grey levels] of the central 64 x 64 patch's luminance about a
    quadratic trend (a flat surface's smooth shading)."""
    h, w = image.shape[:2]
    lum = image[h // 2 - 32:h // 2 + 32, w // 2 - 32:w // 2 + 32].astype(float).mean(axis=2)
    y, x = np.mgrid[:64, :64].astype(float)
    basis = np.column_stack([np.ones(x.size), x.ravel(), y.ravel(), x.ravel() ** 2, y.ravel() ** 2, (x * y).ravel()])
    return float(np.std(lum.ravel() - basis @ np.linalg.lstsq(basis, lum.ravel(), rcond=None)[0]))


@pytest.mark.parametrize("elevation, azimuth", [(0.0, 30.0), (-20.0, -30.0)])
def test_scene_volume_draws_a_skull_top_on_thick_slices_without_slice_bands(elevation, azimuth):
    """The volume demo's skull top: a flat surface is shaded flat, so about its trend only
    noise and the reconstruction's error are left. On 0.5 mm slices the Warp caster leaves
    0.6-0.8 grey levels (jitter noise). On 1.5 mm slices the gradient of trilinear
    interpolation turns at every slice: shaded with it, 8.1-9.4 (a band per slice); VTK's
    fixed-point caster, the scenes' renderer before, 28-40 (also rays sampled in step and
    quantized normals, with holes). The scenes' renderer must stay under 5.5 (measured
    3.4-4.0, shading smoothed across slices)."""
    skull = thick_slices_skull(1.5)
    ripples = {}
    for mapper in ("auto", "cpu"):
        with SurfaceRenderer(128, 128, Camera("top", elevation=elevation, azimuth=azimuth, zoom=2.0),
                             background=(0, 0, 0), background_top=(0, 0, 0), antialias=False) as renderer:
            renderer.add_volume(skull, "ct", **({} if mapper == "auto" else {"mapper": mapper}))
            ripples[mapper] = ripple(renderer.render())
    assert ripples["auto"] < 5.5, ripples
    assert ripples["cpu"] > 15.0, ripples
