"""The runtime: a built scene played frame by frame (DESIGN.md, ``softvr.app``).

* :class:`Player`: a :class:`softvr.Scene` advanced ``steps_per_frame`` sub-steps per frame,
  its per-step hooks in one declared order (:data:`STEP_ORDER`, :data:`FRAME_ORDER`), metrics
  per frame, its surfaces drawn offscreen; :class:`Sensor`: a vector it reads every frame.
* :class:`Drawable`: what a player shows (:meth:`Player.drawables`), as plain data, which the
  window, the offscreen render and the cave cluster read; :class:`SurfaceDrawing` puts them
  into a :class:`~softvr.render.SurfaceRenderer`; :func:`plane_drawable`, :func:`sphere_drawable`.
* :func:`record`: the one frames-to-files loop (MP4, PNG frames, contact sheet, metrics JSON,
  plots) of ``softvr run`` and ``softvr demo``; :func:`output_name` and :func:`out_folder` the
  one naming rule (``softvr-out/NAME/NAME.mp4``).
* :func:`play_window`: the one live window loop of ``softvr view`` (keys :data:`VIEW_LAYERS`).
* :func:`run_parser`, :func:`check_run_args`, :func:`add_device_option`, :func:`record_from_args`,
  :func:`add_view_options`, :func:`shown_layers`: the options every command that plays a scene takes.

It sits above :mod:`softvr.sim` and :mod:`softvr.render` and imports neither
:mod:`softvr.scene`, :mod:`softvr.cave` nor the examples: they build what it plays.
"""

from softvr.app._drawables import (DRAWABLE_KINDS, DRAWABLE_LAYERS, PLANE_COLOR, PLANE_TILES, SPHERE_COLOR, Drawable,
                                   SurfaceDrawing, plane_drawable, pose_matrix, sphere_drawable)
from softvr.app._options import (DEFAULT_OUT, add_device_option, add_view_options, check_run_args, out_folder,
                                 record_from_args, run_parser, shown_layers)
from softvr.app._player import FRAME_ORDER, STEP_ORDER, Player, Sensor, gravity_potential
from softvr.app._record import output_name, record
from softvr.app._window import VIEW_LAYERS, play_window

__all__ = ["DEFAULT_OUT", "DRAWABLE_KINDS", "DRAWABLE_LAYERS", "FRAME_ORDER", "PLANE_COLOR", "PLANE_TILES",
           "SPHERE_COLOR", "STEP_ORDER", "VIEW_LAYERS", "Drawable", "Player", "Sensor", "SurfaceDrawing",
           "add_device_option", "add_view_options", "check_run_args", "gravity_potential", "out_folder", "output_name",
           "plane_drawable", "play_window", "pose_matrix", "record", "record_from_args", "run_parser", "shown_layers",
           "sphere_drawable"]
