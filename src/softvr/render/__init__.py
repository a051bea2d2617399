"""Rendering of softvr volumes with VTK: off-screen images and videos, and an interactive viewer.

* :class:`VolumeRenderer` ray casts :class:`~softvr.volume.Volume` frames off-screen to
  numpy RGB images (no display needed: EGL, else OSMesa -- see :func:`offscreen_backend`),
  reusing one VTK pipeline and a fixed camera across frames;
  :func:`render_volume` renders a single volume.
* :class:`RayCaster`: softvr's own volume ray caster in Warp (``VolumeRenderer(mapper="warp")``):
  gradients on the fly, empty-space skipping updated where the data changed, jittered ray
  starts (no banding), drawn into VTK's frame at the surfaces' depth.
* :class:`Camera` and :data:`VIEWS`: named views (front, side, top, iso, ...) with
  azimuth, elevation, zoom and orthographic projection.
* :data:`PRESETS` / :class:`Preset`: transfer functions for CT (Hounsfield units), T1 MRI
  (uint8) and label volumes.
* :func:`write_mp4`, :func:`contact_sheet`, :func:`save_png`: output; files are written
  atomically (temporary file + :func:`os.replace`).
* :func:`view_volume` / :class:`VolumeViewer`: drag mesh nodes with the mouse and watch the
  volume deform (needs a display); :class:`NodeDragger`, :func:`pick_node`,
  :func:`move_in_view_plane` and :class:`ViewTransform` are its display-free logic.
* :class:`LiveWindow`: the one on-screen event loop (trackball camera, pause / step keys, a
  timer that advances a frame), shared by the volume viewer and :func:`softvr.app.play_window`.

System libraries (Debian/Ubuntu): ``libegl1 libegl-mesa0 libgl1-mesa-dri`` for EGL,
``libosmesa6`` for the OSMesa fallback, ``libgl1 libglx-mesa0`` plus X for the viewer
(:data:`APT_PACKAGES`). No environment variable is needed.

Examples
--------
>>> import numpy as np
>>> from softvr.volume import Volume
>>> from softvr.render import VolumeRenderer, contact_sheet
>>> x, y, z = np.mgrid[-24:24, -24:24, -24:24]
>>> head = np.where(x**2 + y**2 + z**2 < 20**2, 40, -1000).astype(np.int16)
>>> head[(x**2 + y**2 + z**2 > 16**2) & (x**2 + y**2 + z**2 < 18**2)] = 1200  # a skull
>>> with VolumeRenderer(96, 72, preset="ct") as renderer:
...     frames = [renderer.render(Volume(head, origin=(dx, 0, 0))) for dx in (0, 4, 8)]
>>> contact_sheet(frames, columns=3).shape
(72, 296, 3)
"""

from softvr.render._backend import APT_PACKAGES, RenderBackendError, has_display, offscreen_backend, require_display
from softvr.render._live import LiveWindow
from softvr.render.camera import VIEWS, Camera
from softvr.render.contact_sheet import contact_sheet, save_png
from softvr.render.presets import PRESETS, Preset, label_colors
from softvr.render.raycast import RayCaster
from softvr.render.surfaces import SurfaceRenderer, merge_changed
from softvr.render.video import write_mp4
from softvr.render.viewer import (
    NodeDragger,
    ViewTransform,
    VolumeViewer,
    move_in_view_plane,
    pick_node,
    view_volume,
)
from softvr.render.volume_render import VolumeRenderer, render_volume

__all__ = [
    "APT_PACKAGES",
    "PRESETS",
    "VIEWS",
    "Camera",
    "LiveWindow",
    "NodeDragger",
    "Preset",
    "RayCaster",
    "RenderBackendError",
    "SurfaceRenderer",
    "ViewTransform",
    "VolumeRenderer",
    "VolumeViewer",
    "contact_sheet",
    "has_display",
    "label_colors",
    "merge_changed",
    "move_in_view_plane",
    "offscreen_backend",
    "pick_node",
    "render_volume",
    "require_display",
    "save_png",
    "view_volume",
    "write_mp4",
]
