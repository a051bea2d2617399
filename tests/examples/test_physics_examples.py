"""The physics demos run headless for a few frames, and what they did is physically sane.

Truths checked on every demo's per-frame metrics: contacts hold (penetration below 1 mm, the
solver's speculative contacts forbid crossing), energy never grows (backward Euler and
inelastic contact only dissipate: kinetic + gravitational energy stays below its initial
value, elastic energy being >= 0), and the bodies do what the scene says (the stack stays
put, the oranges roll forward in their lanes, the cloth rests on the sphere).
"""

import json

import imageio.v3 as iio
import numpy as np
import pytest

from softvr.examples import (example_box_stack, example_candy, example_cloth_sphere, example_cloth_wall, example_lips,
                             example_oranges, example_probe, example_soft_cube, run)
from softvr.app import play_window
from softvr.examples.run import SCENES

SMALL = dict(width=64, height=48)
FIELDS = {"frame", "sim_time_s", "step_ms", "stage_ms", "render_ms", "wall_ms", "max_penetration_m", "contacts",
          "active_contacts", "pgs_iterations", "pgs_residual_m_per_s", "kinetic_energy_j", "energy_j"}


def run_frames(example, frames: int, render_every: int = 4):
    """Step ``frames`` frames, rendering some; returns the initial total energy and the images."""
    e0 = example.energies()[1]
    images = []
    try:
        for f in range(frames):
            example.step()
            if f % render_every == 0 or f == frames - 1:
                images.append(example.render())
    finally:
        example.close()
    return e0, images


def check_common(example, e0: float, images, *, penetration: float = 1e-3, extra_fields=(), driven: bool = False):
    """Frames, times, penetration, images; and energy never grows, unless ``driven`` (jaws or a
    tool moving on a script do work on the bodies)."""
    m = example.metrics
    assert [r["frame"] for r in m] == list(range(len(m)))
    assert set(m[0]) == FIELDS | set(extra_fields)
    steps = np.arange(1, len(m) + 1) * example.steps_per_frame
    np.testing.assert_allclose([r["sim_time_s"] for r in m], steps * example.dt, rtol=1e-9)
    assert max(r["max_penetration_m"] for r in m) < penetration
    energy = np.array([r["energy_j"] for r in m])
    assert driven or energy.max() <= e0 + 1e-6 + 1e-4 * abs(e0), "energy grew"
    assert all(r["wall_ms"] >= r["step_ms"] > 0 for r in m)
    # The stages run inside the frame's steps, one after the other: each took time, together
    # no more than the frame's physics.
    for r in m:
        assert list(r["stage_ms"]) == ["dynamics", "collision", "contact", "integrate"]
        assert all(ms > 0 for ms in r["stage_ms"].values())
        assert sum(r["stage_ms"].values()) <= r["step_ms"]
    for image in images:
        assert image.shape == (48, 64, 3) and image.dtype == np.uint8
        assert image.std() > 5  # a scene, not a blank frame


def test_soft_cube_lands_without_penetrating_and_loses_energy():
    ex = example_soft_cube.Example(frames=12, **SMALL)
    assert 100 <= len(ex.body.tets) <= 400
    e0, images = run_frames(ex, 12)
    check_common(ex, e0, images)
    # It fell 15 cm and landed: contacts now, and the lowest node at the ground (within the margin).
    assert ex.metrics[-1]["contacts"] > 0
    assert abs(ex.body.q[:, 2].min()) < 2e-3
    # Landing on an edge dissipates: 1/2 m v^2 at impact is mostly gone within the frames.
    assert ex.metrics[-1]["energy_j"] < e0 - 0.5 * ex.body.mass.sum() * 9.81 * 0.15
    # Its render mesh is the closed, outward boundary of the tets (each edge in two triangles).
    edges = np.sort(np.concatenate([ex.faces[:, [0, 1]], ex.faces[:, [1, 2]], ex.faces[:, [2, 0]]]), axis=1)
    assert (np.unique(edges, axis=0, return_counts=True)[1] == 2).all()


def test_box_stack_stays_put():
    ex = example_box_stack.Example(frames=8, **SMALL)
    e0, images = run_frames(ex, 8)
    check_common(ex, e0, images)
    assert ex.drift().max() < 1e-3  # every box within 1 mm of its start
    # 4 ground corners + 4 corners on each of the 4 boxes below the top one.
    assert ex.metrics[-1]["contacts"] == 20
    assert ex.metrics[-1]["kinetic_energy_j"] < 1e-6


def test_cloth_drapes_onto_the_sphere_without_energy_gain():
    ex = example_cloth_sphere.Example(frames=10, **SMALL)
    e0, images = run_frames(ex, 10, render_every=9)
    # Sphere penetration is checked by the next test; here: ground, energy, contacts.
    check_common(ex, e0, images, penetration=np.inf)
    assert ex.metrics[-1]["contacts"] > 20  # the cloth lies on the sphere
    assert -ex.cloth.q[:, 2].min() < 1e-3  # and not through the ground
    centre = ex.cloth.q[len(ex.cloth.q) // 2]
    assert centre[2] == pytest.approx(2 * ex.sphere.radius, abs=5e-3)  # the middle rests on the top


def test_cloth_vertices_stay_outside_the_sphere():
    ex = example_cloth_sphere.Example(frames=6, **SMALL)
    deepest = 0.0
    try:
        for _ in range(6):
            ex.step()
            deepest = max(deepest, -ex.sphere_gap().min())
    finally:
        ex.close()
    assert deepest < 2e-3


def test_oranges_bounce_and_roll_in_their_lanes():
    ex = example_oranges.Example(frames=8, count=3, **SMALL)
    assert all(100 <= len(o.tets) <= 300 for o in ex.oranges)
    start = np.array([o.q.mean(axis=0) for o in ex.oranges])
    e0, images = run_frames(ex, 8)
    check_common(ex, e0, images)
    end = np.array([o.q.mean(axis=0) for o in ex.oranges])
    assert (end[:, 0] > start[:, 0] + 0.1).all()  # moving forward
    np.testing.assert_allclose(end[:-1, 1], start[:-1, 1], atol=0.02)  # in their lanes
    assert end[-1, 1] < start[-1, 1] - 0.03  # the last one crosses towards its neighbour's lane
    # Soft-soft contact keeps them apart: centres at least two squashed radii away.
    for i in range(len(end)):
        for j in range(i):
            assert np.linalg.norm(end[i] - end[j]) > 2 * 0.85 * ex.radius
    assert ex.metrics[-1]["contacts"] > 0  # at least one has landed
    # Their surfaces stay round: every surface vertex within 15 % of the radius from the centre.
    for s in ex.surfaces:
        p = s.positions()
        r = np.linalg.norm(p - p.mean(axis=0), axis=1)
        np.testing.assert_allclose(r, ex.radius, rtol=0.15)


def test_candy_scale_and_candies_landing_on_the_jello():
    """The full scene has the thesis' size (10 K tets, 25-28 K collision triangles); the small
    one runs: candies land on the block and rest on it without sinking in (every contact's
    gap >= -1 mm after the solve), energy never grows."""
    full = example_candy.Example(frames=1, **SMALL)
    assert 9_000 <= full.tet_count <= 12_000 and 24_000 <= full.triangle_count <= 30_000
    # The block's collision surface is closed and outward (each edge in two triangles).
    edges = np.sort(np.concatenate([full.block_triangles[:, [0, 1]], full.block_triangles[:, [1, 2]],
                                    full.block_triangles[:, [2, 0]]]), axis=1)
    assert (np.unique(edges, axis=0, return_counts=True)[1] == 2).all()
    ex = example_candy.Example(frames=10, scale=example_candy.SMALL_SCALE, **SMALL)
    top = ex.block.q[:, 2].max()
    e0, images = run_frames(ex, 10, render_every=9)
    check_common(ex, e0, images)
    centres = np.array([c.q.mean(axis=0) if hasattr(c, "tets") else c.position for c in ex.candies])
    assert (centres[:, 2] < top + 0.06).sum() >= 2  # at least two have come down onto the block
    assert (centres[:, 2] > top - 0.01).all()  # none sank into it
    assert ex.metrics[-1]["active_contacts"] > 0


def test_adhesive_candies_stick_to_the_jello():
    """With adhesion some contacts pull (negative normal impulse) once the candies have
    landed and bonded, every intensity stays in [0, 1], and energy still never grows."""
    ex = example_candy.Example(frames=24, scale=example_candy.SMALL_SCALE, adhesion=True, **SMALL)
    e0, images = run_frames(ex, 24, render_every=23)
    check_common(ex, e0, images)
    pulled = [int((i[:, 0] < 0).sum()) for i in ex.scene.last_solution.impulses]
    beta = np.array(list(ex.scene.adhesion_state.intensity.values()))
    assert beta.size > 0 and beta.min() >= 0.0 and beta.max() <= 1.0
    assert sum(pulled) > 0


def test_cloth_sticks_to_the_wall_then_peels():
    """The swung cloth bonds to the wall on impact and then loses bonded vertices (debonding
    under its weight), never passing through the wall; without adhesion nothing bonds."""
    ex = example_cloth_wall.Example(frames=6, quads=8, **SMALL)
    bonded = []
    e0, images = run_frames(ex, 6, render_every=5)
    check_common(ex, e0, images)
    for _ in range(30):
        ex.step()
        bonded.append(ex.on_wall())
    assert max(bonded) > 10 and bonded[-1] < max(bonded)
    plain = example_cloth_wall.Example(frames=3, quads=8, adhesion=None, **SMALL)
    for _ in range(3):
        plain.step()
    assert plain.on_wall() == 0 and plain.metrics[-1]["contacts"] > 0
    plain.close()


def _run_lips(adhesion):
    ex = example_lips.Example(frames=35, adhesion=adhesion, **SMALL)
    e0, images = run_frames(ex, 35, render_every=17)
    check_common(ex, e0, images, penetration=5e-4, driven=True,
                 extra_fields={"opening_m", "lip_gap_m", "lip_force_n", "bonded_contacts"})
    m = ex.metrics
    # The opening (jaws apart beyond their start) at which the lips' surfaces are 0.5 mm apart.
    parted = next(r["opening_m"] for r in m if r["sim_time_s"] > ex.press_time + ex.hold_time and r["lip_gap_m"] > 5e-4)
    return m, parted


def test_lips_stick_as_they_open():
    """Thesis Fig. 4.3. Dry lips part as soon as the jaws are back where the lips first touched
    (their elastic recovery, ~1 mm into the opening), and a contact never pulls (lambda_n >= 0:
    the force between them stays >= 0). Adhesive lips bond under the press, pull on each other
    as the jaws open (force < 0) and part at least 2 mm later. Pressing is the same for both
    (adhesion acts in tension only): the largest pressing force agrees within 1 %."""
    sticky, sticky_parted = _run_lips(example_lips.LIPS_ADHESION)
    dry, dry_parted = _run_lips(None)
    assert max(r["bonded_contacts"] for r in sticky) > 20 and max(r["bonded_contacts"] for r in dry) == 0
    assert min(r["lip_force_n"] for r in dry) >= -1e-3 * max(r["lip_force_n"] for r in dry)
    assert min(r["lip_force_n"] for r in sticky) < -0.5
    assert dry_parted < 2e-3 and sticky_parted > dry_parted + 2e-3
    press = [max(r["lip_force_n"] for r in m) for m in (sticky, dry)]
    assert press[0] == pytest.approx(press[1], rel=0.01)


def _run_probe(adhesion):
    ex = example_probe.Example(frames=35, cells=(8, 8, 4), speed=0.02, adhesion=adhesion, **SMALL)
    e0, images = run_frames(ex, 35, render_every=17)
    check_common(ex, e0, images, penetration=1e-4, driven=True,
                 extra_fields={"indentation_m", "probe_force_n", "surface_lift_m", "bonded_contacts"})
    assert ex.metrics[-1]["indentation_m"] == pytest.approx(-0.003)  # withdrawn 3 mm above the surface
    return ex.metrics, ex


def test_probe_pressed_and_withdrawn_pulls_the_tissue_only_with_adhesion(tmp_path):
    """Dry contact only pushes: the probe force is never negative, and once the probe is above
    the rest surface the tissue is back below it (within 0.1 mm). With adhesion the force turns
    tensile while withdrawing and the tissue surface follows the probe above its rest height.
    Loading is the same with and without adhesion (tension only): peak forces within 1 %. The
    force rises monotonically while pressing (a stiffening contact: the contact area grows)."""
    sticky, ex = _run_probe(example_probe.PROBE_ADHESION)
    dry, _ = _run_probe(None)
    peak = [max(r["probe_force_n"] for r in m) for m in (sticky, dry)]
    assert peak[0] == pytest.approx(peak[1], rel=0.01)
    assert min(r["probe_force_n"] for r in dry) >= -1e-3 * peak[1]
    assert min(r["probe_force_n"] for r in sticky) < -0.05 * peak[0]
    above = [r for r in dry if r["indentation_m"] < 0 and r["sim_time_s"] > ex.press_time]
    assert max(r["surface_lift_m"] for r in above) < 1e-4
    assert max(r["surface_lift_m"] for r in sticky) > 3e-4
    pressing = [r["probe_force_n"] for r in dry if 0 < r["indentation_m"] and r["sim_time_s"] < ex.press_time]
    assert len(pressing) > 5 and (np.diff(pressing) > 0).all()
    # Its plot is written next to the run's files.
    written = ex.write_plots({"frames": sticky}, tmp_path)
    assert [p.name for p in written] == ["probe_force.png"] and iio.imread(written[0]).shape[2] >= 3


def test_view_plays_a_scene_live_in_a_window(display):
    """Under Xvfb: the window opens, frames advance on the timer, it closes on time."""
    ex = example_soft_cube.Example(frames=3, width=160, height=120)
    assert play_window(ex, timeout_s=3.0) == 3  # all frames played, then idle until closed
    assert [r["frame"] for r in ex.metrics] == [0, 1, 2]


def test_view_without_a_display_says_so(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    from softvr.errors import InputError

    with pytest.raises(InputError, match="display"):
        run.view_main(["soft-cube", "--frames", "2"])
    with pytest.raises(SystemExit):
        run.view_main(["teapot"])
    assert "unknown scene 'teapot'" in capsys.readouterr().err


def test_run_writes_video_sheet_and_metrics(tmp_path):
    out = tmp_path / "out"
    assert run.main(["box-stack", "--frames", "3", "--size", "64", "48", "--out", str(out), "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["box-stack.mp4", "box-stack_metrics.json", "box-stack_sheet.png"]
    assert len(list(iio.imiter(out / "box-stack.mp4"))) == 3
    assert iio.imread(out / "box-stack_sheet.png").shape[2] == 3
    doc = json.loads((out / "box-stack_metrics.json").read_text())
    assert doc["scene"] == "box-stack" and doc["fps"] == pytest.approx(25.0)
    assert len(doc["frames"]) == 3 and set(doc["frames"][0]) == FIELDS
    assert doc["summary"]["max_penetration_m"] < 1e-3


def test_run_passes_scene_options_on(tmp_path, capsys):
    out = tmp_path / "candy"
    assert run.main(["candy", "--small", "--adhesion", "--frames", "1", "--size", "32", "24", "--out", str(out),
                     "--quiet"]) == 0
    doc = json.loads((out / "candy_metrics.json").read_text())
    assert doc["adhesion"] is True and doc["tets"] < 2000  # --adhesion and --small reached the scene
    with pytest.raises(SystemExit):
        run.main(["candy", "--help"])
    assert "--adhesion" in capsys.readouterr().out


def test_each_example_main_runs(tmp_path):
    assert example_soft_cube.main(["--frames", "1", "--size", "32", "24", "--out", str(tmp_path), "--quiet"]) == 0
    assert (tmp_path / "soft-cube.mp4").stat().st_size > 0
    assert set(SCENES.values()) == {"soft_cube", "box_stack", "cloth_sphere", "oranges", "candy", "cloth_wall", "lips",
                                    "probe", "shoulder"}
    from softvr.examples import example_shoulder

    for module in (example_soft_cube, example_box_stack, example_cloth_sphere, example_oranges, example_candy,
                   example_cloth_wall, example_lips, example_probe, example_shoulder):
        assert module.DEFAULT_FRAMES >= 30 and callable(module.main)


@pytest.mark.parametrize("scene, message", [
    ("teapot", "unknown scene 'teapot'; choose a scene file or one of: soft-cube, box-stack, cloth-sphere, oranges, "
               "candy, cloth-wall, lips, probe, shoulder"),
    ("scenes/my_scene.json", "scene files are TOML (.toml) or glTF (.gltf, .glb)"),
])
def test_run_rejects_unknown_scenes_clearly(scene, message, capsys):
    with pytest.raises(SystemExit) as exc:
        run.main([scene])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_run_rejects_bad_sizes(capsys):
    with pytest.raises(SystemExit):
        run.main(["oranges", "--frames", "0"])
    assert "--frames" in capsys.readouterr().err
