"""Interactive viewer: drag tetrahedral-mesh nodes with the mouse and watch the volume deform.

The interaction logic is display-free and testable on its own:

* :class:`ViewTransform` maps world points to display pixels and back for a camera;
* :func:`pick_node` finds the node nearest to the ray through a pixel;
* :func:`move_in_view_plane` moves a point with the cursor, parallel to the image plane;
* :class:`NodeDragger` holds the deformed nodes and calls ``deform_fn`` on every move.

:class:`VolumeViewer` wires them to a VTK window (volume rendering plus the nodes drawn
as small spheres on top) and :func:`view_volume` runs it in softvr's one window loop
(:class:`~softvr.render.LiveWindow`, also :func:`softvr.app.play_window`'s). :func:`main` is the
``softvr view VOLUME`` command (a volume file or DICOM folder).

Mouse: left-drag on a node moves it (in the plane through the node parallel to the
screen); left-drag elsewhere rotates, right-drag or wheel zooms, middle-drag pans.
Keys: ``u`` resets all nodes to their rest positions; ``q``/``e`` closes the window.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from softvr import datasets
from softvr import volume as sv
from softvr.errors import InputError, SoftvrError
from softvr.render._backend import new_onscreen_window, require_display
from softvr.render._live import LiveWindow
from softvr.render._scene import VolumeScene, check_volume
from softvr.render.camera import Camera
from softvr.render.presets import Preset

__all__ = [
    "NodeDragger",
    "ViewTransform",
    "VolumeViewer",
    "main",
    "move_in_view_plane",
    "pick_node",
    "require_display",
    "view_volume",
]

DeformFn = Callable[[np.ndarray], object]


# ----------------------------------------------------------------------------- pure logic
@dataclass(frozen=True)
class ViewTransform:
    """World <-> display mapping of one camera and viewport.

    Display coordinates are VTK's: pixels from the bottom-left corner of the window,
    as in ``vtkRenderWindowInteractor.GetEventPosition()``.

    Parameters
    ----------
    matrix : numpy.ndarray, shape [4, 4]
        World (homogeneous) to clip coordinates; after the perspective divide x, y, z are
        normalised device coordinates in [-1, 1].
    size : tuple of 2 int [pixels]
        Viewport width and height.
    origin : tuple of 2 float [pixels]
        Display position of the viewport's lower-left corner.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.render import ViewTransform
    >>> view = ViewTransform(np.diag([0.1, 0.1, 0.1, 1.0]), (200, 100))  # orthographic, 10 units
    >>> view.to_display([[0.0, 0.0, 0.0], [10.0, -10.0, 0.0]])
    array([[100.,  50.,   0.],
           [200.,   0.,   0.]])
    >>> view.to_world([[200.0, 0.0, 0.0]])
    array([[ 10., -10.,   0.]])
    """

    matrix: np.ndarray
    size: tuple[int, int]
    origin: tuple[float, float] = (0.0, 0.0)

    @classmethod
    def from_renderer(cls, renderer) -> "ViewTransform":
        """The transform of a ``vtkRenderer``'s active camera and viewport."""
        cam = renderer.GetActiveCamera()
        aspect = renderer.GetTiledAspectRatio()
        m4 = cam.GetCompositeProjectionTransformMatrix(aspect, -1, 1)
        m = np.array([[m4.GetElement(r, c) for c in range(4)] for r in range(4)])
        w, h = renderer.GetSize()
        ox, oy = renderer.GetOrigin()
        return cls(m, (max(int(w), 1), max(int(h), 1)), (float(ox), float(oy)))

    def to_display(self, points) -> np.ndarray:
        """Display coordinates [n, 3] (x, y [pixels], depth z in NDC [-1, 1]) of world points [n, 3].

        Points behind the camera get NaN.
        """
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        clip = np.c_[p, np.ones(len(p))] @ self.matrix.T
        w = clip[:, 3:4]
        with np.errstate(divide="ignore", invalid="ignore"):
            ndc = np.where(w > 1e-12, clip[:, :3] / w, np.nan)
        out = np.empty_like(ndc)
        out[:, 0] = (ndc[:, 0] + 1) * 0.5 * self.size[0] + self.origin[0]
        out[:, 1] = (ndc[:, 1] + 1) * 0.5 * self.size[1] + self.origin[1]
        out[:, 2] = ndc[:, 2]
        return out

    def to_world(self, display) -> np.ndarray:
        """World points [n, 3] of display coordinates [n, 3] (x, y [pixels], NDC depth z)."""
        d = np.atleast_2d(np.asarray(display, dtype=np.float64))
        ndc = np.empty((len(d), 4))
        ndc[:, 0] = (d[:, 0] - self.origin[0]) / self.size[0] * 2 - 1
        ndc[:, 1] = (d[:, 1] - self.origin[1]) / self.size[1] * 2 - 1
        ndc[:, 2] = d[:, 2]
        ndc[:, 3] = 1.0
        world = ndc @ np.linalg.inv(self.matrix).T
        return world[:, :3] / world[:, 3:4]

    def ray(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """The ray through display pixel ``xy``: (point on the near plane [3], unit direction [3])."""
        x, y = float(xy[0]), float(xy[1])
        near, far = self.to_world([[x, y, -1.0], [x, y, 1.0]])
        d = far - near
        return near, d / np.linalg.norm(d)


def pick_node(view: ViewTransform, nodes, xy, radius_px: float = 10.0) -> int | None:
    """Index of the node nearest to the ray through display pixel ``xy``, or None.

    Distances are measured on screen (pixels between the node's projection and ``xy``),
    i.e. by the angle between the pick ray and the node as seen from the camera. Only
    nodes within ``radius_px`` and in front of the camera count; of equally near
    projections the node nearest the camera wins.

    Parameters
    ----------
    view : ViewTransform
    nodes : numpy.ndarray, shape [n, 3] [world units]
    xy : tuple of 2 float [display pixels]
    radius_px : float [pixels]

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.render import ViewTransform, pick_node
    >>> view = ViewTransform(np.diag([0.1, 0.1, 0.1, 1.0]), (200, 200))
    >>> pick_node(view, [[0, 0, 0], [5, 5, 0]], (148, 151)), pick_node(view, [[0, 0, 0]], (10, 10))
    (1, None)
    """
    d = view.to_display(nodes)
    ok = np.isfinite(d).all(axis=1) & (np.abs(d[:, 2]) <= 1.0)
    if not ok.any():
        return None
    dist = np.hypot(d[:, 0] - xy[0], d[:, 1] - xy[1])
    dist[~ok] = np.inf
    best = float(dist.min())
    if best > radius_px:
        return None
    near = np.flatnonzero(dist <= best + 0.5)
    return int(near[np.argmin(d[near, 2])])


def move_in_view_plane(view: ViewTransform, point, xy) -> np.ndarray:
    """Where ``point`` [3] goes when dragged to display pixel ``xy``, keeping its depth.

    The result projects to ``xy`` and lies in the plane through ``point`` parallel to
    the image plane (constant NDC depth is such a plane for both projections).

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.render import ViewTransform, move_in_view_plane
    >>> view = ViewTransform(np.diag([0.1, 0.1, 0.1, 1.0]), (200, 200))
    >>> move_in_view_plane(view, [1.0, 2.0, 3.0], (120, 100))
    array([2., 0., 3.])
    """
    depth = view.to_display(point)[0, 2]
    if not np.isfinite(depth):
        raise InputError("point", "a point in front of the camera", str(np.asarray(point).tolist()))
    return view.to_world([[float(xy[0]), float(xy[1]), depth]])[0]


class NodeDragger:
    """Mouse-drag state machine: press picks a node, drag moves it and deforms the volume.

    Parameters
    ----------
    nodes : numpy.ndarray, shape [n, 3] [world units]
        Rest positions of the mesh nodes.
    deform_fn : callable
        ``deform_fn(deformed_nodes [n, 3] float64) -> Volume``; called on every drag step
        with a fresh copy of the current node positions.
    pick_radius_px : float [pixels]
        How close to a node's projection a press must be to grab it.

    Attributes
    ----------
    nodes : numpy.ndarray, shape [n, 3]
        Current (deformed) positions.
    active : int or None
        Index of the node being dragged.
    volume : Volume or None
        The last volume ``deform_fn`` returned.
    calls : int
        How many times ``deform_fn`` ran.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.render import NodeDragger, ViewTransform
    >>> view = ViewTransform(np.diag([0.1, 0.1, 0.1, 1.0]), (200, 200))
    >>> drag = NodeDragger(np.zeros((1, 3)), deform_fn=lambda n: n[0].round(6).tolist())
    >>> drag.press(view, (101, 99))
    0
    >>> drag.drag(view, (111, 99))          # 10 px right = 1 world unit
    [1.0, 0.0, 0.0]
    >>> drag.release(); drag.active is None
    True
    """

    def __init__(self, nodes, deform_fn: DeformFn, *, pick_radius_px: float = 10.0):
        n = np.array(nodes, dtype=np.float64)
        if n.ndim != 2 or n.shape[1] != 3 or len(n) == 0 or not np.isfinite(n).all():
            raise InputError("nodes", "finite positions [n, 3], n >= 1", f"shape {n.shape}")
        if not callable(deform_fn):
            raise InputError("deform_fn", "a callable deformed_nodes -> Volume", type(deform_fn).__name__)
        self.rest_nodes = n
        self.nodes = n.copy()
        self.deform_fn = deform_fn
        self.pick_radius_px = float(pick_radius_px)
        self.active: int | None = None
        self.volume: object = None  # what deform_fn returned last (a Volume)
        self.calls = 0
        self._grab_offset = np.zeros(2)

    def press(self, view: ViewTransform, xy) -> int | None:
        """Start dragging the node under ``xy`` (display pixels); its index, or None."""
        self.active = pick_node(view, self.nodes, xy, self.pick_radius_px)
        if self.active is not None:
            # Keep the node's offset from the cursor so that it does not jump.
            self._grab_offset = view.to_display(self.nodes[self.active])[0, :2] - np.asarray(xy, float)
        return self.active

    def drag(self, view: ViewTransform, xy):
        """Move the active node under the cursor and deform; the new volume, or None.

        If ``deform_fn`` raises a :class:`~softvr.errors.SoftvrError` (e.g. an inverted
        tetrahedron) the node goes back to where it was and the error propagates.
        """
        if self.active is None:
            return None
        target = np.asarray(xy, float) + self._grab_offset
        old = self.nodes[self.active].copy()
        self.nodes[self.active] = move_in_view_plane(view, old, target)
        try:
            volume = self.deform_fn(self.nodes.copy())
        except SoftvrError:
            self.nodes[self.active] = old
            raise
        self.calls += 1
        self.volume = volume
        return volume

    def release(self) -> None:
        """End the drag."""
        self.active = None

    def reset(self):
        """Put every node back at rest and deform; the new volume."""
        self.active = None
        self.nodes = self.rest_nodes.copy()
        self.volume = self.deform_fn(self.nodes.copy())
        self.calls += 1
        return self.volume


# ----------------------------------------------------------------------------- VTK window
def _check_mesh(nodes, tets) -> tuple[np.ndarray, np.ndarray]:
    n = np.asarray(nodes, dtype=np.float64)
    if n.ndim != 2 or n.shape[1] != 3 or len(n) == 0 or not np.isfinite(n).all():
        raise InputError("nodes", "finite positions [n, 3], n >= 1", f"shape {n.shape}")
    t = np.asarray(tets)
    if t.ndim != 2 or t.shape[1] != 4 or t.dtype.kind not in "iu":
        raise InputError("tets", "integer node indices [m, 4]", f"shape {t.shape}, dtype {t.dtype}")
    if t.size and (t.min() < 0 or t.max() >= len(n)):
        raise InputError("tets", f"indices in [0, {len(n) - 1}]", f"[{t.min()}, {t.max()}]")
    return n, t


class VolumeViewer:
    """A VTK window showing a volume and its mesh nodes; dragging a node deforms the volume.

    Needs a display (see :func:`require_display`); the handlers :meth:`on_left_press`,
    :meth:`on_mouse_move` and :meth:`on_left_release` read the interactor's event
    position, so synthetic events (``interactor.SetEventInformation`` +
    ``interactor.InvokeEvent``) drive it exactly as a mouse does.

    Parameters
    ----------
    volume : softvr.volume.Volume
        The undeformed volume, shown first.
    nodes : numpy.ndarray, shape [n, 3] [world units]
    tets : numpy.ndarray, shape [m, 4] int
    deform_fn : callable
        ``deform_fn(deformed_nodes [n, 3]) -> Volume``.
    preset : str or Preset
        Transfer function; ``"auto"`` chooses from the volume.
    camera : Camera or str
        Initial view.
    width, height : int [pixels]
    node_radius : float, optional [world units]
        Radius of the node spheres; default 0.8 % of the bounding-box diagonal.
    pick_radius_px : float [pixels]
    """

    def __init__(
        self,
        volume,
        nodes,
        tets,
        deform_fn: DeformFn,
        *,
        preset: "str | Preset" = "auto",
        camera: "Camera | str | None" = "front",
        width: int = 900,
        height: int = 700,
        node_radius: float | None = None,
        pick_radius_px: float = 10.0,
        title: str = "softvr: drag a node (left button); u resets, q quits",
    ):
        check_volume(volume)
        nodes, tets = _check_mesh(nodes, tets)
        require_display()
        from vtkmodules.util.numpy_support import numpy_to_vtk  # noqa: PLC0415
        from vtkmodules.vtkCommonCore import vtkPoints  # noqa: PLC0415
        from vtkmodules.vtkCommonDataModel import vtkPolyData  # noqa: PLC0415
        from vtkmodules.vtkFiltersCore import vtkGlyph3D  # noqa: PLC0415
        from vtkmodules.vtkFiltersSources import vtkSphereSource  # noqa: PLC0415
        from vtkmodules.vtkRenderingCore import (  # noqa: PLC0415
            vtkActor,
            vtkPolyDataMapper,
            vtkRenderer,
            vtkWindowToImageFilter,
        )

        self._numpy_to_vtk = numpy_to_vtk
        self.tets = tets
        self.dragger = NodeDragger(nodes, deform_fn, pick_radius_px=pick_radius_px)
        self.window = new_onscreen_window(width, height)
        self.window.SetWindowName(title)
        self.window.SetNumberOfLayers(2)
        self.renderer = vtkRenderer()
        self.renderer.SetBackground(0.1, 0.1, 0.12)
        self.renderer.SetLayer(0)
        self.overlay = vtkRenderer()  # nodes drawn over the volume, never hidden inside it
        self.overlay.SetLayer(1)
        self.overlay.InteractiveOff()
        self.overlay.SetActiveCamera(self.renderer.GetActiveCamera())
        self.window.AddRenderer(self.renderer)
        self.window.AddRenderer(self.overlay)

        self.scene = VolumeScene(preset, "cpu", sample_distance=0.5)
        self.scene.mapper.AutoAdjustSampleDistancesOn()  # coarser rays while dragging...
        self.scene.mapper.SetMaximumImageSampleDistance(2.0)  # ...but at most every other pixel
        self.scene.update(volume)
        self.renderer.AddVolume(self.scene.prop)

        lo, hi = nodes.min(axis=0), nodes.max(axis=0)
        diag = float(np.linalg.norm(hi - lo)) or 1.0
        radius = node_radius if node_radius is not None else 0.008 * diag
        self._points = vtkPoints()
        self._poly = vtkPolyData()
        self._poly.SetPoints(self._points)
        sphere = vtkSphereSource()
        sphere.SetRadius(radius)
        sphere.SetThetaResolution(10)
        sphere.SetPhiResolution(8)
        glyph = vtkGlyph3D()
        glyph.SetSourceConnection(sphere.GetOutputPort())
        glyph.SetInputData(self._poly)
        glyph.ScalingOff()
        mapper = vtkPolyDataMapper()
        mapper.SetInputConnection(glyph.GetOutputPort())
        self.node_actor = vtkActor()
        self.node_actor.SetMapper(mapper)
        self.node_actor.GetProperty().SetColor(1.0, 0.85, 0.1)
        self.overlay.AddActor(self.node_actor)
        active = vtkSphereSource()
        active.SetRadius(radius * 1.6)
        active.SetThetaResolution(16)
        active.SetPhiResolution(12)
        self._active_source = active
        amapper = vtkPolyDataMapper()
        amapper.SetInputConnection(active.GetOutputPort())
        self.active_actor = vtkActor()
        self.active_actor.SetMapper(amapper)
        self.active_actor.GetProperty().SetColor(1.0, 0.2, 0.1)
        self.active_actor.VisibilityOff()
        self.overlay.AddActor(self.active_actor)
        self._update_nodes()

        bounds = np.array(self.scene.bounds()).reshape(3, 2)
        bounds[:, 0] = np.minimum(bounds[:, 0], lo)
        bounds[:, 1] = np.maximum(bounds[:, 1], hi)
        Camera.coerce(camera).apply(self.renderer.GetActiveCamera(), bounds.ravel(), width / height)
        self.renderer.ResetCameraClippingRange()

        # softvr's one window loop; its key u resets the nodes.
        self.live = LiveWindow(self.window, keys={"u": self.reset_nodes}, render=self.render)
        self.interactor, self.style = self.live.interactor, self.live.style
        # Observers on the style replace its own handlers; ours forward when not dragging. (VTK takes event
        # names as well as ids; its stubs list the ids only.)
        self.style.AddObserver("LeftButtonPressEvent", self.on_left_press)  # type: ignore[arg-type]
        self.style.AddObserver("MouseMoveEvent", self.on_mouse_move)  # type: ignore[arg-type]
        self.style.AddObserver("LeftButtonReleaseEvent", self.on_left_release)  # type: ignore[arg-type]
        self._grabber = vtkWindowToImageFilter()
        self._grabber.SetInput(self.window)
        self._grabber.SetInputBufferTypeToRGB()
        self._grabber.ReadFrontBufferOff()
        self._grabber.ShouldRerenderOff()
        self.last_error: Exception | None = None
        self.frame_times: list[float] = []
        self._closed = False

    # ------------------------------------------------------------------ helpers
    def view_transform(self) -> ViewTransform:
        """The current :class:`ViewTransform` of the main renderer."""
        return ViewTransform.from_renderer(self.renderer)

    def _event_xy(self) -> tuple[int, int]:
        x, y = self.interactor.GetEventPosition()
        return int(x), int(y)

    def _update_nodes(self) -> None:
        self._points.SetData(self._numpy_to_vtk(np.ascontiguousarray(self.dragger.nodes), deep=True))
        self._points.Modified()
        self._poly.Modified()
        if self.dragger.active is not None:
            self._active_source.SetCenter(*self.dragger.nodes[self.dragger.active])
            self.active_actor.VisibilityOn()
        else:
            self.active_actor.VisibilityOff()

    def set_volume(self, volume) -> None:
        """Show ``volume`` (e.g. a deformed one) and redraw."""
        self.scene.update(volume)
        self.render()

    def render(self) -> None:
        """Redraw the window."""
        t = time.perf_counter()
        self.renderer.ResetCameraClippingRange()
        self.window.Render()
        self.frame_times.append(time.perf_counter() - t)

    def grab(self) -> np.ndarray:
        """The window's current image [height, width, 3] uint8, row 0 at the top."""
        from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: PLC0415

        self._grabber.Modified()
        self._grabber.Update()
        out = self._grabber.GetOutput()
        w, h, _ = out.GetDimensions()
        return np.ascontiguousarray(vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, -1)[::-1, :, :3])

    # ----------------------------------------------------------------- handlers
    def on_left_press(self, obj=None, event=None) -> None:
        """Grab the node under the cursor, or rotate the camera if there is none."""
        if self.dragger.press(self.view_transform(), self._event_xy()) is None:
            self.style.OnLeftButtonDown()
            return
        self.window.SetDesiredUpdateRate(self.interactor.GetDesiredUpdateRate())
        self._update_nodes()
        self.render()

    def on_mouse_move(self, obj=None, event=None) -> None:
        """Move the grabbed node with the cursor, deform and redraw; else default behaviour."""
        if self.dragger.active is None:
            self.style.OnMouseMove()
            return
        try:
            volume = self.dragger.drag(self.view_transform(), self._event_xy())
            self.scene.update(volume)
        except SoftvrError as exc:  # e.g. an inverted element: keep the last good image
            self.last_error = exc
            print(f"softvr view: {exc}", file=sys.stderr)
            return
        self._update_nodes()
        self.render()

    def on_left_release(self, obj=None, event=None) -> None:
        """Drop the node and redraw at full quality."""
        if self.dragger.active is None:
            self.style.OnLeftButtonUp()
            return
        self.dragger.release()
        self.window.SetDesiredUpdateRate(self.interactor.GetStillUpdateRate())
        self._update_nodes()
        self.render()

    def reset_nodes(self) -> None:
        """Key ``u``: every node back at rest, the volume with them (the window redraws after a
        key); other keys are the trackball style's (``q``/``e`` quit, ``r`` resets the view)."""
        self.scene.update(self.dragger.reset())
        self._update_nodes()

    # ---------------------------------------------------------------- lifecycle
    def start(self, timeout_s: float | None = None) -> np.ndarray:
        """Show the window and run the event loop until it is closed (or ``timeout_s``).

        Returns
        -------
        numpy.ndarray, shape [n, 3]
            The node positions when the loop ended.
        """
        self.interactor.Initialize()
        self.render()
        self.live.run(timeout_s=timeout_s)  # nothing advances on a timer: the mouse deforms
        return self.dragger.nodes.copy()

    def close(self) -> None:
        """Close the window and release OpenGL resources."""
        if self._closed:
            return
        self._closed = True
        self.live.close()  # the observers (bound methods of self) held by VTK: the cycle broken
        self.window.Finalize()
        self._grabber.SetInput(None)

    def __enter__(self) -> "VolumeViewer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def view_volume(
    volume,
    nodes,
    tets,
    deform_fn: DeformFn,
    *,
    preset: "str | Preset" = "auto",
    camera: "Camera | str | None" = "front",
    width: int = 900,
    height: int = 700,
    timeout_s: float | None = None,
) -> np.ndarray:
    """Open an interactive window in which dragging mesh nodes deforms ``volume``.

    Left-drag a node (drawn as a yellow sphere) to move it parallel to the screen; on
    every mouse move ``deform_fn`` is called with all node positions and the volume it
    returns is shown. Left-drag elsewhere rotates the view, right-drag zooms, ``u``
    resets the nodes, ``q`` closes the window.

    Parameters
    ----------
    volume : softvr.volume.Volume
        The undeformed volume.
    nodes : numpy.ndarray, shape [n, 3] [world units]
        Rest positions of the embedding mesh's nodes.
    tets : numpy.ndarray, shape [m, 4] int
        The mesh's tetrahedra (indices into ``nodes``).
    deform_fn : callable
        ``deform_fn(deformed_nodes [n, 3] float64) -> Volume``, for example
        ``softvr.volume.Rasterizer(volume, nodes, tets).deform``.
    preset, camera, width, height
        See :class:`VolumeViewer`.
    timeout_s : float, optional [s]
        Close the window after this long (for demos and tests).

    Returns
    -------
    numpy.ndarray, shape [n, 3]
        Node positions when the window closed.

    Raises
    ------
    InputError
        No display (``DISPLAY``/``WAYLAND_DISPLAY`` unset or no X server): the message
        suggests ``softvr demo`` for off-screen images and videos. Bad ``nodes``/``tets``.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.volume import Volume, grid_tet_mesh
    >>> from softvr.render import view_volume
    >>> x, y, z = np.mgrid[-16:16, -16:16, -16:16]
    >>> vol = Volume(np.where(x**2 + y**2 + z**2 < 12**2, 1000, -1000).astype(np.int16))
    >>> nodes, tets = grid_tet_mesh(vol, cells=3)
    >>> def deform(deformed):  # a stand-in; normally Rasterizer(vol, nodes, tets).deform
    ...     return Volume(vol.data, origin=vol.origin + (deformed - nodes).mean(axis=0))
    >>> deform(nodes + 1.0).origin.tolist()
    [1.0, 1.0, 1.0]
    >>> final_nodes = view_volume(vol, nodes, tets, deform)  # doctest: +SKIP
    """
    with VolumeViewer(volume, nodes, tets, deform_fn, preset=preset, camera=camera, width=width, height=height) as viewer:
        return viewer.start(timeout_s)


def main(argv: Sequence[str] | None = None) -> int:
    """``softvr view PATH [--cells N] [--preset P] [--view V]``: the interactive viewer.

    ``argv`` holds the arguments after ``softvr view``. Loads ``PATH`` with
    :func:`softvr.volume.load` (default: :func:`softvr.datasets.head_ct`), embeds it in a
    ``grid_tet_mesh`` of ``N`` cubes per axis and deforms it with
    :class:`softvr.volume.Rasterizer`. Returns the exit status: 0, or 2 after printing
    an input error (such as no display) to stderr.
    """
    parser = argparse.ArgumentParser(
        prog="softvr view VOLUME",
        description="Drag the nodes of an embedding tetrahedral mesh to deform a CT/MRI volume interactively.",
    )
    parser.add_argument("path", nargs="?", help="volume file or DICOM folder (default: the head CT of softvr.datasets)")
    parser.add_argument("--cells", type=int, default=6, help="mesh cubes per axis, 5 tets each (default 6)")
    parser.add_argument("--device", default=None, help="Warp device for the rasterizer: cpu or cuda (default: cuda when present)")
    parser.add_argument("--preset", default="auto", choices=["auto", "ct", "mri", "labels"], help="transfer function")
    parser.add_argument("--view", default="front", choices=["front", "back", "side", "left", "right", "top", "bottom", "iso"])
    parser.add_argument("--size", default="900x700", help="window size WIDTHxHEIGHT in pixels (default 900x700)")
    args = parser.parse_args(list(argv) if argv is not None else None)
    try:
        if args.cells < 1:
            raise InputError("--cells", "an integer >= 1", str(args.cells))
        try:
            width, height = (int(v) for v in args.size.lower().split("x"))
        except ValueError:
            raise InputError("--size", "WIDTHxHEIGHT, e.g. 900x700", repr(args.size)) from None
        require_display()  # before reading the volume
        if args.path:
            vol = sv.load(args.path)
        else:
            vol = datasets.head_ct()
        nodes, tets = sv.grid_tet_mesh(vol, args.cells)
        rasterizer = sv.Rasterizer(vol, nodes, tets, device=args.device)
        view_volume(vol, nodes, tets, rasterizer.deform, preset=args.preset, camera=args.view, width=width, height=height)
    except InputError as exc:
        print(f"softvr view: {exc}", file=sys.stderr)
        return 2
    return 0
