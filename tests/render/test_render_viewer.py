"""The interactive viewer: display-free drag logic, then the real VTK window under Xvfb.

The window tests drive the viewer with synthetic VTK events
(``interactor.SetEventInformation`` + ``InvokeEvent``), exactly the path a mouse takes,
on a private Xvfb server (fixture ``display`` in conftest.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.render import (
    Camera,
    NodeDragger,
    ViewTransform,
    VolumeRenderer,
    VolumeViewer,
    move_in_view_plane,
    pick_node,
    require_display,
    view_volume,
)
from softvr.render import viewer as viewer_module
from softvr.volume import Volume, grid_tet_mesh


def translating_deform(volume: Volume, rest_nodes: np.ndarray):
    """Stand-in deformation: move the whole volume by the summed node displacement."""

    def deform(deformed_nodes: np.ndarray) -> Volume:
        shift = (np.asarray(deformed_nodes) - rest_nodes).sum(axis=0)
        return Volume(volume.data, volume.spacing, volume.origin + shift, volume.direction, volume.is_label)

    return deform


# ------------------------------------------------------------------ no display needed
@pytest.fixture(scope="module")
def perspective_view():
    """A ViewTransform of a real (off-screen) VTK renderer with a perspective camera."""
    from vtkmodules.vtkRenderingCore import vtkCoordinate

    data = np.zeros((20, 20, 20), np.int16)
    with VolumeRenderer(160, 120, "ct", Camera("iso", azimuth=10)) as renderer:
        renderer.render(Volume(data, origin=(-10, -10, -10)))
        coord = vtkCoordinate()
        coord.SetCoordinateSystemToWorld()

        def vtk_display(p):
            coord.SetValue(*p)
            return np.array(coord.GetComputedDoubleDisplayValue(renderer.vtk_renderer))

        yield ViewTransform.from_renderer(renderer.vtk_renderer), vtk_display


def test_view_transform_agrees_with_vtk(perspective_view):
    view, vtk_display = perspective_view
    points = np.random.default_rng(1).uniform(-10, 10, (20, 3))
    mine = view.to_display(points)
    theirs = np.array([vtk_display(p) for p in points])
    assert np.allclose(mine[:, :2], theirs, atol=1e-6)
    assert np.allclose(view.to_world(mine), points, atol=1e-6)
    origin, direction = view.ray(mine[0, :2])
    t = np.dot(points[0] - origin, direction)
    assert np.linalg.norm(origin + t * direction - points[0]) < 1e-6  # the point is on its pick ray


def test_pick_node_takes_the_nearest_projection_then_the_nearest_to_the_camera(perspective_view):
    view, _ = perspective_view
    eye = view.to_world([[80, 60, -1.0]])[0]
    far = view.to_world([[80, 60, 0.99]])[0]
    nodes = np.array([eye + 0.5 * (far - eye), eye + 0.2 * (far - eye), [10.0, 10.0, 10.0]])  # 0, 1 on one ray
    assert pick_node(view, nodes, (80, 60)) == 1
    target = view.to_display(nodes[2])[0]
    assert pick_node(view, nodes, target[:2] + (3, -4), radius_px=6) == 2
    assert pick_node(view, nodes, target[:2] + (30, 0), radius_px=6) is None


def test_move_in_view_plane_keeps_depth_and_follows_the_cursor(perspective_view):
    view, _ = perspective_view
    p = np.array([2.0, -3.0, 4.0])
    moved = move_in_view_plane(view, p, (100.0, 30.0))
    d0, d1 = view.to_display([p, moved])
    assert np.allclose(d1[:2], (100.0, 30.0), atol=1e-6)
    assert d1[2] == pytest.approx(d0[2], abs=1e-9)
    # Constant depth = a plane parallel to the image plane: the motion is orthogonal to the view direction.
    _, direction = view.ray(d0[:2])
    centre_dir = view.ray((view.size[0] / 2, view.size[1] / 2))[1]
    assert abs(np.dot(moved - p, centre_dir)) < 1e-6 * np.linalg.norm(moved - p) + 1e-9


def test_node_dragger_calls_deform_and_reverts_on_error():
    view = ViewTransform(np.diag([0.1, 0.1, 0.1, 1.0]), (200, 200))
    calls = []

    def deform(nodes):
        calls.append(nodes)
        if nodes[1, 0] > 3:
            raise InputError("tets[0]", "positive volume", "inverted")
        return "volume"

    drag = NodeDragger([[0, 0, 0], [1, 0, 0]], deform, pick_radius_px=4)
    assert drag.press(view, (111, 100)) == 1
    assert drag.drag(view, (121, 100)) == "volume"
    assert np.allclose(drag.nodes[1], [2, 0, 0]) and np.allclose(calls[-1][1], [2, 0, 0])
    calls[-1][1] = 99.0  # deform_fn gets a copy
    assert np.allclose(drag.nodes[1], [2, 0, 0])
    with pytest.raises(InputError):
        drag.drag(view, (141, 100))
    assert np.allclose(drag.nodes[1], [2, 0, 0]) and drag.calls == 1
    drag.release()
    assert drag.drag(view, (150, 100)) is None
    assert drag.press(view, (5, 5)) is None


def test_no_display_is_an_input_error_suggesting_demo(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(InputError, match="softvr demo"):
        require_display()
    vol = Volume(np.zeros((4, 4, 4), np.int16))
    nodes, tets = grid_tet_mesh(vol, 1)
    with pytest.raises(InputError, match="display"):
        view_volume(vol, nodes, tets, translating_deform(vol, nodes))
    assert viewer_module.main([]) == 2
    assert "softvr demo" in capsys.readouterr().err
    monkeypatch.setenv("DISPLAY", ":987")  # nothing listens there
    with pytest.raises(InputError, match="no X server"):
        require_display()


# ---------------------------------------------------------------------- under Xvfb
def white(image: np.ndarray) -> np.ndarray:
    return image.min(axis=2) > 127  # the volume; the node glyphs are yellow/red (blue < 127)


def send(viewer: VolumeViewer, event: str, xy) -> None:
    viewer.interactor.SetEventInformation(int(round(xy[0])), int(round(xy[1])), 0, 0, "\0", 0, None)
    viewer.interactor.InvokeEvent(event)


def test_dragging_a_node_deforms_and_redraws(display, make_sphere, opaque_preset):
    vol = make_sphere(8.0, (1.0, 1.0, 1.0), (24, 24, 24))
    nodes, tets = grid_tet_mesh(vol, 2)
    ppu = 4.0  # 160 px / (2 * 20 mm)
    camera = Camera("front", parallel=True, parallel_scale=20.0, focal_point=(0.0, 0.0, 0.0))
    deform = translating_deform(vol, nodes)
    with VolumeViewer(vol, nodes, tets, deform, preset=opaque_preset, camera=camera, width=200, height=160) as viewer:
        assert type(viewer.window).__name__ == "vtkXOpenGLRenderWindow"
        viewer.interactor.Initialize()
        viewer.render()
        before = viewer.grab()
        assert before.shape == (160, 200, 3)
        view = viewer.view_transform()
        screen = view.to_display(nodes)
        k = int(np.argmin(np.hypot(screen[:, 0] - 100, screen[:, 1] - 80) + 1e-3 * screen[:, 2]))  # centre, front
        start = screen[k, :2].round()

        send(viewer, "LeftButtonPressEvent", start)
        assert viewer.dragger.active is not None
        picked = viewer.dragger.active
        assert np.allclose(view.to_display(nodes[picked])[0, :2], screen[k, :2])
        assert view.to_display(nodes[picked])[0, 2] <= screen[k, 2] + 1e-9  # the front-most one
        send(viewer, "MouseMoveEvent", start + (10, 0))
        send(viewer, "MouseMoveEvent", start + (20, 0))
        assert viewer.dragger.calls == 2
        after = viewer.grab()
        send(viewer, "LeftButtonReleaseEvent", start + (20, 0))
        assert viewer.dragger.active is None

        moved = viewer.dragger.nodes[picked] - nodes[picked]
        assert np.allclose(moved, [-20 / ppu, 0, 0], atol=1e-6)  # front view: screen right = world -x
        unmoved = np.delete(np.arange(len(nodes)), picked)
        assert np.array_equal(viewer.dragger.nodes[unmoved], nodes[unmoved])
        assert np.allclose(viewer.dragger.volume.origin, vol.origin + moved)

        def centroid(mask):
            rows, cols = np.nonzero(mask)
            return np.array([cols.mean(), rows.mean()])

        shift = centroid(white(after)) - centroid(white(before))
        assert np.allclose(shift, [20, 0], atol=1.5), shift  # the rendered volume followed the node

        # A press away from every node rotates the camera instead and deforms nothing.
        position = viewer.renderer.GetActiveCamera().GetPosition()
        send(viewer, "LeftButtonPressEvent", (5, 5))
        send(viewer, "MouseMoveEvent", (45, 5))
        send(viewer, "LeftButtonReleaseEvent", (45, 5))
        assert viewer.renderer.GetActiveCamera().GetPosition() != position
        assert viewer.dragger.calls == 2

        # 'u' puts the nodes back.
        viewer.interactor.SetKeyCode("u")
        viewer.interactor.InvokeEvent("CharEvent")
        assert np.array_equal(viewer.dragger.nodes, nodes)


def test_view_volume_opens_and_closes(display, make_sphere):
    vol = make_sphere(5.0, (1.0, 1.0, 1.0), (12, 12, 12))
    nodes, tets = grid_tet_mesh(vol, 1)
    final = view_volume(vol, nodes, tets, translating_deform(vol, nodes), width=120, height=90, timeout_s=0.2)
    assert np.array_equal(final, nodes)


def test_the_one_window_loop_advances_pauses_steps_and_runs_its_keys(display):
    """LiveWindow, the loop of softvr view SCENE and softvr view volume: frames advance on its
    timer until space pauses them (none after, though the timer keeps ticking), n advances
    exactly one while paused, a key's callable runs and the window is redrawn after it, and
    on_exit runs while the loop is still up."""
    from vtkmodules.vtkRenderingCore import vtkRenderer

    from softvr.render import LiveWindow
    from softvr.render._backend import new_onscreen_window

    window = new_onscreen_window(64, 48)
    window.AddRenderer(vtkRenderer())
    pressed, draws, frames, ticks_paused = [], [], [], []
    live = LiveWindow(window, keys={"x": lambda: pressed.append(len(draws))}, render=lambda: draws.append(1))

    def key(k: str) -> None:
        live.interactor.SetKeyCode(k)
        live.interactor.InvokeEvent("CharEvent")

    def advance() -> None:
        frames.append(1)
        if len(frames) == 3:
            key(" ")

    def at_exit() -> None:
        ticks_paused.append(len(frames))
        key("n")

    try:
        live.run(advance, period_ms=5, timeout_s=0.5, on_exit=at_exit)
        assert live.paused and ticks_paused == [3] and len(frames) == 4
        key("x")
        assert pressed == [0] and draws == [1]  # the callable first, then the redraw
    finally:
        live.close()
        window.Finalize()


def test_main_wires_load_mesh_and_rasterizer(display, tmp_path, monkeypatch):
    from softvr.volume import save

    data = np.full((12, 10, 8), -1000, np.int16)
    data[3:9, 3:7, 2:6] = 1000
    path = tmp_path / "vol.npz"
    save(Volume(data, spacing=(1.0, 1.0, 2.0)), path)
    seen = {}

    def fake_view_volume(volume, nodes, tets, deform_fn, **kwargs):
        seen.update(volume=volume, nodes=nodes, tets=tets, out=deform_fn(nodes + (2.0, 0.0, 0.0)), **kwargs)
        return nodes

    monkeypatch.setattr(viewer_module, "view_volume", fake_view_volume)
    assert viewer_module.main([str(path), "--cells", "2", "--view", "side"]) == 0
    assert seen["volume"].shape == (12, 10, 8)
    assert seen["nodes"].shape == (27, 3) and seen["tets"].shape == (40, 4)
    assert np.allclose(seen["out"].origin, seen["volume"].origin + (2.0, 0.0, 0.0))
    assert seen["camera"] == "side"
    assert viewer_module.main([str(tmp_path / "missing.nrrd")]) == 2
