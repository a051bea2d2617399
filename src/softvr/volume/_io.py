"""Reading and writing :class:`~softvr.volume.Volume` files.

The format is chosen from the file name:

========================  ======  ======  ==============================================
suffix                    load    save    library, notes
========================  ======  ======  ==============================================
``.nrrd``, ``.nhdr``      yes     yes     pynrrd; ``.nhdr`` has a detached ``.raw.gz``
``.nii``, ``.nii.gz``     yes     yes     nibabel
``.mha``, ``.mhd``        yes     yes     SimpleITK (MetaImage); ``.mhd`` has a ``.raw``
``.npy``                  yes     yes     numpy; data only (spacing 1, origin 0)
``.npz``                  yes     yes     numpy; keys ``data`` [+ ``spacing``, ``origin``,
                                          ``direction``, ``is_label``]
``.inv3``                 yes     no      InVesalius 3 project (tar.gz + plists)
a folder                  yes     yes     DICOM series (pydicom); a path with no suffix
                                          is written as a DICOM series folder
========================  ======  ======  ==============================================

Conventions
-----------
* Arrays are indexed ``data[i, j, k]`` with axis 0 = x, 1 = y, 2 = z (the order of the
  file's own axes: fastest-varying axis first). Formats or libraries that hand out
  ``[z, y, x]`` arrays (SimpleITK, InVesalius) are transposed; the result is a view, so
  it is usually Fortran-ordered (x fastest), not C-contiguous.
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

import os
import plistlib
import re
import shutil
import tarfile
import tempfile
from pathlib import Path, PurePosixPath

import numpy as np

from softvr.errors import InputError
from softvr.volume._volume import Volume

__all__ = ["LOAD_SUFFIXES", "SAVE_SUFFIXES", "load", "save"]

#: File name endings :func:`load` understands (plus any folder, read as a DICOM series).
LOAD_SUFFIXES = (".nrrd", ".nhdr", ".nii", ".nii.gz", ".mha", ".mhd", ".npy", ".npz", ".inv3")
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
}

#: dtypes the image formats (NRRD, NIfTI, MetaImage) store; ``bool`` is written as uint8.
_IMAGE_DTYPES = tuple(np.dtype(t) for t in ("u1", "i1", "u2", "i2", "u4", "i4", "f4", "f8"))
#: dtypes a DICOM series stores (integers only: DICOM images have no float pixels).
_DICOM_DTYPES = tuple(np.dtype(t) for t in ("u1", "i1", "u2", "i2"))

_LABEL_KEY = "softvr_is_label"


# --------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------


def load(path, *, is_label: bool | None = None) -> Volume:
    """Read a volume from a file or a DICOM series folder.

    Parameters
    ----------
    path : str or os.PathLike
        A file whose name ends in one of :data:`LOAD_SUFFIXES` (``.nrrd``, ``.nhdr``,
        ``.nii``, ``.nii.gz``, ``.mha``, ``.mhd``, ``.npy``, ``.npz``, ``.inv3``), or a
        folder holding one DICOM series (one single-frame image per file).
    is_label : bool, optional
        ``True`` marks the volume as a segmentation (nearest-neighbour deformation),
        ``False`` as an intensity image. ``None`` (default) keeps the file's own marker
        where the format has one (see the module notes), else ``False``.

    Returns
    -------
    Volume
        ``data`` of shape [nx, ny, nz] in the file's voxel type (DICOM and scaled NIfTI:
        see notes), ``spacing`` [3] and ``origin`` [3] in the file's units (mm for all
        medical formats), ``direction`` [3, 3] with columns = world directions of the
        i, j, k axes.

    Raises
    ------
    InputError
        Missing path, unknown suffix, unreadable or corrupt file, data that is not a
        non-empty 3-D scalar array, inconsistent DICOM slices.

    Notes
    -----
    * NIfTI: ``spacing`` = norms of the affine's first three columns, ``direction`` = the
      normalized columns, ``origin`` = the affine translation (RAS+, kept as-is). Trailing
      singleton dimensions (``[nx, ny, nz, 1]``) are dropped.
    * DICOM: slices are sorted by ``ImagePositionPatient`` projected on the slice normal
      (row cosine x column cosine); x runs along the rows (columns of the pixel array),
      ``spacing`` = (PixelSpacing[1], PixelSpacing[0], slice-position step) and ``origin``
      = position of the first sorted slice. ``RescaleSlope``/``RescaleIntercept`` are
      applied: with the identity rescale the stored type (uint8/int16/uint16) is kept,
      otherwise the result is int16 when all values are integers that fit, else float32.
      The same rule applies to NIfTI ``scl_slope``/``scl_inter``.
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
    if not p.exists():
        raise InputError("path", "an existing file or DICOM series folder", "no such file or folder", source)
    if p.is_dir():
        fmt = "dicom"
    else:
        fmt = _format_of(p)
        if fmt is None:
            raise InputError(
                "file name suffix",
                "one of " + ", ".join(LOAD_SUFFIXES) + " or a DICOM series folder",
                repr(_suffix_text(p)),
                source,
            )
    reader = _READERS[fmt]
    try:
        fields = reader(p)
    except (InputError, MemoryError, KeyboardInterrupt):
        raise
    except Exception as exc:  # a library failed on a corrupt or unexpected file
        raise InputError("file", f"a readable {_FORMAT_NAMES[fmt]} file", _describe(exc), source) from exc
    if is_label is not None:
        fields["is_label"] = bool(is_label)
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
    if p.is_dir() or (_suffix_text(p) == "" and not p.exists()):
        fmt = "dicom"
    else:
        fmt = _format_of(p)
        if fmt is None or fmt == "inv3":
            raise InputError(
                "file name suffix",
                "one of " + ", ".join(SAVE_SUFFIXES) + " or a folder name (DICOM series)",
                repr(_suffix_text(p)) + (" (InVesalius projects are read-only)" if fmt == "inv3" else ""),
                source,
            )
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError("folder", "an existing folder to write into", f"{parent} does not exist", source)
    data = _data_for_format(volume, fmt, source)
    if fmt == "dicom":
        _replace_folder_atomically(p, lambda tmp: _write_dicom(volume, data, tmp), source)
    else:
        _replace_files_atomically(p, lambda tmp_file: _WRITERS[fmt](volume, data, tmp_file))
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
    "dicom": "DICOM series",
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
        return Volume(
            data,
            spacing=fields.get("spacing", np.ones(3)),
            origin=fields.get("origin", np.zeros(3)),
            direction=fields.get("direction", np.eye(3)),
            is_label=bool(fields.get("is_label", False)),
        )
    except InputError as exc:  # re-raise naming the file
        raise InputError(exc.what, exc.expected, exc.found, source) from None


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


def _replace_files_atomically(p: Path, write) -> None:
    """Run ``write(tmp_path)`` in a temporary folder next to ``p``, then move the result in.

    Every file the writer creates (e.g. a detached ``.raw`` next to an ``.nhdr``) is moved
    to the target folder with :func:`os.replace`; the main file goes last.
    """
    parent = p.parent if str(p.parent) else Path(".")
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent))
    try:
        tmp_file = tmpdir / p.name
        write(tmp_file)
        produced = sorted(f for f in tmpdir.iterdir() if f.name != p.name) + [tmp_file]
        if not tmp_file.is_file():
            raise RuntimeError(f"writer produced no {p.name}")
        for f in produced:
            os.replace(f, parent / f.name)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)


def _replace_folder_atomically(p: Path, write, source: str) -> None:
    """Run ``write(tmp_folder)`` then swap the new folder in place of ``p``."""
    if p.exists() and not p.is_dir():
        raise InputError(
            "path", "a folder for the DICOM series (or a file name with a suffix)", "an existing file", source
        )
    if p.is_dir():
        _check_replaceable_dicom_folder(p, source)
    parent = p.parent if str(p.parent) else Path(".")
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent))
    backup: Path | None = None
    try:
        write(tmpdir)
        os.chmod(tmpdir, 0o777 & ~_umask())
        if p.is_dir():
            backup = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".old", dir=parent))
            os.rmdir(backup)
            os.rename(p, backup)
        try:
            os.rename(tmpdir, p)
        except BaseException:
            if backup is not None:
                os.rename(backup, p)
                backup = None
            raise
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
        if backup is not None:
            shutil.rmtree(backup, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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


def _read_nrrd(p: Path) -> dict:
    import nrrd

    source = str(p)
    data, header = nrrd.read(str(p), index_order="F")
    data = np.asarray(data)
    if data.ndim != 3:
        raise InputError("dimension", "3 (a scalar 3-D volume)", f"{data.ndim} (shape {data.shape})", source)
    fields: dict = {"data": data}
    sd = header.get("space directions")
    if sd is not None:
        sd = np.asarray(sd, dtype=np.float64)
        if sd.shape != (3, 3):
            raise InputError("space directions", "three 3-D vectors", str(sd.tolist()), source)
        # pynrrd gives one row per axis; columns of our matrix are the axis steps.
        fields["spacing"], fields["direction"] = _columns_geometry(sd.T, "space directions", source)
    elif "spacings" in header:
        sp = np.asarray(header["spacings"], dtype=np.float64).reshape(-1)
        fields["spacing"] = np.where(np.isfinite(sp), sp, 1.0)
    if "space origin" in header:
        fields["origin"] = np.asarray(header["space origin"], dtype=np.float64).reshape(-1)
    if _LABEL_KEY in header:
        fields["is_label"] = str(header[_LABEL_KEY]).strip().lower() in ("1", "true", "yes")
    return fields


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


def _read_nifti(p: Path) -> dict:
    import nibabel as nib

    source = str(p)
    img = nib.load(str(p))
    if not isinstance(img, (nib.Nifti1Image, nib.Nifti2Image)):
        raise InputError("file", "a NIfTI-1 or NIfTI-2 image", type(img).__name__, source)
    shape = tuple(int(n) for n in img.shape)
    while len(shape) > 3 and shape[-1] == 1:
        shape = shape[:-1]
    if len(shape) != 3:
        raise InputError("dim", "a 3-D volume [nx, ny, nz]", f"shape {tuple(img.shape)}", source)
    proxy = img.dataobj  # nibabel moves scl_slope/scl_inter from img.header into the proxy
    raw = np.asarray(proxy.get_unscaled()).reshape(shape, order="F")
    slope, inter = float(getattr(proxy, "slope", 1.0)), float(getattr(proxy, "inter", 0.0))
    if not np.isfinite(slope) or slope == 0:
        slope = 1.0
    if not np.isfinite(inter):
        inter = 0.0
    fields: dict = {"data": _rescale(raw, slope, inter)}
    affine = np.asarray(img.affine, dtype=np.float64)
    fields["spacing"], fields["direction"] = _columns_geometry(affine[:3, :3], "affine", source)
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


def _read_metaimage(p: Path) -> dict:
    import SimpleITK as sitk

    source = str(p)
    with open(p, "rb") as f:
        first = f.readline(256)
    if not re.match(rb"\s*[A-Za-z]\w*\s*=", first):
        raise InputError(
            "header", "a MetaImage text header ('ObjectType = Image', 'NDims = 3', ...)", f"{first[:40]!r}", source
        )
    reader = sitk.ImageFileReader()
    reader.SetImageIO("MetaImageIO")
    reader.SetFileName(str(p))
    img = reader.Execute()
    if img.GetDimension() != 3 or img.GetNumberOfComponentsPerPixel() != 1:
        raise InputError(
            "NDims / ElementNumberOfChannels",
            "a 3-D scalar image",
            f"{img.GetDimension()}-D, {img.GetNumberOfComponentsPerPixel()} component(s), size {img.GetSize()}",
            source,
        )
    arr = sitk.GetArrayFromImage(img)  # [z, y, x]
    fields: dict = {
        "data": arr.transpose(2, 1, 0),
        "spacing": np.asarray(img.GetSpacing(), dtype=np.float64),
        "origin": np.asarray(img.GetOrigin(), dtype=np.float64),
        "direction": np.asarray(img.GetDirection(), dtype=np.float64).reshape(3, 3),
    }
    if img.HasMetaDataKey(_LABEL_KEY):
        fields["is_label"] = img.GetMetaData(_LABEL_KEY).strip().lower() in ("1", "true", "yes")
    return fields


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


def _read_npy(p: Path) -> dict:
    _check_magic(p, b"\x93NUMPY", "a NumPy .npy file")
    data = np.load(p, allow_pickle=False)
    return {"data": np.asarray(data)}


def _read_npz(p: Path) -> dict:
    source = str(p)
    _check_magic(p, b"PK", "a NumPy .npz (zip) file")
    with np.load(p, allow_pickle=False) as z:
        keys = list(z.keys())
        if "data" not in keys:
            raise InputError("key 'data'", "an array named 'data'", f"keys {keys}", source)
        fields: dict = {"data": np.asarray(z["data"])}
        for key in ("spacing", "origin", "direction"):
            if key in keys:
                fields[key] = np.asarray(z[key])
        if "is_label" in keys:
            flag = np.asarray(z["is_label"])
            if flag.size != 1:
                raise InputError("key 'is_label'", "a single boolean", f"shape {flag.shape}", source)
            fields["is_label"] = bool(flag.reshape(-1)[0])
    for key in ("spacing", "origin"):
        if key in fields and fields[key].size != 3:
            raise InputError(f"key {key!r}", "three numbers", f"shape {fields[key].shape}", source)
    if "direction" in fields and fields["direction"].size != 9:
        raise InputError("key 'direction'", "a 3x3 matrix", f"shape {fields['direction'].shape}", source)
    if "direction" in fields:
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
    with tarfile.open(p, "r:gz") as tar:
        members = [m for m in tar.getmembers() if m.isfile()]
        mains = sorted(
            (m for m in members if PurePosixPath(m.name).name == "main.plist"),
            key=lambda m: len(PurePosixPath(m.name).parts),
        )
        if not mains:
            names = [m.name for m in members][:10]
            raise InputError("main.plist", "an InVesalius project holding main.plist", f"members {names}", source)
        main = mains[0]
        try:
            plist = plistlib.loads(tar.extractfile(main).read())
        except plistlib.InvalidFileException as exc:
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
            raise InputError(f"{main.name}: matrix/dtype", "a numpy dtype name", repr(matrix.get("dtype")), source)
        spacing = plist.get("spacing")
        if not isinstance(spacing, (list, tuple)) or len(spacing) != 3:
            raise InputError(f"{main.name}: spacing", "three numbers (x, y, z) [mm]", repr(spacing), source)
        filename = str(matrix.get("filename", "matrix.dat"))
        want = str(PurePosixPath(main.name).parent / filename) if PurePosixPath(main.name).parent.parts else filename
        found = [m for m in members if m.name == want]
        if not found:
            raise InputError(filename, f"a member {want!r} named by {main.name}", "no such member", source)
        member = found[0]
        nbytes = int(np.prod(shape)) * dtype.itemsize
        if member.size != nbytes:
            raise InputError(
                member.name,
                f"{nbytes} bytes ({'x'.join(map(str, shape))} {dtype.name})",
                f"{member.size} bytes",
                source,
            )
        arr = np.empty(int(np.prod(shape)), dtype=dtype)
        buf = memoryview(arr).cast("B")
        f = tar.extractfile(member)
        pos = 0
        while pos < nbytes:
            n = f.readinto(buf[pos:])
            if not n:
                raise InputError(member.name, f"{nbytes} bytes", f"{pos} bytes (truncated archive)", source)
            pos += n
    arr = arr.astype(dtype.newbyteorder("="), copy=False)
    # InVesalius stores the matrix [z, y, x] (slice, row, column) and the spacing (x, y, z).
    return {
        "data": arr.reshape(shape).transpose(2, 1, 0),
        "spacing": np.asarray(spacing, dtype=np.float64),
        "origin": np.zeros(3),
        "direction": np.eye(3),
    }


# --------------------------------------------------------------------------------------
# DICOM series
# --------------------------------------------------------------------------------------


def _read_dicom_folder(p: Path) -> dict:
    import pydicom
    from pydicom.errors import InvalidDicomError

    source = str(p)
    slices = []
    for f in sorted(p.iterdir()):
        if not f.is_file() or f.name.startswith("."):
            continue
        try:
            ds = pydicom.dcmread(f)
        except (InvalidDicomError, EOFError, OSError) as exc:
            if f.suffix.lower() == ".dcm":
                raise InputError("file", "a readable DICOM file", _describe(exc), str(f)) from exc
            continue  # not a DICOM file (README.txt, a thumbnail, ...): skip it
        except Exception as exc:
            raise InputError("file", "a readable DICOM file", _describe(exc), str(f)) from exc
        if "PixelData" not in ds:
            continue  # DICOMDIR, structured reports, ...
        slices.append((f, ds))
    if not slices:
        raise InputError("folder", "DICOM image files (one slice per file)", "no DICOM slices", source)

    series = {}
    for f, ds in slices:
        series.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append((f, ds))
    if len(series) > 1:
        counts = ", ".join(f"{uid or '<none>'}: {len(v)} files" for uid, v in series.items())
        raise InputError(
            "SeriesInstanceUID", "a single series in the folder", f"{len(series)} series ({counts})", source
        )

    f0, ds0 = slices[0]
    rows, cols = int(ds0.Rows), int(ds0.Columns)
    for f, ds in slices:
        if int(ds.get("NumberOfFrames", 1) or 1) != 1:
            raise InputError("NumberOfFrames", "single-frame slices", str(ds.NumberOfFrames), str(f))
        if int(ds.get("SamplesPerPixel", 1)) != 1:
            raise InputError("SamplesPerPixel", "1 (grey-scale)", str(ds.SamplesPerPixel), str(f))
        if (int(ds.Rows), int(ds.Columns)) != (rows, cols):
            raise InputError(
                "Rows x Columns",
                f"{rows} x {cols} as in {f0.name} (consistent slice sizes)",
                f"{int(ds.Rows)} x {int(ds.Columns)}",
                str(f),
            )

    def vec(ds, key, n, default):
        v = ds.get(key)
        if v is None or len(v) != n:
            return None if default is None else np.asarray(default, dtype=np.float64)
        return np.asarray([float(x) for x in v], dtype=np.float64)

    iop = vec(ds0, "ImageOrientationPatient", 6, [1, 0, 0, 0, 1, 0])
    ps = vec(ds0, "PixelSpacing", 2, [1, 1])
    for f, ds in slices[1:]:
        o = vec(ds, "ImageOrientationPatient", 6, [1, 0, 0, 0, 1, 0])
        if not np.allclose(o, iop, atol=1e-4):
            raise InputError(
                "ImageOrientationPatient", f"{iop.tolist()} as in {f0.name}", str(o.tolist()), str(f)
            )
        s = vec(ds, "PixelSpacing", 2, [1, 1])
        if not np.allclose(s, ps, rtol=1e-4):
            raise InputError("PixelSpacing", f"{ps.tolist()} as in {f0.name}", str(s.tolist()), str(f))
    row_dir, col_dir = iop[:3], iop[3:]
    normal = np.cross(row_dir, col_dir)
    positions = [vec(ds, "ImagePositionPatient", 3, None) for _, ds in slices]
    if all(pos is not None for pos in positions):
        dist = np.array([float(pos @ normal) for pos in positions])
        order = np.argsort(dist, kind="stable")
        dist = dist[order]
        steps = np.diff(dist)
        if len(steps):
            if np.any(steps <= 1e-6 * max(1.0, float(np.abs(dist).max()))):
                k = int(np.argmin(steps))
                raise InputError(
                    "ImagePositionPatient",
                    "one slice per position along the slice normal",
                    f"two slices at {dist[k]:.6g} ({slices[order[k]][0].name}, {slices[order[k + 1]][0].name})",
                    source,
                )
            dz = (dist[-1] - dist[0]) / len(steps)
            if np.max(np.abs(steps - dz)) > 1e-3 * dz + 1e-4:
                raise InputError(
                    "ImagePositionPatient",
                    "uniformly spaced slices",
                    f"slice steps from {steps.min():.6g} to {steps.max():.6g}",
                    source,
                )
        else:
            dz = _slice_thickness(ds0)
        origin = positions[order[0]]
    else:
        order = np.argsort([int(ds.get("InstanceNumber", i) or i) for i, (_, ds) in enumerate(slices)], kind="stable")
        dz = _slice_thickness(ds0)
        pos0 = vec(slices[order[0]][1], "ImagePositionPatient", 3, [0, 0, 0])
        origin = pos0
    ordered = [slices[i] for i in order]

    raws = []
    for f, ds in ordered:
        try:
            arr = ds.pixel_array
        except Exception as exc:
            raise InputError("PixelData", "decodable pixel data", _describe(exc), str(f)) from exc
        slope = float(ds.get("RescaleSlope", 1) or 1)
        inter = float(ds.get("RescaleIntercept", 0) or 0)
        raws.append((arr, slope, inter))
    if all(s == 1 and i == 0 for _, s, i in raws):
        vol = np.stack([a for a, _, _ in raws], axis=-1)  # [rows=y, cols=x, z]
    else:
        vals = np.stack([a.astype(np.float64) * s + i for a, s, i in raws], axis=-1)
        vol = _rescale_values(vals)
    data = vol.transpose(1, 0, 2)  # [x, y, z]
    return {
        "data": data,
        # PixelSpacing = (row spacing: between rows, along y; column spacing: along x)
        "spacing": np.array([ps[1], ps[0], dz], dtype=np.float64),
        "origin": origin,
        "direction": np.column_stack([row_dir, col_dir, normal / np.linalg.norm(normal)]),
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
    import datetime

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
    "dicom": _read_dicom_folder,
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
