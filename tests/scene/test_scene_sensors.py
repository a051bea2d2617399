"""The ``[[sensor]]`` tables of a scene file: validated like every other table.

Truths (written here by hand): a misspelt key is named with the key meant (``knd`` ->
``kind``) under its field path; a sensor naming a body the scene does not have is refused
with the list of its bodies; a kind, an ``other`` side or a name that cannot be is refused
with what was expected; every problem of the file is reported at once.
"""

import pytest

from softvr.errors import InputError
from softvr.scene import read_scene

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
         ("sensor[0].kind", "contact_force | coupling_force | position", "nothing"),
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
""") == [("sensor[0].kind", "contact_force | coupling_force | position", "torque"),
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
