"""Stereo images of one screen: an off-axis camera per eye (thesis 6.2.1, 6.4.1).

Each eye gets the generalized perspective frustum of the *same* screen from its own position
(:func:`~softvr.cave.screen_view`), so the two images agree exactly on the screen's plane
(zero parallax) and a point at distance ``D`` from the eye, seen through a screen at distance
``d``, is drawn ``separation * (D - d) / D`` metres apart horizontally: positive (uncrossed)
behind the screen, negative (crossed) in front of it. That is the stereo the thesis' RAVE
shows through shutter glasses (active, quad-buffered); side-by-side and anaglyph are two of
the Blender Game Engine's built-in modes the thesis lists (6.1).

Modes (a screen's ``stereo`` field, :data:`~softvr.cave.STEREO_MODES`):

``"none"``
    One image from the head position (mono), [h, w, 3].
``"side-by-side"``
    The left eye's image, then the right eye's, each the renderer's full size (the screen's
    pixels): [h, 2 w, 3]. For passive projectors fed by a double-wide desktop, or for
    frame-packing converters that scale each half.
``"anaglyph"``
    Red from the left eye's image, green and blue from the right eye's (the plain channel
    split: colours survive partly and each channel is exactly one eye's render; the
    luminance variant is greyer but has less retinal rivalry). [h, w, 3], for red-cyan glasses.
``"quad-buffer"``
    Active stereo: both images into the left and right back buffers of a stereo-capable
    on-screen OpenGL window (a quad-buffered visual: professional GPUs, shutter glasses), which
    must have been requested before its first render with
    ``renderer.vtk_renderer.GetRenderWindow().SetStereoCapableWindow(True)``. Returns the
    left eye's image. Anything else is an :class:`~softvr.errors.InputError`.
"""

from __future__ import annotations

import math

import numpy as np

from softvr.cave.display import STEREO_MODES, Screen
from softvr.cave.rig import UserPose, world_view
from softvr.cave.tracking import HeadPose
from softvr.errors import InputError

__all__ = ["render_stereo"]


def _show(renderer, view) -> None:
    renderer.set_view(view.eye, -view.normal, view.up, view.projection)


def render_stereo(renderer, screen: Screen, head: HeadPose, separation: float = 0.065, mode: str | None = None, *,
                  user: UserPose | None = None, near: float = 0.05, far: float = 100.0) -> np.ndarray:
    """What ``screen`` shows to a tracked head, in a stereo ``mode`` (module docstring).

    Parameters
    ----------
    renderer : SurfaceRenderer
        The scene, at the screen's pixel size (width w, height h).
    screen : Screen
        Corners in the tracker frame [m].
    head : HeadPose
        The tracked head; the eyes are -/+ ``separation`` / 2 along its right axis.
    separation : float [m]
        Interpupillary distance, in [0, 0.2) (a :class:`~softvr.cave.Display`'s ``eye_separation``).
    mode : str, optional
        ``"none"``, ``"side-by-side"``, ``"anaglyph"`` or ``"quad-buffer"``; default the
        screen's own ``stereo``.
    user : UserPose, optional
        The user entity carrying screen and head into the world (:mod:`softvr.cave.rig`).
    near, far : float [m]
        Clipping distances.

    Returns
    -------
    ndarray of uint8, shape [h, w, 3] or [h, 2 w, 3] (side-by-side)
        RGB, row 0 at the top.
    """
    mode = screen.stereo if mode is None else mode
    if mode not in STEREO_MODES:
        raise InputError("stereo mode", " | ".join(STEREO_MODES), repr(mode))
    if not isinstance(head, HeadPose):
        raise InputError("head", "a HeadPose", type(head).__name__)
    ok = isinstance(separation, (int, float, np.integer, np.floating)) and math.isfinite(separation)
    if not (ok and 0 <= separation < 0.2):
        raise InputError("separation", "an eye separation in [0, 0.2) m", repr(separation))
    if mode == "none":
        _show(renderer, world_view(screen, head.position, user, near=near, far=far))
        return renderer.render()
    views = [world_view(screen, eye, user, near=near, far=far) for eye in head.eyes(float(separation))]
    if mode == "quad-buffer":
        _require_stereo_window(renderer)
        return _render_into_stereo_buffers(renderer, views[0], views[1], "CrystalEyes")  # (left, right)
    left: list[np.ndarray] = []
    right: list[np.ndarray] = []
    for view, out in zip(views, (left, right)):
        _show(renderer, view)
        out.append(renderer.render())
    if mode == "side-by-side":
        return np.concatenate([left[0], right[0]], axis=1)
    return np.concatenate([left[0][:, :, :1], right[0][:, :, 1:]], axis=2)


def _require_stereo_window(renderer) -> None:
    """Refuse quad-buffer stereo unless ``renderer`` draws into a stereo-capable on-screen window."""
    window = renderer.vtk_renderer.GetRenderWindow()
    if getattr(renderer, "backend", None) != "onscreen" or window.GetOffScreenRendering():
        found = f"an off-screen window ({getattr(renderer, 'backend', 'unknown')})"
    elif not window.GetStereoCapableWindow():
        found = ("an on-screen window without a stereo GL visual (call "
                 "GetRenderWindow().SetStereoCapableWindow(True) before its first render, on a GPU and driver "
                 "with quad-buffered stereo enabled)")
    else:
        return
    raise InputError("stereo mode 'quad-buffer'", "a stereo-capable on-screen OpenGL window (SurfaceRenderer("
                     "onscreen=True) with a quad-buffered visual); otherwise use 'side-by-side', 'anaglyph' or "
                     "'none'", found)


def _render_into_stereo_buffers(renderer, left_view, right_view, stereo_type: str) -> np.ndarray:
    """One VTK stereo render with our off-axis camera per eye.

    VTK's own stereo shears a symmetric frustum about the focal point, which is not the
    screen-locked frustum a CAVE needs; an explicit projection bypasses that shear, and the
    renderer's StartEvent (fired before each eye's pass, once VTK has chosen the eye) swaps in
    that eye's view and projection. ``stereo_type`` is a VTK stereo type: ``"CrystalEyes"``
    (quad buffer), or ``"Left"`` / ``"Right"`` (one eye, which works off-screen too).
    """
    window = renderer.vtk_renderer.GetRenderWindow()
    camera = renderer.vtk_camera

    def per_eye(_obj, _event) -> None:
        _show(renderer, left_view if camera.GetLeftEye() else right_view)

    tag = renderer.vtk_renderer.AddObserver("StartEvent", per_eye)
    getattr(window, f"SetStereoTypeTo{stereo_type}")()
    window.StereoRenderOn()
    try:
        _show(renderer, left_view)
        return renderer.render()
    finally:
        window.StereoRenderOff()
        renderer.vtk_renderer.RemoveObserver(tag)
