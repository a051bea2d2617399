"""A scene made with Blender itself (``bpy`` 4.2 from PyPI, in ``.venv-blender``, installed by
``scripts/setup.sh test``): objects with custom properties, exported by Blender's own glTF
exporter, load into the same bodies and parameters as the equivalent TOML scene.

Truth: the TOML scene written by hand with the same box (Blender's cube of size 0.2 at height
0.5, z up) and the same properties; the FEM bodies must have the same nodes, tets and masses,
and the scene the same time step and frame count. The add-on's authoring tools (keyframed
kinematic bodies, picked coupling vertices, tet and CAVE previews) against ``dynamics_mesh``, the
``softvr cave preview`` picture and the keyframes and vertices set in Blender.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from softvr.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
BLENDER_PYTHON = Path(os.environ.get("SOFTVR_BPY_PYTHON", ROOT / ".venv-blender" / "bin" / "python"))

pytestmark = pytest.mark.skipif(
    not BLENDER_PYTHON.exists() or sys.version_info[:2] != (3, 11),
    reason="Blender's Python module (bpy 4.2, CPython 3.11) is installed by scripts/setup.sh test")

BLENDER_SCRIPT = """
import os
import sys

import bpy

bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_cube_add(size=0.2, location=(0.0, 0.0, 0.5))
gel = bpy.context.active_object
gel.name = "gel"
gel["softvr_type"] = "fem"
gel["softvr_young"] = 20000.0
gel["softvr_poisson"] = 0.4
gel["softvr_density"] = 900.0
gel["softvr_cells"] = 0.045
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.3, location=(2.0, 0.0, 0.0))  # scenery: no softvr_type
scene = bpy.context.scene
scene["softvr_dt"] = 0.01
scene["softvr_frames"] = 3
bpy.ops.export_scene.gltf(filepath=sys.argv[1], export_format="GLB", export_extras=True)
sys.stdout.flush()
os._exit(0)  # bpy's own teardown at interpreter exit can crash under a test runner's environment
"""


def test_blenders_own_gltf_export_loads_as_the_equivalent_toml_scene(tmp_path):
    glb = tmp_path / "gel.glb"
    done = subprocess.run([str(BLENDER_PYTHON), "-c", BLENDER_SCRIPT, str(glb)], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    import trimesh

    trimesh.creation.box((0.2, 0.2, 0.2)).export(tmp_path / "gel.obj")
    toml = tmp_path / "gel.toml"
    toml.write_text('''format = "softvr-scene 1"
[simulation]
dt = 0.01
frames = 3
[material.gel]
young = 2e4
poisson = 0.4
density = 900.0
[[plane]]
[[body]]
name = "gel"
type = "fem"
mesh = "gel.obj"
cells = 0.045
material = "gel"
position = [0.0, 0.0, 0.5]
''')
    a, b = load_scene(glb), load_scene(toml)
    assert list(a.bodies) == ["gel"]  # the sphere without properties is scenery
    fa, fb = a.bodies["gel"], b.bodies["gel"]
    assert (a.dt, a.frames) == (b.dt, b.frames) == (0.01, 3)
    assert len(fa.tets) == len(fb.tets)
    np.testing.assert_allclose(np.sort(fa.rest, axis=0), np.sort(fb.rest, axis=0), atol=1e-7)  # float32 glTF
    assert fa.mass.sum() == pytest.approx(fb.mass.sum(), rel=1e-6)
    assert fa.mass.sum() == pytest.approx(900.0 * 0.2**3, rel=1e-6)  # rho times the cube
    assert (fa.material.young, fa.material.poisson) == (2e4, 0.4)


ADDON_SCRIPT = """
import os
import sys

import bpy

zip_path, glb = sys.argv[1], sys.argv[2]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path)
bpy.ops.preferences.addon_enable(module="softvr_blender")
bpy.ops.mesh.primitive_cube_add(size=0.1, location=(0.0, 0.0, 0.2))
bpy.context.active_object.name = "jelly"
bpy.ops.softvr.mark(kind="fem")
bpy.context.active_object["softvr_young"] = 5.0e4
bpy.ops.mesh.primitive_cube_add(size=0.04, location=(0.3, 0.0, 0.3))
bpy.context.active_object.name = "die"
bpy.ops.softvr.mark(kind="fem")  # marked soft first, then re-marked: the fem properties must go
bpy.ops.softvr.mark(kind="rigid")
bpy.ops.softvr.adhesive()
bpy.ops.softvr.export(filepath=glb)
sys.stdout.flush()
os._exit(0)
"""


def test_the_addon_installs_marks_and_exports_a_scene_that_checks_and_runs(tmp_path, capsys):
    from softvr.blender import build_addon
    from softvr.cli import main

    addon = build_addon(tmp_path)
    glb = tmp_path / "addon.glb"
    done = subprocess.run([str(BLENDER_PYTHON), "-c", ADDON_SCRIPT, str(addon), str(glb)], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0 and glb.exists(), done.stderr[-2000:]
    assert main(["check", str(glb)]) == 0
    assert "1 fem, 1 rigid" in capsys.readouterr().out
    with load_scene(glb, frames=3, width=64, height=48) as ex:
        jelly, die = ex.bodies["jelly"], ex.bodies["die"]
        assert jelly.material.young == 5.0e4 and jelly.material.poisson == 0.4  # set, and the add-on's default
        assert die.mass == pytest.approx(1000.0 * 0.04**3, rel=1e-6)
        # "Make adhesive": the add-on's default adhesion (wet tissue, thesis ch. 4) on the die only.
        from softvr.contact import Adhesion

        glue = ex.scene._adhesion[("body", ex.index["die"])]
        assert vars(glue) == vars(Adhesion(stiffness=1e7, max_energy=0.4, viscosity=0.2, debond_gap=0.003))
        assert ex.scene._adhesion[("body", ex.index["jelly"])] is None
        z0 = die.position[2]
        for _ in range(3):
            ex.step()
        assert die.position[2] < z0  # it falls


AUTHORING_SCRIPT = """
import json
import os
import sys

import bpy
import bmesh

zip_path, glb, softvr, report = sys.argv[1:5]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path)
bpy.ops.preferences.addon_enable(module="softvr_blender")
bpy.context.preferences.addons["softvr_blender"].preferences.softvr_command = softvr
scene = bpy.context.scene
scene.frame_set(1)
bpy.ops.mesh.primitive_cube_add(size=0.2, location=(0.0, 0.0, 0.15))
gel = bpy.context.active_object
gel.name = "gel"
bpy.ops.softvr.mark(kind="fem")
gel["softvr_cells"] = 0.045
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.03, segments=12, ring_count=6, location=(0.3, 0.0, 0.15))
probe = bpy.context.active_object
probe.name = "probe"
bpy.ops.softvr.mark(kind="kinematic")
probe.keyframe_insert("location", frame=1)
probe.location = (0.3, 0.1, 0.25)
probe.keyframe_insert("location", frame=1 + scene.render.fps)  # one second later
scene.frame_set(1)
bpy.ops.mesh.primitive_cube_add(size=0.04, location=(0.0, 0.0, 0.27))
post = bpy.context.active_object
post.name = "post"
bpy.ops.softvr.mark(kind="kinematic")  # no keyframes: it holds still
scene["softvr_dt"] = 0.01
scene["softvr_steps_per_frame"] = 5

# Two vertices of the gel's top face (x > 0) picked in edit mode, the post selected too.
bpy.ops.object.select_all(action="DESELECT")
post.select_set(True)
gel.select_set(True)
bpy.context.view_layer.objects.active = gel
bpy.ops.object.mode_set(mode="EDIT")
mesh = bmesh.from_edit_mesh(gel.data)
for v in mesh.verts:
    world = gel.matrix_world @ v.co
    v.select = world.z > 0.2 and world.x > 0
mesh.select_flush(False)
bmesh.update_edit_mesh(gel.data)
assert bpy.ops.softvr.pick_coupling() == {"FINISHED"}
bpy.ops.object.mode_set(mode="OBJECT")

bpy.ops.object.select_all(action="DESELECT")
gel.select_set(True)
bpy.context.view_layer.objects.active = gel
assert bpy.ops.softvr.preview_tets() == {"FINISHED"}
assert bpy.ops.softvr.preview_tets() == {"FINISHED"}  # again: replaced, not doubled
tets = bpy.data.objects["gel tets"]
assert bpy.ops.softvr.cave_preview(frames=2) == {"FINISHED"}
image = bpy.data.images["softvr CAVE preview"]
bpy.ops.softvr.export(filepath=glb)
with open(report, "w") as f:
    json.dump({"tet_nodes": len(tets.data.vertices), "tet_edges": len(tets.data.edges),
               "tet_faces": len(tets.data.polygons), "display_type": tets.display_type,
               "hide_render": tets.hide_render, "tet_objects": sum(o.name.startswith("gel tets") for o in bpy.data.objects),
               "image": list(image.size), "image_pixels": len(image.pixels)}, f)
sys.stdout.flush()
os._exit(0)
"""


def test_authoring_in_blender_keyframes_couplings_tet_preview_and_cave_preview(tmp_path):
    """In Blender with the add-on: a FEM cube, a kinematic sphere keyed at two locations one
    second apart, a still kinematic post; two of the cube's vertices picked as coupling points
    to the post; the tet preview and the CAVE preview. Truths: the tet object has the nodes and
    edges of ``dynamics_mesh`` for the same cube and cell size; the CAVE image is the size of
    the picture ``softvr cave preview cube`` makes; in the export the sphere is at its second
    keyframe's location one second in, and the coupling's springs are at the picked vertices."""
    import struct

    import trimesh

    from softvr.blender import build_addon
    from softvr.cli import main
    from softvr.model import dynamics_mesh
    from softvr.scene.gltf import read_gltf_scene

    softvr = Path(sys.executable).with_name("softvr")
    assert softvr.exists()
    addon, glb, report = build_addon(tmp_path), tmp_path / "authored.glb", tmp_path / "report.json"
    done = subprocess.run([str(BLENDER_PYTHON), "-c", AUTHORING_SCRIPT, str(addon), str(glb), str(softvr),
                           str(report)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and report.exists(), (done.stdout[-2000:], done.stderr[-2000:])
    import json

    got = json.loads(report.read_text())
    cube = trimesh.creation.box((0.2, 0.2, 0.2))
    nodes, tets = dynamics_mesh(np.asarray(cube.vertices) + [0.0, 0.0, 0.15], cube.faces, 0.045)
    edges = {tuple(sorted((int(t[i]), int(t[j])))) for t in tets for i in range(4) for j in range(i + 1, 4)}
    assert (got["tet_nodes"], got["tet_edges"], got["tet_faces"]) == (len(nodes), len(edges), 0)
    assert got["display_type"] == "WIRE" and got["hide_render"] and got["tet_objects"] == 1

    assert main(["cave", "preview", "cube", str(glb), "--frames", "1", "--out", str(tmp_path / "cave"), "--quiet"]) == 0
    png = (tmp_path / "cave" / "cave_preview.png").read_bytes()
    assert got["image"] == list(struct.unpack(">II", png[16:24]))  # the PNG's IHDR width, height
    assert got["image_pixels"] == 4 * got["image"][0] * got["image"][1]

    scene = read_gltf_scene(glb)
    assert sorted(b.name for b in scene.bodies) == ["gel", "post", "probe"]  # the tet preview is no body
    assert scene.display == "cube"
    picked = [[0.1, -0.1, 0.25], [0.1, 0.1, 0.25]]  # the top face's vertices with x > 0, Blender's z up
    (coupling,) = scene.couplings
    assert (coupling["a"], coupling["b"], coupling["stiffness"]) == ("gel", "post", 2000.0)
    points = np.asarray(coupling["points"])
    np.testing.assert_allclose(points[np.lexsort(points.T)], picked, atol=1e-6)
    with load_scene(glb) as ex:
        probe = ex.bodies["probe"]
        np.testing.assert_allclose(probe.position, [0.3, 0.0, 0.15], atol=1e-6)  # frame 1 is t = 0
        (springs,) = ex.scene.couplings
        a = springs.a.positions()
        np.testing.assert_allclose(a[np.lexsort(a.T)], picked, atol=1e-6)
        for _ in range(20):  # 20 frames of 5 x 0.01 s
            ex.step()
        assert ex.scene.time == pytest.approx(1.0)
        np.testing.assert_allclose(probe.position, [0.3, 0.1, 0.25], atol=1e-6)  # the second keyframe
        np.testing.assert_allclose(ex.bodies["post"].position, [0.0, 0.0, 0.27], atol=1e-6)  # still


CHECK_SCRIPT = """
import os
import sys

import bpy

zip_path, softvr = sys.argv[1:3]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path)
bpy.ops.preferences.addon_enable(module="softvr_blender")
bpy.context.preferences.addons["softvr_blender"].preferences.softvr_command = softvr
bpy.ops.mesh.primitive_cube_add(size=0.2, location=(0.0, 0.0, 0.15))
bpy.context.active_object.name = "gel"
bpy.ops.softvr.mark(kind="fem")
bpy.context.active_object["softvr_cells"] = 0.045
bpy.ops.mesh.primitive_cube_add(size=0.4, location=(0.0, 0.0, -0.13))  # its top 2 cm into the gel
bpy.context.active_object.name = "table"
bpy.ops.softvr.mark(kind="fixed")
print("CHECK", sorted(bpy.ops.softvr.check()))
bpy.context.scene["softvr_collision_free_start"] = False
try:
    bpy.ops.softvr.check()
except RuntimeError:  # an operator's error report, in a script
    print("CHECK FAILED")
sys.stdout.flush()
os._exit(0)
"""


def test_the_addons_check_runs_the_validator_and_the_collision_free_start(tmp_path):
    """A FEM cube modelled 2 cm into a fixed table: the add-on's Check (the scene's default
    collision-free start on) pushes it out and passes, saying so; with the start turned off
    the same scene fails, naming the crossing pair."""
    from softvr.blender import build_addon

    softvr = Path(sys.executable).with_name("softvr")
    done = subprocess.run([str(BLENDER_PYTHON), "-c", CHECK_SCRIPT, str(build_addon(tmp_path)), str(softvr)],
                          capture_output=True, text=True, timeout=300)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out[-2000:]
    assert "Info: collision-free start: 'gel' pushed out of 'table'" in out
    assert "CHECK ['FINISHED']" in out
    assert "bodies 'gel' and 'table': expected surfaces apart at the start" in out and "CHECK FAILED" in out


SENSOR_SCRIPT = """
import os
import sys

import bpy

zip_path, glb = sys.argv[1:3]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path)
bpy.ops.preferences.addon_enable(module="softvr_blender")
bpy.ops.mesh.primitive_cube_add(size=0.2, location=(0.0, 0.0, 0.0))
floor = bpy.context.active_object
floor.name = "floor"
bpy.ops.softvr.mark(kind="fixed")
try:
    bpy.ops.softvr.add_sensor(kind="position")
except RuntimeError:  # an operator's error report, in a script: a fixed object is no body
    print("FIXED REFUSED")
bpy.ops.mesh.primitive_cube_add(size=0.1, location=(0.0, 0.0, 0.5))
box = bpy.context.active_object
box.name = "box"
bpy.ops.softvr.mark(kind="rigid")
assert bpy.ops.softvr.add_sensor(kind="position", name="fall") == {"FINISHED"}
assert bpy.ops.softvr.add_sensor(kind="hand_force") == {"FINISHED"}
assert bpy.ops.softvr.remove_sensor(kind="hand_force") == {"FINISHED"}
floor.select_set(True)  # the box active, the floor selected too: the contact sensor's other side
assert bpy.ops.softvr.add_sensor(kind="contact_force") == {"FINISHED"}
scene = bpy.context.scene
scene["softvr_dt"] = 0.01
scene["softvr_steps_per_frame"] = 1
bpy.ops.softvr.export(filepath=glb)
sys.stdout.flush()
os._exit(0)
"""


def test_the_addon_adds_edits_and_exports_sensors_that_read_the_scene(tmp_path):
    """In Blender with the add-on: a rigid box over a fixed floor gets a position sensor named
    "fall", a hand force sensor added and removed again, and a contact force sensor with the
    floor (the other selected object: a fixed mesh is static geometry, "static"); a sensor on
    the fixed floor is refused. Truths: the
    export holds exactly the two sensors as the author set them, and played, the box falls
    freely for 3 steps of h = 0.01 s: semi-implicit Euler's z_n = z_0 - g h^2 n (n + 1) / 2,
    with no contact force from the floor 0.35 m below."""
    from softvr.blender import build_addon
    from softvr.scene.gltf import read_gltf_scene

    glb = tmp_path / "sensors.glb"
    done = subprocess.run([str(BLENDER_PYTHON), "-c", SENSOR_SCRIPT, str(build_addon(tmp_path)), str(glb)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and glb.exists(), (done.stdout[-2000:], done.stderr[-2000:])
    assert "FIXED REFUSED" in done.stdout
    sensors = sorted(read_gltf_scene(glb).sensors, key=lambda s: s["name"])
    assert sensors == [{"name": "box contact force", "kind": "contact_force", "body": "box", "other": "static"},
                       {"name": "fall", "kind": "position", "body": "box", "other": None}]
    g, h = 9.81, 0.01
    with load_scene(glb, frames=3, width=64, height=48) as ex:
        for _ in range(3):
            record = ex.step()
    n = 3
    np.testing.assert_allclose(record["sensors"]["fall"], [0.0, 0.0, 0.5 - g * h**2 * n * (n + 1) / 2], rtol=1e-12,
                               atol=1e-12)
    assert record["sensors"]["box contact force"] == [0.0, 0.0, 0.0]


def test_the_addons_sensor_kinds_are_softvrs():
    """The add-on runs inside Blender without softvr, so it lists the sensor kinds itself: the
    same as the scene format's (read from its source: it imports bpy)."""
    import ast

    from softvr.scene._description import SENSOR_KINDS

    source = (ROOT / "src" / "softvr" / "blender" / "softvr_blender" / "__init__.py").read_text()
    listed = next(node.value for node in ast.parse(source).body if isinstance(node, ast.AnnAssign | ast.Assign)
                  and "SENSOR_KINDS" in ast.unparse(node.targets[0] if isinstance(node, ast.Assign) else node.target))
    assert [kind.elts[0].value for kind in listed.elts] == list(SENSOR_KINDS)
