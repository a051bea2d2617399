"""Multi-screen VR: displays, off-axis cameras per screen, the virtual camera cluster (thesis ch. 6).

* :class:`Screen` / :class:`Display`: screens by three corners in the tracker frame [m], pixel
  size, render node, stereo mode; :func:`load_display` reads a TOML display file, validating
  every screen; :data:`PRESETS` (single wall, cube, the thesis' RAVE as wall / cube /
  amphitheatre, 2x2 PowerWall); :func:`tile` splits a screen into a tiled wall.
* :func:`screen_view`: the off-axis (generalized perspective) frustum of a screen from an eye;
  :func:`render_screen` draws a :class:`~softvr.render.SurfaceRenderer` scene through it.
* Head tracking (:mod:`softvr.cave.tracking`): :class:`HeadPose`, the :class:`Tracker` plug-in
  point, :class:`FixedTracker`, :class:`ScriptedTracker`, :class:`OscTracker` (OSC over UDP).
* The user entity (:mod:`softvr.cave.rig`): :class:`UserPose`, :func:`move`, :func:`turn`,
  :class:`CameraRig` (every screen's camera in the world for a user, head and eye).
* :func:`render_stereo`: side-by-side, anaglyph or quad-buffer stereo of one screen.
* :func:`preview_layout` / :func:`preview_image`: all screens unfolded into one desktop picture.
* The render cluster (:mod:`softvr.cave.cluster`): :class:`Master` (input, clock, simulation,
  streaming) and a :class:`Node` per screen over ZeroMQ, :class:`ClusterConfig`,
  :func:`make_keys` (CURVE); the wire format in :mod:`softvr.cave.protocol`, the body-state
  stream in :mod:`softvr.cave.stream`, the shared application state in :mod:`softvr.cave.app`;
  :class:`StateRenderer` draws a node's screen; :class:`KeyboardNavigation` is the master's
  keyboard / mouse input.
"""

from softvr.cave.display import (PRESETS, STEREO_MODES, Display, Screen, eye_pair, load_display, preset, save_display,
                                 tile)
from softvr.cave.projection import ScreenView, frustum_matrix, screen_view
from softvr.cave.cluster import ClusterConfig, Master, Node, make_keys
from softvr.cave.navigation import KeyboardNavigation
from softvr.cave.render import StateRenderer, render_screen
from softvr.cave.preview import Placement, preview_image, preview_layout
from softvr.cave.rig import EYES, CameraRig, UserPose, move, turn, world_view
from softvr.cave.stereo import render_stereo
from softvr.cave.tracking import (DEFAULT_HEAD, FixedTracker, HeadPose, OscTracker, ScriptedTracker, Tracker,
                                  decode_osc, encode_osc, encode_osc_bundle, quaternion_about)

__all__ = ["PRESETS", "STEREO_MODES", "Display", "Screen", "ScreenView", "frustum_matrix", "load_display", "preset",
           "render_screen", "save_display", "screen_view", "tile"]
__all__ += ["DEFAULT_HEAD", "EYES", "CameraRig", "FixedTracker", "HeadPose", "OscTracker", "Placement",
            "ScriptedTracker", "Tracker", "UserPose", "decode_osc", "encode_osc", "encode_osc_bundle", "eye_pair",
            "move", "preview_image", "preview_layout", "quaternion_about", "render_stereo", "turn", "world_view"]
__all__ += ["ClusterConfig", "KeyboardNavigation", "Master", "Node", "StateRenderer", "make_keys"]
