"""``softvr cave``: the local cluster ends with every node on the master's state and writes its
unfolded preview; the amphitheatre's preview is three screens wide; keys are made for every
node of a display; bad input is named (the layout itself is checked in test_preview.py); a
simulated scene streams what its player draws."""

import numpy as np
import pytest

from softvr.cli import main


def test_local_cluster_writes_the_unfolded_preview_and_video(tmp_path, capsys):
    out = tmp_path / "cave"
    code = main(["cave", "local", "cube", "sheet", "--frames", "20", "--fps", "0", "--scale", "0.06",
                 "--save-every", "5", "--out", str(out), "--quiet"])
    assert code == 0
    import imageio.v3 as iio

    preview = iio.imread(out / "cave_preview.png")
    assert preview.shape[0] > 50 and preview.std() > 10
    assert (out / "cave_preview.mp4").stat().st_size > 1000
    assert '"mismatches": 0' in capsys.readouterr().out
    for node in ("front", "left", "right", "floor"):
        assert (out / f"{node}_last.png").exists() and (out / f"{node}.json").exists()


def test_preview_and_keys(tmp_path):
    assert main(["cave", "preview", "rave-amphitheatre", "sheet", "--frames", "3", "--scale", "0.05",
                 "--out", str(tmp_path)]) == 0
    import imageio.v3 as iio

    picture = iio.imread(tmp_path / "cave_preview.png")
    assert picture.shape[1] > 2.5 * picture.shape[0]  # three 3.75 x 3.12 m screens side by side
    assert main(["cave", "keys", str(tmp_path / "keys"), "--display", "cube"]) == 0
    assert sorted(p.name for p in (tmp_path / "keys" / "authorized").iterdir()) == [
        "floor.key", "front.key", "left.key", "right.key"]


@pytest.mark.parametrize("argv, fragment", [
    (["cave", "preview", "dome", "sheet"], "DISPLAY"),
    (["cave", "preview", "cube", "teapot"], "SCENE"),
    (["cave", "node", "cube", "--node", "ceiling"], "--node"),
])
def test_bad_arguments_are_named(argv, fragment, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err


@pytest.mark.parametrize("argv, fragments", [
    (["--join-timeout", "0.3"], ["did not join within 0.3 s", "['wall']", "authorized/NAME.key"]),
    (["--no-curve", "--publish", "tcp://0.0.0.0:0"], ["loopback", "softvr cave keys", "tcp://0.0.0.0:0"]),
])
def test_a_master_that_cannot_start_says_why(argv, fragments, capsys):
    """No node joining in time, or CURVE off on a public address: exit status 2 and a message
    that says what to do, no traceback."""
    assert main(["cave", "master", "single-wall", "sheet", "--frames", "1", "--quiet", "--publish",
                 _free_endpoint(), "--control", _free_endpoint(), *argv]) == 2
    err = capsys.readouterr().err
    assert all(f in err for f in fragments) and "Traceback" not in err, err


def _free_endpoint() -> str:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


def test_master_with_its_window_drives_a_node(display, tmp_path):
    """``softvr cave master --window`` (keyboard navigation, the master screen on screen, under
    Xvfb) runs a node process to the end: it presents all frames."""
    import json
    import subprocess

    from softvr.cave.command import node_command

    publish, control = _free_endpoint(), _free_endpoint()
    assert main(["cave", "keys", "--display", "single-wall"]) == 0  # the node starts first: it needs master.key
    node = subprocess.Popen(node_command("single-wall", "wall", publish, control, out=tmp_path,
                                         extra=["--no-render", "--max-seconds", "120"]))
    try:
        assert main(["cave", "master", "single-wall", "sheet", "--window", "--frames", "30", "--fps", "0",
                     "--publish", publish, "--control", control, "--quiet"]) == 0
        assert node.wait(timeout=60) == 0
    finally:
        node.kill()
    log = json.loads((tmp_path / "wall.json").read_text())
    assert log["presented"] == 30 and log["last_frame"] == 29


def test_a_gltf_scene_is_shown_z_up_with_its_colours(tmp_path):
    """A glTF (y-up) box of height 2 m exported by trimesh comes in z-up: its vertices span
    2 m in z; its base colour survives; the preview renders it."""
    import trimesh

    from softvr.cave.app import SceneFileSource

    box = trimesh.creation.box((1.0, 2.0, 0.5))
    box.visual.face_colors = [200, 30, 30, 255]
    path = tmp_path / "box.glb"
    trimesh.Scene(box).export(path)
    source = SceneFileSource(path)
    mesh = [i for i in source.items if i["kind"] == "mesh"][0]
    extent = mesh["rest"].max(axis=0) - mesh["rest"].min(axis=0)
    assert extent.tolist() == pytest.approx([1.0, 0.5, 2.0])
    assert mesh["color"] == pytest.approx([200 / 255, 30 / 255, 30 / 255])
    assert main(["cave", "preview", "single-wall", str(path), "--frames", "1", "--scale", "0.05",
                 "--out", str(tmp_path)]) == 0


_DROP = """format = "softvr-scene 1"

[simulation]
dt = 0.005
steps_per_frame = 4

[[light]]
position = [1.0, -1.0, 2.0]

[material.pine]
density = 500.0

[[plane]]
size = 2.0

[[sphere]]
center = [0.6, 0.0, 0.1]
radius = 0.1

[[body]]
name = "box"
type = "rigid"
box = [0.2, 0.2, 0.1]
material = "pine"
position = [0.0, 0.0, 1.0]
color = [0.85, 0.33, 0.25]
"""


def test_a_simulated_scene_streams_what_its_player_draws(tmp_path):
    """A scene file played on the cluster: the master's state, decoded as a node decodes it,
    holds the file's ground plane, its sphere and its box in the file's colour, and after 10
    frames (0.2 s) the box has fallen g t^2 / 2 = 0.196 m in free fall (within g dt t, a
    first-order integrator's lag). The file's [[light]] (a window's, not a drawable) does not
    stop it; ``softvr cave preview`` draws it."""
    from softvr.cave.app import FrameBuilder
    from softvr.cave.command import make_source

    path = tmp_path / "drop.toml"
    path.write_text(_DROP)
    source = make_source(str(path), frames=10)
    frames = FrameBuilder(source)
    plane, sphere, box = frames.state.items
    assert (plane["kind"], plane["point"], plane["normal"], plane["size"]) == ("plane", [0, 0, 0], [0, 0, 1], 2.0)
    assert (sphere["kind"], sphere["center"], sphere["radius"]) == ("sphere", [0.6, 0.0, 0.1], 0.1)
    assert box["kind"] == "mesh" and box["color"] == pytest.approx([0.85, 0.33, 0.25])
    assert np.ptp(box["rest"], axis=0) == pytest.approx([0.2, 0.2, 0.1])
    assert box["rest"].mean(axis=0) == pytest.approx([0.0, 0.0, 1.0], abs=1e-9)
    for _ in range(10):
        frames.next_packet(0)
    source.close()
    g, dt, t = 9.81, 0.005, 10 * 4 * 0.005
    fallen = 1.0 - frames.state.mesh_vertices(2).mean(axis=0)[2]
    assert fallen == pytest.approx(g * t**2 / 2, abs=g * dt * t)
    assert np.ptp(frames.state.mesh_vertices(2), axis=0) == pytest.approx([0.2, 0.2, 0.1], abs=1e-4)  # rigid
    assert main(["cave", "preview", "single-wall", str(path), "--frames", "2", "--scale", "0.05",
                 "--out", str(tmp_path / "preview")]) == 0


def test_items_without_a_colour_take_the_viewers():
    """The cluster draws a plane or sphere without a colour of its own as softvr view does."""
    import inspect

    from softvr.cave.app import PLANE_COLOR, SPHERE_COLOR
    from softvr.render import SurfaceRenderer

    assert PLANE_COLOR == inspect.signature(SurfaceRenderer.add_plane).parameters["color"].default
    assert SPHERE_COLOR == inspect.signature(SurfaceRenderer.add_sphere).parameters["color"].default
