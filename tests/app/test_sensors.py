"""Scene-file sensors sampled by the player every frame, against physics.

Truths:
- A body at rest on a plane (thesis eq. 5.5: the contact impulses hold it against gravity)
  receives, after settling, a contact force of exactly m g upward over each step: its
  momentum does not change, so the impulses sum to -m g dt. The PGS sweeps stop when no
  velocity correction exceeds TOL = 1e-5 m/s (``softvr.sim._node_step.SWEEP_TOLERANCE``, the
  per-object path's default too), so each of the box's 4 corner contacts may leave up to
  TOL of velocity: |F - m g| <= 4 m TOL / dt.
- Of a stack, the lower box receives (m1 + m2) g from the plane and -m2 g from the upper box
  (Newton's third law), the sum of which is its own weight (same tolerance, 8 contacts).
- A body falling from rest under g, stepped by semi-implicit (backward) Euler with step h,
  is at z_n = z_0 - g h^2 n (n + 1) / 2 after n steps, exactly (float64 rounding only).
- A block hanging from a fixed post by a damped zero-length spring (thesis eq. 5.4, damping
  ratio 0.95) settles to stretch m g / k: its error decays as exp(-zeta omega t) = exp(-30 t)
  (backward Euler damps more), e^-60 after 2 s, so the spring force is m g to float64
  rounding (relative 1e-9 allows for it).
"""

import json

import numpy as np
import pytest
from PIL import Image

from softvr.app import record
from softvr.scene import load_scene

G = 9.81
TOL = 1e-5  # [m/s] the PGS sweeps' stopping velocity correction
DT = 0.005  # [s]

HEAD = f"""format = "softvr-scene 1"
[simulation]
dt = {DT}
steps_per_frame = 4
frames = 100
[material.m]
density = 1000.0
"""
#: A ball falling from 2 m, its centre sensed.
FALLING = """
[[body]]
name = "ball"
type = "rigid"
sphere = 0.05
material = "m"
position = [0.0, 0.0, 2.0]
[[sensor]]
name = "centre"
kind = "position"
body = "ball"
"""


def _scene(tmp_path, text: str):
    path = tmp_path / "sensed.toml"
    path.write_text(HEAD + text)
    return load_scene(path, width=64, height=48)


def _play(player, frames: int) -> dict:
    for _ in range(frames):
        record_ = player.step()
    return record_["sensors"]


def test_resting_box_reads_its_weight_and_a_stack_reads_newtons_third_law(tmp_path):
    player = _scene(tmp_path, """
[[plane]]
[[body]]
name = "lower"
type = "rigid"
box = [0.1, 0.1, 0.1]
material = "m"
position = [0.0, 0.0, 0.05]
[[body]]
name = "upper"
type = "rigid"
box = [0.1, 0.1, 0.1]
material = "m"
position = [0.0, 0.0, 0.15]
[[sensor]]
name = "lower all"
kind = "contact_force"
body = "lower"
[[sensor]]
name = "lower from floor"
kind = "contact_force"
body = "lower"
other = "static"
[[sensor]]
name = "lower from upper"
kind = "contact_force"
body = "lower"
other = "upper"
[[sensor]]
name = "upper all"
kind = "contact_force"
body = "upper"
""")
    m1, m2 = (player.bodies[n].mass for n in ("lower", "upper"))
    assert m1 == pytest.approx(1.0) and m2 == pytest.approx(1.0)  # 0.1^3 m^3 of 1000 kg/m^3
    s = _play(player, 50)  # 1 s
    tol = 8 * max(m1, m2) * TOL / DT  # [N]
    np.testing.assert_allclose(s["upper all"], [0.0, 0.0, m2 * G], atol=4 * m2 * TOL / DT)
    np.testing.assert_allclose(s["lower from floor"], [0.0, 0.0, (m1 + m2) * G], atol=tol)
    np.testing.assert_allclose(s["lower from upper"], [0.0, 0.0, -m2 * G], atol=tol)
    np.testing.assert_allclose(s["lower all"], [0.0, 0.0, m1 * G], atol=tol)
    assert player.describe()["sensors"]["lower all"] == {"kind": "contact_force", "unit": "N"}


def test_falling_body_reads_the_discrete_free_fall(tmp_path):
    player = _scene(tmp_path, FALLING)
    for frame in range(1, 11):
        z = player.step()["sensors"]["centre"]
        n = 4 * frame  # steps so far
        np.testing.assert_allclose(z, [0.0, 0.0, 2.0 - G * DT ** 2 * n * (n + 1) / 2], rtol=1e-12, atol=1e-12)


def test_a_gltf_objects_position_sensor_reads_the_discrete_free_fall(tmp_path):
    """The same truth through a glTF scene: a rigid 0.1 m box whose node carries
    ``softvr_sensor_position``, its origin 0.1 m above the ground (5 cm to fall before it
    touches: 3 frames of 4 default 5 ms steps fall 1.8 cm)."""
    from tests.scene.test_scene_schema import _glb

    path = _glb(tmp_path / "fall.glb", {"box": {"softvr_type": "rigid", "softvr_density": 500.0,
                                                "softvr_sensor_position": "centre"}})
    with load_scene(path, frames=3, width=32, height=24) as player:
        h = player.dt
        z0 = player.bodies["box"].position.copy()
        assert z0[2] == pytest.approx(0.1, abs=1e-6)
        for frame in range(1, 4):
            z = player.step()["sensors"]["centre"]
            n = player.steps_per_frame * frame
            np.testing.assert_allclose(z, z0 - [0.0, 0.0, G * h**2 * n * (n + 1) / 2], rtol=1e-12, atol=1e-12)


def test_a_tool_pressed_onto_the_ground_reads_its_hand_force_as_the_contact_minus_its_weight(tmp_path):
    """A tool (a 2 cm ball, its haptic handle held 5 mm below where it rests on the plane, read
    once a step) settles on the plane: at rest Newton's second law on the ball, contact N +
    weight -m g + the coupling's pull (the spring's -F_hand, its damper idle) = 0, so the hand
    feels F_hand = N - m g, upward (the ball pulls the hand towards it); the spring's k d
    (300 N/m x 5 mm = 1.5 N) bounds it. Tolerance: the contact's as above (one sphere contact)
    plus the spring's residual motion, none at rest."""
    player = _scene(tmp_path, """
[[plane]]
[[body]]
name = "tip"
type = "tool"
sphere = 0.01
material = "m"
position = [0.0, 0.0, 0.01]
stiffness = 300.0
damping = 5.0
[body.motion]
times = [0.0]
positions = [[0.0, 0.0, 0.005]]
[[sensor]]
name = "hand"
kind = "hand_force"
body = "tip"
[[sensor]]
name = "ground"
kind = "contact_force"
body = "tip"
other = "static"
""")
    with player:
        s = _play(player, 40)
    m = float(player.bodies["tip"].mass)
    np.testing.assert_allclose(s["hand"], np.asarray(s["ground"]) - [0.0, 0.0, m * G], atol=4 * m * TOL / DT)
    assert 0.0 < s["hand"][2] <= 300.0 * 0.005 + 1e-9
    assert player.describe()["sensors"]["hand"] == {"kind": "hand_force", "unit": "N"}


def test_hanging_block_reads_its_weight_in_its_coupling(tmp_path):
    player = _scene(tmp_path, """
[[body]]
name = "post"
type = "fixed"
box = [0.1, 0.1, 0.1]
position = [0.0, 0.0, 1.0]
[[body]]
name = "block"
type = "rigid"
box = [0.1, 0.1, 0.1]
material = "m"
position = [0.0, 0.0, 0.85]
[[coupling]]
a = "block"
b = "post"
points = [[0.0, 0.0, 0.9]]
stiffness = 1000.0
damping = 60.0
[[sensor]]
name = "spring"
kind = "coupling_force"
body = "block"
""")
    m = player.bodies["block"].mass
    s = _play(player, 100)  # 2 s
    np.testing.assert_allclose(s["spring"], [0.0, 0.0, m * G], rtol=1e-9, atol=1e-9)


def test_record_writes_the_sensors_into_the_metrics_and_one_plot(tmp_path):
    player = _scene(tmp_path, FALLING)
    player.frames = 3
    record(player, tmp_path / "out", progress=False)
    doc = json.loads((tmp_path / "out" / "sensed_metrics.json").read_text())
    assert doc["sensors"] == {"centre": {"kind": "position", "unit": "m"}}
    assert [len(f["sensors"]["centre"]) for f in doc["frames"]] == [3, 3, 3]
    with Image.open(tmp_path / "out" / "sensed_sensors.png") as image:
        assert image.format == "PNG" and min(image.size) > 100
