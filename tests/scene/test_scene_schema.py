"""The scene description (softvr.scene._description): unknown keys, defaults, layering.

Truths: a key no table has is refused at every level, each named by its field path and the
key a person meant (written here by hand: ``poison`` -> ``poisson``), all in one error, and
``softvr check`` exits 2 on them; a scene file that leaves the contact settings out gets
softvr.Scene's own, and a glTF scene without extras gets what a TOML scene without
``[simulation]`` gets (both the numbers docs/scenes.md states); the scene layer's reading
modules import nothing of softvr.cave (scene is below the cave: DESIGN.md).
"""

import ast
import json
import struct
from pathlib import Path

import pytest
import trimesh

import softvr.scene
from softvr import Scene
from softvr.cave import load_display
from softvr.cli import main
from softvr.errors import InputError
from softvr.scene import read_gltf_scene, read_scene

#: One typo in a key of every table: (the table's text with the typo, its field path, the key meant).
TYPOS = [
    ("lights = 1", "lights", "light"),
    ("[simulation]\nstpes_per_frame = 4", "simulation.stpes_per_frame", "steps_per_frame"),
    ("[render]\nzooom = 1.0", "render.zooom", "zoom"),
    ("[[light]]\nposition = [1.0, 1.0, 1.0]\nintensty = 0.5", "light[0].intensty", "intensity"),
    ("[material.jelly]\npoison = 0.35", "material.jelly.poison", "poisson"),
    ("[adhesion.tacky]\nstiffness = 1e7\nmax_energy = 5.0\nviscosity = 1.0\nbonding_rat = 1.0",
     "adhesion.tacky.bonding_rat", "bonding_rate"),
    ("[[plane]]\nnormall = [0.0, 0.0, 1.0]", "plane[0].normall", "normal"),
    ("[[sphere]]\ncenter = [0.0, 0.0, 0.0]\nradius = 0.1\nfricton = 0.2", "sphere[0].fricton", "friction"),
    ('[[body]]\nname = "probe"\ntype = "kinematic"\nsphere = 0.01\npositon = [0.0, 0.0, 0.5]',
     "body[0].positon", "position"),
    ("[body.motion]\ntimes = [0.0]\npositions = [[0.0, 0.0, 0.5]]\nrotatons = [[0.0, 0.0, 0.0]]",
     "body[0].motion.rotatons", "rotations"),
    ('[[body]]\nname = "hand"\ntype = "tool"\nsphere = 0.01\nmaterial = "jelly"\nstiffness = 100.0\nmax_forse = 5.0',
     "body[1].max_forse", "max_force"),
    ("[body.motion]\ntimes = [0.0]\npositions = [[0.3, 0.0, 0.5]]", None, None),
    ('[[filter]]\na = "probe"\nb = "hand"\nc = "probe"', None, None),  # a, b: no key is near "c"
    ('[[coupling]]\na = "probe"\nb = "hand"\npoints = [[0.1, 0.0, 0.5]]\nstifness = 10.0\nstiffness = 10.0',
     "coupling[0].stifness", "stiffness"),
    ('[volume]\nfile = "head-ct"\ntreshold = 100.0', "volume.treshold", "threshold"),
    ('[display]\nprest = "cube"', "display.prest", "preset"),
]


def _typo_scene(tmp_path) -> Path:
    path = tmp_path / "typos.toml"
    path.write_text('format = "softvr-scene 1"\n' + "\n".join(text for text, _, _ in TYPOS) + "\n")
    return path


def test_a_typo_in_every_table_is_refused_with_every_typo_and_the_key_meant(tmp_path, capsys):
    path = _typo_scene(tmp_path)
    with pytest.raises(InputError) as info:
        read_scene(path)
    problems = {what: (expected, found) for what, expected, found in info.value.problems}
    for text, what, meant in TYPOS:
        if what is not None:
            typo = what.rsplit(".", 1)[-1]
            assert problems.get(what) == (f"a known key (did you mean {meant!r}?)", repr(typo)), (what, problems)
    # The filter's third key is near none of a, b: every key of [[filter]] is named instead.
    assert problems["filter[0].c"] == ("one of a, b", "'c'")
    # Nothing else is wrong with the file: the typos are all its problems.
    assert len(info.value.problems) == sum(what is not None for _, what, _ in TYPOS) + 1, problems
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "material.jelly.poison: expected a known key (did you mean 'poisson'?), found 'poison'" in err
    assert "body[0].positon: expected a known key (did you mean 'position'?), found 'positon'" in err
    assert "Traceback" not in err


def test_the_typos_of_issue_19_no_longer_pass(tmp_path):
    """``poison = 0.35`` or ``positon = ...`` passed ``softvr check`` with exit 0 before."""
    path = tmp_path / "issue.toml"
    path.write_text('format = "softvr-scene 1"\n[material.jelly]\npoison = 0.35\n[[body]]\nname = "cube"\n'
                    'type = "fem"\nbox = [0.1, 0.1, 0.1]\nmaterial = "jelly"\npositon = [0.0, 0.0, 0.3]\n')
    assert main(["check", str(path)]) == 2


def test_an_empty_table_names_what_it_lacks(tmp_path):
    path = tmp_path / "empty.toml"
    path.write_text('format = "softvr-scene 1"\n[[plane]]\n[[light]]\n[[sphere]]\n')
    with pytest.raises(InputError) as info:
        read_scene(path)
    assert info.value.problems == [("light[0].position", "3 numbers [m]", "nothing"),
                                   ("sphere[0].center", "3 numbers [m]", "nothing"),
                                   ("sphere[0].radius", "a number [m]", "nothing")]


def test_a_scene_without_settings_takes_the_described_and_the_simulations_defaults(tmp_path):
    path = tmp_path / "bare.toml"
    path.write_text('format = "softvr-scene 1"\n[[plane]]\n')
    scene = read_scene(path)
    sim = Scene()
    assert scene.simulation == {"dt": 0.005, "steps_per_frame": 4, "frames": 100, "gravity": sim.gravity,
                                "friction": sim.friction, "pgs_iterations": sim.pgs_iterations,
                                "contact_margin": sim.contact_margin, "collision_free_start": False}
    assert scene.planes == [{"point": (0.0, 0.0, 0.0), "normal": (0.0, 0.0, 1.0), "friction": sim.friction,
                             "size": 3.0, "adhesion": None}]
    gltf = read_gltf_scene(_glb(tmp_path / "bare.glb", {"cube": {"softvr_type": "fixed"}}))
    assert gltf.simulation == scene.simulation
    assert {k: v for k, v in gltf.render.items() if k != "lights"} == \
        {k: v for k, v in scene.render.items() if k != "lights"}
    assert gltf.planes == scene.planes  # the ground


def test_a_gltf_object_and_a_toml_body_get_the_same_defaults(tmp_path):
    """Material, cloth and tool fields left out: the same numbers from both readers, the ones
    docs/scenes.md and the schema's docstring state."""
    toml = tmp_path / "bodies.toml"
    toml.write_text('format = "softvr-scene 1"\n[material.m]\n'
                    '[[body]]\nname = "sheet"\ntype = "cloth"\ncloth = [0.2, 0.2]\n'
                    '[[body]]\nname = "hand"\ntype = "tool"\nsphere = 0.01\nmaterial = "m"\nstiffness = 100.0\n'
                    '[body.motion]\ntimes = [0.0]\npositions = [[0.0, 0.0, 0.5]]\n')
    t = read_scene(toml)
    g = read_gltf_scene(_glb(tmp_path / "bodies.glb", {
        "sheet": {"softvr_type": "cloth"}, "hand": {"softvr_type": "tool", "softvr_stiffness": 100.0}}))
    assert t.materials["m"] == g.materials["hand"] == {"young": 1e5, "poisson": 0.3, "density": 1000.0, "alpha": 0.0,
                                                       "beta": 0.0}
    cloth = {"area_density": 0.2, "stretch": 200.0, "shear": 20.0, "bend": 1.0, "damping": 0.05, "alpha": 0.1}
    for scene in (t, g):
        assert {k: v for k, v in scene.body("sheet").cloth.items() if k != "quads"} == cloth
        assert scene.body("hand").tool == {"stiffness": 100.0, "damping": 0.0, "haptics": False, "max_force": 10.0}
    assert t.body("sheet").cloth["quads"] == (16, 16)


def _glb(path: Path, extras: dict, scene_extras: dict | None = None) -> Path:
    """A GLB of one 0.1 m box per name of ``extras``, each with those node extras (custom
    properties as Blender writes them)."""
    scene = trimesh.Scene()
    for i, name in enumerate(extras):
        scene.add_geometry(trimesh.creation.box((0.1, 0.1, 0.1)), node_name=name, geom_name=f"{name} mesh",
                           transform=trimesh.transformations.translation_matrix((0.3 * i, 0.1, 0.0)))
    data = scene.export(file_type="glb")
    length = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + length])
    for node in doc["nodes"]:
        if node.get("name") in extras:
            node["extras"] = extras[node["name"]]
    if scene_extras:
        doc["scenes"][doc.get("scene", 0)]["extras"] = scene_extras
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    rest = data[20 + length:]
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 20 + len(text) + len(rest)) + struct.pack("<I", len(text))
                     + b"JSON" + text + rest)
    return path


def test_unknown_gltf_properties_are_named_with_the_property_meant(tmp_path):
    path = _glb(tmp_path / "typos.glb", {
        "gel": {"softvr_type": "fem", "softvr_densty": 900.0, "softvr_couple_to": "post",
                "softvr_coupling_stifness": 10.0, "softvr_coupling_radius": 0.01},
        "post": {"softvr_type": "rigid", "softvr_velocty": [0.0, 0.0, 1.0]}},
        {"softvr_frmes": 10, "softvr_ground": 1})
    with pytest.raises(InputError) as info:
        read_gltf_scene(path)
    problems = {what: (expected, found) for what, expected, found in info.value.problems}
    assert problems["node 'gel'.densty"] == ("a known key (did you mean 'density'?)", "'densty'")
    assert problems["node 'gel'.coupling_stifness"] == ("a known key (did you mean 'coupling_stiffness'?)",
                                                        "'coupling_stifness'")
    assert problems["node 'post'.velocty"] == ("a known key (did you mean 'velocity'?)", "'velocty'")
    assert problems["scene.frmes"] == ("a known key (did you mean 'frames'?)", "'frmes'")
    # The coupling's stiffness was misspelt, so it has none: named as the property to write.
    assert problems["node 'gel'.coupling_stiffness"] == ("a number [N/m]", "nothing")
    assert len(problems) == 5, problems


def test_a_display_files_screen_keys_are_checked(tmp_path):
    path = tmp_path / "wall.toml"
    path.write_text('format = "softvr-display 1"\neye_seperation = 0.06\n[[screen]]\nname = "wall"\n'
                    "lower_left = [-1.0, 1.0, 0.0]\nlower_right = [1.0, 1.0, 0.0]\nupper_left = [-1.0, 1.0, 1.5]\n"
                    "pixles = [800, 600]\n")
    with pytest.raises(InputError) as info:
        load_display(path)
    assert info.value.problems == [("eye_seperation", "a known key (did you mean 'eye_separation'?)",
                                    "'eye_seperation'"),
                                   ("screen[0].pixles", "a known key (did you mean 'pixels'?)", "'pixles'")]


def test_the_scene_files_readers_import_nothing_of_the_cave():
    folder = Path(softvr.scene.__file__).parent
    for name in ("schema.py", "gltf.py", "display.py", "_description.py"):
        tree = ast.parse((folder / name).read_text())
        imported = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module] + \
            [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        assert not [m for m in imported if m.startswith("softvr.cave")], (name, imported)
