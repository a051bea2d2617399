"""Checked input files: the one place every reader asks whether a path may be read.

Readers never hand a path to a native library (SimpleITK, meshio, trimesh, zlib) before
:func:`checked_file` has said it is a regular file (not a FIFO, a device or a symlink to one)
no larger than a stated limit, and a detached data file (a MetaImage ``ElementDataFile``, a
glTF buffer URI) before :func:`inside_folder` has said it lies in the header's folder.
The limits are per file and can be raised by the user (``SOFTVR_MAX_FILE_BYTES``,
``SOFTVR_MAX_ELEMENTS``) for the rare real input that exceeds them.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from softvr.errors import InputError

__all__ = ["MAX_ELEMENTS", "MAX_FILE_BYTES", "checked_file", "check_count", "inside_folder"]


def _limit(name: str, default: int) -> int:
    raw = os.environ.get(name)
    if raw is None:
        return default
    try:
        value = int(raw)
    except ValueError:
        raise InputError(name, "a positive integer (environment variable)", repr(raw)) from None
    if value <= 0:
        raise InputError(name, "a positive integer (environment variable)", repr(raw))
    return value


#: Largest input file read [bytes] (4 GiB; ``SOFTVR_MAX_FILE_BYTES`` overrides).
MAX_FILE_BYTES = _limit("SOFTVR_MAX_FILE_BYTES", 4 << 30)
#: Largest count an input may ask softvr to allocate (voxels, cells, vertices, frames) before
#: anything is allocated (2**31; ``SOFTVR_MAX_ELEMENTS`` overrides).
MAX_ELEMENTS = _limit("SOFTVR_MAX_ELEMENTS", 1 << 31)


def checked_file(path: str | os.PathLike, what: str, *, max_bytes: int | None = None) -> Path:
    """``path`` if it is an existing regular file of at most ``max_bytes`` (default
    :data:`MAX_FILE_BYTES`) [bytes], after following symlinks; else an :class:`InputError`
    naming the file, ``what`` it should be and what it is."""
    path = Path(path)
    limit = MAX_FILE_BYTES if max_bytes is None else max_bytes
    try:
        info = path.stat()
    except FileNotFoundError:
        raise InputError(what, "an existing file", "no such file", source=str(path)) from None
    except OSError as exc:
        raise InputError(what, "a readable file", exc.strerror or str(exc), source=str(path)) from None
    if not stat.S_ISREG(info.st_mode):
        kind = ("a folder" if stat.S_ISDIR(info.st_mode) else "a FIFO" if stat.S_ISFIFO(info.st_mode)
                else "a device" if stat.S_ISCHR(info.st_mode) or stat.S_ISBLK(info.st_mode)
                else "a socket" if stat.S_ISSOCK(info.st_mode) else "not a regular file")
        raise InputError(what, "a regular file", kind, source=str(path))
    if info.st_size > limit:
        raise InputError(what, f"a file of at most {limit} bytes (SOFTVR_MAX_FILE_BYTES raises the limit)",
                         f"{info.st_size} bytes", source=str(path))
    return path


def inside_folder(folder: str | os.PathLike, name: str, what: str, source: str | None = None) -> Path:
    """The file ``name`` (relative, as a header writes it) resolved inside ``folder``; an
    :class:`InputError` when it is absolute or escapes the folder (``..``, a symlink out)."""
    folder = Path(folder).resolve()
    if not isinstance(name, str) or not name or "\x00" in name:
        raise InputError(what, "a relative file name", repr(name), source=source)
    candidate = Path(name)
    resolved = (folder / candidate).resolve()
    if candidate.is_absolute() or not resolved.is_relative_to(folder):
        raise InputError(what, f"a file inside {folder}", repr(name), source=source)
    return resolved


def check_count(count, what: str, source: str | None = None, *, limit: int | None = None) -> int:
    """``count`` as an int if it is an integer in ``0 .. limit`` (default :data:`MAX_ELEMENTS`);
    else an :class:`InputError` — called on every size an input states, before allocating."""
    limit = MAX_ELEMENTS if limit is None else limit
    if isinstance(count, bool) or not isinstance(count, int) and not (
            hasattr(count, "__index__") and not isinstance(count, float)):
        raise InputError(what, "an integer count", repr(count), source=source)
    count = int(count)
    if not 0 <= count <= limit:
        raise InputError(what, f"a count in 0 .. {limit} (SOFTVR_MAX_ELEMENTS raises the limit)", str(count),
                         source=source)
    return count
