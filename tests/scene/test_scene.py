"""Scene files: validation against the schema, building against analytic quantities, the
bundled scenes against the physics they show.

Truths: a broken file reports each of its problems (field path, expected, found) in one error
naming the file; a FEM box of side a and density rho weighs rho a^3 and has 5 cells^3 tets; a
rigid box weighs rho V with the box inertia m (b^2 + c^2) / 12; a kinematic body is where
its keyframes put it (linear in between); the dropped soft cube comes to rest on the ground
without sinking, the stacked boxes stay stacked, the cloth stays above the ground, the thrown
oranges roll on above it (each weighing rho times its sphere), the swung cloth reaches the
wall and sticks to it with its pinned edge in place.
"""

import json
import os

import numpy as np
import pytest

from softvr.cli import main
from softvr.errors import InputError
from softvr.scene import BUNDLED, load_scene, read_scene
from softvr.scene.gltf import read_gltf_scene


def _write(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text('format = "softvr-scene 1"\n' + text)
    return path


def test_a_broken_scene_names_every_problem_at_once(tmp_path, capsys):
    path = _write(tmp_path, '''
[simulation]
dt = "fast"
[material.jelly]
young = -5.0
[[body]]
name = "a"
type = "jelly"
box = [0.1, 0.1, 0.1]
[[body]]
name = "b"
type = "fem"
mesh = "missing.obj"
material = "rubber"
[[body]]
name = "a"
type = "rigid"
sphere = 0.1
material = "jelly"
[[filter]]
a = "a"
b = "ghost"
[[coupling]]
a = "b"
b = "nobody"
radius = 0.01
stiffness = 100.0
[lights]
''')
    with pytest.raises(InputError) as info:
        read_scene(path)
    message = str(info.value)
    for fragment in ("scene.toml", "simulation.dt", "material.jelly.young", "body[0].type", "rigid | fem",
                     "body[1].mesh", "missing.obj", "body[1].material", "rubber", "body[2].name",
                     "filter[0].b", "ghost", "coupling[0].b", "nobody", "lights"):
        assert fragment in message, fragment
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "body[1].mesh" in err and "Traceback" not in err


def test_one_check_reports_every_kind_of_problem_with_the_intersecting_start(tmp_path, capsys):
    """A missing mesh file, an unknown body type, numbers in other units (with a unit, or out
    of what SI values can be), a coupling to a missing object and two boxes that start
    crossing: one `softvr check` names them all (the boxes are built although other bodies
    are broken)."""
    path = _write(tmp_path, '''
[simulation]
dt = 5
[material.gel]
young = "20 kPa"
density = 1.05
[material.wood]
density = 600.0
[[plane]]
[[body]]
name = "organ"
type = "fem"
mesh = "organ.stl"
cells = 0.01
material = "wood"
[[body]]
name = "thing"
type = "blob"
sphere = 0.1
[[body]]
name = "big"
type = "rigid"
box = [100, 100, 100]
material = "wood"
[[body]]
name = "left"
type = "rigid"
box = [0.2, 0.2, 0.2]
material = "wood"
position = [0.0, 0.0, 0.15]
[[body]]
name = "right"
type = "rigid"
box = [0.2, 0.2, "20 cm"]
material = "wood"
position = [0.15, 0.05, 0.2]
[[body]]
name = "crossing"
type = "rigid"
box = [0.2, 0.2, 0.2]
material = "wood"
position = [0.1, -0.05, 0.2]
[[coupling]]
a = "left"
b = "ghost"
points = [[0.0, 0.0, 0.3]]
stiffness = 100.0
''')
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    expected = {
        "missing mesh file": ("body[0].mesh", "organ.stl"),
        "unknown body type": ("body[1].type", "found blob"),
        "a step in ms": ("simulation.dt", "0.1 [s]", "5 (in other units?)"),
        "a unit in a string": ("material.gel.young", "'20 kPa'", "write 20000 [Pa]"),
        "a density in g/cm^3": ("material.gel.density", "1.05 (in other units?)"),
        "a size in mm": ("body[2].box", "[100, 100, 100]"),
        "a size with a unit": ("body[4].box", "write 0.2 [m]"),
        "coupling to a missing object": ("coupling[0].b", "ghost"),
        "intersecting start": ("bodies 'left' and 'crossing'", "crossing triangle pairs"),
    }
    for what, fragments in expected.items():
        assert all(f in err for f in fragments), (what, err)
    assert "9 problems" in err and "Traceback" not in err
    # The broken bodies were left out of the geometric check, not reported as crossing.
    assert "'right'" not in err and "'big'" not in err


def test_numbers_written_with_units_are_told_their_si_value():
    from softvr.errors import with_unit

    # Conversions by hand: 5 mm = 0.005 m, 1.05 g/cm^3 = 1050 kg/m^3, 2 N/mm = 2000 N/m, 90 deg/s = pi/2 rad/s.
    assert "write 0.005 [m]" in with_unit("5 mm", "m")
    assert "write 1050 [kg/m^3]" in with_unit("1.05 g/cm^3", "kg/m^3")
    assert "write 2000 [N/m]" in with_unit("2 N/mm", "N/m")
    assert "write 1.5708 [rad/s]" in with_unit("90 deg/s", "rad/s")
    assert "a mass [kg], not [m]" in with_unit("3 kg", "m")
    assert "bare numbers in SI units: [m]" in with_unit("3 furlongs", "m")
    assert "write the number without quotes" in with_unit("0.5", "")
    assert with_unit("fast", "s") is None and with_unit(5.0, "s") is None


def test_bodies_are_built_with_the_files_parameters(tmp_path):
    path = _write(tmp_path, '''
[simulation]
gravity = [0.0, 0.0, 0.0]
[material.gel]
young = 2e4
poisson = 0.4
density = 900.0
[material.oak]
density = 700.0
[[body]]
name = "gel"
type = "fem"
box = [0.2, 0.2, 0.2]
cells = 3
material = "gel"
position = [0.0, 0.0, 0.5]
[[body]]
name = "block"
type = "rigid"
box = [0.1, 0.2, 0.3]
material = "oak"
position = [1.0, 0.0, 0.5]
[[body]]
name = "hand"
type = "kinematic"
sphere = 0.02
position = [0.0, 0.0, 1.0]
[body.motion]
times = [0.0, 1.0]
positions = [[0.0, 0.0, 1.0], [0.0, 0.5, 1.0]]
''')
    ex = load_scene(path, frames=2)
    gel, block, hand = ex.bodies["gel"], ex.bodies["block"], ex.bodies["hand"]
    assert len(gel.tets) == 5 * 27 and gel.mass.sum() == pytest.approx(900.0 * 0.2**3)
    np.testing.assert_allclose(gel.rest.mean(axis=0), [0.0, 0.0, 0.5], atol=1e-12)
    m = 700.0 * 0.1 * 0.2 * 0.3
    assert block.mass == pytest.approx(m)
    np.testing.assert_allclose(np.diag(block.inertia_body), m / 12 * np.array([0.2**2 + 0.3**2, 0.1**2 + 0.3**2,
                                                                           0.1**2 + 0.2**2]), rtol=1e-12)
    for _ in range(25):
        ex.scene.step(0.01)
    np.testing.assert_allclose(hand.position, [0.0, 0.125, 1.0], atol=1e-12)  # a quarter of the way at 0.25 s


def test_a_fem_body_from_a_mesh_file_embeds_its_surface(tmp_path):
    import trimesh

    trimesh.creation.icosphere(subdivisions=2, radius=0.05).export(tmp_path / "ball.obj")
    path = _write(tmp_path, '''
[material.gel]
young = 2e4
[[plane]]
[[body]]
name = "ball"
type = "fem"
mesh = "ball.obj"
cells = 0.02
material = "gel"
position = [0.0, 0.0, 0.2]
''')
    ex = load_scene(path, frames=1)
    drawn = ex.drawn[0].vertices()
    np.testing.assert_allclose(np.linalg.norm(drawn - [0.0, 0.0, 0.2], axis=1), 0.05, atol=1e-9)


def test_every_bundled_scene_is_tested():
    assert sorted(p.name for p in BUNDLED.glob("*.toml")) == [
        "box-knock.toml", "box-stack.toml", "candy-adhesive.toml", "candy.toml", "cloth-sphere.toml",
        "cloth-wall.toml", "lips.toml", "oranges.toml", "palpation.toml", "probe.toml", "shoulder-arthroscopy.toml", "shoulder.toml",
        "soft-cube.toml", "volume.toml"]  # candy, lips, palpation, shoulder, volume: test_demo_scenes.py;
    # box-knock: tests/examples/test_examples.py


@pytest.mark.parametrize("name", ["soft-cube.toml", "box-stack.toml", "cloth-sphere.toml", "probe.toml",
                                  "oranges.toml", "cloth-wall.toml"])
def test_bundled_scenes_check_and_play(name, capsys):
    assert main(["check", name]) == 0
    assert "ok" in capsys.readouterr().out
    frames = {"soft-cube.toml": 12, "box-stack.toml": 10, "cloth-sphere.toml": 10, "probe.toml": 20,
              "oranges.toml": 6, "cloth-wall.toml": 8}[name]
    with load_scene(BUNDLED / name, frames=frames, width=64, height=48) as ex:
        start = {k: b.q.copy() if hasattr(b, "q") else np.asarray(b.position).copy() for k, b in ex.bodies.items()}
        for _ in range(frames):
            record = ex.step()
        ex.render()
        assert record["max_penetration_m"] < 0.003
    if name == "soft-cube.toml":
        assert ex.bodies["soft cube"].q[:, 2].min() < 0.01  # it landed
    if name == "box-stack.toml":
        drift = max(np.linalg.norm(np.asarray(ex.bodies[k].position) - start[k]) for k in ex.bodies)
        assert drift < 1e-3
    if name == "cloth-sphere.toml":
        assert ex.bodies["cloth"].q[:, 2].min() > -0.003
    if name == "oranges.toml":  # thrown along +x, rolling: still above the ground, moving on
        # An orange weighs rho times its sphere (an icosphere encloses 99 % of it).
        assert ex.bodies["orange 0"].mass.sum() == pytest.approx(900.0 * 4 / 3 * np.pi * 0.08**3, rel=0.01)
        for k in range(4):
            skin = ex._drawn_by_name[f"orange {k}"].vertices()  # the embedding cubes reach further
            assert skin[:, 2].min() > -0.003 and ex.bodies[f"orange {k}"].v[:, 0].mean() > 0.1
    if name == "cloth-wall.toml":  # swung onto the wall by 0.32 s, pinned edge still in place
        cloth = ex.bodies["cloth"]
        assert -0.003 < cloth.q[:, 0].min() < 0.005
        assert sum(beta > 0 for beta in ex.scene.adhesion_state.intensity.values()) > 10  # and sticks
        np.testing.assert_allclose(cloth.q[cloth.fixed], start["cloth"][cloth.fixed], atol=1e-12)
    if name == "probe.toml":  # at 0.4 s the probe is 4 mm past the rest surface: the tissue gives way
        tissue = ex.bodies["tissue"]
        assert ex.bodies["probe"].position[2] == pytest.approx(0.011 - 0.005 * 0.4 / 0.5)
        assert tissue.q[:, 2].min() > -0.0301 and (tissue.q[:, 2] < -1e-3).any()
        assert np.linalg.norm(tissue.q - ex.bodies["probe"].position, axis=1).min() > 0.01 - 1e-3


def _glb_with_extras(path, mesh, node_extras, scene_extras, translation):
    """A GLB as Blender's exporter writes custom properties: node and scene ``extras``."""
    import json
    import struct

    import trimesh

    scene = trimesh.Scene()
    scene.add_geometry(mesh, node_name="gel", geom_name="gel_mesh",
                       transform=trimesh.transformations.translation_matrix(translation))
    data = scene.export(file_type="glb")
    length = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + length])
    doc["nodes"][0]["extras"] = node_extras
    doc["scenes"][doc.get("scene", 0)]["extras"] = scene_extras
    chunk = json.dumps(doc).encode()
    chunk += b" " * (-len(chunk) % 4)
    rest = data[20 + length:]
    body = struct.pack("<I4s", len(chunk), b"JSON") + chunk + rest
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)


def test_a_gltf_with_blender_extras_loads_as_the_equivalent_toml_scene(tmp_path, capsys):
    """The glTF box (0.1 x 0.2 x 0.3, y up, at y = 0.5) and the TOML scene with the same box
    in z-up coordinates (0.1 x 0.3 x 0.2 at z = 0.5) give the same FEM body."""
    import trimesh

    _glb_with_extras(tmp_path / "gel.glb", trimesh.creation.box((0.1, 0.2, 0.3)),
                     {"softvr_type": "fem", "softvr_young": 2e4, "softvr_poisson": 0.4, "softvr_density": 900.0,
                      "softvr_cells": 0.045, "blender_only": 1},
                     {"softvr_dt": 0.01, "softvr_frames": 3}, (0.0, 0.5, 0.0))
    trimesh.creation.box((0.1, 0.3, 0.2)).export(tmp_path / "gel.obj")
    toml = _write(tmp_path, '''
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
    from softvr.scene import load_scene

    a, b = load_scene(tmp_path / "gel.glb"), load_scene(toml)
    fa, fb = a.bodies["gel"], b.bodies["gel"]
    assert a.frames == b.frames == 3 and a.dt == b.dt
    assert len(fa.tets) == len(fb.tets)
    np.testing.assert_allclose(np.sort(fa.rest, axis=0), np.sort(fb.rest, axis=0), atol=1e-12)
    # The object weighs rho times the box it is (the embedding cubes reach past it); the glTF's
    # float32 vertices round the volume at 1e-7.
    assert fa.mass.sum() == pytest.approx(900.0 * 0.1 * 0.2 * 0.3, rel=1e-6)
    assert fb.mass.sum() == pytest.approx(900.0 * 0.1 * 0.2 * 0.3, rel=1e-9)
    assert abs(fa.stiffness_matrix()).sum() == pytest.approx(abs(fb.stiffness_matrix()).sum(), rel=1e-9)
    assert main(["check", str(tmp_path / "gel.glb")]) == 0
    assert "1 fem" in capsys.readouterr().out


def test_bad_gltf_properties_are_named_by_node(tmp_path):
    import trimesh

    _glb_with_extras(tmp_path / "bad.glb", trimesh.creation.box((0.1, 0.1, 0.1)),
                     {"softvr_type": "fem", "softvr_young": -1.0, "softvr_cells": "big"}, {"softvr_dt": 0},
                     (0.0, 0.0, 0.0))
    from softvr.scene import read_gltf_scene

    with pytest.raises(InputError) as info:
        read_gltf_scene(tmp_path / "bad.glb")
    for fragment in ("bad.glb", "node 'gel'.young", "node 'gel'.cells", "scene.dt"):
        assert fragment in str(info.value), fragment


def test_check_refuses_bodies_that_start_inside_each_other_or_the_ground(tmp_path, capsys):
    path = _write(tmp_path, '''
[material.wood]
density = 600.0
[[plane]]
[[body]]
name = "left"
type = "rigid"
box = [0.2, 0.2, 0.2]
material = "wood"
position = [0.0, 0.0, 0.15]
[[body]]
name = "right"
type = "rigid"
box = [0.2, 0.2, 0.2]
material = "wood"
position = [0.15, 0.05, 0.2]
[[body]]
name = "sunk"
type = "rigid"
sphere = 0.05
material = "wood"
position = [1.0, 0.0, 0.02]
''')
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "bodies 'left' and 'right'" in err and "crossing triangle pairs" in err
    assert "body 'sunk'" in err and "30.00 mm below" in err


def test_a_coupled_soft_block_hangs_from_a_fixed_post(tmp_path):
    """Zero-length springs from the block's top nodes to a fixed box carry its weight: with
    k = 2e4 N/m per spring the block sags by about m g / (n k), far less than free fall."""
    path = _write(tmp_path, '''
[simulation]
dt = 0.01
[material.gel]
young = 5e4
poisson = 0.3
density = 1000.0
alpha = 5.0
[[body]]
name = "post"
type = "fixed"
box = [0.1, 0.1, 0.02]
position = [0.0, 0.0, 0.51]
[[body]]
name = "block"
type = "fem"
box = [0.1, 0.1, 0.1]
cells = 2
material = "gel"
position = [0.0, 0.0, 0.45]
[[coupling]]
a = "block"
b = "post"
radius = 0.001
stiffness = 2e4
''')
    ex = load_scene(path, frames=1)
    block = ex.bodies["block"]
    springs = len(ex.scene.couplings[0].a.nodes)
    assert springs == 9  # the 3 x 3 top nodes touch the post
    z0 = block.q[:, 2].mean()
    for _ in range(100):
        ex.scene.step(0.01)
    sag = z0 - block.q[:, 2].mean()
    weight = 1000.0 * 0.1**3 * 9.81
    assert 0 < sag < 10 * weight / (springs * 2e4) + 2e-3  # spring stretch plus the gel's own sag


def test_the_viewer_opens_a_scene_and_its_screenshot_shows_it(display, tmp_path):
    """Under Xvfb: ``softvr view soft-cube.toml`` plays a second with the contact and tet
    overlays on; the screenshot has the cube's colour in it (its red channel well above the
    others somewhere) and the yellow tet edges / status text."""
    import imageio.v3 as iio

    shot = tmp_path / "view.png"
    assert main(["view", "soft-cube.toml", "--seconds", "2", "--screenshot", str(shot),
                 "--show", "contacts", "tets"]) == 0
    image = iio.imread(shot).astype(int)
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    assert ((r > 150) & (r - b > 60) & (g < 160)).mean() > 0.01  # the cube (0.85, 0.45, 0.35)
    assert ((r > 180) & (g > 180) & (b < 120)).sum() > 50  # the yellow tet edges and status line


def test_the_viewer_shows_the_collision_surface_instead_of_the_render_surface(display, tmp_path):
    """``--show collision --hide render contacts``: the cyan collision edges and no cube colour
    (thesis 5.1's representations, toggled by keys k and r)."""
    import imageio.v3 as iio

    shot = tmp_path / "collision.png"
    assert main(["view", "soft-cube.toml", "--seconds", "1", "--screenshot", str(shot), "--show", "collision",
                 "--hide", "render", "contacts"]) == 0
    image = iio.imread(shot).astype(int)
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    assert ((r > 150) & (r - b > 60) & (g < 160)).mean() < 1e-3  # no cube surface
    assert ((b > 180) & (g > 160) & (r < 140)).sum() > 50  # the cyan (0.3, 0.9, 1.0) edges


def test_kinematic_and_tool_meshes_follow_their_keyframes(tmp_path):
    """A kinematic mesh is where its keyframes put it; a tool mesh hangs from its handle, in
    equilibrium, m g / k below it (the virtual coupling a spring of stiffness k)."""
    import trimesh

    trimesh.creation.box((0.02, 0.02, 0.02)).export(tmp_path / "cube.obj")
    path = tmp_path / "tools.toml"
    path.write_text('''format = "softvr-scene 1"
[simulation]
dt = 0.01
steps_per_frame = 10
frames = 30
[material.wood]
density = 1000.0
[[body]]
name = "pusher"
type = "kinematic"
mesh = "cube.obj"
position = [0.5, 0.0, 0.5]
[body.motion]
times = [0.0, 1.0]
positions = [[0.5, 0.0, 0.5], [0.5, 0.1, 0.5]]
[[body]]
name = "hand"
type = "tool"
mesh = "cube.obj"
material = "wood"
position = [0.0, 0.0, 0.5]
stiffness = 300.0
damping = 1.0
[body.motion]
times = [0.0, 1.0]
positions = [[0.0, 0.0, 0.5], [0.0, 0.0, 0.55]]
''')
    with load_scene(path) as ex:
        pusher, hand = ex._drawn_by_name["pusher"], ex._drawn_by_name["hand"]
        corners = pusher.vertices() - [0.5, 0.0, 0.5]
        for _ in range(5):
            ex.step()
        np.testing.assert_allclose(pusher.vertices(), corners + [0.5, 0.05, 0.5], atol=1e-12)  # at 0.5 s
        for _ in range(25):
            ex.step()
        mass = 1000.0 * 0.02**3
        sag = mass * 9.81 / 300.0
        centre = hand.vertices().mean(axis=0)  # the cube's centre: its position and its centre of mass
        np.testing.assert_allclose(centre, [0.0, 0.0, 0.55 - sag], atol=0.02 * sag)


def test_render_settings_light_the_scene(tmp_path):
    """A white body lit only by a red light looks red (a diffuse surface reflects the light's
    colour; the surfaces' 12 % ambient term adds 0.12 x 255 = 31 of white); with the default
    light kit it is grey; the background is the file's colour."""
    def render(lights: str) -> np.ndarray:
        path = tmp_path / "lit.toml"
        path.write_text(f'''format = "softvr-scene 1"
[render]
size = [64, 48]
camera = "front"
background = [0.0, 0.2, 0.0]
background_top = [0.0, 0.2, 0.0]
{lights}
[material.wood]
density = 500.0
[[body]]
name = "box"
type = "fixed"
box = [0.4, 0.4, 0.4]
color = [1.0, 1.0, 1.0]
''')
        with load_scene(path, frames=1) as ex:
            return ex.render().astype(int)

    red = render('light_kit = false\n[[light]]\nposition = [0.0, 2.0, 0.0]\ncolor = [1.0, 0.0, 0.0]')
    kit = render("")
    centre = (slice(20, 28), slice(28, 36))
    r, g, b = (red[centre][..., k].mean() for k in range(3))
    assert r > 150 and abs(g - 31) < 4 and abs(b - 31) < 4
    r, g, b = (kit[centre][..., k].mean() for k in range(3))
    assert min(r, g, b) > 100 and max(r, g, b) - min(r, g, b) < 20
    np.testing.assert_allclose(red[0, 0], [0, 51, 0], atol=2)  # 0.2 * 255


def test_run_writes_video_frames_sheet_and_metrics_of_a_scene_file(tmp_path, capsys):
    import json

    import imageio.v3 as iio

    out = tmp_path / "out"
    assert main(["run", "lips.toml", "--frames", "4", "--size", "64", "48", "--png-every", "2", "--out", str(out),
                 "--quiet"]) == 0
    assert len(list(iio.imiter(out / "lips.mp4"))) == 4
    frames = sorted(p.name for p in (out / "lips_frames").iterdir())
    assert frames == ["frame_00000.png", "frame_00002.png"]
    assert iio.imread(out / "lips_frames" / "frame_00002.png").shape == (48, 64, 3)
    doc = json.loads((out / "lips_metrics.json").read_text())
    assert len(doc["frames"]) == 4 and doc["scene_file"].endswith("lips.toml")
    with pytest.raises(SystemExit):
        main(["run", "lips.toml", "--png-every", "-1"])
    assert "--png-every" in capsys.readouterr().err


def test_a_body_has_its_own_render_collision_and_dynamics_representations(tmp_path):
    """Thesis 5.1: the drawn surface (render_mesh) is placed as the shape and carried by the
    tets; the collision surface is the shape simplified to its triangle budget; the tets are
    the cubes around the shape."""
    import trimesh

    from softvr.model.shapes import icosphere

    fine = trimesh.Trimesh(*icosphere(4))  # 5120 triangles, unit radius
    path = tmp_path / "ball.toml"
    path.write_text('''format = "softvr-scene 1"
[material.gel]
young = 5e4
[[plane]]
[[body]]
name = "ball"
type = "fem"
sphere = 0.05
cells = 0.02
collision_triangles = 80
render_mesh = "fine_5cm.obj"
material = "gel"
position = [0.0, 0.0, 0.1]
''')
    from softvr.errors import InputError

    with pytest.raises(InputError, match=r"body\[0\]\.render_mesh: expected an existing file"):
        read_scene(path)
    fine.apply_scale(0.05)
    fine.export(tmp_path / "fine_5cm.obj")
    with load_scene(path, frames=3) as ex:
        (surface,) = ex.scene.collision_surfaces
        assert 60 <= len(surface.triangles) <= 100  # about the budget of 80
        drawn = ex._drawn_by_name["ball"]
        assert len(drawn.triangles) == 5120
        # As placed (the OBJ file holds 8 decimals).
        np.testing.assert_allclose(drawn.vertices(), np.asarray(fine.vertices) + [0.0, 0.0, 0.1], atol=1e-8)
        body = ex.bodies["ball"]
        for _ in range(3):
            ex.step()
        # Carried by the tets: the drawn surface moved with the nodes (it fell).
        fall = body.q[:, 2].mean() - (body.rest[:, 2].mean())
        assert fall < -1e-3
        assert drawn.vertices()[:, 2].mean() - 0.1 == pytest.approx(fall, abs=2e-3)


# ------------------------------------------------------------------ hostile files (issue 17)
# Truth: the requirement itself. A bad file is an InputError whose source is the file and
# whose message names the field at fault; nothing is allocated, opened or parsed that the
# file asks for beyond a stated limit (softvr.scene.schema.LIMITS, softvr.files).
_CUBE = ('format = "softvr-scene 1"\n[simulation]\nframes = 10\n[material.jelly]\nyoung = 1e5\n'
         '[[body]]\nname = "cube"\ntype = "fem"\nbox = [0.1, 0.1, 0.1]\ncells = 2\nmaterial = "jelly"\n'
         'position = [0.0, 0.0, 0.2]\n')


def _raw(tmp_path, text, name="scene.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _refusal(path) -> InputError:
    with pytest.raises(InputError) as caught:
        read_scene(path)
    assert caught.value.source == str(path)
    return caught.value


def test_undecodable_deep_and_huge_toml_is_refused_naming_the_file(tmp_path):
    latin = tmp_path / "latin.toml"
    latin.write_bytes(_CUBE.replace("cube", "cub\xe9").encode("latin-1"))
    assert "UTF-8" in str(_refusal(latin)) and "offset" in str(_refusal(latin))
    deep = _raw(tmp_path, _CUBE + "x = " + "[" * 3000 + "]" * 3000 + "\n", "deep.toml")
    assert "nested" in str(_refusal(deep))
    digits = _raw(tmp_path, _CUBE.replace("frames = 10", "frames = " + "9" * 5000), "digits.toml")
    assert "TOML" in str(_refusal(digits))
    wide = _raw(tmp_path, _CUBE.replace("frames = 10", "frames = 99999999999999999999"), "wide.toml")
    assert "simulation.frames" in str(_refusal(wide)) and "64 bits" in str(_refusal(wide))


def test_a_list_or_a_number_where_a_table_is_expected_is_named(tmp_path):
    path = _raw(tmp_path, _CUBE.replace("[simulation]\nframes = 10\n", 'simulation = 3.5\nrender = [1]\n')
                  + '[[plane]]\nadhesion = ["x"]\n')
    message = str(_refusal(path))
    for field in ("simulation", "render", "plane[0].adhesion"):
        assert f"- {field}:" in message, (field, message)


@pytest.mark.parametrize("edit, field", [
    (("cells = 2", "cells = 4096"), "body[0].cells"),
    (("cells = 2", "cells = [2, 2, 100000]"), "body[0].cells"),
    (("cells = 2", "cells = 2\nsurface_quads = 1000000"), "body[0].surface_quads"),
    (("frames = 10", "frames = 100000000"), "simulation.frames"),
    (("position = [0.0, 0.0, 0.2]", "position = [1e308, 0.0, 0.2]"), "body[0].position"),
])
def test_counts_and_sizes_beyond_the_limits_are_refused_before_building(tmp_path, edit, field):
    path = _raw(tmp_path, _CUBE.replace(*edit))
    assert field in str(_refusal(path))


def test_cloth_quads_beyond_the_limit_are_refused(tmp_path):
    cloth = ('format = "softvr-scene 1"\n[[body]]\nname = "sheet"\ntype = "cloth"\ncloth = [0.5, 0.5]\n'
             'quads = [100000, 2]\n')
    assert "body[0].quads" in str(_refusal(_raw(tmp_path, cloth)))


@pytest.mark.parametrize("name, found", [("a\\u0000b.obj", "NUL"), ("m" * 300 + ".obj", "characters"),
                                         ("fifo.obj", "FIFO")])
def test_mesh_names_with_nul_bytes_too_long_or_naming_a_fifo_are_refused(tmp_path, name, found):
    os.mkfifo(tmp_path / "fifo.obj")
    path = _raw(tmp_path, _CUBE.replace("box = [0.1, 0.1, 0.1]\ncells = 2", f'mesh = "{name}"\ncells = 0.02'))
    error = _refusal(path)
    assert "body[0].mesh" in str(error) and found in str(error)


def test_a_tet_mesh_meshio_gives_up_on_is_an_error_not_an_exit(tmp_path, capsys):
    """meshio calls sys.exit(1) on an unreadable .vtu: softvr check reports it as the scene's
    problem (exit status 2) instead of the process ending."""
    (tmp_path / "bad.vtu").write_text("<VTKFile>garbage")
    path = _raw(tmp_path, _CUBE.replace("box = [0.1, 0.1, 0.1]\ncells = 2", 'tets = "bad.vtu"'))
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "body 'cube'.tets" in err and "bad.vtu" in err


def _gltf(tmp_path, edit, name="scene.gltf"):
    """A one-box glTF scene (external buffer scene.bin) after ``edit(doc)``."""
    import trimesh

    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box((0.1, 0.1, 0.1)), node_name="box", geom_name="box")
    files = scene.export(file_type="gltf")
    doc = json.loads(files["model.gltf"])
    (tmp_path / "scene.bin").write_bytes(files[doc["buffers"][0]["uri"]])
    doc["buffers"][0]["uri"] = "scene.bin"
    doc["nodes"][0]["extras"] = {"softvr_type": "fixed"}
    edit(doc)
    path = tmp_path / name
    path.write_text(json.dumps(doc).replace('"__deep__"', "[" * 3000 + "]" * 3000))  # deeper than json.dumps goes
    return path


@pytest.mark.parametrize("edit, field, found", [
    (lambda d: d["buffers"][0].update(uri="../../../../etc/passwd"), "buffers[0].uri", "a file inside"),
    (lambda d: d["buffers"][0].update(uri="/etc/passwd"), "buffers[0].uri", "a file inside"),
    (lambda d: d["buffers"][0].update(uri="fifo.bin"), "buffers[0].uri", "FIFO"),
    (lambda d: d["meshes"][0]["primitives"][0]["attributes"].update(POSITION=99),
     "meshes[0].primitives[0].attributes.POSITION", "99"),
    (lambda d: d["accessors"][0].update(count=10 ** 9), "accessors[0]", "bufferViews"),
    (lambda d: d["nodes"][0].update(extras=[1, 2]), "nodes[0].extras", "list"),
    (lambda d: d["nodes"][0].update(children=[0]), "nodes[0].children[0]", "one parent"),
    (lambda d: d.update(asset="__deep__"), "glTF JSON", "nested"),
])
def test_gltf_indices_buffers_and_extras_are_checked_before_trimesh_reads_the_file(tmp_path, edit, field, found):
    os.mkfifo(tmp_path / "fifo.bin")
    path = _gltf(tmp_path, edit)
    with pytest.raises(InputError) as caught:
        read_gltf_scene(path)
    assert caught.value.source == str(path)
    assert field in str(caught.value) and found in str(caught.value), str(caught.value)


@pytest.mark.parametrize("table, field", [
    ('[volume]\nfile = "a\\u0000b.nrrd"\n', "volume.file"),
    ('[volume]\nfile = "' + "v" * 300 + '.nrrd"\n', "volume.file"),
    ('[display]\nfile = "a\\u0000b.toml"\n', "display.file"),
    ('[display]\nfile = "fifo.toml"\n', "display.file"),
])
def test_volume_and_display_file_names_are_checked_like_mesh_names(tmp_path, table, field):
    os.mkfifo(tmp_path / "fifo.toml")
    error = _refusal(_raw(tmp_path, _CUBE + table))
    assert field in str(error), str(error)


@pytest.mark.parametrize("display", ["a\u0000b.toml", "fifo.toml", "../" * 30 + "etc/passwd.toml"])
def test_a_gltf_scene_display_file_is_checked_and_loaded(tmp_path, display):
    os.mkfifo(tmp_path / "fifo.toml")
    path = _gltf(tmp_path, lambda d: d["scenes"][0].update(extras={"softvr_display": display}))
    with pytest.raises(InputError, match="scene.display"):
        read_gltf_scene(path)


def test_a_cube_size_too_fine_for_a_fem_sphere_is_named_as_the_body_field(tmp_path, capsys):
    """A 1 m sphere in 0.1 mm cubes needs 1e12 grid tets: refused before the grid is made."""
    path = _raw(tmp_path, _CUBE.replace("box = [0.1, 0.1, 0.1]\ncells = 2", "sphere = 0.5\ncells = 0.0001"))
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "body 'cube'.cells" in err and "tets" in err
