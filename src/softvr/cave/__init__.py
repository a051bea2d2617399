"""Multi-screen VR: displays, off-axis cameras per screen, the virtual camera cluster (thesis ch. 6).

* :class:`Screen` / :class:`Display`: screens by three corners in the tracker frame [m], pixel
  size, render node, stereo mode; :func:`load_display` reads a TOML display file, validating
  every screen; :data:`PRESETS` (single wall, cube, the thesis' RAVE as wall / cube /
  amphitheatre, 2x2 PowerWall); :func:`tile` splits a screen into a tiled wall.
* :func:`screen_view`: the off-axis (generalized perspective) frustum of a screen from an eye;
  :func:`render_screen` draws a :class:`~softvr.render.SurfaceRenderer` scene through it.
"""

from softvr.cave.display import PRESETS, STEREO_MODES, Display, Screen, load_display, preset, tile
from softvr.cave.projection import ScreenView, frustum_matrix, screen_view
from softvr.cave.render import render_screen

__all__ = ["PRESETS", "STEREO_MODES", "Display", "Screen", "ScreenView", "frustum_matrix", "load_display", "preset",
           "render_screen", "screen_view", "tile"]
