"""Tiling frames into one labelled image, and writing PNG files."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from softvr.errors import InputError
from softvr.files import atomic_output

__all__ = ["contact_sheet", "save_png"]


def contact_sheet(
    frames: Sequence[np.ndarray],
    columns: int = 4,
    labels: Sequence[str] | None = None,
    *,
    gap: int = 4,
    background: tuple[int, int, int] = (32, 32, 32),
) -> np.ndarray:
    """Tile equally sized frames row by row into one image, optionally labelled.

    Parameters
    ----------
    frames : sequence of numpy.ndarray, each [h, w, 3] uint8 (or [h, w] grey)
        At least one frame; all the same size.
    columns : int
        Tiles per row; fewer if there are fewer frames. ``rows = ceil(n / columns)``.
    labels : sequence of str, optional
        One caption per frame, drawn in white with a black outline in the tile's
        top-left corner (over the image, so the sheet size does not change).
    gap : int [pixels]
        Space between tiles (not around the edge).
    background : tuple of 3 int
        RGB of the gaps and of empty tiles in the last row.

    Returns
    -------
    numpy.ndarray, shape [rows * h + (rows - 1) * gap, cols * w + (cols - 1) * gap, 3], uint8
        where ``cols = min(columns, n)``.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.render import contact_sheet
    >>> frames = [np.full((30, 40, 3), 40 * i, np.uint8) for i in range(6)]
    >>> contact_sheet(frames, columns=4, labels=[f"t={i}" for i in range(6)]).shape
    (64, 172, 3)
    """
    frames = [np.asarray(f) for f in frames]
    if not frames:
        raise InputError("frames", "at least one frame", "none")
    if not isinstance(columns, (int, np.integer)) or columns < 1:
        raise InputError("columns", "an integer >= 1", repr(columns))
    if not isinstance(gap, (int, np.integer)) or gap < 0:
        raise InputError("gap", "an integer >= 0", repr(gap))
    if labels is not None and len(labels) != len(frames):
        raise InputError("labels", f"{len(frames)} labels (one per frame)", f"{len(labels)}")
    tiles: list[np.ndarray] = []
    for i, f in enumerate(frames):
        if f.dtype != np.uint8:
            raise InputError(f"frames[{i}]", "dtype uint8", f"dtype {f.dtype}")
        if f.ndim == 2:
            f = np.repeat(f[:, :, None], 3, axis=2)
        elif f.ndim == 3 and f.shape[2] == 4:
            f = f[:, :, :3]
        if f.ndim != 3 or f.shape[2] != 3:
            raise InputError(f"frames[{i}]", "an image [h, w, 3] or [h, w]", f"shape {f.shape}")
        if tiles and f.shape != tiles[0].shape:
            raise InputError(f"frames[{i}]", f"the size of frames[0], {tiles[0].shape[:2]}", f"{f.shape[:2]}")
        tiles.append(f)
    h, w = tiles[0].shape[:2]
    cols = min(int(columns), len(tiles))
    rows = math.ceil(len(tiles) / cols)
    sheet = np.empty((rows * h + (rows - 1) * gap, cols * w + (cols - 1) * gap, 3), np.uint8)
    sheet[:] = np.asarray(background, dtype=np.uint8)
    origins = []
    for n, tile in enumerate(tiles):
        r, c = divmod(n, cols)
        y, x = r * (h + gap), c * (w + gap)
        sheet[y : y + h, x : x + w] = tile
        origins.append((x, y))
    if labels is not None:
        sheet = _draw_labels(sheet, origins, [str(s) for s in labels], h)
    return sheet


def _draw_labels(sheet: np.ndarray, origins, labels, tile_h: int) -> np.ndarray:
    from PIL import Image, ImageDraw, ImageFont  # noqa: PLC0415 - Pillow comes with imageio

    size = max(10, min(48, tile_h // 12))
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has only the fixed bitmap font
        font = ImageFont.load_default()
    image = Image.fromarray(sheet)
    draw = ImageDraw.Draw(image)
    pad = max(2, size // 4)
    for (x, y), text in zip(origins, labels):
        if text:
            draw.text((x + pad, y + pad), text, fill=(255, 255, 255), font=font, stroke_width=max(1, size // 8), stroke_fill=(0, 0, 0))
    return np.asarray(image).copy()


def save_png(image: np.ndarray, path: "str | os.PathLike") -> Path:
    """Write an image to a PNG file, atomically.

    The file is written under a temporary name in the same directory and renamed onto
    ``path``; on any error no partial file is left and an existing ``path`` is untouched.

    Parameters
    ----------
    image : numpy.ndarray, [h, w, 3] RGB, [h, w, 4] RGBA or [h, w] grey, uint8
    path : str or os.PathLike
        Output file; its directory must exist.

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> import numpy as np, tempfile, os, imageio.v3 as iio
    >>> from softvr.render import save_png
    >>> path = save_png(np.zeros((8, 12, 3), np.uint8), os.path.join(tempfile.mkdtemp(), "a.png"))
    >>> iio.imread(path).shape
    (8, 12, 3)
    """
    import imageio.v3 as iio  # noqa: PLC0415

    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise InputError("image", "dtype uint8", f"dtype {a.dtype}")
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (3, 4))) or 0 in a.shape:
        raise InputError("image", "an image [h, w], [h, w, 3] or [h, w, 4]", f"shape {a.shape}")
    path = Path(path)
    with atomic_output(path, ".png") as tmp:
        iio.imwrite(tmp, a, extension=".png")
    return path
