"""Every leaf example (``softvr/examples/example_<topic>.py``) played headless for a few frames,
and what its scene did checked against physics, never against another softvr path.

The truths, each stated where it is checked:

* Free fall. Before a body touches anything only gravity acts, so its centre of mass falls by
  1/2 g t^2 and its velocity changes by -g t; the integrators (velocity first, then position:
  semi-implicit / backward Euler) put the position after N steps of dt at
  -g dt^2 N (N + 1) / 2 = -1/2 g t^2 - 1/2 g dt t, a lag of exactly 1/2 g dt t, which is the
  tolerance. Mass-proportional (Rayleigh) damping alpha turns the fall into
  z(t) = (g / alpha) (t - (1 - exp(-alpha t)) / alpha).
* Momentum. Without horizontal forces (in the air) the horizontal momentum of every body stays
  what it was; between two bodies that touch only each other the contact forces are equal and
  opposite (Newton's third law).
* Energy. Backward Euler, inelastic contact and adhesion only dissipate, so kinetic plus
  gravitational energy never exceeds its start value (elastic energy, >= 0, is zero at the start
  of every scene here); float round-off over a few hundred steps stays below 1e-9 of it.
* Contact. A resting or landing contact is solved at the velocity level with speculative gaps:
  what one step's gravity carries past the surface, g dt^2, bounds the overlap after the solve;
  a kinematic body moving at v carries at most v dt into a surface.
* Rest. A stack of boxes of height h rests with box i's centre at (2 i + 1) h / 2, each of the
  i + 1 contacts below it overlapping by at most g dt^2, and never above where it started.
"""

from __future__ import annotations

import contextlib
import json
import re
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from softvr.examples import (example_box_stack, example_candy, example_cloth_sphere, example_cloth_wall, example_lips,
                             example_oranges, example_palpation, example_probe, example_shoulder, example_soft_cube,
                             example_volume_deform)
from softvr.scene import BUNDLED, load_scene

G = 9.81  # [m/s^2], every scene with gravity here has gravity = (0, 0, -9.81)


def play(module, frames: int, tmp_path):
    """The example's own command, headless: ``--headless --frames N`` into ``tmp_path``; returns the
    played player (its bodies at the last frame, its metrics)."""
    return module.main(["--headless", "--frames", str(frames), "--size", "48", "32", "--out", str(tmp_path)])


def start_of(module):
    """The example's scene as it starts (built, not played): the initial state to compare with."""
    return load_scene(module.SCENE, frames=1, width=48, height=32)


def check_energy_never_grows(player, e0: float) -> None:
    energy = np.array([r["energy_j"] for r in player.metrics])
    assert energy.max() <= e0 + 1e-9 * max(abs(e0), 1.0), (e0, energy.max())


def centre_of_mass(body) -> np.ndarray:
    m = np.asarray(body.mass, float)
    return (m[:, None] * body.q).sum(axis=0) / m.sum()


def test_the_leaf_writes_video_sheet_and_metrics(tmp_path):
    player = play(example_box_stack, 3, tmp_path)
    name = player.name
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{name}.mp4", f"{name}_metrics.json", f"{name}_sheet.png"]
    assert len(list(iio.imiter(tmp_path / f"{name}.mp4"))) == 3
    doc = json.loads((tmp_path / f"{name}_metrics.json").read_text())
    # fps = 1 / (dt steps_per_frame) of the file: 1 / (0.01 s x 4).
    assert len(doc["frames"]) == 3 and doc["fps"] == pytest.approx(1 / (0.01 * 4))


@pytest.mark.parametrize("module", [example_shoulder, example_palpation, example_volume_deform],
                         ids=lambda m: m.__name__.rsplit(".", 1)[-1])
def test_the_scene_leaves_play_headless(module, tmp_path):
    """The leaves whose physics tests/scene/test_demo_scenes.py and test_shoulder.py check on the
    same scene file: two frames each through the script, its clock the fixed step's
    (t = frames x steps_per_frame x dt), its three files written."""
    player = play(module, 2, tmp_path)
    assert player.scene.time == pytest.approx(2 * player.steps_per_frame * player.dt, rel=1e-12)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"{player.name}{s}" for s in
                                                                 (".mp4", "_metrics.json", "_sheet.png"))


def test_box_stack_rests_at_the_height_its_boxes_stack_to(tmp_path):
    start = start_of(example_box_stack)
    e0 = start.energies()[1]
    z0 = np.array([start.bodies[f"box {i}"].position[2] for i in range(5)])
    player = play(example_box_stack, 8, tmp_path)
    h, dt = 0.1, player.dt  # the boxes' height [m] (box = [0.2, 0.2, 0.1]) and the step
    boxes = [player.bodies[f"box {i}"] for i in range(5)]
    z = np.array([b.position[2] for b in boxes])
    rest = (2 * np.arange(5) + 1) * h / 2
    assert (z >= rest - (np.arange(5) + 1) * G * dt**2).all(), z - rest
    assert (z <= z0 + 1e-12).all()  # settled down onto each other, never lifted
    # At rest: no horizontal drift but what the solver's velocity error (at most its residual,
    # m/s, every step) carries over the time played, and less kinetic energy than one step of
    # free fall would give the whole stack, 1/2 M (g dt)^2.
    mass = sum(b.mass for b in boxes)
    residual = max(r["pgs_residual_m_per_s"] for r in player.metrics)
    assert np.abs([b.position[:2] for b in boxes]).max() <= residual * player.scene.time
    assert player.metrics[-1]["kinetic_energy_j"] < 0.5 * mass * (G * dt) ** 2
    assert max(r["max_penetration_m"] for r in player.metrics) < G * dt**2
    check_energy_never_grows(player, e0)


def test_box_knock_topples_the_stack_with_the_ram(tmp_path):
    """box-knock.toml: box-stack's five boxes and a kinematic ram on a script (held, then driven
    through the stack's middle). 32 frames (1.28 s): the ram is where its keys put it (linear
    between them) at every frame; by then it has passed through the stack (its back past the
    stack's far side) and the top box has had longer than a free fall from its height to land.
    Knocked over: the top box ends lower than it started by at least a box height and moved
    sideways off the stack's footprint (more than half a box width); no box is deeper in the
    ground than one step of gravity carries it (g dt^2), every box centre at least its smallest
    half-extent above the ground."""
    player = load_scene(BUNDLED / "box-knock.toml", frames=32, width=48, height=32)
    spec, ram_spec = player.file.body("box 4"), player.file.body("ram")
    w, _, h = spec.size  # [m] box width and height
    times, keys = np.asarray(ram_spec.motion["times"]), np.asarray(ram_spec.motion["positions"])
    top, ram = player.bodies["box 4"], player.bodies["ram"]
    x0 = top.position.copy()
    boxes = [player.bodies[f"box {i}"] for i in range(5)]
    with player:
        for _ in range(32):
            player.step()
            t = player.scene.time
            expected = [np.interp(t, times, keys[:, k]) for k in range(3)]
            np.testing.assert_allclose(ram.position, expected, atol=1e-9)
            assert all(b.position[2] >= h / 2 - G * player.dt**2 for b in boxes)
    t = player.scene.time
    passed = keys[-1, 0] - ram_spec.size[0] / 2 > w / 2  # the ram's back beyond the stack's far side
    reach = np.interp(w / 2 + ram_spec.size[0] / 2, keys[-2:, 0], times[-2:])  # when (its last keys drive it)
    assert passed and t > reach + np.sqrt(2 * x0[2] / G)
    assert top.position[2] <= x0[2] - h
    assert np.linalg.norm(top.position[:2] - x0[:2]) > w / 2
    assert max(r["max_penetration_m"] for r in player.metrics) < G * player.dt**2


def test_soft_cube_falls_as_gravity_and_its_damping_say(tmp_path):
    """3 frames (0.12 s) of the fall: the lowest node, 0.177 m up, needs sqrt(2 x 0.177 / g) =
    0.19 s to reach the ground, so only gravity and the mass damping (alpha = 1 /s) act.
    Rigid translation strains nothing: the elastic and stiffness-damping forces vanish."""
    start = start_of(example_soft_cube)
    c0 = centre_of_mass(start.bodies["soft cube"])
    assert np.sqrt(2 * start.bodies["soft cube"].q[:, 2].min() / G) > 0.12
    player = play(example_soft_cube, 3, tmp_path)
    cube, t, dt, alpha = player.bodies["soft cube"], player.scene.time, player.dt, 1.0
    c, v = centre_of_mass(cube), (np.asarray(cube.mass)[:, None] * cube.v).sum(axis=0) / np.sum(cube.mass)
    fall = G / alpha * (t - (1 - np.exp(-alpha * t)) / alpha)  # 0.0679 m (1/2 g t^2: 0.0706 m)
    assert c0[2] - c[2] == pytest.approx(fall, abs=0.5 * G * dt * t)  # the integrator's lag, 2.9 mm
    # Backward Euler's velocity on v' = -g - alpha v errs by at most alpha g dt t (5.9 mm/s here);
    # without the damping v would be -g t, 70 mm/s further.
    assert v[2] == pytest.approx(-G / alpha * (1 - np.exp(-alpha * t)), abs=alpha * G * dt * t)
    np.testing.assert_allclose(c[:2], c0[:2], atol=1e-12)  # no horizontal force
    assert player.metrics[-1]["contacts"] == 0


def test_soft_cube_lands_without_sinking_and_dissipates(tmp_path):
    start = start_of(example_soft_cube)
    e0 = start.energies()[1]
    drop = start.bodies["soft cube"].q[:, 2].min()  # [m] its lowest node above the ground
    player = play(example_soft_cube, 12, tmp_path)
    cube, dt = player.bodies["soft cube"], player.dt
    assert player.metrics[-1]["contacts"] > 0
    assert -cube.q[:, 2].min() < G * dt**2
    assert max(r["max_penetration_m"] for r in player.metrics) < G * dt**2
    # Landing on an edge is inelastic: at least the 1/2 m v^2 = m g drop it had at impact is gone
    # within 0.3 s of it (the bounce of a damped soft body keeps less than its impact energy).
    assert player.metrics[-1]["energy_j"] < e0 - 0.5 * np.sum(cube.mass) * G * drop
    check_energy_never_grows(player, e0)


def test_cloth_drapes_over_the_sphere_without_entering_it(tmp_path):
    start = start_of(example_cloth_sphere)
    e0 = start.energies()[1]
    player = play(example_cloth_sphere, 10, tmp_path)
    cloth, sphere, dt = player.bodies["cloth"], player.spheres[0], player.dt
    gap = np.linalg.norm(cloth.q - np.asarray(sphere.center), axis=1) - sphere.radius
    assert -gap.min() < G * dt**2  # 2.7 mm at dt = 1/60 s
    assert -cloth.q[:, 2].min() < G * dt**2
    # Fallen 0.1 m (0.14 s < the 0.33 s played), the cloth's middle rests on the sphere's top.
    middle = cloth.q[len(cloth.q) // 2]
    assert middle[2] == pytest.approx(2 * sphere.radius, abs=G * dt**2)
    check_energy_never_grows(player, e0)


def test_oranges_keep_their_momentum_in_the_air(tmp_path):
    """0.16 s (4 frames): the lowest orange (0.25 m, r 0.08 m) needs sqrt(2 x 0.17 / g) = 0.186 s
    to land, so each one's horizontal momentum is its start momentum."""
    start = start_of(example_oranges)
    names = [f"orange {i}" for i in range(4)]
    momentum0 = [np.sum(np.asarray(start.bodies[n].mass)[:, None] * start.bodies[n].v, axis=0) for n in names]
    player = play(example_oranges, 4, tmp_path)
    for name, p0 in zip(names, momentum0):
        body = player.bodies[name]
        p = np.sum(np.asarray(body.mass)[:, None] * body.v, axis=0)
        mass = np.sum(body.mass)
        np.testing.assert_allclose(p[:2], p0[:2], atol=1e-9 * mass)
        # Vertically: gravity's impulse -M g t (the oranges' material has no mass damping, alpha = 0).
        assert p[2] - p0[2] == pytest.approx(-mass * G * player.scene.time, rel=1e-9)
    assert player.metrics[-1]["contacts"] == 0


def test_oranges_land_roll_on_and_lose_energy(tmp_path):
    start = start_of(example_oranges)
    e0 = start.energies()[1]
    x0 = np.array([centre_of_mass(start.bodies[f"orange {i}"]) for i in range(4)])
    player = play(example_oranges, 8, tmp_path)
    x = np.array([centre_of_mass(player.bodies[f"orange {i}"]) for i in range(4)])
    assert max(r["contacts"] for r in player.metrics) > 0  # landed (and bounced)
    assert (x[:, 0] > x0[:, 0] + 0.1).all()  # thrown forward at 0.5 - 0.9 m/s: >= 0.16 m in 0.32 s
    assert max(r["max_penetration_m"] for r in player.metrics) < G * player.dt**2
    check_energy_never_grows(player, e0)


def _stuck_area(cloth, gap: float) -> float:
    """Area [m^2] of the cloth's triangles whose three nodes lie within ``gap`` [m] of the wall x = 0."""
    x = cloth.q[cloth.triangles]
    areas = 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
    return float(areas[(x[:, :, 0] < gap).all(axis=1)].sum())


def test_cloth_sticks_to_the_wall_then_peels_off(tmp_path):
    """The swung cloth bonds where it hits the wall (intensities in [0, 1]), never passes it,
    and debonds again under its weight: the bonded contacts rise, then fall to none.

    The peel, as the sheet shows it: the area lying on the wall (within the adhesion's debond
    gap, from the scene file) grows to a sizeable part of the cloth, then only shrinks (a bond
    re-forming at the peel front may add back at most one triangle) until none is left, and
    the whole cloth hangs off the wall. Every frame the cloth is inside the camera's
    ``[render] bounds`` and in front of the drawn part of the wall (its square, ``size``
    around ``point``), so the sheet shows all of it."""
    start = start_of(example_cloth_wall)
    e0 = start.energies()[1]
    start.close()
    player = load_scene(example_cloth_wall.SCENE, frames=36, width=48, height=32)
    gap = player.file.adhesions["wall"]["debond_gap"]
    bounds = np.asarray(player.file.render["bounds"], float)
    wall = player.file.planes[0]
    cloth = player.bodies["cloth"]
    w, h = player.file.body("cloth").size
    triangle = w * h / len(cloth.triangles)  # [m^2] one triangle of the rest grid
    bonded, stuck, deepest = [], [], 0.0
    with player:
        for _ in range(36):
            player.step()
            beta = np.array(list(player.scene.adhesion_state.intensity.values()))
            assert ((beta >= 0) & (beta <= 1)).all()
            bonded.append(int((beta > 0).sum()))
            stuck.append(_stuck_area(cloth, gap))
            deepest = max(deepest, -float(cloth.q[:, 0].min()))
            assert ((cloth.q >= bounds[0::2]) & (cloth.q <= bounds[1::2])).all()
            assert (np.abs(cloth.q[:, 1:] - np.asarray(wall["point"])[1:]) <= wall["size"] / 2).all()
    assert max(bonded) > 20 and bonded[-1] < max(bonded) / 4
    assert deepest < G * player.dt**2
    peak = int(np.argmax(stuck))
    assert stuck[peak] > 0.2 * w * h
    assert (np.diff(stuck[peak:]) <= triangle).all(), np.round(stuck, 4)
    assert stuck[-1] == 0.0 and cloth.q[:, 0].min() > gap
    check_energy_never_grows(player, e0)
    example_cloth_wall.main(["--headless", "--frames", "1", "--size", "48", "32", "--out", str(tmp_path)])


def _held_candy_scene(folder: Path) -> Path:
    """candy-adhesive.toml with only what the pull-off involves: the Jell-O (in 6 x 6 x 3 cubes, 12
    quads a side, a quarter of the file's cubes per axis: same material, adhesion and plate), the held
    candy, the hand and their spring; every number of these is the file's."""
    text = (BUNDLED / "candy-adhesive.toml").read_text(encoding="utf-8")
    # (The file's [variant.*] tables are left out with the bodies they name.)
    head, *tables = re.split(r"(?m)^(?=\[\[body\]\]|\[\[coupling\]\]|\[variant\.)", text)
    kept = [t for t in tables if t.startswith("[[coupling]]")
            or re.search(r'^name = "(jello|pulled candy|hand)"$', t, re.M)]
    small = "".join([head, *kept]).replace("cells = [12, 12, 5]", "cells = [6, 6, 3]").replace(
        "surface_quads = 48", "surface_quads = 12")
    path = folder / "held-candy.toml"
    path.write_text(small, encoding="utf-8")
    return path


def test_candy_quick_variant_drops_its_hard_candies_freely_onto_a_held_jello(tmp_path):
    """example_candy with ``--variant quick`` (candy.toml's small scale): the Jell-O is the
    variant's 6 x 6 x 3 cubes of 5 tets (540), four candies are left of eight; for two frames
    (0.08 s) the hard candies are in the air, so each falls as semi-implicit Euler integrates
    gravity (the free-fall truth above, to round-off), and the ball's spin stays what it was
    (isotropic inertia: the gyroscopic torque omega x I omega of Euler's equations is zero; the
    box's is not, and precesses); the Jell-O's bottom nodes (fixed_below) never move; energy
    never grows."""
    start = load_scene(example_candy.SCENE, ["quick"], frames=1, width=48, height=32)
    hard = [n for n in start.bodies if n.startswith("hard candy")]
    x0 = {n: start.bodies[n].position.copy() for n in hard}
    w0 = {n: start.bodies[n].angular_velocity.copy() for n in hard}
    e0 = start.energies()[1]
    player = example_candy.main(["--headless", "--variant", "quick", "--frames", "2", "--size", "48", "32", "--out",
                                 str(tmp_path)])
    jello = player.bodies["jello"]
    assert len(jello.tets) == 5 * 6 * 6 * 3 and len(player.bodies) == 5 and len(hard) == 2
    held = jello.fixed
    assert held.sum() == 7 * 7  # the bottom layer of the 6 x 6 grid's nodes
    np.testing.assert_array_equal(jello.q[held][:, 2], 0.0)
    t, dt = player.scene.time, player.dt
    assert t == pytest.approx(2 * 5 * 0.008, rel=1e-12)
    for n in hard:
        body = player.bodies[n]
        np.testing.assert_allclose(body.position - x0[n], [0.0, 0.0, -0.5 * G * t**2 - 0.5 * G * dt * t], atol=1e-12)
    np.testing.assert_allclose(player.bodies["hard candy 3"].angular_velocity, w0["hard candy 3"], atol=1e-12)
    check_energy_never_grows(player, e0)


def test_the_held_candy_sticks_then_comes_off_the_jello(tmp_path):
    """candy-adhesive.toml's hand (kinematic, on its keys) holds a candy resting on the Jell-O by a
    zero-length spring (stiffness k, damping c; thesis 5.4), presses it, holds, then rises.

    * Held: until the hand rises the candy's underside stays within the adhesion's debond gap
      of the Jell-O's top beneath it.
    * Stuck: the pull on it, k s + c (v_hand - v_candy) (s the spring's stretch), grows past
      its weight m g while the contact still holds it down (a dry contact only pushes: a pull
      is the adhesion). The pull stays below what the bonds can hold at full intensity,
      m g + A sqrt(W C) (thesis eq. 4.16 with beta = 1; A its underside, W and C the
      coating - Jell-O pair's geometric means, thesis 4.4).
    * Pulled off: then its distance to the Jell-O grows past the debond gap and on to over
      a centimetre: it follows the hand."""
    player = load_scene(_held_candy_scene(tmp_path), frames=24, width=48, height=32)
    spec, hand_spec = player.file.body("pulled candy"), player.file.body("hand")
    coupling = player.file.couplings[0]
    k, c = coupling["stiffness"], coupling["damping"]
    wet, jello_adhesion = player.file.adhesions["coating"], player.file.adhesions["k4e7"]
    gap = min(wet["debond_gap"], jello_adhesion["debond_gap"])
    w_c = np.sqrt(wet["max_energy"] * jello_adhesion["max_energy"] * wet["stiffness"] * jello_adhesion["stiffness"])
    lx, ly, lz = spec.size
    candy, hand, jello = player.bodies["pulled candy"], player.bodies["hand"], player.bodies["jello"]
    mg = float(candy.mass) * G
    limit = mg + lx * ly * np.sqrt(w_c)  # [N]
    rise = hand_spec.motion["times"][2]  # [s] the hand holds still until here
    under = (np.abs(jello.q[:, 0] - candy.position[0]) <= lx / 2) & (np.abs(jello.q[:, 1] - candy.position[1]) <= ly / 2)
    assert under.any()
    candy0, hand0 = candy.position[2], hand.position[2]
    rows = []  # (t, gap under the candy [m], pull [N], vertical contact force on it [N])
    with player:
        for _ in range(24):
            player.step()
            below = candy.position[2] - lz / 2 - jello.q[under, 2].max()
            stretch = (hand.position[2] - hand0) - (candy.position[2] - candy0)
            pull = k * stretch + c * (hand.velocity[2] - candy.velocity[2])
            contact = player.scene.last_solution.force_on(player.index["pulled candy"], player.dt)[2]
            rows.append((player.scene.time, below, pull, contact))
    held = [r for r in rows if r[0] <= rise + 1e-9]
    assert held and all(r[1] < gap for r in held)
    stuck = [r for r in rows if r[3] < 0]  # the contact pulls it down: adhesion
    assert stuck and max(r[2] for r in stuck) > mg
    assert max(r[2] for r in rows) < limit
    off = [i for i, r in enumerate(rows) if r[1] > gap]
    assert off and all(r[1] > gap for r in rows[off[0]:]) and rows[-1][1] > 0.01, rows


def _jaws_apart(t: float) -> float:
    """Distance [m] between the jaws at time t [s], from lips.toml's story: 26 mm at the start
    (a 2 mm gap between two 12 mm lips), each jaw pressed in 1.5 mm over 0.2 s, held 0.2 s,
    then opened at 2 cm/s."""
    each = -0.0015 * min(t, 0.2) / 0.2 + 0.02 * max(t - 0.4, 0.0)
    return 0.026 + 2 * each


def test_lips_follow_their_jaws_and_stick_as_they_open(tmp_path):
    """The jaws are driven, so they are where the script puts them at every frame; the lips touch
    only each other, so the contact forces on them are equal and opposite; a dry contact only
    pushes (the force on the upper lip >= 0), so a pull while the jaws open is the adhesion."""
    player = load_scene(example_lips.SCENE, frames=31, width=48, height=32)
    upper, lower = player.bodies["upper lip"], player.bodies["lower lip"]
    iu, il = player.index["upper lip"], player.index["lower lip"]
    force = []
    with player:
        for _ in range(31):
            record = player.step()
            t = player.scene.time
            jaws = upper.q[upper.fixed, 2].mean() - lower.q[lower.fixed, 2].mean()
            assert jaws == pytest.approx(_jaws_apart(t), abs=1e-9)
            solution = player.scene.last_solution
            fu, fl = solution.force_on(iu, player.dt), solution.force_on(il, player.dt)
            np.testing.assert_allclose(fu, -fl, atol=1e-9 * max(1.0, np.abs(fu).max()))
            force.append((t, float(fu[2]), record["contacts"]))
    pressing = [f for t, f, _ in force if t <= 0.4]
    opening = [f for t, f, _ in force if t > 0.4]
    assert min(pressing) > 0  # pressed together: they push each other apart
    assert min(opening) < -0.5  # opening: the wet lips pull on each other (N)
    # and they do let go: no contact once the jaws are 5.8 mm past their start (t = 0.62 s)
    apart = [c for t, _, c in force if t >= 0.62 - 1e-9]
    assert apart and all(c == 0 for c in apart)
    example_lips.main(["--headless", "--frames", "1", "--size", "48", "32", "--out", str(tmp_path)])


def _hertz(depth: float, radius: float = 0.01, young: float = 2e4, poisson: float = 0.4) -> float:
    """Hertz's force [N] of a rigid sphere pressed ``depth`` [m] into an elastic half-space:
    F = 4/3 E / (1 - nu^2) sqrt(R) d^1.5 (probe.toml: R 1 cm, E 20 kPa, nu 0.4)."""
    return 4.0 / 3.0 * young / (1.0 - poisson**2) * np.sqrt(radius) * max(depth, 0.0) ** 1.5


def test_probe_pushes_at_least_as_hard_as_hertz_and_pulls_only_by_adhesion(tmp_path):
    """The probe (kinematic, R 1 cm) goes 1 mm above the surface down to 4 mm into it over 0.5 s,
    holds 0.1 s and withdraws to 4 mm above it by 1.4 s.

    * Newton's third law: it touches only the tissue: equal and opposite contact forces.
    * Hertz is a lower bound of the loading force: a displacement FEM is stiffer than the
      continuum it discretizes, and a 3 cm block on a clamped base stiffer than a half-space.
    * The dry part of a contact only pushes: a pull (force < 0) is the tacky tissue's adhesion,
      and it lifts the tissue above its rest surface z = 0.
    * The probe moves at 1 cm/s: it carries at most v dt = 40 um into the tissue in a step."""
    player = load_scene(example_probe.SCENE, frames=64, width=48, height=32)
    probe, tissue = player.bodies["probe"], player.bodies["tissue"]
    ip, it = player.index["probe"], player.index["tissue"]
    rows = []
    with player:
        for _ in range(64):
            record = player.step()
            solution = player.scene.last_solution
            fp, ft = solution.force_on(ip, player.dt), solution.force_on(it, player.dt)
            np.testing.assert_allclose(fp, -ft, atol=1e-9 * max(1.0, np.abs(fp).max()))
            rows.append((player.scene.time, 0.01 - probe.position[2], fp[2], tissue.q[:, 2].max(),
                         record["max_penetration_m"]))
    loading = [(d, f) for t, d, f, _, _ in rows if t <= 0.5 + 1e-9 and d > 0]
    assert len(loading) > 10 and all(f >= _hertz(d) for d, f in loading)
    pulls = [(d, lift) for t, d, f, lift, _ in rows if f < -0.01]
    assert pulls and all(d < 0 for d, _ in pulls)  # it pulls only once above the rest surface
    assert max(lift for _, lift in pulls) > 1e-4  # and the tissue follows it up (> 0.1 mm)
    assert max(r[4] for r in rows) < 0.01 * player.dt
    example_probe.main(["--headless", "--frames", "1", "--size", "48", "32", "--out", str(tmp_path)])


# -- the registry of softvr run / view / demo NAME (softvr.examples.run) --------------------------
def test_view_plays_a_bundled_scene_live_in_a_window(display):
    """Under Xvfb: ``softvr view soft-cube`` opens the window, plays every frame, closes on time."""
    from softvr.examples import run

    assert run.view_main(["soft-cube", "--frames", "3", "--size", "160", "120", "--seconds", "3"]) == 0


def test_view_volume_plays_the_bundled_volume_scene_and_a_volume_file_opens_the_drag_viewer(monkeypatch, tmp_path):
    """``softvr view volume`` is the demo named volume, the bundled volume.toml, played in the
    window (a demo's ``--variant`` its file's); ``softvr view FILE`` of a volume file (not a scene file) is the
    drag viewer, given the words as typed. (The window and the viewer are stood in for: what is
    checked is what they are handed.)"""
    from softvr import cli
    from softvr.examples import run
    from softvr.render import viewer

    played, dragged = [], []
    monkeypatch.setattr(run, "require_display", lambda: None)
    monkeypatch.setattr(run, "load_scene", lambda path, variants, **kw: contextlib.nullcontext(
        (path, list(variants), kw["frames"])))
    monkeypatch.setattr(run, "play_window", lambda player, **kw: played.append(player))
    monkeypatch.setattr(viewer, "main", lambda argv: dragged.append(list(argv)) or 0)
    assert cli.main(["view", "volume", "--frames", "2", "--size", "32", "24"]) == 0
    assert cli.main(["view", "candy", "--variant", "quick"]) == 0
    assert played == [(BUNDLED / "volume.toml", [], 2), (BUNDLED / "candy.toml", ["quick"], None)] and dragged == []
    volume = tmp_path / "ct.nrrd"
    volume.write_bytes(b"")
    assert cli.main(["view", str(volume), "--cells", "3"]) == 0
    assert dragged == [[str(volume), "--cells", "3"]] and len(played) == 2


def test_view_without_a_display_says_so(monkeypatch, capsys):
    from softvr.errors import InputError
    from softvr.examples import run

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(InputError, match="display"):
        run.view_main(["soft-cube", "--frames", "2"])


def test_run_names_the_bad_option_and_the_demos(capsys):
    from softvr.examples import run

    with pytest.raises(SystemExit):
        run.main(["oranges", "--frames", "0"])
    assert "--frames" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        run.main(["teapot"])
    assert "soft-cube" in str(exc.value) and "candy-adhesive" in str(exc.value)
    with pytest.raises(SystemExit):
        run.main(["shoulder", "--variant", "knee"])
    assert "arthroscopy" in capsys.readouterr().err
