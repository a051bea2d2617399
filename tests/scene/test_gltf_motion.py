"""glTF scenes with scripted motion, tools and couplings (what Blender writes for location
keyframes and the add-on's properties), read without Blender.

Truths: a kinematic box keyed at two glTF (y-up) translations is, at each time, where linear
interpolation of those keys turned z-up puts it (its corners the box's half-size around it);
a tool's properties and a coupling's springs are those of the equivalent TOML scene written by
hand; bad properties and bad animation data are each named in one error. ``softvr tetmesh``
writes the nodes and tets ``dynamics_mesh`` gives for the same surface, whose volume lies between
the box's and that of the whole cubes over it.
"""

import json
import struct

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.scene import load_scene, read_scene
from softvr.scene.gltf import read_gltf_scene


def _glb(path, nodes, scene_extras=None, animations=(), component_type=5126):
    """A GLB of box nodes ``(name, size, translation (glTF y-up), extras)`` with ``extras`` as
    Blender writes custom properties, and translation ``animations``
    ``(node name, times [k], translations [k, 3] (y-up), interpolation)`` as Blender writes
    location keyframes: float arrays appended to the BIN chunk, one buffer view and accessor
    each."""
    import trimesh

    scene = trimesh.Scene()
    for name, size, translation, _ in nodes:
        scene.add_geometry(trimesh.creation.box(size), node_name=name, geom_name=f"{name} mesh",
                           transform=trimesh.transformations.translation_matrix(translation))
    data = scene.export(file_type="glb")
    length = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + length])
    bin_length = struct.unpack("<I", data[20 + length:24 + length])[0]
    binary = bytearray(data[28 + length:28 + length + bin_length])
    index = {}
    for i, node in enumerate(doc["nodes"]):
        index[node["name"]] = i
        extras = next(e for n, _, _, e in nodes if n == node["name"])
        if extras:
            node["extras"] = extras
        matrix = node.pop("matrix", None)  # animated nodes need TRS (glTF 2.0): a translation here
        if matrix is not None:
            node["translation"] = matrix[12:15]
    if scene_extras:
        doc["scenes"][doc.get("scene", 0)]["extras"] = scene_extras

    def accessor(values, kind):
        values = np.asarray(values, "<f4" if component_type == 5126 else "<u2")
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": values.nbytes})
        binary.extend(values.tobytes())
        binary.extend(b"\0" * (-len(binary) % 4))
        doc["accessors"].append({"bufferView": len(doc["bufferViews"]) - 1, "componentType": component_type,
                                 "count": len(values), "type": kind})
        return len(doc["accessors"]) - 1

    for name, times, translations, interpolation in animations:
        doc.setdefault("animations", []).append({
            "name": f"{name}Action",
            "channels": [{"sampler": 0, "target": {"node": index[name], "path": "translation"}}],
            "samplers": [{"input": accessor(times, "SCALAR"), "output": accessor(translations, "VEC3"),
                          "interpolation": interpolation}]})
    doc["buffers"][0]["byteLength"] = len(binary)
    chunk = json.dumps(doc).encode()
    chunk += b" " * (-len(chunk) % 4)
    body = struct.pack("<I4s", len(chunk), b"JSON") + chunk + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
    return path


def _z_up(p):
    x, y, z = p
    return np.array([x, -z, y])


def test_a_kinematic_box_moves_as_its_translation_keys_turned_z_up(tmp_path):
    """Keys at 0.5 s and 1.5 s (Blender's frames start after 0 s): the motion starts at the
    first key; at simulated time t the box is at the keys' linear interpolation at 0.5 + t."""
    keys = [(0.0, 0.3, 0.0), (0.2, 0.4, -0.1)]  # y-up
    path = _glb(tmp_path / "moving.glb", [("probe", (0.1, 0.06, 0.04), keys[0], {"softvr_type": "kinematic"})],
                {"softvr_dt": 0.01, "softvr_steps_per_frame": 5, "softvr_ground": False},
                [("probe", [0.5, 1.5], keys, "LINEAR")])
    a, b = _z_up(keys[0]), _z_up(keys[1])
    spec = read_gltf_scene(path).body("probe")
    np.testing.assert_allclose(spec.motion["times"], [0.0, 1.0])
    np.testing.assert_allclose(spec.motion["positions"], [a, b], atol=1e-7)
    half = np.array([0.1, 0.04, 0.06]) / 2  # the y-up box's (x, y, z) sizes turned z-up
    with load_scene(path) as ex:
        probe = ex._drawn_by_name["probe"]
        for frame in range(1, 25):
            ex.step()
            t = frame * 0.05
            centre = a + min(t, 1.0) * (b - a)
            v = probe.vertices()
            np.testing.assert_allclose(v.min(axis=0), centre - half, atol=1e-6)
            np.testing.assert_allclose(v.max(axis=0), centre + half, atol=1e-6)
            np.testing.assert_allclose(ex.bodies["probe"].position, centre, atol=1e-6)


def test_the_scene_start_time_and_step_and_cubic_keys(tmp_path):
    """``softvr_start_time`` sets t = 0 (keys before it are the past); STEP keys hold until the
    next; CUBICSPLINE keys pass through their values (the triples' middles)."""
    keys = [(0.0, 0.3, 0.0), (0.2, 0.3, 0.0), (0.2, 0.5, 0.0)]
    cubic = [v for k in keys for v in ((9.0, 9.0, 9.0), k, (-9.0, -9.0, -9.0))]  # tangents, value, tangents
    path = _glb(tmp_path / "keys.glb", [
        ("step", (0.05, 0.05, 0.05), keys[0], {"softvr_type": "kinematic"}),
        ("cubic", (0.05, 0.05, 0.05), (1.0, 0.3, 0.0), {"softvr_type": "kinematic"})],
        {"softvr_start_time": 0.0, "softvr_ground": False},
        [("step", [0.0, 1.0, 2.0], keys, "STEP"), ("cubic", [0.5, 1.0, 2.0], cubic, "CUBICSPLINE")])
    scene = read_gltf_scene(path)
    step, cubic_spec = scene.body("step"), scene.body("cubic")
    from softvr.scene.build import _linear

    times, positions = np.asarray(step.motion["times"]), np.asarray(step.motion["positions"])
    for t, key in ((0.0, 0), (0.5, 0), (0.999, 0), (1.0, 1), (1.7, 1), (2.0, 2), (3.0, 2)):
        np.testing.assert_allclose(_linear(times, positions, t), _z_up(keys[key]), atol=1e-6)
    np.testing.assert_allclose(cubic_spec.motion["times"], [0.5, 1.0, 2.0])  # start time 0: not shifted
    np.testing.assert_allclose(cubic_spec.motion["positions"], [_z_up(k) for k in keys], atol=1e-7)
    assert cubic_spec.position == pytest.approx(tuple(_z_up(keys[0])), abs=1e-7)  # the motion's start


def test_a_still_kinematic_box_and_a_tool_read_as_the_equivalent_toml(tmp_path):
    """A kinematic node without animation holds still where it is; a tool node reads its
    coupling to the hand, material and collision partners as the TOML scene gives them."""
    path = _glb(tmp_path / "tool.glb", [
        ("post", (0.1, 0.1, 0.1), (0.5, 0.05, 0.0), {"softvr_type": "kinematic"}),
        ("finger", (0.02, 0.02, 0.02), (0.0, 0.3, 0.0), {
            "softvr_type": "tool", "softvr_density": 500.0, "softvr_stiffness": 300.0, "softvr_damping": 2.0,
            "softvr_haptics": False, "softvr_max_force": 5.0, "softvr_collides_with": "post"})],
        {"softvr_ground": False}, [("finger", [0.0, 1.0], [(0.0, 0.3, 0.0), (0.0, 0.3, 0.1)], "LINEAR")])
    toml = tmp_path / "tool.toml"
    toml.write_text('''format = "softvr-scene 1"
[material.finger]
density = 500.0
[[body]]
name = "post"
type = "kinematic"
box = [0.1, 0.1, 0.1]
position = [0.5, 0.0, 0.05]
[body.motion]
times = [0.0]
positions = [[0.5, 0.0, 0.05]]
[[body]]
name = "finger"
type = "tool"
box = [0.02, 0.02, 0.02]
material = "finger"
position = [0.0, 0.0, 0.3]
stiffness = 300.0
damping = 2.0
max_force = 5.0
collides_with = ["post"]
[body.motion]
times = [0.0, 1.0]
positions = [[0.0, 0.0, 0.3], [0.0, -0.1, 0.3]]
''')
    g, t = read_gltf_scene(path), read_scene(toml)
    for name in ("post", "finger"):
        a, b = g.body(name), t.body(name)
        assert a.type == b.type
        np.testing.assert_allclose(a.position, b.position, atol=1e-7)
        np.testing.assert_allclose(a.motion["times"], b.motion["times"])
        np.testing.assert_allclose(a.motion["positions"], b.motion["positions"], atol=1e-7)
    assert g.body("finger").tool == t.body("finger").tool
    assert g.body("finger").collides_with == ("post",)
    assert g.display is None and t.display is None
    assert g.materials["finger"]["density"] == 500.0
    with load_scene(path) as ex:
        assert ex.bodies["finger"].mass == pytest.approx(500.0 * 0.02**3, rel=1e-5)
        (tool,) = ex.tools
        assert (tool.coupling.stiffness, tool.coupling.damping) == (300.0, 2.0)
        assert ex.scene.collision_enabled(ex.index["finger"], ex.index["post"])


_GEL_AND_POST = '''format = "softvr-scene 1"
[material.gel]
young = 2e4
density = 900.0
[[plane]]
[[body]]
name = "gel"
type = "fem"
mesh = "gel.obj"
cells = 0.045
material = "gel"
position = [0.0, 0.0, 0.06]
[[body]]
name = "post"
type = "kinematic"
box = [0.04, 0.04, 0.04]
position = [0.0, 0.0, 0.13]
[body.motion]
times = [0.0]
positions = [[0.0, 0.0, 0.13]]
[[coupling]]
a = "gel"
b = "post"
stiffness = 2000.0
damping = 0.5
'''


@pytest.mark.parametrize("by", ["points", "radius"])
def test_couplings_load_as_the_equivalent_toml_scene(tmp_path, by):
    """A gel block (0.1 m, z-up centre at 0.06) with a small kinematic post on top: springs at
    two given world points, or at the gel's nodes within 5 mm of the post, as in TOML."""
    import trimesh

    points = [[0.0, 0.0, 0.11], [0.01, -0.005, 0.11]]  # Blender's world (z up) = softvr's
    coupling = {"softvr_couple_to": "post", "softvr_coupling_stiffness": 2000.0, "softvr_coupling_damping": 0.5}
    coupling.update({"softvr_coupling_points": [x for p in points for x in p]} if by == "points" else
                    {"softvr_coupling_radius": 0.005})
    path = _glb(tmp_path / "coupled.glb", [
        ("gel", (0.1, 0.1, 0.1), (0.0, 0.06, 0.0), {"softvr_type": "fem", "softvr_young": 2e4,
                                                     "softvr_density": 900.0, "softvr_cells": 0.045, **coupling}),
        ("post", (0.04, 0.04, 0.04), (0.0, 0.13, 0.0), {"softvr_type": "kinematic"})])
    trimesh.creation.box((0.1, 0.1, 0.1)).export(tmp_path / "gel.obj")
    toml = tmp_path / "coupled.toml"
    toml.write_text(_GEL_AND_POST + (f"points = {points}\n" if by == "points" else "radius = 0.005\n"))
    g, t = read_gltf_scene(path), read_scene(toml)
    assert g.couplings == t.couplings
    a, b = load_scene(path, frames=1), load_scene(toml, frames=1)
    (ca,), (cb,) = a.scene.couplings, b.scene.couplings
    assert len(ca) == len(cb) == (2 if by == "points" else 4)  # radius: the 4 top nodes beside the post
    for side in ("a", "b"):
        pa, pb = getattr(ca, side).positions(), getattr(cb, side).positions()
        np.testing.assert_allclose(pa[np.lexsort(pa.T)], pb[np.lexsort(pb.T)], atol=1e-6)
    if by == "points":
        np.testing.assert_allclose(ca.a.positions(), points, atol=1e-9)
    assert (ca.stiffness, ca.damping) == (2000.0, 0.5)


def test_bad_motion_tool_and_coupling_properties_are_named_by_node(tmp_path):
    path = _glb(tmp_path / "bad.glb", [
        ("gel", (0.1, 0.1, 0.1), (0.0, 0.06, 0.0), {
            "softvr_type": "fem", "softvr_couple_to": "nobody", "softvr_coupling_radius": 0.01}),
        ("finger", (0.02, 0.02, 0.02), (0.0, 0.3, 0.0), {"softvr_type": "tool", "softvr_collides_with": "gel, ghost"}),
        ("cloth", (0.1, 0.1, 0.01), (0.5, 0.3, 0.0), {
            "softvr_type": "cloth", "softvr_couple_to": "gel", "softvr_coupling_stiffness": 10.0,
            "softvr_coupling_points": [0.0, 0.1]})], {"softvr_display": "moon"})
    with pytest.raises(InputError) as info:
        read_gltf_scene(path)
    message = str(info.value)
    for fragment in ("bad.glb", "node 'gel'.couple_to", "'nobody'", "node 'gel'.coupling_stiffness",
                     "node 'finger'.stiffness", "node 'finger'.collides_with", "'ghost'",
                     "node 'cloth'.coupling_points", "scene.display", "'moon'"):
        assert fragment in message, fragment


def test_a_non_float_animation_accessor_is_named(tmp_path):
    path = _glb(tmp_path / "ints.glb", [("probe", (0.1, 0.1, 0.1), (0.0, 0.3, 0.0), {"softvr_type": "kinematic"})],
                animations=[("probe", [0, 1], [(0, 0, 0), (1, 1, 1)], "LINEAR")], component_type=5123)
    with pytest.raises(InputError) as info:
        read_gltf_scene(path)
    assert "node 'probe'" in str(info.value) and "componentType" in str(info.value)
    assert "5126" in str(info.value) and "5123" in str(info.value)


def test_an_animated_child_object_is_refused(tmp_path):
    path = _glb(tmp_path / "child.glb", [
        ("arm", (0.1, 0.1, 0.1), (0.0, 0.3, 0.0), {"softvr_type": "kinematic"}),
        ("hand", (0.05, 0.05, 0.05), (0.2, 0.3, 0.0), {"softvr_type": "kinematic"})],
        animations=[("hand", [0.0, 1.0], [(0.2, 0.3, 0.0), (0.3, 0.3, 0.0)], "LINEAR")])
    doc = _read_json(path)
    doc["nodes"][0]["children"] = [1]
    doc["scenes"][0]["nodes"] = [0]
    _write_json(path, doc)
    with pytest.raises(InputError) as info:
        read_gltf_scene(path)
    assert "node 'hand' animation" in str(info.value) and "an animated object without a parent" in str(info.value)


def test_a_gltf_with_a_buffer_file_and_a_data_uri_reads_the_same_motion(tmp_path):
    """The same animation from a .gltf whose buffer is a file next to it, and from one whose
    buffer is a base64 ``data:`` URI."""
    import base64

    keys = [(0.0, 0.3, 0.0), (0.1, 0.3, 0.2)]
    glb = _glb(tmp_path / "m.glb", [("probe", (0.1, 0.1, 0.1), keys[0], {"softvr_type": "kinematic"})],
               animations=[("probe", [0.0, 2.0], keys, "LINEAR")])
    doc, binary = _read_json(glb), _bin(glb)
    (tmp_path / "m.bin").write_bytes(binary)
    doc["buffers"][0]["uri"] = "m.bin"
    (tmp_path / "file.gltf").write_text(json.dumps(doc))
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(binary).decode()
    (tmp_path / "inline.gltf").write_text(json.dumps(doc))
    for name in ("m.glb", "file.gltf", "inline.gltf"):
        spec = read_gltf_scene(tmp_path / name).body("probe")
        np.testing.assert_allclose(spec.motion["positions"], [_z_up(k) for k in keys], atol=1e-7)
        np.testing.assert_allclose(spec.motion["times"], [0.0, 2.0])


def _read_json(path):
    data = path.read_bytes()
    length = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20:20 + length])


def _bin(path):
    data = path.read_bytes()
    length = struct.unpack("<I", data[12:16])[0]
    n = struct.unpack("<I", data[20 + length:24 + length])[0]
    return data[28 + length:28 + length + n]


def _write_json(path, doc):
    binary = _bin(path)
    chunk = json.dumps(doc).encode()
    chunk += b" " * (-len(chunk) % 4)
    body = struct.pack("<I4s", len(chunk), b"JSON") + chunk + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)


def test_softvr_tetmesh_writes_the_fem_mesh_a_scene_builds(tmp_path, capsys):
    """``softvr tetmesh`` (the add-on's tet preview): the nodes and tets of ``dynamics_mesh`` on
    the same surface, in .npz (with every tet edge once) and .vtu; the cubes cover the box (their
    volume at least the box's) and stay within the grid of whole cubes over it."""
    import trimesh

    from softvr.cli import main
    from softvr.model import dynamics_mesh, load_mesh
    from softvr.volume import load_tet_mesh

    size, h = np.array([0.1, 0.2, 0.3]), 0.045
    trimesh.creation.box(size).export(tmp_path / "box.stl")
    assert main(["tetmesh", str(tmp_path / "box.stl"), "--cell-size", str(h), "-o", str(tmp_path / "box.npz")]) == 0
    assert main(["tetmesh", str(tmp_path / "box.stl"), "--cell-size", str(h)]) == 0  # box.vtu beside it
    assert "box.vtu" in capsys.readouterr().out
    nodes, tets = dynamics_mesh(*load_mesh(tmp_path / "box.stl"), h)
    with np.load(tmp_path / "box.npz") as f:
        np.testing.assert_array_equal(f["nodes"], nodes)
        np.testing.assert_array_equal(f["tets"], tets)
        assert f["nodes"].dtype == np.float64 and f["edges"].shape[1] == 2
        edges = {tuple(sorted((int(t[i]), int(t[j])))) for t in tets for i in range(4) for j in range(i + 1, 4)}
        assert {tuple(e) for e in f["edges"].tolist()} == edges and len(f["edges"]) == len(edges)
    vtu_nodes, vtu_tets = load_tet_mesh(tmp_path / "box.vtu")
    np.testing.assert_allclose(vtu_nodes, nodes)
    np.testing.assert_array_equal(vtu_tets, tets)
    volume = np.abs(np.linalg.det(nodes[tets[:, 1:]] - nodes[tets[:, :1]])).sum() / 6.0
    assert np.prod(size) <= volume <= np.prod(np.ceil(size / h) * h) * (1 + 1e-9)


def test_softvr_tetmesh_refuses_a_missing_file_and_a_bad_cell_size(tmp_path, capsys):
    from softvr.cli import main

    assert main(["tetmesh", str(tmp_path / "nothing.obj"), "--cell-size", "0.01"]) == 2
    assert "nothing.obj" in capsys.readouterr().err
    import trimesh

    trimesh.creation.box((0.1, 0.1, 0.1)).export(tmp_path / "box.obj")
    assert main(["tetmesh", str(tmp_path / "box.obj"), "--cell-size", "0"]) == 2
    assert "--cell-size" in capsys.readouterr().err


def test_adhesion_properties_make_the_same_adhesive_surfaces_as_toml(tmp_path):
    """softvr_adhesion_* on a node and softvr_ground_adhesion_* on the scene: the bodies and the
    ground get the softvr.contact.Adhesion of the equivalent [adhesion.NAME] tables; a missing
    required parameter and an unknown one are named."""
    sticky = {"stiffness": 1e7, "max_energy": 0.4, "viscosity": 0.2, "debond_gap": 0.003}
    path = _glb(tmp_path / "sticky.glb", [
        ("pad", (0.1, 0.1, 0.02), (0.0, 0.2, 0.0), {"softvr_type": "rigid", "softvr_density": 500.0,
                                                   **{f"softvr_adhesion_{k}": v for k, v in sticky.items()}})],
        scene_extras={**{f"softvr_ground_adhesion_{k}": v for k, v in sticky.items()}, "softvr_frames": 2})
    scene = read_gltf_scene(path)
    assert scene.adhesions == {"pad": sticky, "ground": sticky}
    assert scene.body("pad").adhesion == "pad" and scene.planes[0]["adhesion"] == "ground"
    from softvr.contact import Adhesion

    with load_scene(path, frames=1) as ex:
        assert vars(ex.scene._adhesion[("body", ex.index["pad"])]) == vars(Adhesion(**sticky))
    bad = _glb(tmp_path / "bad.glb", [
        ("pad", (0.1, 0.1, 0.02), (0.0, 0.2, 0.0), {"softvr_type": "rigid", "softvr_adhesion_stiffness": 1e7,
                                                   "softvr_adhesion_max_energy": 0.4, "softvr_adhesion_glue": 1.0})])
    with pytest.raises(InputError) as err:
        read_gltf_scene(bad)
    assert "node 'pad'.adhesion.viscosity" in str(err.value) and "node 'pad'.adhesion.glue" in str(err.value)
