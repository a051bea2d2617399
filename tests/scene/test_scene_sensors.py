"""The ``[[sensor]]`` tables of a scene file: validated like every other table.

Truths (written here by hand): a misspelt key is named with the key meant (``knd`` ->
``kind``) under its field path; a sensor naming a body the scene does not have is refused
with the list of its bodies; a kind, an ``other`` side or a name that cannot be is refused
with what was expected; every problem of the file is reported at once.
"""

import pytest

from softvr.errors import InputError
from softvr.scene import read_gltf_scene, read_scene

SCENE = """format = "softvr-scene 1"
[material.m]
density = 1000.0
[[plane]]
[[body]]
name = "ball"
type = "rigid"
sphere = 0.05
material = "m"
position = [0.0, 0.0, 0.05]
[[body]]
name = "post"
type = "fixed"
box = [0.1, 0.1, 0.1]
position = [0.0, 0.0, 1.0]
"""


def _problems(tmp_path, sensors: str) -> list:
    path = tmp_path / "s.toml"
    path.write_text(SCENE + sensors)
    with pytest.raises(InputError) as info:
        read_scene(path)
    return info.value.problems


def test_a_typo_in_a_sensor_and_a_sensor_section_is_named_with_the_key_meant(tmp_path):
    assert _problems(tmp_path, """
[[sensor]]
name = "height"
knd = "position"
body = "ball"
[[sensr]]
name = "x"
""") == [("sensr", "a known key (did you mean 'sensor'?)", "'sensr'"),
         ("sensor[0].kind", "contact_force | coupling_force | position | hand_force", "nothing"),
         ("sensor[0].knd", "a known key (did you mean 'kind'?)", "'knd'")]


def test_a_sensor_on_a_body_that_does_not_exist_is_refused_with_the_bodies(tmp_path):
    assert _problems(tmp_path, """
[[sensor]]
name = "press"
kind = "contact_force"
body = "bal"
other = "floor"
""") == [("sensor[0].body", "the name of a body (ball, post)", "'bal'"),
         ("sensor[0].other", 'the name of another body (ball, post) or "static"', "'floor'")]


def test_a_sensors_kind_other_side_and_name_are_checked(tmp_path):
    assert _problems(tmp_path, """
[[sensor]]
name = "f"
kind = "torque"
body = "ball"
[[sensor]]
name = "f"
kind = "coupling_force"
body = "ball"
[[sensor]]
name = "p"
kind = "position"
body = "ball"
other = "static"
""") == [("sensor[0].kind", "contact_force | coupling_force | position | hand_force", "torque"),
         ("sensor[1].body", "a body with couplings (none in this scene)", "'ball'"),
         ("sensor[1].name", "a name no other sensor has", "'f'"),
         ("sensor[2].other", "other only on a contact_force sensor", "a position sensor")]


def test_valid_sensors_are_read_with_their_defaults(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(SCENE + """
[[sensor]]
name = "press"
kind = "contact_force"
body = "ball"
[[sensor]]
name = "on floor"
kind = "contact_force"
body = "ball"
other = "static"
""")
    assert read_scene(path).sensors == [
        {"name": "press", "kind": "contact_force", "body": "ball", "other": None},
        {"name": "on floor", "kind": "contact_force", "body": "ball", "other": "static"}]


def test_gltf_sensor_properties_are_the_same_sensors(tmp_path):
    """A node's ``softvr_sensor_<kind>`` (its value the sensor's name, the node its body) and
    ``softvr_sensor_contact_force_other`` are the description's ``[[sensor]]`` tables: those
    written here by hand, as the TOML file above would give them."""
    from tests.scene.test_scene_schema import _glb

    path = _glb(tmp_path / "s.glb", {
        "ball": {"softvr_type": "rigid", "softvr_density": 1000.0, "softvr_sensor_position": "height",
                 "softvr_sensor_contact_force": "on floor", "softvr_sensor_contact_force_other": "static"},
        "gel": {"softvr_type": "fem", "softvr_young": 1e5, "softvr_sensor_coupling_force": "pull",
                "softvr_couple_to": "ball", "softvr_coupling_stiffness": 10.0, "softvr_coupling_radius": 0.2}})
    assert read_gltf_scene(path).sensors == [  # node by node, each node's in the order of the kinds
        {"name": "on floor", "kind": "contact_force", "body": "ball", "other": "static"},
        {"name": "height", "kind": "position", "body": "ball", "other": None},
        {"name": "pull", "kind": "coupling_force", "body": "gel", "other": None}]


def test_gltf_sensor_problems_are_named_by_the_property_all_at_once(tmp_path):
    """What a [[sensor]] is refused for, named as the node property it came from: an ``other``
    the scene does not have, a coupling_force sensor on a body without couplings, a name two
    sensors share, a misspelt kind (with the property meant), a sensor on a fixed object (an
    obstacle, not a body: refused as a key of the other types)."""
    from tests.scene.test_scene_schema import _glb

    path = _glb(tmp_path / "s.glb", {
        "ball": {"softvr_type": "rigid", "softvr_density": 1000.0, "softvr_sensor_contact_force": "f",
                 "softvr_sensor_contact_force_other": "wal", "softvr_sensor_coupling_force": "f",
                 "softvr_sensor_postion": "h"},
        "wall": {"softvr_type": "fixed", "softvr_sensor_position": "w"}})
    with pytest.raises(InputError) as info:
        read_gltf_scene(path)
    problems = sorted(info.value.problems)
    fixed = [p for p in problems if p[0] == "node 'wall'.sensor_position"]
    assert len(fixed) == 1 and fixed[0][1].startswith("a key of a fixed object") and fixed[0][2] == (
        "'sensor_position' (a key of rigid | fem | cloth | kinematic | tool | volume objects)")
    assert [p for p in problems if p not in fixed] == sorted([
        ("node 'ball'.sensor_postion", "a known key (did you mean 'sensor_position'?)", "'sensor_postion'"),
        ("node 'ball'.sensor_contact_force_other", 'the name of another body (ball) or "static"', "'wal'"),
        ("node 'ball'.sensor_coupling_force", "a body with couplings (none in this scene)", "'ball'"),
        ("node 'ball'.sensor_coupling_force", "a name no other sensor has", "'f'")])
