"""The scene description (softvr.scene._description): unknown keys, defaults, layering.

Truths: a key no table has is refused at every level, each named by its field path and the
key a person meant (written here by hand: ``poison`` -> ``poisson``), all in one error, and
``softvr check`` exits 2 on them; a scene file that leaves the contact settings out gets
softvr.Scene's own, and a glTF scene without extras gets what a TOML scene without
``[simulation]`` gets (both the numbers docs/scenes.md states); the scene layer's reading
modules import nothing of softvr.cave (scene is below the cave: DESIGN.md).
"""

import ast
import re
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
    ('[variant.small]\nremuve = ["hand"]', "variant.small.remuve", "remove"),
    ('[variant.small.body."probe"]\npositon = [0.0, 0.0, 0.4]', "variant.small.body.probe.positon", "position"),
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
                                "pgs_tolerance": sim.pgs_tolerance, "rotation_lag": sim.rotation_lag,
                                "contact_margin": sim.contact_margin, "collision_free_start": False,
                                "adhesion": True, "edge_contacts": sim.edge_contacts}
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
        assert scene.body("hand").tool == {"stiffness": 100.0, "angular_stiffness": 0.0, "damping": 0.0, "haptics": False,
                                           "max_force": 10.0}
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


# --- a typo in a key of every table, and each body type given a key of another (issue 19) ---------------------------

#: A parts file with a typo in each of its tables (softvr.model.parts' docstring: format, [defaults],
#: [[part]], [[coupling]]).
_PARTS = '''format = "softvr-parts 1"
couplings = []
[defaults]
cel_size = 0.01
[[part]]
name = "bone"
mesh = "ball.ply"
kind = "fixed"
densty = 1900.0
[[part]]
name = "cap"
mesh = "ball.ply"
kind = "fixed"
[[coupling]]
a = "bone"
b = "cap"
radius = 0.004
stiffness = 10.0
colide = false
'''

#: One scene file with a typo in a key of every table of the format (softvr.scene.schema's
#: docstring, docs/scenes.md) and, on each of the six body types, a key only other types take.
_EVERY_TABLE = '''format = "softvr-scene 1"
lights = 1
[simulation]
stpes_per_frame = 4
[render]
zooom = 1.0
[[light]]
position = [1.0, 1.0, 1.0]
intensty = 0.5
[material.jelly]
poison = 0.35
[adhesion.tacky]
stiffness = 1e7
max_energy = 5.0
viscosity = 1.0
bonding_rat = 1.0
[[plane]]
normall = [0.0, 0.0, 1.0]
[[sphere]]
center = [2.0, 0.0, 0.0]
radius = 0.1
fricton = 0.2
[[body]]
name = "brick"
type = "rigid"
box = [0.1, 0.1, 0.1]
material = "jelly"
position = [0.0, 0.0, 0.5]
angular_velocty = [0.0, 0.0, 1.0]
cells = 2
poisson = 0.3
[[body]]
name = "gel"
type = "fem"
box = [0.1, 0.1, 0.1]
material = "jelly"
position = [0.3, 0.0, 0.5]
fixed_below = 0.46
celss = 2
haptics = true
[body.drive]
times = [0.0]
offset = [[0.0, 0.0, 0.0]]
[[body]]
name = "sheet"
type = "cloth"
cloth = [0.2, 0.2]
position = [0.6, 0.0, 0.5]
area_densty = 0.2
collision_triangles = 100
[[body]]
name = "post"
type = "fixed"
box = [0.1, 0.1, 0.1]
position = [0.9, 0.0, 0.05]
rotaton = [0.0, 0.0, 10.0]
velocity = [0.0, 0.0, 1.0]
[[body]]
name = "probe"
type = "kinematic"
sphere = 0.01
position = [1.2, 0.0, 0.5]
collides_wth = ["gel"]
quads = [2, 2]
[body.motion]
times = [0.0]
positions = [[1.2, 0.0, 0.5]]
rotatons = [[0.0, 0.0, 0.0]]
[[body]]
name = "hand"
type = "tool"
sphere = 0.01
material = "jelly"
stiffness = 100.0
position = [1.5, 0.0, 0.5]
max_forse = 5.0
fixed_below = 0.0
[body.motion]
times = [0.0]
positions = [[1.5, 0.0, 0.5]]
[[filter]]
a = "brick"
b = "probe"
bb = "gel"
[[coupling]]
a = "gel"
b = "post"
points = [[0.6, 0.0, 0.3]]
stiffness = 10.0
dampng = 1.0
[[model]]
file = "parts.toml"
colours = { bone = [0.9, 0.9, 0.8] }
[volume]
file = "head-ct"
treshold = 100.0
[display]
prest = "cube"
'''

#: Each problem's field path and the key it names as meant (None: none is near, every key the
#: table takes is listed; for a required key misspelt, what is expected of it), written by hand
#: from the format's docs: the keys of each table, and of each body type (docs/scenes.md, "A
#: body's keys by type").
_EXPECTED = {
    ("lights", "light"), ("simulation.stpes_per_frame", "steps_per_frame"), ("render.zooom", "zoom"),
    ("light[0].intensty", "intensity"), ("material.jelly.poison", "poisson"),
    ("adhesion.tacky.bonding_rat", "bonding_rate"), ("plane[0].normall", "normal"), ("sphere[0].fricton", "friction"),
    ("body[0].angular_velocty", "angular_velocity"), ("body[0].cells", None),                       # rigid
    ("body[0].poisson", "position"),  # a material's key, not a body's: said so (below)
    ("body[1].celss", "cells"), ("body[1].haptics", None), ("body[1].drive.offset", "offsets"),      # fem
    ("body[1].drive.offsets", "one [x, y, z] [m] per time"),  # misspelt, so it has none
    ("body[2].area_densty", "area_density"), ("body[2].collision_triangles", None),                 # cloth
    ("body[3].rotaton", "rotation"), ("body[3].velocity", None),                                    # fixed
    ("body[4].collides_wth", "collides_with"), ("body[4].quads", None),                             # kinematic
    ("body[4].motion.rotatons", "rotations"),
    ("body[5].max_forse", "max_force"), ("body[5].fixed_below", None),                              # tool
    ("filter[0].bb", "b"), ("coupling[0].dampng", "damping"), ("model[0].colours", "colors"),
    ("model[0].file couplings", "coupling"), ("model[0].file defaults.cel_size", "cell_size"),       # the parts file
    ("model[0].file part[0].densty", "density"), ("model[0].file coupling[0].colide", "collide"),
    ("volume.treshold", "threshold"), ("display.prest", "preset"),
}
#: The keys of another type, and the types that take them (docs/scenes.md).
_OTHER_TYPES = {"body[0].cells": ("rigid", "fem"), "body[1].haptics": ("fem", "tool"),
                "body[2].collision_triangles": ("cloth", "rigid | fem | kinematic | tool"),
                "body[3].velocity": ("fixed", "rigid | fem | cloth"), "body[4].quads": ("kinematic", "cloth"),
                "body[5].fixed_below": ("tool", "fem | cloth")}


def _meant(expected: str):
    """The key a problem names as meant (``did you mean 'x'?``), None when it lists them all;
    what was expected when it is no key's problem."""
    match = re.search(r"did you mean '([^']+)'\?", expected)
    return match.group(1) if match else None if "one of " in expected else expected


def test_a_typo_in_a_key_of_every_table_and_each_types_foreign_keys_are_refused_at_once(tmp_path, capsys):
    trimesh.creation.icosphere(1, radius=0.02).export(tmp_path / "ball.ply")
    (tmp_path / "parts.toml").write_text(_PARTS)
    path = tmp_path / "every.toml"
    path.write_text(_EVERY_TABLE)
    with pytest.raises(InputError) as info:
        read_scene(path)
    problems = info.value.problems
    assert {(what, _meant(expected)) for what, expected, _ in problems} == _EXPECTED
    assert len(problems) == len(_EXPECTED)  # each once, nothing else wrong with the file
    found = {what: (expected, found) for what, expected, found in problems}
    for what, (kind, takers) in _OTHER_TYPES.items():
        key = what.rsplit(".", 1)[-1]
        assert found[what][0].startswith(f"a key of a {kind} body"), found[what]
        assert found[what][1] == f"{key!r} (a key of {takers} bodies)", found[what]
    assert found["body[0].poisson"][1] == \
        "'poisson' (a key of [material.NAME] tables, which a body names with material = NAME)"
    # Listed in full where none is near: the rigid body's own keys, which do not include cells.
    assert "angular_velocity" in found["body[0].cells"][0] and "cells" not in found["body[0].cells"][0]
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{len(_EXPECTED)} problems" in err and "Traceback" not in err
    assert "body[1].haptics: expected a key of a fem body: one of " in err
    assert "model[0].file part[0].densty: expected a known key (did you mean 'density'?), found 'densty'" in err


def test_each_gltf_object_type_refuses_the_properties_of_other_types_and_typos_at_once(tmp_path):
    """The same keys as a TOML body's, per type (docs/scenes.md): a rigid object's material is its
    density only, so ``softvr_poisson`` (a fem object's) is refused, as a cloth object's
    ``softvr_collision_triangles``, each named with the nearest key its type takes."""
    trimesh.creation.icosphere(1, radius=0.02).export(tmp_path / "ball.ply")
    (tmp_path / "parts.toml").write_text(_PARTS.replace("densty", "density").replace("cel_size", "cell_size")
                                         .replace("colide", "collide").replace("couplings = []\n", ""))
    path = _glb(tmp_path / "every.glb", {
        "brick": {"softvr_type": "rigid", "softvr_densty": 500.0, "softvr_poisson": 0.3},
        "gel": {"softvr_type": "fem", "softvr_youngs": 2e4, "softvr_haptics": 1},
        "sheet": {"softvr_type": "cloth", "softvr_strech": 100.0, "softvr_collision_triangles": 100},
        "post": {"softvr_type": "fixed", "softvr_collides_wth": "gel", "softvr_density": 500.0},
        "probe": {"softvr_type": "kinematic", "softvr_render_msh": "post", "softvr_velocity": [0.0, 0.0, 1.0]},
        "hand": {"softvr_type": "tool", "softvr_stiffness": 100.0, "softvr_max_forse": 5.0, "softvr_cells": 0.02,
                 "softvr_couple_to": "gel", "softvr_coupling_stiffnes": 1.0, "softvr_coupling_points": [0, 0, 0]},
        "ct": {"softvr_type": "volume", "softvr_file": "head-ct", "softvr_treshold": 100.0},
        "arm": {"softvr_type": "model", "softvr_file": "parts.toml", "softvr_colours": {}}},
        {"softvr_frmes": 10, "softvr_zooom": 1.0})
    with pytest.raises(InputError) as info:
        read_gltf_scene(path)
    problems = info.value.problems
    assert {(what, _meant(expected)) for what, expected, _ in problems} == {
        ("scene.frmes", "frames"), ("scene.zooom", "zoom"),
        ("node 'brick'.densty", "density"), ("node 'brick'.poisson", None),
        ("node 'gel'.youngs", "young"), ("node 'gel'.haptics", None),
        ("node 'sheet'.strech", "stretch"), ("node 'sheet'.collision_triangles", None),
        ("node 'post'.collides_wth", "collides_with"), ("node 'post'.density", None),
        ("node 'probe'.render_msh", "render_mesh"), ("node 'probe'.velocity", None),
        ("node 'hand'.max_forse", "max_force"), ("node 'hand'.cells", None),
        ("node 'hand'.coupling_stiffnes", "coupling_stiffness"),
        ("node 'hand'.coupling_stiffness", "a number [N/m]"),  # misspelt, so it has none
        ("node 'ct'.treshold", "threshold"), ("node 'arm'.colours", "colors")}, problems
    found = {what: (expected, found) for what, expected, found in problems}
    assert found["node 'hand'.coupling_stiffness"][1] == "nothing"
    assert found["node 'brick'.poisson"][0].startswith("a key of a rigid object: one of ")
    assert found["node 'brick'.poisson"][1] == "'poisson' (a key of fem objects)"
    assert found["node 'sheet'.collision_triangles"][1] == \
        "'collision_triangles' (a key of rigid | fem | kinematic | tool objects)"


def _candy_with(tmp_path, text: str) -> Path:
    """The bundled candy.toml (bodies jello, soft candy 0 .. hard candy 7) with ``text`` appended."""
    path = tmp_path / "candy.toml"
    path.write_text((softvr.scene.BUNDLED / "candy.toml").read_text(encoding="utf-8") + text, encoding="utf-8")
    return path


def test_a_variant_replaces_the_keys_it_writes_and_removes_bodies(tmp_path):
    """``[variant.NAME]``: the file read with it is the file with its keys written in (by hand
    here: jello's cells and quads, frames, the dry switch) and its bodies left out; without it,
    the file as written; two variants apply in turn, the later one's keys winning."""
    path = _candy_with(tmp_path, """
[variant.coarse]
remove = ["hard candy 7", "soft candy 6"]
[variant.coarse.simulation]
frames = 7
[variant.coarse.body."jello"]
cells = [3, 3, 2]
surface_quads = 5
[variant.dry.simulation]
adhesion = false
frames = 9
""")
    plain = read_scene(path)
    assert plain.variants == () and len(plain.bodies) == 9 and plain.simulation["frames"] == 100
    assert plain.body("jello").cells == (12, 12, 5) and plain.simulation["adhesion"] is True
    coarse = read_scene(path, ["coarse"])
    assert coarse.variants == ("coarse",)
    assert [b.name for b in coarse.bodies] == [b.name for b in plain.bodies][:7]
    assert coarse.body("jello").cells == (3, 3, 2) and coarse.body("jello").surface_quads == 5
    assert coarse.body("jello").size == (0.3, 0.3, 0.12) and coarse.simulation["frames"] == 7
    both = read_scene(path, ["coarse", "dry"])
    assert both.simulation["frames"] == 9 and both.simulation["adhesion"] is False
    assert len(both.bodies) == 7


def test_a_variants_typos_and_bad_values_are_named_where_it_writes_them_all_at_once(tmp_path, capsys):
    """Every problem of every variant, each under the variant's own path with the key or body
    meant (written by hand); asking for a variant the file has not is named too."""
    path = _candy_with(tmp_path, """
[[sensor]]
name = "block"
kind = "position"
body = "jello"

[variant.bad]
remov = ["x"]
remove = ["soft candy 9"]
[variant.bad.simulation]
frame = 3
dt = -1.0
[variant.bad.body."jelo"]
cells = 3
[variant.bad.body."jello"]
celss = 3
surface_quads = -2
type = "rigid"
""")
    with pytest.raises(InputError) as info:
        read_scene(path, ["qiuck"])
    problems = {what: (expected, found) for what, expected, found in info.value.problems}
    assert problems == {
        "variant": ("the name of one of its [variant.NAME] tables (did you mean 'quick'?)", "'qiuck'"),
        "variant.bad.remov": ("a known key (did you mean 'remove'?)", "'remov'"),
        "variant.bad.remove[0]": ("the name of a [[body]] (did you mean 'soft candy 6'?)", "'soft candy 9'"),
        "variant.bad.simulation.frame": ("a known key (did you mean 'frames'?)", "'frame'"),
        "variant.bad.simulation.dt": ("a number > 0 [s]", "-1.0"),
        "variant.bad.body.jelo": ("the name of a [[body]] (did you mean 'jello'?)", "'jelo'"),
        "variant.bad.body.jello.celss": ("a known key (did you mean 'cells'?)", "'celss'"),
        "variant.bad.body.jello.surface_quads": ("an integer >= 1", "-2"),
        "variant.bad.body.jello.type": ("another key of the body (a variant keeps its name and type)", "'rigid'")
    }, problems
    assert main(["check", str(path)]) == 2  # the file's variants are checked without asking for one
    assert "variant.bad.body.jello.celss: expected a known key (did you mean 'cells'?)" in capsys.readouterr().err


def test_a_variant_removes_what_names_the_bodies_it_removes_and_what_it_breaks_is_named_below_it(tmp_path):
    """Removing bodies removes the couplings, filters and sensors naming them, and their names
    from collides_with; a variant that leaves a file no body (and no plane) is named below the
    variant with what the file then lacks."""
    path = tmp_path / "pair.toml"
    path.write_text('format = "softvr-scene 1"\n[material.m]\ndensity = 1000.0\n'
                    '[[body]]\nname = "a"\ntype = "rigid"\nsphere = 0.1\nmaterial = "m"\ncollides_with = ["b", "c"]\n'
                    '[[body]]\nname = "b"\ntype = "rigid"\nsphere = 0.1\nmaterial = "m"\nposition = [1.0, 0.0, 0.0]\n'
                    '[[body]]\nname = "c"\ntype = "rigid"\nsphere = 0.1\nmaterial = "m"\nposition = [2.0, 0.0, 0.0]\n'
                    '[[coupling]]\na = "a"\nb = "b"\npoints = [[0.5, 0.0, 0.0]]\nstiffness = 10.0\n'
                    '[[filter]]\na = "b"\nb = "c"\n'
                    '[[sensor]]\nname = "f"\nkind = "contact_force"\nbody = "a"\nother = "b"\n'
                    '[[sensor]]\nname = "x"\nkind = "position"\nbody = "a"\n'
                    '[variant.alone]\nremove = ["b"]\n[variant.empty]\nremove = ["a", "b", "c"]\n')
    with pytest.raises(InputError) as info:
        read_scene(path)  # every variant checked, none asked for
    assert info.value.problems == [("variant.empty body", "at least one [[body]]", "none")]
    path.write_text(path.read_text().replace('[variant.empty]\nremove = ["a", "b", "c"]\n', ""))
    whole = read_scene(path)
    assert len(whole.couplings) == 1 and len(whole.filters) == 1 and len(whole.sensors) == 2
    alone = read_scene(path, ["alone"])
    assert [b.name for b in alone.bodies] == ["a", "c"] and alone.body("a").collides_with == ("c",)
    assert alone.couplings == [] and alone.filters == [] and [s["name"] for s in alone.sensors] == ["x"]
