"""``[simulation] edge_contacts`` (a glTF scene's ``softvr_edge_contacts``): edge-edge contacts
on or off per scene file.

Truth (geometry, as tests/sim/test_node_edge_cover.py): two soft, stiff cubes of half edge h,
one turned 45 degrees about x moving down onto one turned 45 degrees about y, meet edge on
edge where no vertex touches a face. With edge-edge contacts the normal rows of eq. 5.5 hold
the crossing edges apart, so the centres stay >= 2 h sqrt(2) apart (tolerance 0.5 mm: the
cubes' compression under the 0.5 m/s impact at E = 1e8 Pa, a few um, and the contact's
linearization over a step); vertex-triangle contacts alone let them sink until a vertex meets
a face (~2 cm deeper in 40 steps of 5 ms at 0.25 m/s after the impact, > 1 cm asserted).
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.errors import InputError
from softvr.scene import load_scene, read_gltf_scene, read_scene
from tests.scene.test_scene_schema import _glb

HALF = 0.05
CROSSED = """format = "softvr-scene 1"
[simulation]
gravity = [0.0, 0.0, 0.0]
friction = 0.0
{key}
[material.stiff]
young = 1e8
poisson = 0.3
density = 500.0
alpha = 0.0
beta = 1e-3
"""
#: One cube of the pair, turned 45 degrees about x (a) or y (b).
CUBE = """[[body]]
name = "{name}"
type = "fem"
box = [0.1, 0.1, 0.1]
cells = [1, 1, 1]
material = "stiff"
rotation = {rotation}
{rest}
"""


def _closest_centres(tmp_path, key: str) -> float:
    """The smallest z distance [m] between the crossed cubes' centres over 40 steps of 5 ms."""
    path = tmp_path / "crossed.toml"
    height = 2 * HALF * np.sqrt(2) + 0.004
    path.write_text(CROSSED.format(key=key)
                    + CUBE.format(name="a", rotation=[45.0, 0.0, 0.0],
                                  rest=f"position = [0.0, 0.0, {height}]\nvelocity = [0.0, 0.0, -0.5]")
                    + CUBE.format(name="b", rotation=[0.0, 45.0, 0.0], rest=""))
    scene = load_scene(path, frames=1, width=32, height=32).scene
    a, b = scene.bodies
    closest = np.inf
    for _ in range(40):
        scene.step(0.005)
        closest = min(closest, a.q.mean(axis=0)[2] - b.q.mean(axis=0)[2])
    return closest


def test_crossed_edges_are_held_apart_by_default_and_pass_with_the_key_off(tmp_path):
    touching = 2 * HALF * np.sqrt(2)
    assert _closest_centres(tmp_path, "") > touching - 5e-4
    assert _closest_centres(tmp_path, "edge_contacts = true") > touching - 5e-4
    assert _closest_centres(tmp_path, "edge_contacts = false") < touching - 0.01


def test_the_key_defaults_to_the_scenes_and_a_bad_value_is_named(tmp_path):
    path = tmp_path / "bare.toml"
    path.write_text('format = "softvr-scene 1"\n[[plane]]\n')
    assert read_scene(path).simulation["edge_contacts"] is Scene().edge_contacts is True
    path.write_text('format = "softvr-scene 1"\n[simulation]\nedge_contacts = "no"\n[[plane]]\n')
    with pytest.raises(InputError) as info:
        read_scene(path)
    assert str(path) in str(info.value)
    assert [p[0] for p in info.value.problems] == ["simulation.edge_contacts"]
    # Blender writes a boolean custom property as 0 / 1.
    gltf = _glb(tmp_path / "off.glb", {"cube": {"softvr_type": "fixed"}}, {"softvr_edge_contacts": 0})
    assert read_gltf_scene(gltf).simulation["edge_contacts"] is False
