"""Drawing a scene through one screen's off-axis camera."""

from __future__ import annotations

import numpy as np

from softvr.cave.display import Screen

__all__ = ["render_screen"]


def render_screen(renderer, screen: Screen, eye, *, near: float = 0.05, far: float = 100.0) -> np.ndarray:
    """What ``screen`` shows to an eye at ``eye`` [3] [m]: the scene of ``renderer`` (a
    :class:`~softvr.render.SurfaceRenderer` of the screen's pixel size) through the screen's
    off-axis frustum. Returns RGB uint8 [height, width, 3]."""
    view = screen.view(eye, near=near, far=far)
    renderer.set_view(view.eye, -view.normal, view.up, view.projection)
    return renderer.render()
