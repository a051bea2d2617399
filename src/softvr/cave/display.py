"""Display files: the screens of a CAVE, a PowerWall or a tiled wall (thesis 6.2, 6.4), with
their off-axis cameras.

The file format (TOML, versioned: ``format = "softvr-display 1"``, an ``eye_separation`` and one
``[[screen]]`` table per screen), its validation and the presets (a single wall, a 4-wall cube,
the thesis' RAVE as wall / cube / amphitheatre, a 2 x 2 PowerWall) are the scene layer's:
:mod:`softvr.scene.display`, what a scene file's ``[display]`` names, documents them. Here a
:class:`Screen` gets its off-axis camera (:meth:`Screen.view`) and the screens of one
installation make a :class:`Display`, which :func:`save_display` writes and
:func:`load_display` reads back.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softvr.cave.projection import ScreenView, screen_view
from softvr.errors import InputError, raise_all
from softvr.files import atomic_output
from softvr.scene.display import FORMAT, STEREO_MODES, display_problems, read_display, tile
from softvr.scene.display import PRESETS as _SCREENS
from softvr.scene.display import Screen as _Screen

__all__ = ["PRESETS", "STEREO_MODES", "Display", "Screen", "eye_pair", "load_display", "preset", "save_display", "tile"]


@dataclass(frozen=True)
class Screen(_Screen):
    """One screen: corners [3] [m] in the tracker frame, ``pixels`` (width, height); its
    off-axis camera for an eye (:meth:`view`)."""

    def view(self, eye, *, near: float = 0.05, far: float = 100.0) -> ScreenView:
        """The off-axis camera of this screen for ``eye`` [3] [m]."""
        try:
            return screen_view(self.lower_left, self.lower_right, self.upper_left, eye, near=near, far=far,
                               name=self.name)
        except InputError as exc:
            if self.source is None or exc.source is not None:
                raise
            raise InputError(exc.what, exc.expected, exc.found, source=self.source) from None


@dataclass
class Display:
    """The screens of one installation and the viewer's eye separation [m]."""

    screens: list
    eye_separation: float = 0.065
    name: str = "display"

    def __post_init__(self) -> None:
        raise_all(display_problems(self.screens, self.eye_separation), self.name, "display")

    def screen(self, name: str) -> Screen:
        for s in self.screens:
            if s.name == name:
                return s
        raise InputError("screen", f"one of {[s.name for s in self.screens]}", repr(name))

    def views(self, eye, **kw) -> dict:
        """Screen name -> :class:`ScreenView` for ``eye`` [3] [m] (the virtual camera cluster)."""
        return {s.name: s.view(eye, **kw) for s in self.screens}

    def eyes(self, head, right) -> tuple[np.ndarray, np.ndarray]:
        """Left and right eye positions [3] [m] of a head at ``head`` whose right is ``right``."""
        return eye_pair(head, right, self.eye_separation)


def eye_pair(head, right, separation: float) -> tuple[np.ndarray, np.ndarray]:
    """Left and right eye positions [3] [m]: ``head`` [3] [m] -/+ ``separation`` / 2 [m] along
    ``right`` [3] (any length; the head's right axis)."""
    r = np.asarray(right, float) / np.linalg.norm(right)
    h = np.asarray(head, float)
    return h - 0.5 * separation * r, h + 0.5 * separation * r


#: Built-in displays: name -> a function making the :class:`Display` (softvr.scene.display.PRESETS).
PRESETS = {name: (lambda name=name, screens=screens: Display(screens(Screen), name=name))
           for name, screens in _SCREENS.items()}


def preset(name: str) -> Display:
    """A built-in display (:data:`PRESETS`)."""
    if name not in PRESETS:
        raise InputError("display preset", " | ".join(PRESETS), repr(name))
    return PRESETS[name]()


def save_display(display: Display, path) -> Path:
    """Write ``display`` as a display file (:mod:`softvr.scene.display`) that :func:`load_display` reads
    back to the same screens; atomically (an existing file survives a failed write)."""
    def vec(v) -> str:
        return "[" + ", ".join(repr(float(x)) for x in v) + "]"

    lines = [f'format = "{FORMAT}"', f"eye_separation = {float(display.eye_separation)!r}"]
    for s in display.screens:
        lines += ["", "[[screen]]", f"name = {json.dumps(s.name)}", f"lower_left = {vec(s.lower_left)}",
                  f"lower_right = {vec(s.lower_right)}", f"upper_left = {vec(s.upper_left)}",
                  f"pixels = [{int(s.pixels[0])}, {int(s.pixels[1])}]", f"node = {json.dumps(s.node or s.name)}",
                  f"stereo = {json.dumps(s.stereo)}"]
    path = Path(path)
    with atomic_output(path, path.suffix or ".toml") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    return path


def load_display(path) -> Display:
    """Read and validate a display file (:func:`softvr.scene.display.read_display`)."""
    screens, separation = read_display(Path(path), Screen)
    return Display(screens, separation, name=str(path))
