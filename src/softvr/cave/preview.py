"""Desktop preview of a multi-screen display: every screen's image in one picture, unfolded.

A CAVE's screens are faces of a polyhedron around the viewer (thesis 6.2.1, fig. 6.2). To check
on a desktop what each render node draws, and that the images meet at the seams, the screens
are unfolded into a plane like a polyhedron's net:

1. the root screen (``"front"`` if there is one, else the first) stays as it is, seen from the
   viewer's side: its right edge along the picture's x, its up edge along y;
2. screens in the root's plane (the tiles of a wall) keep their place in it;
3. breadth-first, each screen sharing an edge (a common segment, 1 mm tolerance) with a placed
   screen is rotated about that edge into the placed screen's plane, on the far side of the
   edge (a side wall opens out beside the front one, the floor below it);
4. screens connected to nothing are laid in a row to the right.

Because a hinge keeps the shared edge fixed, the images of neighbouring screens continue
across the seams in the preview exactly as they do in the room.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from softvr.cave.display import Display, Screen
from softvr.errors import InputError

__all__ = ["Placement", "preview_image", "preview_layout"]

_TOLERANCE = 1e-3  # [m]: corners of real installations are measured to about a millimetre


@dataclass(frozen=True)
class Placement:
    """Where a screen lies in the preview plane.

    Attributes
    ----------
    origin : ndarray, shape [2] [m]
        The screen's lower-left corner (x right, y up).
    right, up : ndarray, shape [2] [m]
        Its lower edge (lower-left to lower-right) and left edge (lower-left to upper-left):
        the screen point at fractions (s, t) of its width and height is at
        ``origin + s * right + t * up``.
    """

    origin: np.ndarray
    right: np.ndarray
    up: np.ndarray

    def corners(self) -> np.ndarray:
        """Lower-left, lower-right, upper-right, upper-left [4, 2] [m]."""
        return np.array([self.origin, self.origin + self.right, self.origin + self.right + self.up,
                         self.origin + self.up])


def _corners(screen: Screen) -> np.ndarray:
    """Lower-left, lower-right, upper-right, upper-left [4, 3] [m]."""
    ll, lr, ul = (np.asarray(c, float) for c in (screen.lower_left, screen.lower_right, screen.upper_left))
    return np.array([ll, lr, lr + ul - ll, ul])


def _normal(corners: np.ndarray) -> np.ndarray:
    n = np.cross(corners[1] - corners[0], corners[3] - corners[0])
    return n / np.linalg.norm(n)


def _rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation [3, 3] by ``angle`` [rad] about the unit ``axis``."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _hinge(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """The rigid transform [4, 4] turning screen ``b`` (corners [4, 3]) about an edge it
    shares with ``a`` into ``a``'s plane, on the far side of the edge; None if they share none."""
    for i in range(4):
        p, q = a[i], a[(i + 1) % 4]
        axis = (q - p) / np.linalg.norm(q - p)
        for j in range(4):
            r, s = b[j], b[(j + 1) % 4]
            off_line = [np.linalg.norm((x - p) - ((x - p) @ axis) * axis) for x in (r, s)]
            if max(off_line) > _TOLERANCE:
                continue
            ta, tb = sorted(((r - p) @ axis, (s - p) @ axis))
            if min(tb, np.linalg.norm(q - p)) - max(ta, 0.0) <= _TOLERANCE:
                continue  # collinear edges that only touch at a corner
            # Directions from the edge into each screen, perpendicular to the edge.
            into_a = a.mean(axis=0) - p
            into_a -= (into_a @ axis) * axis
            into_b = b.mean(axis=0) - p
            into_b -= (into_b @ axis) * axis
            into_a, into_b = into_a / np.linalg.norm(into_a), into_b / np.linalg.norm(into_b)
            # Signed angle turning into_b onto -into_a about the edge.
            angle = math.atan2(np.cross(into_b, -into_a) @ axis, into_b @ -into_a)
            m = np.eye(4)
            m[:3, :3] = _rotation_about(axis, angle)
            m[:3, 3] = p - m[:3, :3] @ p
            return m
    return None


def _coplanar(a: np.ndarray, b: np.ndarray) -> bool:
    na, nb = _normal(a), _normal(b)
    return bool(na @ nb > 1 - 1e-9 and abs((b[0] - a[0]) @ na) < _TOLERANCE)


def preview_layout(display: Display) -> dict:
    """Screen name -> :class:`Placement` in the preview plane [m] (module docstring).

    The plane's origin is the root screen's lower-left corner, x along its lower edge, y along
    its left edge.
    """
    if not isinstance(display, Display):
        raise InputError("display", "a Display (softvr.cave.preset or load_display)", type(display).__name__)
    screens = display.screens
    corners = [_corners(s) for s in screens]
    names = [s.name for s in screens]
    root = names.index("front") if "front" in names else 0
    # Every placed screen carries the rigid transform [4, 4] that unfolds it into the root's plane.
    unfold: dict[int, np.ndarray] = {root: np.eye(4)}
    queue = deque([root])
    pending = [i for i in range(len(screens)) if i != root]
    while pending:
        while queue:
            i = queue.popleft()
            for j in list(pending):
                if _coplanar(corners[i], corners[j]):
                    unfold[j] = unfold[i]
                else:
                    hinge = _hinge(corners[i], corners[j])
                    if hinge is None:
                        continue
                    unfold[j] = unfold[i] @ hinge
                pending.remove(j)
                queue.append(j)
        if pending:
            # Not connected to anything placed: to the right of everything so far, on the root's floor line.
            j = pending.pop(0)
            right_end = max(_flat(corners[k], unfold[k], corners[root])[:, 0].max() for k in unfold)
            width, height = screens[j].size
            target = np.array([[0, 0], [width, 0], [width, height], [0, height]], float)
            target[:, 0] += right_end + 0.1 * width
            unfold[j] = _placing(corners[j], target, corners[root])
            queue.append(j)
    out = {}
    for k, s in enumerate(screens):
        flat = _flat(corners[k], unfold[k], corners[root])
        out[s.name] = Placement(flat[0], flat[1] - flat[0], flat[3] - flat[0])
    return out


def _flat(corners: np.ndarray, unfold: np.ndarray, root: np.ndarray) -> np.ndarray:
    """Preview coordinates [4, 2] [m] of a screen's corners unfolded into the root's plane."""
    x = corners @ unfold[:3, :3].T + unfold[:3, 3] - root[0]
    ex = (root[1] - root[0]) / np.linalg.norm(root[1] - root[0])
    ey = (root[3] - root[0]) / np.linalg.norm(root[3] - root[0])
    return np.stack([x @ ex, x @ ey], axis=1)


def _placing(corners: np.ndarray, target: np.ndarray, root: np.ndarray) -> np.ndarray:
    """The rigid transform [4, 4] putting a screen's lower-left, lower-right and upper-left
    corners onto ``target`` [4, 2] (preview coordinates [m]) in the root's plane."""
    ex = (root[1] - root[0]) / np.linalg.norm(root[1] - root[0])
    ey = (root[3] - root[0]) / np.linalg.norm(root[3] - root[0])
    to_3d = lambda p: root[0] + p[0] * ex + p[1] * ey  # noqa: E731
    src = np.stack([corners[1] - corners[0], corners[3] - corners[0]])
    src = np.vstack([src, np.cross(src[0], src[1])])
    dst = np.stack([to_3d(target[1]) - to_3d(target[0]), to_3d(target[3]) - to_3d(target[0])])
    dst = np.vstack([dst, np.cross(dst[0], dst[1])])
    m = np.eye(4)
    m[:3, :3] = np.linalg.solve(src, dst).T
    m[:3, 3] = to_3d(target[0]) - m[:3, :3] @ corners[0]
    return m


def _sample(image: np.ndarray, s: np.ndarray, t: np.ndarray, interpolation: str) -> np.ndarray:
    """Colours [k, 3] of ``image`` [h, w, 3] at screen fractions ``s``, ``t`` [k] in [0, 1]
    (t = 0 at the bottom, the image's last row)."""
    h, w = image.shape[:2]
    x, y = s * w, (1 - t) * h  # continuous pixel coordinates, pixel centres at +0.5
    if interpolation == "nearest":
        return image[np.clip(y.astype(int), 0, h - 1), np.clip(x.astype(int), 0, w - 1)]
    x0f, y0f = np.floor(x - 0.5), np.floor(y - 0.5)
    fx, fy = (x - 0.5 - x0f)[:, None], (y - 0.5 - y0f)[:, None]
    x0, y0 = np.clip(x0f.astype(int), 0, w - 1), np.clip(y0f.astype(int), 0, h - 1)
    x1, y1 = np.clip(x0 + 1, 0, w - 1), np.clip(y0 + 1, 0, h - 1)
    f = image.astype(float)
    top = (1 - fx) * f[y0, x0] + fx * f[y0, x1]
    bottom = (1 - fx) * f[y1, x0] + fx * f[y1, x1]
    return np.clip(np.rint((1 - fy) * top + fy * bottom), 0, 255).astype(np.uint8)


def preview_image(display: Display, images: dict, pixels_per_metre: float | None = None, gap: int = 0, *,
                  background=(24, 24, 28), missing=(90, 90, 96), interpolation: str = "nearest",
                  max_size: int = 4096) -> np.ndarray:
    """All screens' images in one picture, unfolded (:func:`preview_layout`).

    Parameters
    ----------
    display : Display
    images : dict of str to ndarray of uint8, shape [h, w, 3]
        Screen name -> what it shows (RGB, row 0 at the top), any size; screens without an
        image are filled with ``missing``.
    pixels_per_metre : float, optional [1/m]
        Preview resolution; default the finest of the images' (width / screen width), reduced
        so that the picture's longer side stays within ``max_size`` pixels.
    gap : int [pixels]
        Background border drawn inside every screen's edges (seams shown as lines 2 ``gap``
        wide); 0 = seamless.
    background, missing : tuple of 3 int
        RGB in 0..255 around the screens, and of screens without an image.
    interpolation : {"nearest", "bilinear"}
        Sampling of the screens' images (inverse mapping: every preview pixel centre is taken
        back to the screen it falls on).
    max_size : int [pixels]

    Returns
    -------
    ndarray of uint8, shape [H, W, 3]
        Row 0 at the top; x grows to the right as in the layout, y upwards.
    """
    layout = preview_layout(display)
    if not isinstance(images, dict):
        raise InputError("images", "a dict screen name -> RGB image", type(images).__name__)
    for name, image in images.items():
        if name not in layout:
            raise InputError(f"images[{name!r}]", f"a screen of the display ({', '.join(layout)})", repr(name))
        a = np.asarray(image)
        if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) < 1:
            raise InputError(f"images[{name!r}]", "an RGB uint8 array [h, w, 3]", f"dtype {a.dtype}, shape {a.shape}")
    if interpolation not in ("nearest", "bilinear"):
        raise InputError("interpolation", "nearest | bilinear", repr(interpolation))
    if not isinstance(gap, (int, np.integer)) or gap < 0:
        raise InputError("gap", "an integer number of pixels >= 0", repr(gap))
    colours = {}
    for key, value in (("background", background), ("missing", missing)):
        c = np.asarray(value)
        if c.shape != (3,) or not np.isfinite(c).all() or (c < 0).any() or (c > 255).any():
            raise InputError(key, "an RGB triple in 0..255", repr(value))
        colours[key] = c.astype(np.uint8)
    sizes = {s.name: s.size for s in display.screens}
    allc = np.concatenate([p.corners() for p in layout.values()])
    low, high = allc.min(axis=0), allc.max(axis=0)
    extent = high - low
    if pixels_per_metre is None:
        densities = [max(images[n].shape[1] / sizes[n][0], images[n].shape[0] / sizes[n][1]) for n in images]
        pixels_per_metre = min(max(densities, default=100.0), max_size / extent.max())
    ok = isinstance(pixels_per_metre, (int, float, np.integer, np.floating)) and math.isfinite(pixels_per_metre)
    if not (ok and pixels_per_metre > 0):
        raise InputError("pixels_per_metre", "a finite number > 0 [1/m]", repr(pixels_per_metre))
    # The 1e-9 keeps an exact multiple (4 m at 16 px/m) from gaining a pixel to rounding.
    width, height = (int(math.ceil(v * pixels_per_metre - 1e-9)) for v in extent)
    if not (1 <= width <= max_size and 1 <= height <= max_size):
        raise InputError("pixels_per_metre", f"a preview of at most {max_size} pixels a side",
                         f"{width} x {height} pixels at {pixels_per_metre} px/m")
    out = np.empty((height, width, 3), np.uint8)
    out[:] = colours["background"]
    cols, rows = np.meshgrid(np.arange(width), np.arange(height))
    x = low[0] + (cols.ravel() + 0.5) / pixels_per_metre
    y = high[1] - (rows.ravel() + 0.5) / pixels_per_metre
    for name, place in layout.items():
        basis = np.stack([place.right, place.up], axis=1)
        s, t = np.linalg.solve(basis, np.stack([x - place.origin[0], y - place.origin[1]]))
        margin_s = gap / (pixels_per_metre * np.linalg.norm(place.right))
        margin_t = gap / (pixels_per_metre * np.linalg.norm(place.up))
        inside = (s >= margin_s) & (s < 1 - margin_s) & (t >= margin_t) & (t < 1 - margin_t)
        if not inside.any():
            continue
        flat = out.reshape(-1, 3)
        if name in images:
            flat[inside] = _sample(np.asarray(images[name]), s[inside], t[inside], interpolation)
        else:
            flat[inside] = colours["missing"]
    return out
