"""A built bundled scene's :meth:`~softvr.app.Player.drawables` hold its bodies' geometry: box
corners placed by the pose SciPy computes from each body's quaternion, a FEM cube's surface
nodes on the rotated cube the file describes, the ground plane the file gives."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from softvr.scene import bundled, load_scene


def _box_corners(size, position, quaternion_wxyz) -> np.ndarray:
    """The 8 corners [8, 3] [m] of a box of ``size`` [3] [m] centred at ``position`` [3] [m] and
    turned by the unit quaternion (w, x, y, z), with SciPy's rotation (scalar last)."""
    w, x, y, z = quaternion_wxyz
    local = np.array(list(itertools.product(*[(-s / 2, s / 2) for s in size])))
    return Rotation.from_quat([x, y, z, w]).apply(local) + position


def _same_points(a, b, tol: float) -> bool:
    """Each point of ``a`` within ``tol`` of a point of ``b`` and the counts equal (any order)."""
    distances = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    return len(a) == len(b) and bool((distances.min(axis=1) < tol).all() and (distances.min(axis=0) < tol).all())


def test_a_knocked_stack_draws_each_box_where_its_pose_puts_it():
    """box-knock.toml: at the start each box's 8 drawn corners are the file's box [0.2, 0.2, 0.1]
    m about its position, unturned; after 25 frames (1 s: the ram has gone through) the boxes
    it hit are turned and each drawn box is still the same box at the pose SciPy makes of the
    body's quaternion and position (1e-9 m: float rounding of |x| < 1 m); the pose matrix is
    that rotation and position; the ground plane is z = 0 with its normal up."""
    with load_scene(bundled("box-knock.toml"), frames=25, haptics=False) as player:
        spec = {b.name: b for b in player.file.bodies}
        first = {d.name: d for d in player.drawables()}
        plane = first["plane 0"]
        assert plane.kind == "plane" and plane.layer == "scenery"
        assert plane.normal == pytest.approx([0, 0, 1]) and np.abs(plane.vertices[:, 2]).max() < 1e-12
        for k in range(5):
            d = first[f"box {k}"]
            assert (d.kind, d.layer, len(d.vertices)) == ("mesh", "render", 8)
            assert _same_points(d.vertices, _box_corners(spec[f"box {k}"].size, spec[f"box {k}"].position,
                                                         (1, 0, 0, 0)), 1e-9)
        for _ in range(25):
            player.step()
        turned = 0
        for d in player.drawables():
            if d.kind != "mesh":
                continue
            body = player.bodies[d.name]
            truth = Rotation.from_quat(np.r_[body.orientation[1:], body.orientation[0]])
            assert d.pose[:3, :3] == pytest.approx(truth.as_matrix(), abs=1e-12)
            assert d.pose[:3, 3] == pytest.approx(body.position, abs=1e-12)
            assert _same_points(d.vertices, _box_corners(spec[d.name].size, body.position, body.orientation), 1e-9)
            turned += truth.magnitude() > np.radians(5)
        assert turned >= 2  # the story: boxes knocked over, so the poses are not just translations


def test_a_tilted_fem_cube_draws_its_surface_nodes_on_the_cube_of_the_file():
    """soft-cube.toml: a 4-cell FEM cube turned x-then-y-then-z by the file's angles. Its drawn
    surface has the (4 + 1)^3 - (4 - 1)^3 = 98 boundary nodes of the grid, and turned back by
    SciPy's rotation each lies on a face of the cube of the file's size about its position
    (1e-9 m); a deforming body has no pose."""
    with load_scene(bundled("soft-cube.toml"), frames=1, haptics=False) as player:
        spec = player.file.bodies[0]
        (cube,) = [d for d in player.drawables() if d.kind == "mesh"]
        assert cube.pose is None and len(cube.vertices) == 98
        local = Rotation.from_euler("xyz", spec.rotation, degrees=True).inv().apply(cube.vertices - spec.position)
        half = np.asarray(spec.size, float) / 2
        assert (np.abs(local) <= half + 1e-9).all()
        assert np.abs(np.abs(local) - half).min(axis=1).max() < 1e-9  # every node on a face


_TOOL = """format = "softvr-scene 1"

[simulation]
dt = 0.005
steps_per_frame = 4
gravity = [0.0, 0.0, 0.0]

[material.m]
density = 1000.0

[[body]]
name = "finger"
type = "tool"
sphere = 0.01
material = "m"
position = [0.0, 0.0, 0.1]
stiffness = 100.0
haptics = false
[body.motion]
times = [0.0, 1.0]
positions = [[0.0, 0.0, 0.1], [0.0, 0.2, 0.1]]
"""


def test_a_tools_haptic_handle_is_drawn_where_its_motion_puts_the_hand(tmp_path):
    """A tool whose handle follows keyframes (0, 0, 0.1) -> (0, 0.2, 0.1) m over 1 s, read once a
    step: after 10 frames (0.2 s) the drawn handle, a ball of 8 mm, is centred on the keyframes'
    linear path (numpy.interp) at the time of the last step's reading (0.2 s - dt), within 1e-9 m,
    and it is the last drawable, after the tool's own surface."""
    from softvr.scene import load_scene

    path = tmp_path / "tool.toml"
    path.write_text(_TOOL)
    with load_scene(path, frames=10, haptics=False) as player:
        for _ in range(10):
            player.step()
        *_, tool, handle = player.drawables()
        assert (tool.name, handle.name, handle.kind, handle.layer) == ("finger", "finger handle", "mesh", "render")
        t = player.scene.time - player.dt
        expected = np.array([0.0, np.interp(t, [0.0, 1.0], [0.0, 0.2]), 0.1])
        centre = handle.vertices.mean(axis=0)
        assert np.abs(handle.pose[:3, 3] - expected).max() < 1e-9
        assert np.abs(np.linalg.norm(handle.vertices - handle.pose[:3, 3], axis=1) - 0.008).max() < 1e-9
        assert np.abs(centre - expected).max() < 1e-9
