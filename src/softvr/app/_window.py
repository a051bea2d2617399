"""The live window: a player played on screen, one frame per timer tick, with its keys."""

from __future__ import annotations

import time

import numpy as np

from softvr.app._drag_tool import DragTool
from softvr.errors import InputError
from softvr.render import LiveWindow, save_png
from softvr.render.overlays import ContactOverlay, LineOverlay, TextOverlay
from softvr.render.surfaces import SurfaceRenderer
from softvr.volume import tet_edges

__all__ = ["VIEW_LAYERS", "play_window"]


#: What :func:`play_window` can show, each toggled by a key: the render surfaces (and volume),
#: the collision surfaces' edges, the FEM tets' edges, the contacts, their adhesion colours.
VIEW_LAYERS = {"render": "r", "collision": "k", "tets": "t", "contacts": "c", "adhesion": "a"}


def play_window(player, *, timeout_s: float | None = None, screenshot=None,
                overlays: tuple = ("render", "contacts")) -> int:
    """Play ``player`` (a :class:`~softvr.app.Player`) live in a window: one frame per timer tick, drawn on screen.

    Mouse: the trackball camera (left rotates, right zooms, middle pans); the right button
    (or control + left) on a body grabs it and drags it with a spring
    (:class:`~softvr.app._drag_tool.DragTool`). Keys: space pauses
    and resumes, ``n`` advances one frame while paused, ``q`` quits; ``c`` shows the contacts
    (points, normal force lines, the largest a tenth of the view across), ``a`` colours them by
    adhesion intensity; the three representations of a body (thesis 5.1): ``r`` its render
    surface, ``k`` its collision surface (edges, cyan), ``t`` its FEM tets (edges, yellow). A
    status line gives the frame, the simulated time, the frame rate and the ms of the physics
    step and of the render. The simulation stops after ``player.frames`` frames (the window
    stays open). ``overlays`` names the layers shown at the start (keys of
    :data:`VIEW_LAYERS`); ``screenshot`` (a PNG path) saves the window as it is when the loop
    ends. Returns the frames simulated.

    Raises :class:`~softvr.errors.InputError` when there is no display.
    """
    unknown = sorted(set(overlays) - set(VIEW_LAYERS))
    if unknown:
        raise InputError("overlays", f"names of {', '.join(VIEW_LAYERS)}", ", ".join(unknown))
    renderer = SurfaceRenderer(player.width, player.height, player.camera, bounds=player.bounds, onscreen=True,
                               **player.renderer_options())
    player.setup_render(renderer)
    window = renderer.vtk_renderer.GetRenderWindow()
    window.SetWindowName(f"softvr: {player.name} (space: pause, n: step, "
                         + ", ".join(f"{k}: {name}" for name, k in VIEW_LAYERS.items()) + ")")
    status = TextOverlay(renderer.vtk_renderer)
    contacts = ContactOverlay(renderer.vtk_renderer)
    bounds = np.asarray(player.bounds if player.bounds is not None else (-1, 1, -1, 1, -1, 1), float)
    reach = float(np.linalg.norm(bounds[1::2] - bounds[0::2]))
    soft = [b for b in player.scene.bodies if hasattr(b, "tets")]
    tets = [LineOverlay(renderer.vtk_renderer, tet_edges(b.tets)) for b in soft]
    surfaces = player.scene.collision_surfaces
    collision = [LineOverlay(renderer.vtk_renderer, s.edge_set.edges, color=(0.3, 0.9, 1.0)) for s in surfaces]
    render_handles = renderer.handles("mesh") + renderer.handles("volume")
    shown = {name: name in overlays for name in VIEW_LAYERS}
    last = {"time": time.perf_counter()}

    def draw_overlays() -> None:
        solution = player.scene.last_solution
        points, normals, forces, beta = [], [], [], []
        if solution is not None and shown["contacts"]:
            intensity = player.scene.adhesion_state.intensity
            for c, impulse in zip(solution.contacts, solution.impulses):
                if len(impulse):
                    points.append(c.point_a)
                    normals.append(c.normal)
                    forces.append(impulse[:, 0] / player.dt)
                    beta.append([intensity.get(int(i), 0.0) for i in c.ids])
        cat = (lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape))
        magnitudes = cat(forces, (0,))
        # The largest force is drawn a tenth of the view across; the others in proportion.
        contacts.scale = 0.1 * reach / max(float(magnitudes.max(initial=0.0)), 1e-9)
        contacts.update(cat(points, (0, 3)), cat(normals, (0, 3)), magnitudes,
                        cat(beta, (0,)) if shown["adhesion"] else None)
        contacts.show(shown["contacts"])
        for overlay, body in zip(tets, soft):
            overlay.show(shown["tets"])
            if shown["tets"]:
                overlay.update(body.q)
        for overlay, surface in zip(collision, surfaces):
            overlay.show(shown["collision"])
            if shown["collision"]:
                overlay.update(surface.points.positions())
        for handle in render_handles:
            renderer.set_visible(handle, shown["render"])
        m = player.metrics[-1] if player.metrics else {}
        drawn = player.metrics[-2] if len(player.metrics) > 1 else {}  # this frame's render is not done yet
        now = time.perf_counter()
        fps = 1.0 / max(now - last["time"], 1e-6)
        last["time"] = now
        stages = "  ".join(f"{k} {v:.1f}" for k, v in m.get("stage_ms", {}).items())
        status.set(f"frame {player.frame}/{player.frames}  t {player.scene.time:.3f} s  {fps:4.1f} fps  "
                   f"contacts {m.get('contacts', 0)}\n"
                   f"ms: step {m.get('step_ms', 0.0):.1f} ({stages})  render {drawn.get('render_ms', 0.0):.1f}")

    tool = DragTool(player.scene, renderer.vtk_renderer)

    def mouse(interactor, style) -> None:
        """Right button (or control + left) drags a body; otherwise the trackball camera."""
        # A grab reads the bodies and a release changes the scene's forces: not while a frame steps.
        def press(obj, event) -> None:
            player.settle()
            right = event == "RightButtonPressEvent"
            if (right or interactor.GetControlKey()) and tool.press(*interactor.GetEventPosition()):
                return
            (style.OnRightButtonDown if right else style.OnLeftButtonDown)()

        def move(obj, event) -> None:
            if tool.grab is not None:
                tool.move(*interactor.GetEventPosition())
            else:
                style.OnMouseMove()

        def release(obj, event) -> None:
            player.settle()
            if tool.grab is not None:
                tool.release()
            else:
                (style.OnRightButtonUp if event == "RightButtonReleaseEvent" else style.OnLeftButtonUp)()

        for event in ("RightButtonPressEvent", "LeftButtonPressEvent"):
            style.AddObserver(event, press)
        style.AddObserver("MouseMoveEvent", move)
        for event in ("RightButtonReleaseEvent", "LeftButtonReleaseEvent"):
            style.AddObserver(event, release)

    def advance() -> None:
        if player.frame < player.frames:
            if not player.ahead:  # a sequential player (or the first frame): the drag force of this step
                tool.apply()
            player.step()
            t0 = time.perf_counter()
            player.update_render(renderer)
            draw_overlays()
            if player.overlap:
                # The next frame steps on the player's worker thread while this one is drawn: its
                # drag force is set, and it starts, once the renderer holds this frame.
                tool.apply()
                player.step_ahead()
            window.Render()
            player._drawn(t0)

    def toggle(name: str):
        def flip() -> None:
            player.settle()  # the overlays read the scene
            shown[name] = not shown[name]
            draw_overlays()
        return flip

    player.update_render(renderer)
    # The camera is fitted at the first render to what is shown: render before draw_overlays
    # hides any layer, so that a start with the render surfaces hidden (--hide render --show
    # collision) frames the bodies, not the default box of an empty scene.
    renderer.render()
    draw_overlays()
    live = LiveWindow(window, keys={key: toggle(name) for name, key in VIEW_LAYERS.items()})
    mouse(live.interactor, live.style)
    try:
        live.run(advance, period_ms=int(1000 / player.fps), timeout_s=timeout_s,
                 on_exit=None if screenshot is None else lambda: save_png(renderer.grab(), screenshot))
    finally:
        live.close()
        renderer.close()
    return player.frame
