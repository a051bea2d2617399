"""The bundled demo scenes without a leaf example of their own (candy, candy-adhesive, palpation,
volume, shoulder-arthroscopy; the shoulder in tests/examples/test_shoulder.py) checked, each for
a few frames, against physics and the scene file's own numbers, never against another softvr path.

Truths:

* Free fall. A rigid body in the air falls by 1/2 g t^2 plus the semi-implicit Euler lag
  1/2 g dt t (velocity first, then position: x_N = x_0 + v_0 t - g dt^2 N (N + 1) / 2), and its
  velocity changes by exactly -g t; its horizontal velocity does not change.
* Newton's third law: bodies that touch only each other feel equal and opposite contact forces.
* A dry contact only pushes (normal impulse >= 0): a pulling contact is adhesion; adhesion
  intensities lie in [0, 1].
* Clamped nodes stay where they are; keyed nodes are where their keys put them.
* A tet map is valid while no tet inverts (its signed volume stays > 0).
"""

from __future__ import annotations

import numpy as np
import pytest

from softvr.cli import main
from softvr.scene import BUNDLED, load_scene

G = 9.81  # [m/s^2]


def test_every_demo_is_a_bundled_scene_file():
    """One definition per demo: ``softvr run NAME`` plays the bundled scene file NAME, and every
    leaf example plays a bundled scene file."""
    import importlib
    import pkgutil

    import softvr.examples
    from softvr.examples.run import SCENES

    assert SCENES == {p.stem: p for p in BUNDLED.glob("*.toml")}
    leaves = [m.name for m in pkgutil.iter_modules(softvr.examples.__path__) if m.name.startswith("example_")]
    played = {}
    for name in leaves:
        module = importlib.import_module(f"softvr.examples.{name}")
        if hasattr(module, "SCENE"):
            played[name] = module.SCENE
            assert module.SCENE.parent == BUNDLED and module.SCENE.is_file(), name
    assert len(played) == 11, played  # every leaf: the candy's too


@pytest.mark.parametrize("name", ["candy.toml", "candy-adhesive.toml"])
def test_candy_hard_pieces_fall_freely_then_land_on_the_jello(name, capsys):
    """Two frames (0.08 s of 8 ms steps): the hard candies are still in the air, so each falls
    exactly as semi-implicit Euler integrates gravity; nothing sinks into the Jell-O."""
    assert main(["check", name]) == 0
    with load_scene(BUNDLED / name, frames=2, width=48, height=32) as scene:
        hard = {n: b for n, b in scene.bodies.items() if n.startswith("hard candy")}
        assert len(hard) >= 4
        x0 = {n: b.position.copy() for n, b in hard.items()}
        v0 = {n: b.velocity.copy() for n, b in hard.items()}
        for _ in range(2):
            record = scene.step()
        t, dt = scene.scene.time, scene.dt
        for n, body in hard.items():
            np.testing.assert_allclose(body.velocity - v0[n], [0.0, 0.0, -G * t], atol=1e-12)
            fall = body.position[2] - x0[n][2] - v0[n][2] * t
            assert fall == pytest.approx(-0.5 * G * t**2 - 0.5 * G * dt * t, abs=1e-12)
        assert record["max_penetration_m"] < G * dt**2


def test_adhesive_candies_pull_on_the_jello_once_they_bond():
    """The same drop with adhesive surfaces: once the candies have landed and bonded, some
    contacts pull (normal impulse < 0, which a dry contact never does), every intensity in
    [0, 1]; the plain candy scene never pulls."""
    pulled = {}
    for name in ("candy.toml", "candy-adhesive.toml"):
        with load_scene(BUNDLED / name, frames=6, width=48, height=32) as scene:
            pulls = 0
            for _ in range(6):
                scene.step()
                impulses = [i for i in scene.scene.last_solution.impulses if len(i)]
                pulls = max(pulls, sum(int((i[:, 0] < 0).sum()) for i in impulses))
                beta = np.array(list(scene.scene.adhesion_state.intensity.values()))
                assert ((beta >= 0) & (beta <= 1)).all()
            pulled[name] = pulls
    assert pulled["candy.toml"] == 0 and pulled["candy-adhesive.toml"] > 0, pulled


def test_the_dry_variant_is_the_same_scene_without_a_pull():
    """candy-adhesive.toml's ``dry`` variant (simulation.adhesion = false): the same bodies, and
    no contact ever pulls (a dry contact only pushes), where the adhesive file's held candy, pressed
    into the Jell-O by its hand, bonds and pulls within 0.2 s."""
    pulls = {}
    for variants in (("quick",), ("quick", "dry")):
        with load_scene(BUNDLED / "candy-adhesive.toml", variants, frames=5, width=48, height=32) as scene:
            assert len(scene.bodies) == 7
            most = 0
            for _ in range(5):
                scene.step()
                most = max(most, sum(int((i[:, 0] < 0).sum()) for i in scene.scene.last_solution.impulses if len(i)))
            pulls[variants[-1]] = most
    assert pulls["dry"] == 0 and pulls["quick"] > 0, pulls


def test_shoulder_arthroscopy_scene_checks_and_plays(capsys):
    assert main(["check", "shoulder-arthroscopy.toml"]) == 0
    with load_scene(BUNDLED / "shoulder-arthroscopy.toml", frames=3, width=64, height=48, haptics=False) as scene:
        probe = scene.index["probe"]
        for name in ("scapula", "humerus"):  # the portal: the probe passes the bones
            assert not scene.scene.collision_enabled(probe, scene.index[name])
        assert scene.scene.collision_enabled(probe, scene.index["supraspinatus"])
        for _ in range(3):
            record = scene.step()
        assert record["max_penetration_m"] < 1e-3
        assert scene.bodies["probe"].position[0] < 0.075  # on its way in under the acromion (from x = 75 mm)


def test_palpation_presses_the_cheek_and_holds_the_skull(capsys):
    """palpation.toml: the probe (kinematic) starts 2 mm off the cheek's skin and goes 5 mm past
    it at 0.2 s (its front travels 7 mm). Clamped
    (bone) nodes never move; the probe touches only the head, so their contact forces are equal
    and opposite; the contact is dry, so the cheek only pushes the probe back out (+y, the way it
    came: never a pull), and it does push once the probe is in; the CT is drawn through the tets."""
    assert main(["check", "palpation.toml"]) == 0
    assert "a volume body 'head'" in capsys.readouterr().out
    with load_scene(BUNDLED / "palpation.toml", frames=20, width=96, height=96) as scene:
        head, probe = scene.bodies["head"], scene.bodies["probe"]
        rest = head.q.copy()
        front = probe.position[1] - 0.012  # [m] the probe's front (radius 12 mm) at the start
        held = head.fixed.copy()
        assert held.any()
        deepest, push = 0.0, []
        for _ in range(20):
            record = scene.step()
            np.testing.assert_array_equal(head.q[held], rest[held])
            s = scene.scene.last_solution
            fp, fh = s.force_on(scene.index["probe"], scene.dt), s.force_on(scene.index["head"], scene.dt)
            np.testing.assert_allclose(fp, -fh, atol=1e-9 * max(1.0, np.abs(fp).max()))
            push.append(float(fp[1]))
            deepest = max(deepest, front - (probe.position[1] - 0.012) - 0.002)  # past the skin
        assert deepest == pytest.approx(0.005, abs=1e-6)  # the keys' 5 mm
        assert max(push) > 0.1 and min(push) >= -1e-9 * max(push)  # [N]
        assert record["raster_voxels"] >= 0 and "raster_ms" in record
        image = scene.render()
    # The CT is drawn (skin colours in the middle of the image), not just the probe.
    middle = image[32:64, 32:64].reshape(-1, 3).astype(int)
    assert (middle[:, 0] - middle[:, 2] > 40).mean() > 0.3


def test_volume_follows_its_animation_which_inverts_no_tet(capsys):
    """volume.toml: the head's nodes are keyed (volume/press-and-twist.npz), so at every frame
    they are the keys linearly interpolated at its time; no key inverts a tet (signed volumes
    stay > 0: the rasterization through them is a valid map), and the CT is drawn through them."""
    assert main(["check", "volume.toml"]) == 0
    frames = 4
    with np.load(BUNDLED / "volume" / "press-and-twist.npz") as f:
        times, keys = np.asarray(f["times"]), np.asarray(f["nodes"], float)
    with load_scene(BUNDLED / "volume.toml", frames=frames, width=96, height=72) as scene:
        head = scene.bodies["head"]  # the keys are in metres, float32 (0.1 um at 0.3 m)
        tets = head.tets

        def signed_volumes(x):
            a, b, c, d = (x[tets[:, k]] for k in range(4))
            return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0

        rest_volumes = signed_volumes(keys[0])
        for k in range(len(keys)):
            assert (signed_volumes(keys[k]) / rest_volumes).min() > 0.3, k
        for _ in range(frames):
            record = scene.step()
            t = scene.scene.time
            j = np.searchsorted(times, t) - 1
            w = (t - times[j]) / (times[j + 1] - times[j])
            np.testing.assert_allclose(head.q, (1 - w) * keys[j] + w * keys[j + 1], atol=1e-7)
        assert record["raster_voxels"] > 0
        image = scene.render()
    middle = image[24:48, 32:64].reshape(-1, 3).astype(int)
    assert (middle.sum(axis=1) > 200).mean() > 0.3  # the bright CT fills the middle


def test_volume_section_errors_are_named_at_once(tmp_path):
    from softvr.errors import InputError
    from softvr.scene import read_scene

    bad = tmp_path / "bad.toml"
    bad.write_text('format = "softvr-scene 1"\n[volume]\nfile = "no-such.nrrd"\ncells = [16, 16]\npreset = "glow"\n'
                   'animation = "missing.npz"\nunit = -1.0\nshine = 1\n')
    with pytest.raises(InputError) as err:
        read_scene(bad)
    text = str(err.value)
    for field in ("volume.file", "volume.cells", "volume.preset", "volume.animation", "volume.unit", "volume.shine"):
        assert field in text, field
    # An animation that does not fit the mesh: named with its file and field.
    np.savez(tmp_path / "short.npz", times=[0.0, 1.0], nodes=np.zeros((2, 5, 3)))
    good = tmp_path / "anim.toml"
    good.write_text('format = "softvr-scene 1"\n[volume]\nfile = "head-ct"\ncells = [4, 4, 2]\nmask = false\n'
                    'animation = "short.npz"\n')
    with pytest.raises(InputError, match=r"short.npz: nodes: expected \[2, 75, 3\]"):
        load_scene(good, frames=1)
