"""Display files: the screens of a CAVE, a PowerWall or a tiled wall (thesis 6.2, 6.4).

Each screen is given in the tracker frame (metres, z up) by three corners, its pixel size, the
render node that draws it and its stereo mode. TOML, versioned::

    format = "softvr-display 1"
    eye_separation = 0.065            # [m], for stereo

    [[screen]]
    name = "front"
    lower_left = [-1.875, 1.875, 0.0]
    lower_right = [1.875, 1.875, 0.0]
    upper_left = [-1.875, 1.875, 3.12]
    pixels = [1400, 1050]
    node = "front"                    # the render process that draws it
    stereo = "none"                   # none | side-by-side | anaglyph | quad-buffer

Every problem of a file is reported at once, naming the file, the field and what was found:
corners that do not make a rectangle, duplicate nodes, unknown stereo modes, keys a screen does
not have (with the nearest known one). Presets (:data:`PRESETS`): a single wall, a 4-wall cube,
the thesis' RAVE (3.75 x 3.12 m screens) as wall / cube / amphitheatre, a 2 x 2 PowerWall.

This is the description a scene file's ``[display]`` names; :mod:`softvr.cave.display` adds the
screens' off-axis cameras and the display they make (the scene layer does not import the cave).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from softvr.errors import Problems, raise_all
from softvr.files import read_toml

__all__ = ["FORMAT", "MAX_PIXELS", "MAX_SCREENS", "PRESETS", "STEREO_MODES", "Screen", "display_problems",
           "read_display", "tile"]

FORMAT = "softvr-display 1"
STEREO_MODES = ("none", "side-by-side", "anaglyph", "quad-buffer")
#: Most screens a display file may have (a render node each): far above any installation.
MAX_SCREENS = 256
#: Most pixels all screens of a display file may have together (8 screens of 8K): every one
#: is rendered, and ``softvr cave preview`` renders them all in one process.
MAX_PIXELS = 1 << 28
_MAX_NAME = 64  # characters of a screen or node name (they name processes and key files)
_MAX_COORDINATE = 1e4  # [m]: a screen corner further from the tracker origin is a unit mistake
_SCREEN_KEYS = ("name", "lower_left", "lower_right", "upper_left", "pixels", "node", "stereo")


@dataclass(frozen=True)
class Screen:
    """One screen: corners [3] [m] in the tracker frame, ``pixels`` (width, height)."""

    name: str
    lower_left: tuple
    lower_right: tuple
    upper_left: tuple
    pixels: tuple = (1024, 768)
    node: str = ""
    stereo: str = "none"
    #: The display file it was read from (None for presets and tiles): named by the errors
    #: its geometry causes later (an eye behind it).
    source: str | None = field(default=None, compare=False, repr=False)

    @property
    def upper_right(self) -> np.ndarray:
        return np.asarray(self.lower_right) + np.asarray(self.upper_left) - np.asarray(self.lower_left)

    @property
    def size(self) -> tuple[float, float]:
        """(width, height) [m]."""
        ll = np.asarray(self.lower_left)
        return (float(np.linalg.norm(np.asarray(self.lower_right) - ll)),
                float(np.linalg.norm(np.asarray(self.upper_left) - ll)))

    def problems(self) -> list[tuple[str, str, str]]:
        """(field, expected, found) for what is wrong with this screen (empty when fine)."""
        out = []
        ll, lr, ul = (np.asarray(c, float) for c in (self.lower_left, self.lower_right, self.upper_left))
        width, height = lr - ll, ul - ll
        if min(np.linalg.norm(width), np.linalg.norm(height)) < 1e-6:
            out.append(("corners", "three distinct corners", "a screen of zero width or height"))
        else:
            cosine = abs(width @ height) / (np.linalg.norm(width) * np.linalg.norm(height))
            if cosine > 1e-3:
                angle = math.degrees(math.acos(min(1.0, cosine)))
                out.append(("corners", "lower-left -> lower-right perpendicular to lower-left -> upper-left "
                            "(a rectangle)", f"edges at {angle:.2f} degrees"))
        if not (len(self.pixels) == 2 and all(isinstance(p, int) and 0 < p <= 16384 for p in self.pixels)):
            out.append(("pixels", "[width, height] in 1..16384", repr(self.pixels)))
        if self.stereo not in STEREO_MODES:
            out.append(("stereo", " | ".join(STEREO_MODES), repr(self.stereo)))
        return out


def display_problems(screens: list, eye_separation, unread=frozenset()) -> list:
    """(field, expected, found) for everything wrong with a set of screens; the screens of
    indices ``unread`` (corners a file got wrong, already reported) are not judged again."""
    out = []
    for i, s in enumerate(screens):
        if i not in unread:
            out += [(f"screen[{i}] ({s.name}).{f}", e, v) for f, e, v in s.problems()]
    nodes = [s.node or s.name for s in screens]
    out += [(f"screen[{i}].node", "one screen per render node", f"{n!r} twice")
            for i, n in enumerate(nodes) if n in nodes[:i]]
    names = [s.name for s in screens]  # images, views and previews are keyed by screen name
    out += [(f"screen[{i}].name", "a name no other screen has", f"{n!r} twice")
            for i, n in enumerate(names) if n in names[:i]]
    ok = isinstance(eye_separation, (int, float)) and math.isfinite(eye_separation) and 0 <= eye_separation < 0.2
    if not ok:
        out.append(("eye_separation", "a distance in [0, 0.2) m", repr(eye_separation)))
    if not screens:
        out.append(("screen", "at least one [[screen]]", "none"))
    return out


def tile(screen: Screen, columns: int, rows: int) -> list[Screen]:
    """``screen`` split into ``columns`` x ``rows`` tiles (row 0 at the bottom), each with its
    share of the pixels and its own node: a tiled wall (of ``screen``'s class)."""
    ll, lr, ul = (np.asarray(c, float) for c in (screen.lower_left, screen.lower_right, screen.upper_left))
    dx, dy = (lr - ll) / columns, (ul - ll) / rows
    w, h = screen.pixels[0] // columns, screen.pixels[1] // rows
    out = []
    for j in range(rows):
        for i in range(columns):
            corner = ll + i * dx + j * dy
            out.append(type(screen)(f"{screen.name}_{i}{j}", tuple(corner), tuple(corner + dx), tuple(corner + dy),
                                    (w, h), node=f"{screen.node or screen.name}_{i}{j}", stereo=screen.stereo))
    return out


def _rave(layout: str, screen=Screen, pixels=(1400, 1050)) -> list[Screen]:
    """The RAVE II of thesis 6.4: four 3.75 x 3.12 m screens, the side ones hinged at the front
    screen's edges and turned 0 (wall), 90 (cube) or 45 (amphitheatre) degrees towards the
    viewer; the floor under the cube."""
    w, h = 3.75, 3.12
    turn = {"wall": 0.0, "cube": 90.0, "amphitheatre": 45.0}[layout]
    a = math.radians(turn)
    front = screen("front", (-w / 2, w / 2, 0.0), (w / 2, w / 2, 0.0), (-w / 2, w / 2, h), pixels, "front")
    # The left screen runs from its outer edge to the front screen's left edge.
    outer_left = (-w / 2 - w * math.cos(a), w / 2 - w * math.sin(a), 0.0)
    left = screen("left", outer_left, (-w / 2, w / 2, 0.0), (outer_left[0], outer_left[1], h), pixels, "left")
    outer_right = (w / 2 + w * math.cos(a), w / 2 - w * math.sin(a), 0.0)
    right = screen("right", (w / 2, w / 2, 0.0), outer_right, (w / 2, w / 2, h), pixels, "right")
    screens = [left, front, right]
    if layout == "cube":
        screens.append(screen("floor", (-w / 2, -w / 2, 0.0), (w / 2, -w / 2, 0.0), (-w / 2, w / 2, 0.0), pixels,
                              "floor"))
    return screens


#: Built-in displays: name -> the screens, made of a given screen class (:class:`Screen` or
#: :class:`softvr.cave.Screen`, which adds the off-axis camera).
PRESETS = {
    "single-wall": lambda screen=Screen: [screen("wall", (-1.5, 1.5, 0.0), (1.5, 1.5, 0.0), (-1.5, 1.5, 2.25),
                                                 (1600, 1200), "wall")],
    "cube": lambda screen=Screen: _rave("cube", screen, (1024, 1024)),
    "rave-wall": lambda screen=Screen: _rave("wall", screen),
    "rave-cube": lambda screen=Screen: _rave("cube", screen),
    "rave-amphitheatre": lambda screen=Screen: _rave("amphitheatre", screen),
    "powerwall-2x2": lambda screen=Screen: tile(screen("wall", (-2.0, 2.0, 0.5), (2.0, 2.0, 0.5), (-2.0, 2.0, 2.75),
                                                       (3840, 2160), "wall"), 2, 2),
}


def read_display(path, screen=Screen) -> tuple[list, float]:
    """The screens (of class ``screen``) and eye separation [m] of a display file (module
    docstring), validated; one :class:`~softvr.errors.InputError` listing every problem."""
    source = str(path)
    doc = read_toml(path, "display file")
    keys = Problems(source, "display")
    problems = keys.items  # (what, expected, found), keys no table has first
    if doc.get("format") != FORMAT:
        problems.append(("format", f'"{FORMAT}"', repr(doc.get("format"))[:200]))
    keys.unknown_keys(doc, {"format", "eye_separation", "screen"}, "")
    raw_screens = doc.get("screen", [])
    if not isinstance(raw_screens, list) or not all(isinstance(raw, dict) for raw in raw_screens):
        problems.append(("screen", "[[screen]] tables", type(raw_screens).__name__))
        raw_screens = []
    if len(raw_screens) > MAX_SCREENS:
        problems.append(("screen", f"at most {MAX_SCREENS} screens", f"{len(raw_screens)}"))
        raw_screens = []
    screens, unread = [], set()
    for i, raw in enumerate(raw_screens):
        keys.unknown_keys(raw, _SCREEN_KEYS, f"screen[{i}]")
        corners = {}
        for key in ("lower_left", "lower_right", "upper_left"):
            value = raw.get(key)
            ok = isinstance(value, list) and len(value) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= _MAX_COORDINATE
                for v in value)
            if not ok:
                problems.append((f"screen[{i}].{key}", f"[x, y, z] in metres, within {_MAX_COORDINATE:g}",
                                 repr(value)[:200]))
                unread.add(i)
                value = [0.0, 0.0, 0.0]
            corners[key] = tuple(float(v) for v in value)
        names = {}
        for key, default in (("name", f"screen {i}"), ("node", "")):
            value = raw.get(key, default)
            if not (isinstance(value, str) and len(value) <= _MAX_NAME and value.isprintable()):
                problems.append((f"screen[{i}].{key}", f"a printable name of at most {_MAX_NAME} characters",
                                 repr(value)[:100]))
                value = default
            names[key] = value
        pixels = raw.get("pixels", [1024, 768])
        if not (isinstance(pixels, list) and len(pixels) == 2 and all(
                isinstance(p, int) and not isinstance(p, bool) and 0 < p <= 16384 for p in pixels)):
            problems.append((f"screen[{i}].pixels", "[width, height] in 1..16384", repr(pixels)[:200]))
            pixels = [1024, 768]
        stereo = raw.get("stereo", "none")  # judged by Screen.problems (a list compares unequal, no error)
        screens.append(screen(names["name"], corners["lower_left"], corners["lower_right"], corners["upper_left"],
                              tuple(pixels), names["node"], stereo if isinstance(stereo, str) else repr(stereo)[:100],
                              source=source))
    total = sum(s.pixels[0] * s.pixels[1] for s in screens)
    if total > MAX_PIXELS:
        problems.append(("screen[*].pixels", f"at most {MAX_PIXELS} pixels on all screens together",
                         f"{total} pixels"))
    separation = doc.get("eye_separation", 0.065)
    raise_all(problems + display_problems(screens, separation, unread), source, "display")
    return screens, float(separation)
