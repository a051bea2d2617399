"""Drawing a scene through one screen's off-axis camera."""

from __future__ import annotations

import numpy as np

from softvr.cave.display import Screen
from softvr.cave.rig import UserPose
from softvr.cave.stereo import render_stereo
from softvr.cave.tracking import HeadPose
from softvr.render.surfaces import SurfaceRenderer  # vtk loads with the first renderer

__all__ = ["StateRenderer", "render_screen"]


def render_screen(renderer, screen: Screen, eye, *, near: float = 0.05, far: float = 100.0) -> np.ndarray:
    """What ``screen`` shows to an eye at ``eye`` [3] [m]: the scene of ``renderer`` (a
    :class:`~softvr.render.SurfaceRenderer` of the screen's pixel size) through the screen's
    off-axis frustum. Returns RGB uint8 [height, width, 3]."""
    view = screen.view(eye, near=near, far=far)
    renderer.set_view(view.eye, -view.normal, view.up, view.projection)
    return renderer.render()


class StateRenderer:
    """A render node's drawing of a :class:`~softvr.cave.app.ClusterState` on its screen.

    Replays the state's items (planes, spheres, meshes) into a
    :class:`~softvr.render.SurfaceRenderer` of the screen's pixel size times ``scale`` and,
    every frame, moves the meshes to the streamed vertices and draws the screen from the
    state's head pose carried into the world by its user pose, in the screen's stereo mode
    (:func:`~softvr.cave.render_stereo`). ``image`` holds the last picture.

    Parameters
    ----------
    screen : Screen
    separation : float [m]
        Eye separation (the display's).
    scale : float
        Pixel scale of the render against the screen's own pixels (previews, tests).
    onscreen : bool
        Draw into a window (the master's own view) instead of off-screen.
    """

    def __init__(self, screen: Screen, separation: float = 0.065, *, scale: float = 1.0, onscreen: bool = False):
        self.screen, self.separation, self.scale, self.onscreen = screen, float(separation), float(scale), onscreen
        self.image: np.ndarray | None = None
        self._renderer: SurfaceRenderer | None = None
        self._items = None
        self._handles: dict[int, int] = {}

    def _build(self, state) -> None:
        if self._renderer is not None:
            self._renderer.close()
        w, h = (max(int(round(p * self.scale)), 8) for p in self.screen.pixels)
        self._renderer = r = SurfaceRenderer(w, h, background=(0.16, 0.17, 0.2), background_top=(0.16, 0.17, 0.2),
                                             onscreen=self.onscreen)
        self._handles = {}
        for handle, item in enumerate(state.items):
            if item["kind"] == "mesh":
                self._handles[handle] = r.add_mesh(state.mesh_vertices(handle), item["faces"], color=item["color"],
                                                   opacity=item["opacity"])
            elif item["kind"] == "plane":
                r.add_plane(item["point"], item["normal"], item["size"], item["color"], tiles=item["tiles"])
            else:
                r.add_sphere(item["center"], item["radius"], item["color"], item["opacity"])
        self._items = state.geometry_digest()

    def __call__(self, state) -> np.ndarray:
        """Draw ``state``; returns the RGB image (uint8, [h, w, 3], or [h, 2 w, 3] side-by-side)."""
        if self._items != state.geometry_digest():  # the first frame, or a snapshot of another scene
            self._build(state)
        assert self._renderer is not None  # built for the first state
        for handle, h in self._handles.items():
            self._renderer.update(h, state.mesh_vertices(handle))
        head = HeadPose(tuple(state.head[:3]), tuple(state.head[3:]))
        self.image = render_stereo(self._renderer, self.screen, head, self.separation, user=UserPose(matrix=state.user))
        return self.image

    @property
    def window(self):
        """The VTK render window (None before the first frame)."""
        return None if self._renderer is None else self._renderer.vtk_renderer.GetRenderWindow()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
