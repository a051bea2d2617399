"""Writing rendered frames to an H.264 MP4 file."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from softvr.errors import InputError
from softvr.files import atomic_output

__all__ = ["write_mp4"]


def _as_frame(frame, index: int) -> np.ndarray:
    a = np.asarray(frame)
    if a.ndim == 3 and a.shape[2] == 4:
        a = a[:, :, :3]
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise InputError(f"frames[{index}]", "an RGB image [height, width, 3]", f"shape {a.shape}")
    if a.dtype != np.uint8:
        raise InputError(f"frames[{index}]", "dtype uint8", f"dtype {a.dtype}")
    return a


def _even(frame: np.ndarray) -> np.ndarray:
    """Pad odd sizes by one black row/column: yuv420p needs even width and height."""
    h, w = frame.shape[:2]
    if h % 2 or w % 2:
        frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)))
    return np.ascontiguousarray(frame)


def write_mp4(frames: Iterable[np.ndarray], path: "str | os.PathLike", fps: float = 24, *, quality: float = 7.0) -> Path:
    """Encode RGB frames as an H.264 (yuv420p) MP4 file, atomically.

    Frames are streamed to ffmpeg (from ``imageio-ffmpeg``) one at a time, so a generator
    of frames needs no more memory than one frame. The file is written under a temporary
    name in the same directory and renamed onto ``path`` only when encoding succeeded:
    on any error no partial file is left and an existing ``path`` is untouched.

    Parameters
    ----------
    frames : iterable of numpy.ndarray, each [height, width, 3] uint8
        RGB frames, all the same size (RGBA is accepted; alpha is dropped). Odd widths or
        heights are padded with one black column/row (H.264 with yuv420p needs even sizes).
    path : str or os.PathLike
        Output file, normally ending in ``.mp4``; its directory must exist.
    fps : float [frames per second]
    quality : float
        imageio's quality scale, 0 (worst) to 10 (best).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    InputError
        No frames, a frame of the wrong shape/dtype/size, or a bad ``fps``/``quality``.

    Examples
    --------
    >>> import numpy as np, tempfile, os, imageio.v2 as imageio
    >>> from softvr.render import write_mp4
    >>> frames = [np.full((48, 64, 3), 20 * i, np.uint8) for i in range(5)]
    >>> path = write_mp4(frames, os.path.join(tempfile.mkdtemp(), "clip.mp4"), fps=10)
    >>> reader = imageio.get_reader(path)
    >>> reader.count_frames(), reader.get_data(0).shape
    (5, (48, 64, 3))
    >>> reader.close()
    """
    import imageio.v2 as imageio  # noqa: PLC0415 - heavy, load on use

    if not (isinstance(fps, (int, float, np.number)) and np.isfinite(fps) and fps > 0):
        raise InputError("fps", "a number > 0", repr(fps))
    if not 0 <= quality <= 10:
        raise InputError("quality", "a number in [0, 10]", repr(quality))
    path = Path(path)
    with atomic_output(path, path.suffix or ".mp4") as tmp:
        writer = None
        size = None
        count = 0
        try:
            for count, frame in enumerate(frames, start=1):
                frame = _as_frame(frame, count - 1)
                if size is None:
                    size = frame.shape
                    writer = imageio.get_writer(
                        str(tmp),
                        format="FFMPEG",
                        mode="I",
                        fps=float(fps),
                        codec="libx264",
                        pixelformat="yuv420p",
                        quality=float(quality),
                        macro_block_size=1,
                        ffmpeg_log_level="error",
                    )
                elif frame.shape != size:
                    raise InputError(f"frames[{count - 1}]", f"the size of frame 0, {size}", f"{frame.shape}")
                assert writer is not None  # opened with the first frame
                writer.append_data(_even(frame))
            if count == 0:
                raise InputError("frames", "at least one frame", "none")
        except BaseException:
            if writer is not None:
                try:
                    writer.close()  # stop ffmpeg; its own complaint would hide the cause
                except Exception:
                    pass
            raise
        assert writer is not None  # there was a frame
        writer.close()  # flushes ffmpeg; raises if encoding failed
    return path
