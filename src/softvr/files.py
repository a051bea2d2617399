"""Checked input files: the one place every reader asks whether a path may be read.

Readers never hand a path to a native library (SimpleITK, meshio, trimesh, zlib) before
:func:`checked_file` has said it is a regular file (not a FIFO, a device or a symlink to one)
no larger than a stated limit, and a detached data file (a MetaImage ``ElementDataFile``, a
glTF buffer URI) before :func:`inside_folder` has said it lies in the header's folder.
The limits are per file and can be raised by the user (``SOFTVR_MAX_FILE_BYTES``,
``SOFTVR_MAX_ELEMENTS``, ``SOFTVR_MAX_TEXT_BYTES``) for the rare real input that exceeds them
(docs/input-limits.md).

Text formats are parsed here too: :func:`read_toml` and :func:`load_json` refuse bad UTF-8,
nesting deeper than :data:`MAX_DEPTH` and integers beyond 64 bits before a reader walks the
tree; :func:`file_name` checks a file name an input writes (NUL bytes, lengths);
:func:`check_npz` an ``.npz`` archive's arrays against their entries; :func:`native_read`
turns a native reader's exceptions and ``sys.exit`` into an error naming the file.

Output is written here too, atomically: :func:`atomic_output` (a temporary file in the target's
folder, renamed over it on success), :func:`atomic_files` (a file and the files its writer puts
beside it), :func:`atomic_folder` (a folder swapped in) and :func:`write_json`.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import tempfile
import tomllib
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from softvr.errors import InputError, SoftvrError

__all__ = ["MAX_DEPTH", "MAX_ELEMENTS", "MAX_FILE_BYTES", "MAX_TEXT_BYTES", "atomic_files", "atomic_folder",
           "atomic_output", "checked_file", "check_count", "check_npz", "check_tree", "file_name", "inside_folder",
           "load_json", "native_read", "read_text", "read_toml", "write_json"]


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
#: Largest text input (a TOML file, a glTF's JSON) [bytes] (64 MiB; ``SOFTVR_MAX_TEXT_BYTES``
#: overrides): text files this large are not hand-written scenes, and are parsed in memory.
MAX_TEXT_BYTES = _limit("SOFTVR_MAX_TEXT_BYTES", 64 << 20)
#: Deepest nesting of tables / arrays a TOML or JSON input may have: softvr's formats nest
#: at most 5 levels; deeper input is refused before any recursive code walks it.
MAX_DEPTH = 32
#: Longest file name an input may write (characters), and longest name component: POSIX's
#: PATH_MAX and NAME_MAX, beyond which the OS refuses the name anyway.
_MAX_PATH, _MAX_NAME = 4096, 255


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


def read_text(path: str | os.PathLike, what: str, *, max_bytes: int | None = None) -> str:
    """The UTF-8 text of the regular file ``path`` (:func:`checked_file`, default limit
    :data:`MAX_TEXT_BYTES`); bytes that are not UTF-8 are an :class:`InputError` naming
    their offset."""
    path = checked_file(path, what, max_bytes=MAX_TEXT_BYTES if max_bytes is None else max_bytes)
    data = _read_bytes(path, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(what, "UTF-8 text", f"byte 0x{data[exc.start]:02x} at offset {exc.start} ({exc.reason})",
                         source=str(path)) from None


def _read_bytes(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError(what, "a readable file", exc.strerror or str(exc), source=str(path)) from None


def read_toml(path: str | os.PathLike, kind: str) -> dict:
    """The table of a TOML file (``kind``: "scene file", "display file", ...), checked by
    :func:`read_text` and :func:`check_tree`: bad UTF-8, bad TOML, nesting deeper than
    :data:`MAX_DEPTH` and integers beyond 64 bits (TOML's range) are an :class:`InputError`
    naming the file (and the field)."""
    text = read_text(path, kind)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError("TOML", "valid TOML", str(exc), source=str(path)) from None
    except RecursionError:
        raise InputError("TOML", f"tables and arrays nested at most {MAX_DEPTH} deep", "deeper nesting",
                         source=str(path)) from None
    except ValueError as exc:  # an integer of more digits than Python converts (sys.int_info)
        raise InputError("TOML", "valid TOML", str(exc), source=str(path)) from None
    check_tree(doc, str(path))
    return doc


def load_json(data: bytes | str, what: str, source: str | None = None):
    """A JSON document (a glTF's), checked by :func:`check_tree`; bad JSON, bad UTF-8 and
    nesting that exhausts the parser are an :class:`InputError` naming ``source``."""
    try:
        doc = json.loads(data)
    except RecursionError:
        raise InputError(what, f"JSON nested at most {MAX_DEPTH} deep", "deeper nesting", source=source) from None
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError, too many digits
        raise InputError(what, "valid UTF-8 JSON", str(exc)[:200], source=source) from None
    check_tree(doc, source)
    return doc


def check_tree(tree, source: str | None = None, *, max_depth: int = MAX_DEPTH) -> None:
    """An :class:`InputError` naming the first field of a parsed TOML / JSON tree nested deeper
    than ``max_depth`` or holding an integer outside the signed 64-bit range (TOML's own
    limit; beyond it numbers cannot be converted to floats or arrays). Iterative: a deep tree
    cannot exhaust the stack here."""
    stack = [(tree, "", 0)]
    while stack:
        node, where, depth = stack.pop()
        if depth > max_depth:
            raise InputError(where or "document", f"tables and arrays nested at most {max_depth} deep",
                             "deeper nesting", source=source)
        if isinstance(node, dict):
            stack.extend((v, f"{where}.{k}" if where else str(k), depth + 1) for k, v in node.items())
        elif isinstance(node, list):
            stack.extend((v, f"{where}[{i}]", depth + 1) for i, v in enumerate(node))
        elif isinstance(node, int) and not isinstance(node, bool) and not -(1 << 63) <= node < (1 << 63):
            raise InputError(where or "document", "an integer within 64 bits", f"an integer of {len(str(node))} "
                             "digits" if node.bit_length() < 14000 else "a huge integer", source=source)


def file_name(folder: str | os.PathLike, name, what: str, source: str | None = None) -> Path:
    """The file an input names (``name``, relative to ``folder``, or absolute), resolved; an
    :class:`InputError` naming ``what`` when it is not a string, holds a NUL byte or is longer
    than the OS allows. Whether it exists is the caller's :func:`checked_file`."""
    if not isinstance(name, str) or not name:
        raise InputError(what, "a file name", repr(name)[:200], source=source)
    if "\x00" in name:
        raise InputError(what, "a file name without NUL bytes", repr(name)[:200], source=source)
    if len(name) > _MAX_PATH or any(len(part.encode("utf-8", "surrogateescape")) > _MAX_NAME
                                    for part in name.split("/")):
        raise InputError(what, f"a file name of at most {_MAX_NAME} bytes per folder or file name",
                         f"{name[:40]!r}... ({len(name)} characters)", source=source)
    try:
        return (Path(folder) / name).resolve()
    except (OSError, RuntimeError, ValueError) as exc:  # a symlink loop, an unencodable name
        raise InputError(what, "a file name that resolves", str(exc), source=source) from None


def native_read(read, path: str | os.PathLike, what: str, expected: str):
    """``read(path)`` by a native reader (meshio, trimesh, SimpleITK) after
    :func:`checked_file`; any error it raises, ``sys.exit`` included (meshio exits on some
    unreadable files), becomes an :class:`InputError` naming the file. MemoryError is not
    caught: sizes are checked before a reader runs, so one is a bug to see."""
    path = checked_file(path, what)
    try:
        return read(path)
    except (MemoryError, SoftvrError):  # a bug to see; a reader's own clear error
        raise
    except SystemExit as exc:
        raise InputError(what, expected, f"the reader gave up (exit {exc.code!r})", source=str(path)) from None
    except Exception as exc:  # noqa: BLE001 - native readers raise every type for bad files
        raise InputError(what, expected, f"{type(exc).__name__}: {str(exc)[:300]}", source=str(path)) from None


def check_npz(path: str | os.PathLike, what: str) -> Path:
    """``path`` if it is a regular ``.npz`` file whose arrays hold no more than their zip
    entries say (a header claiming 1e18 elements would make NumPy allocate them before reading)
    and whose entries together stay within :data:`MAX_FILE_BYTES` uncompressed (no zip bomb);
    else an :class:`InputError` naming the file and the entry."""
    path = checked_file(path, what)
    source = str(path)
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.infolist()
            total = sum(m.file_size for m in members)
            if total > MAX_FILE_BYTES:
                raise InputError(what, f"at most {MAX_FILE_BYTES} bytes uncompressed (SOFTVR_MAX_FILE_BYTES raises "
                                 "the limit)", f"{total} bytes", source=source)
            for member in members:
                with archive.open(member) as f:
                    version = np.lib.format.read_magic(f)
                    shape, _, dtype = (np.lib.format.read_array_header_1_0(f) if version == (1, 0)
                                       else np.lib.format.read_array_header_2_0(f))
                    count = 1
                    for n in shape:
                        count *= n
                    if dtype.hasobject or count * dtype.itemsize > member.file_size:
                        raise InputError(f"{what} {member.filename}", "an array no larger than its zip entry",
                                         f"shape {shape} of {dtype} in {member.file_size} bytes", source=source)
                    while f.read(1 << 20):  # the rest, in chunks: zipfile checks the CRC at the end
                        pass
    except (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError, NotImplementedError) as exc:
        raise InputError(what, "a .npz file (a zip of .npy arrays)", f"{type(exc).__name__}: {str(exc)[:200]}",
                         source=source) from None
    return path


# -- output ------------------------------------------------------------------------------
def _umask() -> int:
    """The process umask, read without changing it (Linux), else the usual 0o022."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022


@contextmanager
def atomic_output(path: str | os.PathLike, suffix: str) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success rename it over ``path``.

    The temporary file lives in the same directory (so :func:`os.replace` is atomic)
    and ends in ``suffix`` (writers such as ffmpeg pick the format from it). If the body
    raises, the temporary file is removed and an existing ``path`` is left untouched.
    The final file gets the permissions a plain ``open(path, "w")`` would give it.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise InputError("path", "a file in an existing directory", f"no directory {str(parent)!r}", str(path))
    fd, tmp_name = tempfile.mkstemp(dir=parent, prefix=f".{path.name}.", suffix=f".tmp{suffix}")
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if not tmp.exists() or tmp.stat().st_size == 0:
            raise OSError(f"writing {path} produced no data")
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
        raise


@contextmanager
def atomic_files(path: str | os.PathLike) -> Iterator[Path]:
    """Yield ``path``'s name inside a fresh hidden folder next to it, for a writer that may put
    more files beside it (an ``.nhdr``'s detached ``.raw``); on success every file written there
    is moved next to ``path`` (:func:`os.replace`), ``path`` itself last, so a reader never finds
    the header before its data. On failure nothing is moved and the folder is removed."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    folder = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=parent))
    try:
        main = folder / path.name
        yield main
        if not main.is_file():
            raise RuntimeError(f"writer produced no {path.name}")
        for f in sorted(f for f in folder.iterdir() if f.name != path.name) + [main]:
            os.replace(f, parent / f.name)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def atomic_folder(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a fresh hidden folder next to ``path`` to fill; on success it takes ``path``'s place.
    A folder already at ``path`` is moved aside first and deleted only once the new one is in (put
    back if the swap fails), so a failure at any point leaves the old folder as it was."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    folder = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=parent))
    backup: Path | None = None
    try:
        yield folder
        os.chmod(folder, 0o777 & ~_umask())  # mkdtemp's 0o700, opened up as a plain mkdir would
        if path.is_dir():
            backup = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=parent))
            os.rmdir(backup)
            os.rename(path, backup)
        try:
            os.rename(folder, path)
        except BaseException:
            if backup is not None:
                os.rename(backup, path)
                backup = None
            raise
    finally:
        shutil.rmtree(folder, ignore_errors=True)
        if backup is not None:
            shutil.rmtree(backup, ignore_errors=True)


def write_json(data: dict, path: str | os.PathLike) -> Path:
    """Write ``data`` as indented JSON to ``path`` (its folder is created), atomically; numpy
    scalars and arrays become numbers and lists. Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path, ".json") as tmp:
        tmp.write_text(json.dumps(data, indent=1, default=_json_default) + "\n")
    return path


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"{type(o).__name__} is not JSON serializable")
