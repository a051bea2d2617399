"""Reading and writing :class:`~softvr.volume.Volume` files.

The format is chosen from the file name:

========================  ======  ======  ==============================================
suffix                    load    save    library, notes
========================  ======  ======  ==============================================
``.nrrd``, ``.nhdr``      yes     yes     pynrrd; ``.nhdr`` has a detached ``.raw.gz``
``.nii``, ``.nii.gz``     yes     yes     nibabel
``.mha``, ``.mhd``        yes     yes     MetaImage (SimpleITK writes it); ``.mhd`` has
                                          a ``.raw``
``.npy``                  yes     yes     numpy; data only (spacing 1, origin 0)
``.npz``                  yes     yes     numpy; keys ``data`` [+ ``spacing``, ``origin``,
                                          ``direction``, ``is_label``]
``.inv3``                 yes     no      InVesalius 3 project (tar.gz + plists)
``.dcm``, ``DICOMDIR``    yes     no      pydicom; one single- or multi-frame image, or
                                          the series a DICOMDIR lists
a folder                  yes     yes     DICOM series (pydicom); a path with no suffix
                                          is written as a DICOM series folder
========================  ======  ======  ==============================================

Conventions
-----------
* Arrays are indexed ``data[i, j, k]`` with axis 0 = x, 1 = y, 2 = z (the order of the
  file's own axes: fastest-varying axis first), so they are usually Fortran-ordered
  (x fastest), not C-contiguous; formats that store ``[z, y, x]`` (InVesalius, DICOM
  pixel arrays) are transposed views.
* Voxels come back in native byte order and in one of
  :data:`~softvr.volume.SUPPORTED_DTYPES` (the types :func:`~softvr.volume.deform`
  takes); other stored types are converted with one :class:`UserWarning` that names the
  file, both types and whether the conversion is exact (see :func:`load`).
* Untrusted input: a path must be a regular file (not a FIFO, a device or a symlink to
  one), a detached data file (MetaImage ``ElementDataFile``, NRRD ``data file``, DICOMDIR
  ``ReferencedFileID``) must lie inside the header's folder, and every size a header
  states is checked against :data:`softvr.files.MAX_ELEMENTS` and against the bytes the
  file holds before a voxel buffer is allocated; compressed data are inflated only up to
  the size the header states (:mod:`softvr.files`).
* Positions (``spacing``, ``origin``) are kept in the file's own units, which for all
  medical formats here is millimetres; softvr does not convert them.
* Geometry is stored as the file gives it, with no change of patient coordinate frame:
  NIfTI affines are RAS+ while NRRD (as written here), MetaImage and DICOM are LPS+, so a
  NIfTI file read here and written as MetaImage keeps the same numbers but a viewer will
  show it mirrored in x and y. ``direction`` columns are the world directions of the
  i, j, k axes and ``spacing`` the lengths of the affine / space-direction columns.
* ``is_label=None`` takes the file's own marker when the format has one (``.npz`` key
  ``is_label``; NIfTI intent code ``NIFTI_INTENT_LABEL``; NRRD field ``softvr_is_label``;
  MetaImage field ``softvr_is_label`` -- all written by :func:`save`), else ``False``.
  ``True``/``False`` override it.
* Every bad input raises :class:`~softvr.errors.InputError` naming the file, the field,
  what was expected and what was found; library exceptions are wrapped.
* :func:`save` is atomic: the file(s) are written under a temporary name in the target
  folder and moved into place with :func:`os.replace`, so a failed save leaves any
  previous file intact and no partial or temporary file behind.
"""

from __future__ import annotations

import bz2
import contextlib
import datetime
import gzip
import math
import os
import plistlib
import re
import struct
import tarfile
import warnings
import zipfile
import zlib
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from softvr.errors import InputError
from softvr.files import atomic_files, atomic_folder, check_count, checked_file, inside_folder
from softvr.volume._volume import SUPPORTED_DTYPES, Volume

__all__ = ["LOAD_SUFFIXES", "SAVE_SUFFIXES", "load", "save"]

#: File name endings :func:`load` understands (plus any folder, read as a DICOM series).
LOAD_SUFFIXES = (".nrrd", ".nhdr", ".nii", ".nii.gz", ".mha", ".mhd", ".npy", ".npz", ".inv3", ".dcm")
#: File name endings :func:`save` writes (plus a folder / no suffix: a DICOM series).
SAVE_SUFFIXES = (".nrrd", ".nhdr", ".nii", ".nii.gz", ".mha", ".mhd", ".npy", ".npz")

_FORMAT_OF_SUFFIX = {
    ".nrrd": "nrrd",
    ".nhdr": "nrrd",
    ".nii": "nifti",
    ".nii.gz": "nifti",
    ".mha": "metaimage",
    ".mhd": "metaimage",
    ".npy": "npy",
    ".npz": "npz",
    ".inv3": "inv3",
    ".dcm": "dicom",
}

#: dtypes the image formats (NRRD, NIfTI, MetaImage) store; ``bool`` is written as uint8.
_IMAGE_DTYPES = tuple(np.dtype(t) for t in ("u1", "i1", "u2", "i2", "u4", "i4", "f4", "f8"))
#: dtypes a DICOM series stores (integers only: DICOM images have no float pixels).
_DICOM_DTYPES = tuple(np.dtype(t) for t in ("u1", "i1", "u2", "i2"))

_LABEL_KEY = "softvr_is_label"


# --------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------


def load(path, *, is_label: bool | None = None, frame: int | None = None, series: int | str | None = None) -> Volume:
    """Read a volume from a file, a DICOM series folder or a DICOMDIR.

    Parameters
    ----------
    path : str or os.PathLike
        A file whose name ends in one of :data:`LOAD_SUFFIXES` (``.nrrd``, ``.nhdr``,
        ``.nii``, ``.nii.gz``, ``.mha``, ``.mhd``, ``.npy``, ``.npz``, ``.inv3``, ``.dcm``),
        a DICOM file without suffix or a ``DICOMDIR``, or a folder holding DICOM images
        (one series, or several and ``series``; a folder holding only a ``DICOMDIR`` is
        read through it).
    is_label : bool, optional
        ``True`` marks the volume as a segmentation (nearest-neighbour deformation),
        ``False`` as an intensity image. ``None`` (default) keeps the file's own marker
        where the format has one (see the module notes), else ``False``.
    frame : int, optional
        For a 4-D file (NIfTI ``dim[4]`` / ``dim[5]``, NRRD with a fourth, non-spatial
        axis, MetaImage ``NDims = 4`` or ``ElementNumberOfChannels > 1``): which frame
        (time point) or channel to read, ``0 .. n - 1``. A 4-D file without it is
        refused with a message giving ``n``; a 3-D file with it too.
    series : int or str, optional
        For a folder or DICOMDIR holding several DICOM series: which one, as the index in
        the list the refusal without it prints (sorted by SeriesNumber) or as the
        SeriesInstanceUID.

    Returns
    -------
    Volume
        ``data`` of shape [nx, ny, nz] in native byte order and of one of
        :data:`~softvr.volume.SUPPORTED_DTYPES` (other voxel types are converted, with a
        :class:`UserWarning` naming the file and both types: bool -> uint8,
        int8 -> int16, wider integers -> int16 / uint16 when the values fit, else float32,
        float64 -> float32); ``spacing`` [3] and ``origin`` [3] in the file's units (mm for
        all medical formats), ``direction`` [3, 3] with columns = world directions of the
        i, j, k axes.

    Raises
    ------
    InputError
        Missing path, unknown suffix, a path that is not a regular file (a FIFO, a
        device, a symlink to one), a detached data file outside the header's folder,
        sizes that exceed :data:`softvr.files.MAX_ELEMENTS` voxels or the file, unreadable
        or corrupt file, data that is not a non-empty 3-D scalar array (or 4-D without
        ``frame``), several DICOM series without ``series``, inconsistent DICOM slices.

    Notes
    -----
    * Every header (MetaImage, NRRD, NIfTI, NumPy, DICOM) is read and checked by softvr
      before any voxel buffer is allocated, and the voxel data are read by softvr with
      bounded decompression; SimpleITK is not used for reading, pynrrd only to parse an
      already bounded NRRD header, nibabel only for the NIfTI header fields (affine,
      scaling), pydicom for DICOM elements and pixel decoding after Rows x Columns x
      NumberOfFrames was checked.
    * NIfTI: ``spacing`` = norms of the affine's first three columns, ``direction`` = the
      normalized columns, ``origin`` = the affine translation (RAS+, kept as-is). Singleton
      dimensions beyond the third (``[nx, ny, nz, 1]``) are dropped.
    * DICOM: slices are sorted by ``ImagePositionPatient`` projected on the slice normal
      (row cosine x column cosine; not SimpleITK's series reader, which averages over a missing
      slice and scans folders natively: docs/volume.md); x runs along the rows (columns of the pixel array),
      ``spacing`` = (PixelSpacing[1], PixelSpacing[0], slice-position step) and ``origin``
      = position of the first sorted slice. A multi-frame file is one volume with its
      frames as slices, placed by ``GridFrameOffsetVector`` (RT dose) or the per-frame
      ``PlanePositionSequence`` (enhanced CT / MR), else one ``SliceThickness`` apart. A
      single single-frame file is a volume one slice thick (nz = 1).
      ``RescaleSlope``/``RescaleIntercept`` (RT dose: ``DoseGridScaling``) are applied:
      with the identity rescale the stored type is kept, otherwise the result is int16
      when all values are integers that fit, else float32. The same rule applies to NIfTI
      ``scl_slope``/``scl_inter``.
    * InVesalius ``.inv3`` (a tar.gz): ``main.plist`` has ``matrix`` = {``filename``
      (``matrix.dat``), ``shape`` [nz, ny, nx], ``dtype``} and ``spacing`` in mm, already
      in x, y, z order; ``matrix.dat`` is the raw little-endian array in C order, i.e.
      [z, y, x], returned transposed to [x, y, z]. The project stores no origin or
      patient orientation, so origin is 0 and direction the identity; note that
      InVesalius flips rows relative to DICOM (in the sample head CT the face is towards
      +y, where DICOM's LPS would put it towards -y). Masks and surfaces are ignored.
    """
    p = Path(os.fspath(path))
    source = str(p)
    if is_label is not None and not isinstance(is_label, (bool, np.bool_)):
        raise InputError("is_label", "True, False or None", repr(is_label), source=source)
    if frame is not None and (isinstance(frame, (bool, np.bool_)) or not isinstance(frame, (int, np.integer))
                              or frame < 0):
        raise InputError("frame", "None or an integer >= 0 (a frame / channel index)", repr(frame), source=source)
    if series is not None and (isinstance(series, (bool, np.bool_))
                               or not isinstance(series, (int, np.integer, str))
                               or isinstance(series, (int, np.integer)) and series < 0):
        raise InputError("series", "None, an index >= 0 or a SeriesInstanceUID", repr(series), source=source)
    if not p.exists():
        raise InputError("path", "an existing file or DICOM series folder", "no such file or folder", source)
    fmt: str | None
    if p.is_dir():
        fmt = "dicom"
    else:
        checked_file(p, "file")
        fmt = _format_of(p)
        if fmt is None and _is_dicom_file(p):
            fmt = "dicom"
        if fmt is None:
            raise InputError(
                "file name suffix",
                "one of " + ", ".join(LOAD_SUFFIXES) + ", a DICOM file or DICOMDIR, or a DICOM series folder",
                repr(_suffix_text(p)),
                source,
            )
    if series is not None and fmt != "dicom":
        raise InputError("series", "None (only DICOM folders and DICOMDIRs hold several series)", repr(series), source)
    try:
        fields = _read_dicom(p, series) if fmt == "dicom" else _READERS[fmt](p)
    except (InputError, MemoryError, KeyboardInterrupt):
        raise
    except Exception as exc:  # a library failed on a corrupt or unexpected file
        raise InputError(_LIBRARY_PART[fmt], f"a readable {_FORMAT_NAMES[fmt]} file", _describe(exc), source) from exc
    if is_label is not None:
        fields["is_label"] = bool(is_label)
    _pick_frame(fields, frame, source)
    return _make_volume(fields, source)


def save(volume: Volume, path) -> Path:
    """Write a volume to a file, or to a DICOM series folder; atomically.

    Parameters
    ----------
    volume : Volume
        The volume; ``data`` [nx, ny, nz], ``spacing`` / ``origin`` in its own units
        (written unchanged, so mm for files other tools will read).
    path : str or os.PathLike
        Target. Its suffix picks the format (:data:`SAVE_SUFFIXES`); a path with no
        suffix, or an existing folder, is written as a DICOM series folder holding one
        ``slice_NNNN.dcm`` per z slice. The parent folder must exist.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    InputError
        Not a :class:`Volume`, unknown suffix, missing parent folder, a voxel type the
        format cannot store (image formats: bool, uint8, int8, uint16, int16, uint32,
        int32, float32, float64 -- bool is written as uint8; DICOM: integers up to 16
        bit), or a DICOM target folder that holds anything but a DICOM series.

    Notes
    -----
    * ``.npy`` keeps the data only; spacing, origin, direction and ``is_label`` are lost.
    * NRRD is written gzip-compressed with ``space dimension: 3`` (no named patient
      space), ``space directions`` = ``spacing * direction`` columns, ``space origin``.
    * NIfTI gets the affine ``[[direction * spacing, origin], [0, 0, 0, 1]]`` as both
      sform and qform (code 1); ``is_label`` sets intent ``NIFTI_INTENT_LABEL``.
    * DICOM: Secondary Capture images, identity rescale, ``ImagePositionPatient`` per
      slice. A left-handed ``direction`` (det < 0) is written with the k axis reversed
      (same world geometry), so it reads back with ``data[:, :, ::-1]``. ``is_label`` is
      not stored.
    * Atomicity: everything is written into a hidden temporary folder next to ``path``
      and then moved into place (:func:`os.replace`; for a DICOM folder, the old folder is
      swapped out and deleted only after the new one is in place). On any failure the
      temporary files are removed and a previous file at ``path`` is left as it was.
    """
    if not isinstance(volume, Volume):
        raise InputError("volume", "a softvr.volume.Volume", type(volume).__name__)
    p = Path(os.fspath(path))
    source = str(p)
    fmt: str | None
    if p.is_dir() or (_suffix_text(p) == "" and not p.exists()):
        fmt = "dicom"
    else:
        fmt = _format_of(p)
        if fmt is None or fmt in ("inv3", "dicom"):
            raise InputError(
                "file name suffix",
                "one of " + ", ".join(SAVE_SUFFIXES) + " or a folder name (DICOM series)",
                repr(_suffix_text(p)) + {
                    "inv3": " (InVesalius projects are read-only)",
                    "dicom": " (a DICOM volume is saved as a folder of slices)"}.get(fmt or "", ""),
                source,
            )
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError("folder", "an existing folder to write into", f"{parent} does not exist", source)
    data = _data_for_format(volume, fmt, source)
    if fmt == "dicom":
        if p.exists() and not p.is_dir():
            raise InputError(
                "path", "a folder for the DICOM series (or a file name with a suffix)", "an existing file", source
            )
        if p.is_dir():
            _check_replaceable_dicom_folder(p, source)
        with atomic_folder(p) as folder:
            _write_dicom(volume, data, folder)
    else:
        with atomic_files(p) as file:
            _WRITERS[fmt](volume, data, file)
    return p


# --------------------------------------------------------------------------------------
# helpers shared by all formats
# --------------------------------------------------------------------------------------

_FORMAT_NAMES = {
    "nrrd": "NRRD",
    "nifti": "NIfTI",
    "metaimage": "MetaImage",
    "npy": "NumPy .npy",
    "npz": "NumPy .npz",
    "inv3": "InVesalius .inv3 project",
    "dicom": "DICOM",
}


#: The part of a file a library was reading when it failed (the field of the InputError).
_LIBRARY_PART = {
    "nrrd": "NRRD header / data",
    "nifti": "NIfTI header / data",
    "metaimage": "MetaImage header / data",
    "npy": "npy header / data",
    "npz": "npz members",
    "inv3": "inv3 members",
    "dicom": "DICOM data elements",
}


def _suffix_text(p: Path) -> str:
    name = p.name.lower()
    if name.endswith(".nii.gz"):
        return ".nii.gz"
    return p.suffix.lower()


def _format_of(p: Path) -> str | None:
    return _FORMAT_OF_SUFFIX.get(_suffix_text(p))


def _describe(exc: BaseException) -> str:
    """One line ``Type: message`` for a library exception (ITK source locations removed)."""
    text = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    text = re.sub(r"Exception thrown in SimpleITK \w+:\s*", "", text)
    text = re.sub(r"\S+\.(?:cxx|hxx|h|cpp):\d+:\s*", "", text)
    if len(text) > 300:
        text = text[:300] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _make_volume(fields: dict, source: str) -> Volume:
    data = fields["data"]
    if data.ndim != 3:
        raise InputError("data", "a 3-D scalar array [nx, ny, nz]", f"shape {tuple(data.shape)}", source)
    if data.size == 0:
        raise InputError("data", "a non-empty 3-D array", f"shape {tuple(data.shape)}", source)
    if data.dtype.kind not in "biuf":
        raise InputError("data", "integer, float or bool voxels", f"dtype {data.dtype}", source)
    try:
        volume = Volume(
            data,
            spacing=fields.get("spacing", np.ones(3)),
            origin=fields.get("origin", np.zeros(3)),
            direction=fields.get("direction", np.eye(3)),
            is_label=bool(fields.get("is_label", False)),
        )
    except InputError as exc:  # re-raise naming the file and the file's own field
        attribute = exc.what.rpartition(".")[2]  # "Volume.spacing" -> "spacing"
        raise InputError(fields.get("field_names", {}).get(attribute, exc.what), exc.expected, exc.found,
                         source) from None
    volume.data = _deformable(volume.data, source)  # after the geometry is known good: no warning for a refusal
    return volume


def _pick_frame(fields: dict, frame: int | None, source: str) -> None:
    """Replace a 4-D ``fields["data"]`` [nx, ny, nz, n] by its frame ``frame``; refuse a 4-D
    file without ``frame`` (naming the field that made it 4-D) and a 3-D one with it."""
    data = fields["data"]
    if data.ndim == 4:
        n = data.shape[3]
        if frame is None:
            raise InputError(
                fields.get("frame_field", "data"),
                f"a 3-D volume, or load(path, frame=N) with N in 0 .. {n - 1} to read one of its {n} frames / channels",
                f"a 4-D image of shape {tuple(data.shape)}",
                source,
            )
        if frame >= n:
            raise InputError("frame", f"an index in 0 .. {n - 1} (the file has {n} frames / channels)", str(frame),
                             source)
        fields["data"] = data[..., frame].copy(order="K")  # a copy: the other frames are freed
    elif frame is not None:
        raise InputError("frame", "None (the file holds a single 3-D volume)", str(frame), source)


def _deformable(data: np.ndarray, source: str) -> np.ndarray:
    """``data`` in native byte order and one of :data:`SUPPORTED_DTYPES`; a conversion that
    changes the voxel type is announced once per call with a :class:`UserWarning`."""
    if not data.dtype.isnative:  # a byte swap: the same values
        data = data.astype(data.dtype.newbyteorder("="))
    if data.dtype in SUPPORTED_DTYPES:
        return data
    kind, before = data.dtype.kind, data.dtype.name
    target: np.dtype
    if kind == "b":
        target, why = np.dtype(np.uint8), "exact: 0 / 1"
    elif kind in "iu" and data.dtype.itemsize == 1:
        target, why = np.dtype(np.int16), "exact"
    elif kind in "iu":
        lo, hi = (int(data.min()), int(data.max()))
        if np.iinfo(np.int16).min <= lo and hi <= np.iinfo(np.int16).max:
            target, why = np.dtype(np.int16), f"exact: the values {lo} .. {hi} fit"
        elif 0 <= lo and hi <= np.iinfo(np.uint16).max:
            target, why = np.dtype(np.uint16), f"exact: the values {lo} .. {hi} fit"
        else:
            exact = max(abs(lo), abs(hi)) <= 1 << 24
            target = np.dtype(np.float32)
            why = f"the values {lo} .. {hi} exceed 16 bits; " + ("exact below 2**24" if exact else
                                                                  "rounded to 24 significant bits")
    else:
        target, why = np.dtype(np.float32), "exact" if data.dtype.itemsize < 4 else "rounded to float32 precision"
    names = ", ".join(d.name for d in SUPPORTED_DTYPES)
    warnings.warn(f"{source}: voxel type {before} converted to {target.name} ({why}); softvr deforms {names}",
                  UserWarning, stacklevel=4)
    return data.astype(target)


def _is_dicom_file(p: Path) -> bool:
    """Whether ``p`` has the DICOM Part 10 preamble ("DICM" at byte 128) or is named DICOMDIR."""
    if p.name.upper() == "DICOMDIR":
        return True
    with open(p, "rb") as f:
        return f.read(132)[128:] == b"DICM"


#: Bytes read from a stream at a time: memory grows only as real (decompressed) data arrives.
_CHUNK = 1 << 20


def _read_exact(stream, nbytes: int, what: str, source: str) -> bytearray:
    """Exactly ``nbytes`` bytes from ``stream`` (a file or a decompressing reader), read in
    chunks so that a header claiming more data than the stream holds allocates no more than
    the stream gives; an :class:`InputError` naming ``what`` when it ends early."""
    buf = bytearray()
    while len(buf) < nbytes:
        chunk = stream.read(min(_CHUNK, nbytes - len(buf)))
        if not chunk:
            raise InputError(what, f"{nbytes} bytes of voxel data", f"{len(buf)} bytes (truncated)", source)
        buf += chunk
    return buf


class _Inflated:
    """A read-only stream of the zlib- or gzip-inflated bytes of the file object ``f``
    (MetaImage ``CompressedData``): ``read(n)`` never inflates more than ``n`` bytes."""

    def __init__(self, f):
        self._f = f
        self._z = zlib.decompressobj(47)  # 32 + 15: zlib or gzip header, detected

    def read(self, n: int) -> bytes:
        out = bytearray()
        while len(out) < n and not self._z.eof:
            data = self._z.unconsumed_tail or self._f.read(1 << 20)
            if not data:
                break
            out += self._z.decompress(data, n - len(out))
        return bytes(out)


def _read_voxels(f, start: int, count: int, dtype: np.dtype, encoding: str, what: str, source: str,
                 *, skip: int = 0) -> np.ndarray:
    """``count`` voxels of ``dtype`` from the open file ``f``, starting at byte ``start``.

    ``encoding`` is ``raw`` (the file must hold them: checked before anything is
    allocated), ``gzip``, ``bzip2``, ``zlib`` (zlib or gzip stream) or ``ascii``
    (whitespace-separated numbers); ``skip`` bytes of the decoded stream are dropped first
    (NRRD ``byte skip`` after decompression; -1: the voxels are the stream's last bytes, at
    most :data:`_HEADER_BYTES` after the first). Returns a 1-D array."""
    nbytes = count * dtype.itemsize
    f.seek(start)
    if encoding == "raw":
        left = os.fstat(f.fileno()).st_size - start - skip
        if left < nbytes:
            raise InputError(what, f"{nbytes} bytes of voxel data ({count} x {dtype.name})",
                             f"{max(left, 0)} bytes in the file", source)
        f.seek(start + skip)
        return np.fromfile(f, dtype=dtype, count=count)
    if encoding == "ascii":
        left = os.fstat(f.fileno()).st_size - start
        # a number takes at least 2 characters with its separator; refuse a text that cannot hold them
        if 2 * count > left + 1:
            raise InputError(what, f"{count} numbers as text", f"{left} bytes", source)
        try:
            values = np.array(f.read().split()[:count + 1], dtype=np.float64)
        except ValueError as exc:
            raise InputError(what, f"{count} numbers as text", _describe(exc), source) from None
        if values.size != count:
            raise InputError(what, f"{count} numbers as text", f"{values.size} numbers", source)
        return values.astype(dtype)
    stream: Any = {"gzip": lambda: gzip.GzipFile(fileobj=f, mode="rb"), "bzip2": lambda: bz2.BZ2File(f, mode="rb"),
              "zlib": lambda: _Inflated(f)}[encoding]()
    try:
        if skip > 0:
            _read_exact(stream, skip, what, source)
        buf = _read_exact(stream, nbytes, what, source)
        if skip == -1:
            tail = stream.read(_HEADER_BYTES + 1)
            if len(tail) > _HEADER_BYTES:
                raise InputError("byte skip", f"-1 with at most {_HEADER_BYTES} bytes before the voxel data",
                                 "a longer stream", source)
            buf = (buf + tail)[len(tail):]
        return np.frombuffer(buf, dtype=dtype)
    except InputError:
        raise
    except (zlib.error, OSError, EOFError, ValueError) as exc:  # a corrupt compressed stream
        raise InputError(what, f"a valid {encoding} stream of voxel data", _describe(exc), source) from None


def _columns_geometry(m: np.ndarray, what: str, source: str) -> tuple[np.ndarray, np.ndarray]:
    """Split a 3x3 matrix whose columns are axis steps into (spacing [3], direction [3, 3])."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise InputError(what, "a finite 3x3 matrix", str(np.round(m, 6).tolist()), source)
    spacing = np.linalg.norm(m, axis=0)
    if np.any(spacing <= 0):
        raise InputError(what, "three non-zero axis vectors", str(np.round(m, 6).tolist()), source)
    return spacing, m / spacing


def _rescale(raw: np.ndarray, slope: float, inter: float) -> np.ndarray:
    """Apply ``raw * slope + inter``: raw dtype if identity, int16 if integral and fitting, else float32."""
    if slope == 1 and inter == 0:
        return raw
    return _rescale_values(raw.astype(np.float64) * slope + inter)


def _data_for_format(volume: Volume, fmt: str, source: str) -> np.ndarray:
    data = volume.data
    if data.dtype == np.bool_ and fmt not in ("npy", "npz"):
        return data.astype(np.uint8)
    if fmt in ("npy", "npz"):
        allowed: tuple = ()
    elif fmt == "dicom":
        allowed = _DICOM_DTYPES
    else:
        allowed = _IMAGE_DTYPES
    if allowed and data.dtype not in allowed:
        names = ", ".join(str(d) for d in allowed)
        hint = "; cast the data or use .nrrd/.nii/.mha" if fmt == "dicom" else ""
        raise InputError(
            "Volume.data dtype", f"one of bool, {names} for {_FORMAT_NAMES[fmt]}{hint}", str(data.dtype), source
        )
    return data


def _check_replaceable_dicom_folder(p: Path, source: str) -> None:
    """Refuse to delete a folder that holds anything but DICOM files."""
    import pydicom

    for f in p.iterdir():
        if f.is_dir():
            raise InputError(
                "folder", "an empty folder or one holding only a DICOM series", f"subfolder {f.name!r}", source
            )
        if f.suffix.lower() == ".dcm":
            continue
        try:
            pydicom.dcmread(f, stop_before_pixels=True)
        except Exception:
            raise InputError(
                "folder", "an empty folder or one holding only a DICOM series", f"non-DICOM file {f.name!r}", source
            ) from None


# --------------------------------------------------------------------------------------
# NRRD
# --------------------------------------------------------------------------------------


#: Largest text header read (NRRD, MetaImage) [bytes], and longest line in it.
_HEADER_BYTES = 1 << 20
_HEADER_LINE = 1 << 16

#: NRRD ``type`` names (the NRRD spec's, as pynrrd maps them) -> numpy type codes.
_NRRD_TYPES = {
    **dict.fromkeys(("signed char", "int8", "int8_t"), "i1"),
    **dict.fromkeys(("uchar", "unsigned char", "uint8", "uint8_t"), "u1"),
    **dict.fromkeys(("short", "short int", "signed short", "signed short int", "int16", "int16_t"), "i2"),
    **dict.fromkeys(("ushort", "unsigned short", "unsigned short int", "uint16", "uint16_t"), "u2"),
    **dict.fromkeys(("int", "signed int", "int32", "int32_t"), "i4"),
    **dict.fromkeys(("uint", "unsigned int", "uint32", "uint32_t"), "u4"),
    **dict.fromkeys(("longlong", "long long", "long long int", "signed long long", "signed long long int",
                     "int64", "int64_t"), "i8"),
    **dict.fromkeys(("ulonglong", "unsigned long long", "unsigned long long int", "uint64", "uint64_t"), "u8"),
    "float": "f4",
    "double": "f8",
}
_NRRD_ENCODINGS = {"raw": "raw", "gzip": "gzip", "gz": "gzip", "bzip2": "bzip2", "bz2": "bzip2",
                   "ascii": "ascii", "text": "ascii", "txt": "ascii"}


def _nrrd_header_lines(f, source: str) -> list[bytes]:
    """The lines of an NRRD header, each at most :data:`_HEADER_LINE` and all together at most
    :data:`_HEADER_BYTES` bytes; stops after the blank line that ends it (``f`` is left at
    the first data byte) or at the end of the file (a detached ``.nhdr``)."""
    lines: list[bytes] = []
    total = 0
    while True:
        line = f.readline(_HEADER_LINE)
        if not line:
            return lines
        total += len(line)
        if total > _HEADER_BYTES or (len(line) == _HEADER_LINE and not line.endswith(b"\n")):
            raise InputError("header", f"a text header of at most {_HEADER_BYTES} bytes in lines of at most "
                             f"{_HEADER_LINE}", "a longer header (binary data, or no blank line after it?)", source)
        if lines and not line.strip():
            return lines
        lines.append(line)


def _read_nrrd(p: Path) -> dict:
    source = str(p)
    with open(p, "rb") as f:
        lines = _nrrd_header_lines(f, source)
        data_start = f.tell()
        if not lines or not re.match(rb"NRRD000\d\s*$", lines[0]):
            raise InputError("magic line", "'NRRD0001' .. 'NRRD0005'", repr(lines[0][:40] if lines else b""), source)
        header = _nrrd_fields(lines, source)
        dim = header.get("dimension")
        if dim not in (3, 4):
            raise InputError("dimension", "3 (a 3-D volume) or 4 (3-D frames or channels)", repr(dim), source)
        sizes = [int(n) for n in np.asarray(header.get("sizes", []), dtype=object).reshape(-1)]
        if len(sizes) != dim or min(sizes) < 1:
            raise InputError("sizes", f"{dim} integers >= 1", repr(header.get("sizes")), source)
        count = check_count(math.prod(sizes), "sizes (number of voxels)", source)
        if header.get("type") not in _NRRD_TYPES:
            raise InputError("type", "a scalar type (" + ", ".join(sorted(set(_NRRD_TYPES))) + ")",
                             repr(header.get("type")), source)
        dtype = np.dtype(_NRRD_TYPES[header["type"]])
        encoding = _NRRD_ENCODINGS.get(str(header.get("encoding", "")).lower())
        if encoding is None:
            raise InputError("encoding", "raw, gzip, bzip2 or ascii", repr(header.get("encoding")), source)
        if dtype.itemsize > 1 and encoding != "ascii":
            endian = header.get("endian")
            if endian not in ("little", "big"):
                raise InputError("endian", "little or big", repr(endian), source)
            dtype = dtype.newbyteorder("<" if endian == "little" else ">")
        line_skip = _nrrd_skip(header, ("line skip", "lineskip"), 0, source)
        byte_skip = _nrrd_skip(header, ("byte skip", "byteskip"), 0 if encoding == "ascii" else -1, source)
        name = header.get("data file", header.get("datafile"))
        if name is None:
            data_path = p
        else:
            # "LIST" and "<format with %> <min> <max> <step>" name several files; a name may hold spaces
            if not isinstance(name, str) or name.startswith("LIST") or "%" in name:
                raise InputError("data file", "one detached data file name (LIST and name patterns are not read)",
                                 repr(name), source)
            data_path, data_start = _data_file(p, name, "data file"), 0
        with open(data_path, "rb") if data_path != p else contextlib.nullcontext(f) as g:
            g.seek(data_start)
            for _ in range(line_skip):
                while not g.readline(_HEADER_LINE).endswith(b"\n"):
                    if g.tell() >= os.fstat(g.fileno()).st_size:
                        raise InputError("line skip", f"{line_skip} lines before the data", "the end of the file",
                                         source)
            start = g.tell()
            if byte_skip == -1 and encoding == "raw":  # the data are the last bytes of the file
                start = max(os.fstat(g.fileno()).st_size - count * dtype.itemsize, start)
                byte_skip = 0
            flat = _read_voxels(g, start, count, dtype, encoding, "data", source, skip=byte_skip)
    data = flat.reshape(sizes, order="F")
    fields: dict = {"data": data, "field_names": {"spacing": "space directions / spacings",
                                                  "direction": "space directions", "origin": "space origin"}}
    sd = header.get("space directions")
    if sd is not None:
        sd = np.asarray(sd, dtype=np.float64)
        if sd.ndim != 2 or sd.shape[0] != dim:
            raise InputError("space directions", f"{dim} vectors or 'none'", str(sd.tolist()), source)
    spatial = list(range(dim))
    if dim == 4:
        kinds = header.get("kinds")
        if sd is not None:
            other = [i for i in range(dim) if not np.all(np.isfinite(sd[i]))]
        elif isinstance(kinds, list) and len(kinds) == dim:
            other = [i for i in range(dim) if str(kinds[i]).lower() not in ("domain", "space")]
        else:
            other = [3]
        if len(other) != 1:
            raise InputError("space directions / kinds", "three spatial axes and one 'none' (frame or channel) axis",
                             f"{dim - len(other)} spatial axes", source)
        spatial.remove(other[0])
        fields["data"] = np.moveaxis(data, other[0], 3)
        fields["frame_field"] = "sizes"
    if sd is not None:
        # pynrrd gives one row per axis; columns of our matrix are the axis steps.
        fields["spacing"], fields["direction"] = _columns_geometry(sd[spatial].T, "space directions", source)
    elif "spacings" in header:
        sp = np.asarray(header["spacings"], dtype=np.float64).reshape(-1)
        if sp.size != dim:
            raise InputError("spacings", f"{dim} numbers", str(sp.tolist()), source)
        sp = sp[spatial]
        fields["spacing"] = np.where(np.isfinite(sp), sp, 1.0)
    if "space origin" in header:
        fields["origin"] = np.asarray(header["space origin"], dtype=np.float64).reshape(-1)
    if _LABEL_KEY in header:
        fields["is_label"] = str(header[_LABEL_KEY]).strip().lower() in ("1", "true", "yes")
    return fields


def _nrrd_fields(lines: list[bytes], source: str) -> dict:
    """The NRRD header ``lines`` (magic line first) parsed field by field with pynrrd's
    parser, so that a value it cannot parse is reported under its field's name."""
    import nrrd

    header: dict = {}
    for line in lines[1:]:
        text = line.decode("ascii", "ignore").rstrip()
        if not text or text.startswith("#"):
            continue
        key, sep, _ = text.partition(":")
        key = key.strip()
        if not sep or not key:
            raise InputError("header", "'field: value' lines", repr(text[:60]), source)
        if key in header:
            raise InputError(key, "one line per field", "a second line", source)
        try:
            header.update(nrrd.read_header([lines[0], line]))
        except Exception as exc:  # pynrrd's parse of this one field
            raise InputError(key, "a valid NRRD value", _describe(exc), source) from None
    return header


def _nrrd_skip(header: dict, keys: tuple, lowest: int, source: str) -> int:
    value = next((header[k] for k in keys if k in header), 0)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lowest <= value <= _HEADER_BYTES:
        raise InputError(keys[0], f"an integer in {lowest} .. {_HEADER_BYTES}", repr(value), source)
    return int(value)


def _data_file(header: Path, name: str, field: str) -> Path:
    """The detached data file ``name`` of the header ``header``: inside the header's folder
    and a regular file, else an :class:`InputError` naming the header and ``field``."""
    path = inside_folder(header.parent, name, field, source=str(header))
    try:
        return checked_file(path, field)
    except InputError as exc:
        raise InputError(field, exc.expected, f"{name!r}: {exc.found}", str(header)) from None


def _write_nrrd(volume: Volume, data: np.ndarray, path: Path) -> None:
    import nrrd

    header = {
        "space dimension": 3,
        "space directions": (volume.direction * volume.spacing).T,
        "space origin": volume.origin,
        "kinds": ["domain", "domain", "domain"],
        "encoding": "gzip",
        _LABEL_KEY: "1" if volume.is_label else "0",
    }
    nrrd.write(str(path), np.asarray(data), header, index_order="F", custom_field_map={_LABEL_KEY: "string"})


# --------------------------------------------------------------------------------------
# NIfTI
# --------------------------------------------------------------------------------------


#: NIfTI ``datatype`` codes of scalar voxels (uint8, int16, int32, float32, float64, int8,
#: uint16, uint32, int64, uint64); complex and RGB images are not volumes softvr deforms.
_NIFTI_SCALAR_CODES = (2, 4, 8, 16, 64, 256, 512, 768, 1024, 1280)


def _check_nifti_header(p: Path, source: str) -> None:
    """Check the NIfTI-1 / NIfTI-2 header's ``sizeof_hdr``, ``magic``, ``datatype`` and
    ``dim`` (sizes) before nibabel sees the file."""
    opener = gzip.open if _suffix_text(p) == ".nii.gz" else open
    try:
        with opener(p, "rb") as f:
            head = f.read(540)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError("gzip stream", "a readable gzip-compressed NIfTI file", _describe(exc), source) from None
    for order in "<>":
        if len(head) >= 348 and struct.unpack(order + "i", head[:4])[0] == 348:
            magic, want = head[344:348], (b"n+1\0",)
            datatype, dims = struct.unpack(order + "h", head[70:72])[0], struct.unpack(order + "8h", head[40:56])
            break
        if len(head) >= 540 and struct.unpack(order + "i", head[:4])[0] == 540:
            magic, want = head[4:12], (b"n+2\0\r\n\x1a\n",)
            datatype, dims = struct.unpack(order + "h", head[12:14])[0], struct.unpack(order + "8q", head[16:80])
            break
    else:
        raise InputError("sizeof_hdr", "348 (NIfTI-1) or 540 (NIfTI-2)", f"{head[:4]!r} ({len(head)} header bytes)",
                         source)
    if magic not in want:
        raise InputError("magic", f"{want[0]!r} (a single-file NIfTI image)", repr(magic), source)
    if datatype not in _NIFTI_SCALAR_CODES:
        raise InputError("datatype", "a scalar voxel type code (" + ", ".join(map(str, _NIFTI_SCALAR_CODES)) + ")",
                         str(datatype), source)
    if not 1 <= dims[0] <= 7:
        raise InputError("dim[0]", "the number of dimensions, 1 .. 7", str(dims[0]), source)
    for i in range(1, dims[0] + 1):
        if dims[i] < 1:
            raise InputError(f"dim[{i}]", "a size >= 1", str(dims[i]), source)
    check_count(math.prod(dims[1:dims[0] + 1]), f"dim[1..{dims[0]}] (number of voxels)", source)


def _read_nifti(p: Path) -> dict:
    import nibabel as nib

    source = str(p)
    _check_nifti_header(p, source)
    try:
        img = nib.load(str(p))  # header only: nibabel reads no voxels until asked
    except Exception as exc:
        raise InputError("header", "a NIfTI header nibabel accepts", _describe(exc), source) from exc
    if not isinstance(img, (nib.Nifti1Image, nib.Nifti2Image)):
        raise InputError("file", "a NIfTI-1 or NIfTI-2 image", type(img).__name__, source)
    full = tuple(int(n) for n in img.shape)
    # axes beyond x, y, z that are not singletons: time (dim[4]) or components (dim[5]) ...
    extra = [i for i in range(3, len(full)) if full[i] != 1]
    if len(full) < 3 or len(extra) > 1:
        raise InputError("dim", "a 3-D volume [nx, ny, nz], or 4-D with frame=", f"shape {full}", source)
    # An ArrayProxy (offset, slope, ...): nibabel moves scl_slope/scl_inter from img.header into it.
    proxy: Any = img.dataobj
    dtype = np.dtype(img.get_data_dtype())
    count = math.prod(full)
    encoding = "gzip" if _suffix_text(p) == ".nii.gz" else "raw"
    offset = int(proxy.offset)
    if not 0 <= offset <= _HEADER_BYTES:  # the header is 348 / 540 bytes plus extensions
        raise InputError("vox_offset", f"0 .. {_HEADER_BYTES} [bytes]", str(offset), source)
    with open(p, "rb") as f:
        if encoding == "raw":
            flat = _read_voxels(f, offset, count, dtype, "raw", "vox_offset / dim (voxel data)", source)
        else:
            flat = _read_voxels(f, 0, count, dtype, "gzip", "vox_offset / dim (voxel data)", source, skip=offset)
    raw = flat.reshape(full, order="F").reshape(full[:3] + tuple(full[i] for i in extra), order="F")
    slope, inter = float(getattr(proxy, "slope", 1.0)), float(getattr(proxy, "inter", 0.0))
    if not np.isfinite(slope) or slope == 0:
        slope = 1.0
    if not np.isfinite(inter):
        inter = 0.0
    fields: dict = {"data": _rescale(raw, slope, inter)}
    if extra:
        fields["frame_field"] = f"dim[{extra[0] + 1}]"
    affine = np.asarray(img.affine, dtype=np.float64)
    fields["spacing"], fields["direction"] = _columns_geometry(affine[:3, :3], "affine", source)
    fields["field_names"] = dict.fromkeys(("spacing", "direction", "origin"), "affine (sform / qform)")
    fields["origin"] = affine[:3, 3]
    if img.header.get_intent()[0] == "label":
        fields["is_label"] = True
    return fields


def _write_nifti(volume: Volume, data: np.ndarray, path: Path) -> None:
    import nibabel as nib

    affine = np.eye(4)
    affine[:3, :3] = volume.direction * volume.spacing
    affine[:3, 3] = volume.origin
    img = nib.Nifti1Image(np.asarray(data), affine, dtype=data.dtype)
    img.set_sform(affine, code=1)
    img.set_qform(affine, code=1)
    if volume.is_label:
        img.header.set_intent("label")
    nib.save(img, str(path))


# --------------------------------------------------------------------------------------
# MetaImage (SimpleITK)
# --------------------------------------------------------------------------------------


#: MetaImage ``ElementType`` -> numpy type code (MetaIO's sizes: MET_LONG is 4 bytes).
_MET_TYPES = {"MET_CHAR": "i1", "MET_UCHAR": "u1", "MET_SHORT": "i2", "MET_USHORT": "u2", "MET_INT": "i4",
              "MET_UINT": "u4", "MET_LONG": "i4", "MET_ULONG": "u4", "MET_LONG_LONG": "i8", "MET_ULONG_LONG": "u8",
              "MET_FLOAT": "f4", "MET_DOUBLE": "f8"}


def _read_metaimage(p: Path) -> dict:
    """Read a MetaImage (``.mha`` / ``.mhd``) with softvr's own bounded header parser.

    The header is ``Key = Value`` lines ending with ``ElementDataFile``: ``LOCAL`` (the
    voxels follow the header) or one file name inside the header's folder; ``LIST`` and
    name patterns are refused. ``TransformMatrix`` row ``i`` is the world direction of axis
    ``i`` (as ITK reads it), so it is our ``direction`` transposed."""
    source = str(p)
    with open(p, "rb") as f:
        h: dict = {}
        total = 0
        while "ElementDataFile" not in h:
            line = f.readline(_HEADER_LINE)
            total += len(line)
            if not line:
                raise InputError("ElementDataFile", "a MetaImage text header ending with 'ElementDataFile = ...'",
                                 "the end of the file", source)
            if total > _HEADER_BYTES or (len(line) == _HEADER_LINE and not line.endswith(b"\n")):
                raise InputError("header", f"a text header of at most {_HEADER_BYTES} bytes", "a longer one", source)
            text = line.decode("latin-1").strip()
            if not text:
                continue
            key, eq, value = text.partition("=")
            if not eq or not re.fullmatch(r"[A-Za-z_]\w*", key.strip()):
                raise InputError("header", "a MetaImage text header of 'Key = Value' lines ('NDims = 3', ...)",
                                 repr(text[:60]), source)
            key = key.strip()
            if key in h:
                raise InputError(key, "one line per field", "a second line", source)
            h[key] = value.strip()
        data_start = f.tell()
        if h.get("ObjectType", "Image") != "Image":
            raise InputError("ObjectType", "Image", repr(h["ObjectType"]), source)
        ndims = _met_ints(h, "NDims", 1, source, low=1)[0]
        if ndims not in (3, 4):
            raise InputError("NDims", "3 (a 3-D image) or 4 (3-D frames)", str(ndims), source)
        sizes = _met_ints(h, "DimSize", ndims, source, low=1)
        channels = _met_ints(h, "ElementNumberOfChannels", 1, source, low=1, default="1")[0]
        if channels > 1 and ndims == 4:
            raise InputError("ElementNumberOfChannels", "1 for a 4-D image", str(channels), source)
        count = check_count(math.prod(sizes) * channels, "DimSize x ElementNumberOfChannels (number of voxels)",
                            source)
        if h.get("ElementType") not in _MET_TYPES:
            raise InputError("ElementType", "one of " + ", ".join(_MET_TYPES), repr(h.get("ElementType")), source)
        msb = _met_bool(h, ("BinaryDataByteOrderMSB", "ElementByteOrderMSB"), source)
        dtype = np.dtype(_MET_TYPES[h["ElementType"]]).newbyteorder(">" if msb else "<")
        if not _met_bool(h, ("BinaryData",), source, default=True):
            raise InputError("BinaryData", "True (binary voxel data)", repr(h["BinaryData"]), source)
        compressed = _met_bool(h, ("CompressedData",), source)
        header_size = _met_ints(h, "HeaderSize", 1, source, low=-1, default="0")[0]
        name = h["ElementDataFile"]
        if name == "LOCAL":
            data_path = p
        elif name.startswith("LIST") or "%" in name:  # several files; a single name may hold spaces
            raise InputError("ElementDataFile", "LOCAL or one data file name (LIST and name patterns are not read)",
                             repr(name), source)
        else:
            data_path, data_start = _data_file(p, name, "ElementDataFile"), 0
        with open(data_path, "rb") if data_path != p else contextlib.nullcontext(f) as g:
            if header_size == -1:
                if compressed:
                    raise InputError("HeaderSize", ">= 0 with CompressedData = True", "-1", source)
                data_start = max(os.fstat(g.fileno()).st_size - count * dtype.itemsize, data_start)
            elif data_path != p:
                data_start = header_size
            flat = _read_voxels(g, data_start, count, dtype, "zlib" if compressed else "raw", "ElementDataFile",
                                source)
    spacing = _met_floats(h, "ElementSpacing" if "ElementSpacing" in h else "ElementSize", ndims, source,
                          default=[1.0] * ndims)
    origin_key = next((k for k in ("Offset", "Origin", "Position") if k in h), "Offset")
    origin = _met_floats(h, origin_key, ndims, source, default=[0.0] * ndims)
    matrix_key = next((k for k in ("TransformMatrix", "Rotation", "Orientation") if k in h), "TransformMatrix")
    matrix = np.asarray(_met_floats(h, matrix_key, ndims * ndims, source,
                                    default=np.eye(ndims).reshape(-1))).reshape(ndims, ndims)
    if channels > 1:  # channels vary fastest: [c, x, y, z] -> [x, y, z, c]
        data = np.moveaxis(flat.reshape([channels] + sizes, order="F"), 0, 3)
        frame_field = "ElementNumberOfChannels"
    else:
        data = flat.reshape(sizes, order="F")
        frame_field = "DimSize"
    if min(spacing[:3]) <= 0:
        raise InputError("ElementSpacing", "three values > 0", str(spacing[:3]), source)
    fields: dict = {
        "data": data,
        "frame_field": frame_field,
        "spacing": np.asarray(spacing[:3]),
        "origin": np.asarray(origin[:3]),
        "direction": matrix[:3, :3].T,
        "field_names": {"spacing": "ElementSpacing", "direction": matrix_key, "origin": origin_key},
    }
    if _LABEL_KEY in h:
        fields["is_label"] = h[_LABEL_KEY].strip().lower() in ("1", "true", "yes")
    return fields


def _met_ints(h: dict, key: str, n: int, source: str, *, low: int, default: str | None = None) -> list[int]:
    text = h.get(key, default)
    words = [] if text is None else text.split()
    if len(words) != n or not all(re.fullmatch(r"[+-]?\d{1,18}", w) for w in words) \
            or min(int(w) for w in words) < low:
        raise InputError(key, f"{n} integer(s) >= {low}", repr(text) if text is not None else "nothing", source)
    return [int(w) for w in words]


def _met_floats(h: dict, key: str, n: int, source: str, *, default) -> list[float]:
    if key not in h:
        return [float(v) for v in default]
    words = h[key].split()
    try:
        values = [float(w) for w in words]
    except ValueError:
        values = []
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise InputError(key, f"{n} finite numbers", repr(h[key][:80]), source)
    return values


def _met_bool(h: dict, keys: tuple, source: str, *, default: bool = False) -> bool:
    key = next((k for k in keys if k in h), None)
    if key is None:
        return default
    if h[key].lower() not in ("true", "false", "1", "0"):
        raise InputError(key, "True or False", repr(h[key][:40]), source)
    return h[key].lower() in ("true", "1")


def _write_metaimage(volume: Volume, data: np.ndarray, path: Path) -> None:
    import SimpleITK as sitk

    img = sitk.GetImageFromArray(np.ascontiguousarray(np.asarray(data).transpose(2, 1, 0)), isVector=False)
    img.SetSpacing([float(v) for v in volume.spacing])
    img.SetOrigin([float(v) for v in volume.origin])
    img.SetDirection([float(v) for v in volume.direction.reshape(-1)])
    img.SetMetaData(_LABEL_KEY, "1" if volume.is_label else "0")
    writer = sitk.ImageFileWriter()
    writer.SetImageIO("MetaImageIO")
    writer.SetFileName(str(path))
    writer.UseCompressionOff()
    writer.Execute(img)


# --------------------------------------------------------------------------------------
# NumPy
# --------------------------------------------------------------------------------------


def _check_magic(p: Path, magic: bytes, expected: str) -> None:
    with open(p, "rb") as f:
        head = f.read(len(magic))
    if head != magic:
        raise InputError("file signature", f"{expected} (starting {magic!r})", f"{head!r}", str(p))


def _archive(open_archive, what: str, source: str):
    """``open_archive()`` (a zip or tar file), its errors an :class:`InputError` naming ``what``."""
    try:
        return open_archive()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, tarfile.TarError, OSError, EOFError, zlib.error) as exc:
        raise InputError(what, "a readable archive (zip / tar.gz)", _describe(exc), source) from None


def _npy_header(f, what: str, source: str) -> tuple[tuple, bool, np.dtype, int]:
    """(shape, fortran_order, dtype, count) of the ``.npy`` stream ``f`` (left at its first
    data byte), checked: a plain numeric dtype and at most ``MAX_ELEMENTS`` elements."""
    try:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            raise ValueError(f"format version {version} (1.0 and 2.0 are read)")
    except Exception as exc:  # numpy's literal_eval of the header: ValueError, SyntaxError, TokenError, ...
        raise InputError(what, "a NumPy .npy header", _describe(exc), source) from None
    if dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None:
        raise InputError(f"{what} descr", "a plain numeric dtype", str(dtype), source)
    if any(n < 0 for n in shape):
        raise InputError(f"{what} shape", "sizes >= 0", str(shape), source)
    count = check_count(math.prod(shape), f"{what} shape (number of elements)", source)
    return shape, fortran, dtype, count


def _npy_array(f, what: str, source: str) -> np.ndarray:
    """The array of the ``.npy`` stream ``f``, read in bounded chunks after its header was checked."""
    shape, fortran, dtype, count = _npy_header(f, what, source)
    flat = np.frombuffer(_read_exact(f, count * dtype.itemsize, what, source), dtype=dtype)
    return flat.reshape(shape, order="F" if fortran else "C")


def _read_npy(p: Path) -> dict:
    _check_magic(p, b"\x93NUMPY", "a NumPy .npy file")
    source = str(p)
    with open(p, "rb") as f:
        shape, fortran, dtype, count = _npy_header(f, "header", source)
        flat = _read_voxels(f, f.tell(), count, dtype, "raw", "data", source)
    return {"data": flat.reshape(shape, order="F" if fortran else "C")}


def _read_npz(p: Path) -> dict:
    source = str(p)
    _check_magic(p, b"PK", "a NumPy .npz (zip) file")
    with _archive(lambda: zipfile.ZipFile(p), "zip directory", source) as z:
        members = {name[:-4]: name for name in z.namelist() if name.endswith(".npy")}
        keys = list(members)
        if "data" not in members:
            raise InputError("key 'data'", "an array named 'data'", f"keys {keys[:20]}", source)
        fields: dict = {"field_names": {k: f"key {k!r}" for k in ("spacing", "origin", "direction")}}
        for key in ("data", "spacing", "origin", "direction", "is_label"):
            if key in members:
                with _archive(lambda: z.open(members[key]), f"key {key!r}", source) as f:
                    if key != "data":  # small metadata: refuse a huge claim before reading it
                        shape = _npy_header(f, f"key {key!r}", source)[0]
                        if math.prod(shape) > 9:
                            raise InputError(f"key {key!r}", "at most 9 numbers", f"shape {shape}", source)
                        f.seek(0)
                    fields[key] = _npy_array(f, f"key {key!r}", source)
    if "is_label" in fields:
        flag = fields["is_label"]
        if flag.size != 1:
            raise InputError("key 'is_label'", "a single boolean", f"shape {flag.shape}", source)
        fields["is_label"] = bool(flag.reshape(-1)[0])
    for key in ("spacing", "origin"):
        if key in fields and fields[key].size != 3:
            raise InputError(f"key {key!r}", "three numbers", f"shape {fields[key].shape}", source)
    if "direction" in fields:
        if fields["direction"].size != 9:
            raise InputError("key 'direction'", "a 3x3 matrix", f"shape {fields['direction'].shape}", source)
        fields["direction"] = fields["direction"].reshape(3, 3)
    return fields


def _write_npy(volume: Volume, data: np.ndarray, path: Path) -> None:
    with open(path, "wb") as f:
        np.save(f, data, allow_pickle=False)


def _write_npz(volume: Volume, data: np.ndarray, path: Path) -> None:
    with open(path, "wb") as f:
        np.savez(
            f,
            data=data,
            spacing=volume.spacing,
            origin=volume.origin,
            direction=volume.direction,
            is_label=np.bool_(volume.is_label),
        )


# --------------------------------------------------------------------------------------
# InVesalius 3 project (.inv3): a tar.gz of plists and raw arrays
# --------------------------------------------------------------------------------------


def _read_inv3(p: Path) -> dict:
    source = str(p)
    with _archive(lambda: tarfile.open(p, "r:gz"), "tar.gz archive", source) as tar:
        try:
            members = [m for m in tar.getmembers() if m.isfile()]
        except (tarfile.TarError, OSError, EOFError, zlib.error) as exc:
            raise InputError("tar.gz archive", "a readable tar.gz archive", _describe(exc), source) from None
        mains = sorted(
            (m for m in members if PurePosixPath(m.name).name == "main.plist"),
            key=lambda m: len(PurePosixPath(m.name).parts),
        )
        if not mains:
            names = [m.name for m in members][:10]
            raise InputError("main.plist", "an InVesalius project holding main.plist", f"members {names}", source)
        main = mains[0]
        if main.size > _HEADER_BYTES:
            raise InputError(main.name, f"a property list of at most {_HEADER_BYTES} bytes", f"{main.size} bytes",
                             source)
        try:
            plist = plistlib.loads(tar.extractfile(main).read(_HEADER_BYTES))
        except Exception as exc:  # plistlib: InvalidFileException, ExpatError, ...
            raise InputError(main.name, "a property list", _describe(exc), source) from None
        matrix = plist.get("matrix")
        if not isinstance(matrix, dict):
            raise InputError(f"{main.name}: matrix", "a dict with filename, shape, dtype", repr(matrix), source)
        shape = matrix.get("shape")
        if (
            not isinstance(shape, (list, tuple))
            or len(shape) != 3
            or not all(isinstance(n, int) and n > 0 for n in shape)
        ):
            raise InputError(f"{main.name}: matrix/shape", "three positive integers [nz, ny, nx]", repr(shape), source)
        try:
            dtype = np.dtype(str(matrix.get("dtype", "int16"))).newbyteorder("<")
        except TypeError:
            dtype = None
        if dtype is None or dtype.kind not in "biuf" or dtype.subdtype is not None:
            raise InputError(f"{main.name}: matrix/dtype", "a numeric numpy dtype name", repr(matrix.get("dtype")),
                             source)
        spacing = plist.get("spacing")
        if not isinstance(spacing, (list, tuple)) or len(spacing) != 3:
            raise InputError(f"{main.name}: spacing", "three numbers (x, y, z) [mm]", repr(spacing), source)
        filename = str(matrix.get("filename", "matrix.dat"))
        want = str(PurePosixPath(main.name).parent / filename) if PurePosixPath(main.name).parent.parts else filename
        found = [m for m in members if m.name == want]
        if not found:
            raise InputError(filename, f"a member {want!r} named by {main.name}", "no such member", source)
        member = found[0]
        count = check_count(math.prod(shape), f"{main.name}: matrix/shape (number of voxels)", source)
        nbytes = count * dtype.itemsize
        if member.size != nbytes:
            raise InputError(
                member.name,
                f"{nbytes} bytes ({'x'.join(map(str, shape))} {dtype.name})",
                f"{member.size} bytes",
                source,
            )
        arr = np.frombuffer(_read_exact(tar.extractfile(member), nbytes, member.name, source), dtype=dtype)
    # InVesalius stores the matrix [z, y, x] (slice, row, column) and the spacing (x, y, z).
    return {
        "data": arr.reshape(shape).transpose(2, 1, 0),
        "spacing": np.asarray(spacing, dtype=np.float64),
        "origin": np.zeros(3),
        "direction": np.eye(3),
        "field_names": {"spacing": f"{main.name}: spacing"},
    }


# --------------------------------------------------------------------------------------
# DICOM series
# --------------------------------------------------------------------------------------


def _read_dicom(p: Path, series: int | str | None) -> dict:
    """A volume from a DICOM folder, a DICOMDIR or one (single- or multi-frame) file."""
    source = str(p)
    if p.is_dir():
        files = [f for f in sorted(p.iterdir()) if not f.name.startswith(".") and f.is_file()]
        check_count(len(files), "number of files in the folder", source)
        images = _dicom_images(files, strict=False)
        dicomdir = p / "DICOMDIR"
        if not images and dicomdir.is_file():
            return _read_dicom(dicomdir, series)
        if not images:
            raise InputError("folder", "DICOM image files (one slice per file)", "no DICOM slices", source)
    else:
        ds = _dcmread(p, stop_before_pixels=True)
        if "DirectoryRecordSequence" in ds:
            images = _dicom_images(_dicomdir_files(p, ds), strict=True)
            if not images:
                raise InputError("DirectoryRecordSequence", "IMAGE records of DICOM images", "none", source)
        elif "Rows" in ds and "Columns" in ds:
            images = [(p, ds)]
        else:
            raise InputError("Rows / Columns", "a DICOM image", "a DICOM file without an image", source)
    slices = _pick_series(images, series, source)
    full = [(f, _dcmread(f, stop_before_pixels=False)) for f, _ in slices]
    if len(full) == 1 and int(full[0][1].get("NumberOfFrames", 1) or 1) > 1:
        return _dicom_multiframe(*full[0])
    return _dicom_slices(full, source)


def _dcmread(f: Path, *, stop_before_pixels: bool):
    import pydicom

    try:
        return pydicom.dcmread(checked_file(f, "file"), stop_before_pixels=stop_before_pixels)
    except InputError:
        raise
    except Exception as exc:
        raise InputError("DICOM header", "readable DICOM data elements", _describe(exc), str(f)) from exc


def _dicom_images(files: list[Path], *, strict: bool) -> list:
    """(file, header) of the DICOM images among ``files`` (pixel data not read). With
    ``strict`` False (a folder), files that are not DICOM are skipped, except ``*.dcm``."""
    import pydicom
    from pydicom.errors import InvalidDicomError

    images = []
    for f in files:
        if not strict and f.suffix.lower() != ".dcm":
            try:
                ds = pydicom.dcmread(checked_file(f, "file"), stop_before_pixels=True)
            except (InvalidDicomError, EOFError, OSError, InputError):
                continue  # not a DICOM file (README.txt, a thumbnail, a FIFO, ...): skip it
            except Exception as exc:
                raise InputError("DICOM header", "readable DICOM data elements", _describe(exc), str(f)) from exc
        else:
            ds = _dcmread(f, stop_before_pixels=True)
        if "Rows" in ds and "Columns" in ds:  # not a DICOMDIR, structured report, ...
            images.append((f, ds))
    return images


def _dicomdir_files(p: Path, ds) -> list[Path]:
    """The image files a DICOMDIR ``ds`` (read from ``p``) refers to, each inside its folder."""
    files = []
    for i, record in enumerate(ds.DirectoryRecordSequence):
        if record.get("DirectoryRecordType") != "IMAGE" or "ReferencedFileID" not in record:
            continue
        parts = record.ReferencedFileID
        name = "/".join([parts] if isinstance(parts, str) else [str(x) for x in parts])
        files.append(_data_file(p, name, f"DirectoryRecordSequence[{i}].ReferencedFileID"))
    check_count(len(files), "number of IMAGE records", str(p))
    return files


def _pick_series(images: list, series: int | str | None, source: str) -> list:
    """The (file, header) pairs of one series: the only one, or the one ``series`` names."""
    groups: dict = {}
    for f, ds in images:
        groups.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append((f, ds))

    def number(uid):
        value = groups[uid][0][1].get("SeriesNumber")
        return (int(value) if isinstance(value, int) or str(value).strip().isdigit() else 1 << 62, uid)

    uids = sorted(groups, key=number)
    if series is None and len(uids) == 1:
        return groups[uids[0]]
    if isinstance(series, str) and series in groups:
        return groups[series]
    if isinstance(series, (int, np.integer)) and not isinstance(series, bool) and series < len(uids):
        return groups[uids[int(series)]]
    listing = []
    for i, uid in enumerate(uids[:20]):
        ds = groups[uid][0][1]
        desc = str(ds.get("SeriesDescription", "")).strip()
        listing.append(f"[{i}] {uid or '<no SeriesInstanceUID>'} (SeriesNumber {ds.get('SeriesNumber', '-')}, "
                       f"{ds.get('Modality', '?')}{', ' + repr(desc) if desc else ''}, {len(groups[uid])} files)")
    more = f"; and {len(uids) - 20} more" if len(uids) > 20 else ""
    if series is None:
        what, expected = "SeriesInstanceUID", "one series, or load(path, series=N) with N an index or a UID below"
    else:
        what, expected = "series", "an index or a SeriesInstanceUID from the list"
    found = f"{len(uids)} series: " + "; ".join(listing) + more
    if series is not None:
        found = f"{series!r}; the {found}"
    raise InputError(what, expected, found, source)


def _vec(ds, key: str, n: int, default):
    """``ds[key]`` as ``n`` floats, or ``default`` (None: no default) when it is missing or malformed."""
    v = ds.get(key)
    try:
        values = None if v is None or len(v) != n else [float(x) for x in v]
    except (TypeError, ValueError):
        values = None
    if values is None or not all(math.isfinite(x) for x in values):
        return None if default is None else np.asarray(default, dtype=np.float64)
    return np.asarray(values, dtype=np.float64)


def _slice_order(positions: list, normal: np.ndarray, names: list[str], thickness: float, source: str):
    """(order, step along ``normal``, origin) of slices at ``positions`` [3] (None: unknown)."""
    if len(positions) > 1 and all(pos is not None for pos in positions):
        dist = np.array([float(pos @ normal) for pos in positions])
        order = np.argsort(dist, kind="stable")
        dist = dist[order]
        steps = np.diff(dist)
        if np.any(steps <= 1e-6 * max(1.0, float(np.abs(dist).max()))):
            k = int(np.argmin(steps))
            raise InputError(
                "ImagePositionPatient",
                "one slice per position along the slice normal (a time series or two series mixed?)",
                f"two slices at {dist[k]:.6g} ({names[order[k]]}, {names[order[k + 1]]})",
                source,
            )
        dz = (dist[-1] - dist[0]) / len(steps)
        if np.max(np.abs(steps - dz)) > 1e-3 * dz + 1e-4:
            raise InputError(
                "ImagePositionPatient",
                "uniformly spaced slices (missing slices, or a localizer: load another series, series=)",
                f"slice steps from {steps.min():.6g} to {steps.max():.6g}",
                source,
            )
        return order, dz, positions[order[0]]
    order = np.arange(len(positions))
    return order, thickness, positions[0] if positions[0] is not None else np.zeros(3)


def _check_image(ds, f: Path, frames: int) -> None:
    if int(ds.get("SamplesPerPixel", 1) or 1) != 1:
        raise InputError("SamplesPerPixel", "1 (grey-scale; convert a colour image to grey-scale first)",
                         str(ds.SamplesPerPixel), str(f))
    check_count(int(ds.Rows) * int(ds.Columns) * frames, "Rows x Columns x NumberOfFrames (number of voxels)",
                str(f))


def _pixels(ds, f: Path) -> np.ndarray:
    try:
        return ds.pixel_array
    except Exception as exc:
        raise InputError("PixelData", "decodable pixel data", _describe(exc), str(f)) from exc


def _slope_intercept(ds) -> tuple[float, float]:
    slope = float(ds.get("RescaleSlope", ds.get("DoseGridScaling", 1)) or 1)
    inter = float(ds.get("RescaleIntercept", 0) or 0)
    return (slope, inter) if math.isfinite(slope) and math.isfinite(inter) else (1.0, 0.0)


def _dicom_slices(slices: list, source: str) -> dict:
    """One volume from single-frame images of one series (one file per slice)."""
    f0, ds0 = slices[0]
    rows, cols = int(ds0.Rows), int(ds0.Columns)
    check_count(rows * cols * len(slices), "Rows x Columns x number of slices", source)
    for f, ds in slices:
        if int(ds.get("NumberOfFrames", 1) or 1) != 1:
            raise InputError("NumberOfFrames", "single-frame slices (or one multi-frame file)",
                             str(ds.NumberOfFrames), str(f))
        _check_image(ds, f, 1)
        if (int(ds.Rows), int(ds.Columns)) != (rows, cols):
            raise InputError(
                "Rows x Columns",
                f"{rows} x {cols} as in {f0.name} (consistent slice sizes)",
                f"{int(ds.Rows)} x {int(ds.Columns)}",
                str(f),
            )
    iop = _vec(ds0, "ImageOrientationPatient", 6, [1, 0, 0, 0, 1, 0])
    ps = _vec(ds0, "PixelSpacing", 2, [1, 1])
    for f, ds in slices[1:]:
        o = _vec(ds, "ImageOrientationPatient", 6, [1, 0, 0, 0, 1, 0])
        if not np.allclose(o, iop, atol=1e-4):
            raise InputError(
                "ImageOrientationPatient",
                f"{iop.tolist()} as in {f0.name} (one orientation; a localizer mixes them: load another series)",
                str(o.tolist()), str(f)
            )
        sp = _vec(ds, "PixelSpacing", 2, [1, 1])
        if not np.allclose(sp, ps, rtol=1e-4):
            raise InputError("PixelSpacing", f"{ps.tolist()} as in {f0.name}", str(sp.tolist()), str(f))
    row_dir, col_dir = iop[:3], iop[3:]
    normal = _normal(row_dir, col_dir, str(f0))
    positions = [_vec(ds, "ImagePositionPatient", 3, None) for _, ds in slices]
    if not all(pos is not None for pos in positions):  # no geometry: InstanceNumber order
        numbers = [ds.get("InstanceNumber", i) for i, (_, ds) in enumerate(slices)]
        keys = [int(n) if str(n).strip().lstrip("-").isdigit() else i for i, n in enumerate(numbers)]
        slices = [slices[i] for i in np.argsort(keys, kind="stable")]
        positions = [_vec(slices[0][1], "ImagePositionPatient", 3, [0, 0, 0])] + [None] * (len(slices) - 1)
    order, dz, origin = _slice_order(positions, normal, [f.name for f, _ in slices], _slice_thickness(ds0), source)
    ordered = [slices[i] for i in order]
    raws = [(_pixels(ds, f), *_slope_intercept(ds)) for f, ds in ordered]
    if all(s == 1 and i == 0 for _, s, i in raws):
        vol = np.stack([a for a, _, _ in raws], axis=-1)  # [rows=y, cols=x, z]
    else:
        vol = _rescale_values(np.stack([a.astype(np.float64) * s + i for a, s, i in raws], axis=-1))
    return {
        "data": vol.transpose(1, 0, 2),  # [x, y, z]
        # PixelSpacing = (row spacing: between rows, along y; column spacing: along x)
        "spacing": np.array([ps[1], ps[0], dz], dtype=np.float64),
        "origin": origin,
        "direction": np.column_stack([row_dir, col_dir, normal]),
        "field_names": {"spacing": "PixelSpacing / slice positions", "direction": "ImageOrientationPatient",
                        "origin": "ImagePositionPatient"},
    }


def _normal(row_dir: np.ndarray, col_dir: np.ndarray, source: str) -> np.ndarray:
    normal = np.cross(row_dir, col_dir)
    length = float(np.linalg.norm(normal))
    if not length > 1e-6:
        raise InputError("ImageOrientationPatient", "two perpendicular unit vectors",
                         str(np.concatenate([row_dir, col_dir]).tolist()), source)
    return normal / length


def _dicom_multiframe(f: Path, ds) -> dict:
    """One volume from a multi-frame image whose frames are slices (RT dose, enhanced CT/MR)."""
    source = str(f)
    n = int(ds.NumberOfFrames)
    _check_image(ds, f, n)
    shared = ds.get("SharedFunctionalGroupsSequence")
    group = shared[0] if shared else None

    def functional(sequence: str, key: str, size: int, default):
        if key in ds:
            return _vec(ds, key, size, default)
        if group is not None and sequence in group and len(group[sequence]):
            return _vec(group[sequence][0], key, size, default)
        return None if default is None else np.asarray(default, dtype=np.float64)

    iop = functional("PlaneOrientationSequence", "ImageOrientationPatient", 6, [1, 0, 0, 0, 1, 0])
    ps = functional("PixelMeasuresSequence", "PixelSpacing", 2, [1, 1])
    normal = _normal(iop[:3], iop[3:], source)
    first = _vec(ds, "ImagePositionPatient", 3, None)
    offsets = _vec(ds, "GridFrameOffsetVector", n, None) if "GridFrameOffsetVector" in ds else None
    per_frame = ds.get("PerFrameFunctionalGroupsSequence")
    # RT dose: offsets along the normal, relative to the first frame (whose offset is 0, or its z)
    if first is not None and offsets is not None:
        positions = [first + normal * (o - offsets[0]) for o in offsets]
    elif per_frame is not None and len(per_frame) == n:
        positions = [_vec(g.PlanePositionSequence[0], "ImagePositionPatient", 3, None)
                     if "PlanePositionSequence" in g and len(g.PlanePositionSequence) else None for g in per_frame]
    else:
        positions = [first] + [None] * (n - 1)
    thickness = float(functional("PixelMeasuresSequence", "SliceThickness", 1, [_slice_thickness(ds)])[0])
    order, dz, origin = _slice_order(positions, normal, [f"frame {i + 1}" for i in range(n)],
                                     thickness if thickness > 0 else 1.0, source)
    arr = _pixels(ds, f)  # [frames, rows, cols]
    if arr.shape != (n, int(ds.Rows), int(ds.Columns)):
        raise InputError("PixelData", f"{n} frames of {int(ds.Rows)} x {int(ds.Columns)}",
                         f"an array of shape {arr.shape}", source)
    slope, inter = _slope_intercept(ds)
    data = _rescale(arr[order], slope, inter)
    return {
        "data": data.transpose(2, 1, 0),  # [x = cols, y = rows, z = frames]
        "spacing": np.array([ps[1], ps[0], dz], dtype=np.float64),
        "origin": origin,
        "direction": np.column_stack([iop[:3], iop[3:], normal]),
        "field_names": {"spacing": "PixelSpacing / slice positions", "direction": "ImageOrientationPatient",
                        "origin": "ImagePositionPatient"},
    }


def _rescale_values(vals: np.ndarray) -> np.ndarray:
    """float64 values -> int16 when all integral and fitting, else float32."""
    if vals.size and np.all(np.isfinite(vals)) and np.all(vals == np.round(vals)):
        if vals.min() >= np.iinfo(np.int16).min and vals.max() <= np.iinfo(np.int16).max:
            return vals.astype(np.int16)
    return vals.astype(np.float32)


def _slice_thickness(ds) -> float:
    for key in ("SpacingBetweenSlices", "SliceThickness"):
        v = ds.get(key)
        if v is not None and v != "" and float(v) > 0:
            return float(v)
    return 1.0


def _write_dicom(volume: Volume, data: np.ndarray, folder: Path) -> None:
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, SecondaryCaptureImageStorage, generate_uid
    from pydicom.valuerep import format_number_as_ds

    def ds_str(x: float) -> str:
        return format_number_as_ds(float(x) + 0.0)

    direction = volume.direction.copy()
    origin = volume.origin.copy()
    spacing = volume.spacing
    data = np.asarray(data)
    if np.linalg.det(direction) < 0:  # the slice normal is row x column: reverse k
        origin = origin + direction[:, 2] * spacing[2] * (data.shape[2] - 1)
        direction[:, 2] = -direction[:, 2]
        data = data[:, :, ::-1]
    dt = data.dtype
    bits = dt.itemsize * 8
    study, series, frame = generate_uid(), generate_uid(), generate_uid()
    now = datetime.datetime.now()
    for k in range(data.shape[2]):
        sop = generate_uid()
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = SecondaryCaptureImageStorage
        meta.MediaStorageSOPInstanceUID = sop
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = Dataset()
        ds.file_meta = meta
        ds.SOPClassUID = SecondaryCaptureImageStorage
        ds.SOPInstanceUID = sop
        ds.StudyInstanceUID = study
        ds.SeriesInstanceUID = series
        ds.FrameOfReferenceUID = frame
        ds.Modality = "OT"
        ds.ConversionType = "WSD"
        ds.PatientName = "softvr"
        ds.PatientID = "softvr"
        ds.StudyDate = ds.SeriesDate = now.strftime("%Y%m%d")
        ds.StudyTime = ds.SeriesTime = now.strftime("%H%M%S")
        ds.SeriesDescription = "written by softvr"
        ds.SeriesNumber = 1
        ds.InstanceNumber = k + 1
        pos = origin + direction[:, 2] * spacing[2] * k
        ds.ImagePositionPatient = [ds_str(v) for v in pos]
        ds.ImageOrientationPatient = [ds_str(v) for v in np.concatenate([direction[:, 0], direction[:, 1]])]
        ds.PixelSpacing = [ds_str(spacing[1]), ds_str(spacing[0])]
        ds.SliceThickness = ds_str(spacing[2])
        ds.SpacingBetweenSlices = ds_str(spacing[2])
        ds.SamplesPerPixel = 1
        ds.PhotometricInterpretation = "MONOCHROME2"
        ds.Rows = int(data.shape[1])
        ds.Columns = int(data.shape[0])
        ds.BitsAllocated = bits
        ds.BitsStored = bits
        ds.HighBit = bits - 1
        ds.PixelRepresentation = 1 if dt.kind == "i" else 0
        ds.RescaleIntercept = "0"
        ds.RescaleSlope = "1"
        ds.RescaleType = "US"
        plane = np.ascontiguousarray(data[:, :, k].T).astype(dt.newbyteorder("<"), copy=False)
        ds.PixelData = plane.tobytes()
        ds.save_as(folder / f"slice_{k:04d}.dcm", enforce_file_format=True)


_READERS = {
    "nrrd": _read_nrrd,
    "nifti": _read_nifti,
    "metaimage": _read_metaimage,
    "npy": _read_npy,
    "npz": _read_npz,
    "inv3": _read_inv3,
}


class _WriterTable(dict):
    """Looks writers up by name at call time (so tests can monkeypatch ``_write_*``)."""

    def __getitem__(self, fmt: str):
        return globals()[dict.__getitem__(self, fmt)]


_WRITERS = _WriterTable(
    nrrd="_write_nrrd",
    nifti="_write_nifti",
    metaimage="_write_metaimage",
    npy="_write_npy",
    npz="_write_npz",
)
