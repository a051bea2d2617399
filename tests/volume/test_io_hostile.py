"""Hostile volume files (issue 17): every one is refused with an InputError that names the
file and the field, before a native library sees it and before anything large is allocated."""

from __future__ import annotations

import gzip
import os
import struct
import threading
import tracemalloc
import zlib
from pathlib import Path

import nibabel as nib
import numpy as np
import pytest

from softvr import files
from softvr.errors import InputError
from softvr.volume import Volume, load, save

MHD_HEAD = "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\n"


def _refused(path, what: str, *, found: str | None = None, **kw) -> InputError:
    """``load(path)`` raises an InputError naming ``path`` and the field ``what``, within 10 s
    (a hang fails the test instead of stalling it) and allocating at most 16 MiB."""
    result: dict = {}

    def run():
        tracemalloc.start()
        try:
            load(path, **kw)
        except Exception as exc:  # noqa: BLE001 - the test classifies it below
            result["error"] = exc
        result["peak"] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(10)
    assert not worker.is_alive(), f"load({path}) hangs"
    err = result.get("error")
    assert isinstance(err, InputError), f"{path}: {err!r}"
    assert err.source is not None and os.path.basename(str(path)) in err.source, err
    assert what in err.what, err
    if found is not None:
        assert found in err.found, err
    assert result["peak"] < 16 << 20, f"{path}: {result['peak']} bytes allocated"
    return err


# ---------------------------------------------------------------- MetaImage


@pytest.mark.parametrize("ndims", ["1e308", "-5", "0", "2", "99999999999999999999999", "three", ""])
def test_metaimage_ndims_out_of_range(tmp_path, ndims):
    path = tmp_path / "bad.mha"
    path.write_bytes(f"ObjectType = Image\nNDims = {ndims}\nDimSize = 2 2 2\nElementType = MET_UCHAR\n"
                     f"ElementDataFile = LOCAL\n".encode() + bytes(8))
    _refused(path, "NDims")


@pytest.mark.parametrize("name", ["/etc/passwd", "../outside.raw", "sub/../../outside.raw", "link.raw"])
def test_metaimage_data_file_outside_the_header_folder(tmp_path, name):
    folder = tmp_path / "scan"
    folder.mkdir()
    (tmp_path / "outside.raw").write_bytes(bytes(8))
    os.symlink(tmp_path / "outside.raw", folder / "link.raw")  # inside by name, outside in fact
    path = folder / "v.mhd"
    path.write_text(MHD_HEAD + f"ElementDataFile = {name}\n")
    _refused(path, "ElementDataFile")


def test_metaimage_data_file_that_is_a_fifo_or_missing(tmp_path):
    os.mkfifo(tmp_path / "pipe.raw")  # reading it would block forever
    path = tmp_path / "v.mhd"
    path.write_text(MHD_HEAD + "ElementDataFile = pipe.raw\n")
    _refused(path, "ElementDataFile", found="a FIFO")
    path.write_text(MHD_HEAD + "ElementDataFile = gone.raw\n")
    _refused(path, "ElementDataFile", found="no such file")


def test_metaimage_sizes_checked_against_the_limit_and_the_file(tmp_path):
    path = tmp_path / "huge.mha"
    path.write_bytes(b"NDims = 3\nDimSize = 1000000 1000000 1000000\nElementType = MET_FLOAT\n"
                     b"ElementDataFile = LOCAL\n" + bytes(64))
    _refused(path, "DimSize", found="1000000000000000000")
    path.write_bytes(b"NDims = 3\nDimSize = 100 100 100\nElementType = MET_FLOAT\nElementDataFile = LOCAL\n"
                     + bytes(64))
    _refused(path, "ElementDataFile", found="64 bytes")


def test_metaimage_compressed_bomb_and_short_stream(tmp_path):
    path = tmp_path / "bomb.mha"
    # 256 MiB of zeros deflate to ~1 MiB: only the 8 voxels the header states are inflated
    bomb = zlib.compressobj(1)
    payload = b"".join(bomb.compress(bytes(1 << 24)) for _ in range(16)) + bomb.flush()
    path.write_bytes(MHD_HEAD.encode() + b"CompressedData = True\nElementDataFile = LOCAL\n" + payload)
    assert load(path).data.tolist() == np.zeros((2, 2, 2)).tolist()
    # the header claims 64 M voxels, the stream holds 8: refused, without allocating 64 MiB
    path.write_bytes(MHD_HEAD.replace("2 2 2", "400 400 400").encode()
                     + b"CompressedData = True\nElementDataFile = LOCAL\n" + zlib.compress(bytes(8)))
    _refused(path, "ElementDataFile", found="truncated")


@pytest.mark.parametrize(
    ("line", "field"),
    [
        ("ElementType = MET_STRING", "ElementType"),
        ("ElementSpacing = 1 nan 1", "ElementSpacing"),
        ("TransformMatrix = 1 0 0", "TransformMatrix"),
        ("BinaryDataByteOrderMSB = maybe", "BinaryDataByteOrderMSB"),
        ("HeaderSize = -7", "HeaderSize"),
    ],
)
def test_metaimage_bad_fields_named(tmp_path, line, field):
    path = tmp_path / "f.mha"
    head = MHD_HEAD.replace("ElementType = MET_UCHAR\n", "") if field == "ElementType" else MHD_HEAD
    path.write_bytes(f"{head}{line}\nElementDataFile = LOCAL\n".encode() + bytes(8))
    _refused(path, field)


def test_metaimage_binary_garbage_header(tmp_path):
    path = tmp_path / "g.mhd"
    path.write_bytes(b"NDims = 3\n\x00\xff\x13garbage\n")
    _refused(path, "header")


# ---------------------------------------------------------------- NRRD


def test_nrrd_symlinked_to_dev_zero(tmp_path):
    os.symlink("/dev/zero", tmp_path / "zero.nrrd")
    _refused(tmp_path / "zero.nrrd", "file", found="a device")


def test_fifo_is_not_opened(tmp_path):
    os.mkfifo(tmp_path / "pipe.nrrd")  # opening it would block forever
    _refused(tmp_path / "pipe.nrrd", "file", found="a FIFO")


@pytest.mark.parametrize("name", ["/etc/passwd", "../x.raw", "LIST", "x%03d.raw 1 3 1"])
def test_nhdr_data_file_outside_or_unsupported(tmp_path, name):
    folder = tmp_path / "d"
    folder.mkdir()
    path = folder / "v.nhdr"
    path.write_text(f"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: {name}\n")
    _refused(path, "data file")


@pytest.mark.parametrize(
    ("fields", "what"),
    [
        ("dimension: 3\nsizes: 100000 100000 100000\n", "sizes"),
        ("dimension: 7\nsizes: 1 1 1 1 1 1 1\n", "dimension"),
        ("dimension: 3\nsizes: 2 0 2\n", "sizes"),
        ("dimension: 3\nsizes: 20 20 20\n", "data"),  # 8000 bytes promised, 8 present
    ],
)
def test_nrrd_sizes_checked_before_reading(tmp_path, fields, what):
    path = tmp_path / "v.nrrd"
    path.write_bytes(f"NRRD0004\ntype: uchar\n{fields}encoding: raw\n\n".encode() + bytes(8))
    _refused(path, what)


def test_nrrd_gzip_bomb_inflates_only_what_the_header_states(tmp_path):
    path = tmp_path / "bomb.nrrd"
    payload = gzip.compress(bytes(1 << 26), compresslevel=1)
    path.write_bytes(b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: gzip\n\n" + payload)
    assert load(path).shape == (2, 2, 2)
    path.write_bytes(b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 400 400 400\nencoding: gzip\n\n"
                     + gzip.compress(bytes(8)))
    _refused(path, "data", found="truncated")


def test_nrrd_header_without_end(tmp_path):
    path = tmp_path / "long.nrrd"
    path.write_bytes(b"NRRD0004\n" + b"x" * (2 << 20))  # no newline, no blank line: no unbounded read
    _refused(path, "header")


# ---------------------------------------------------------------- NumPy, NIfTI, inv3


def _npy_header(shape, descr="<f4") -> bytes:
    text = repr({"descr": descr, "fortran_order": False, "shape": shape}).encode()
    text += b" " * (63 - (len(text) + 10) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text


def test_npy_claiming_1e18_voxels(tmp_path):
    path = tmp_path / "huge.npy"
    path.write_bytes(_npy_header((10**6, 10**6, 10**6)) + bytes(64))
    _refused(path, "shape", found="1000000000000000000")
    path.write_bytes(_npy_header((100, 100, 100)) + bytes(64))  # under the limit, but the file is short
    _refused(path, "data", found="64 bytes")
    path.write_bytes(_npy_header((2, 2, 2), descr="|O") + bytes(64))
    _refused(path, "descr")


def test_npz_member_claiming_1e18_voxels(tmp_path):
    import zipfile

    path = tmp_path / "huge.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("data.npy", _npy_header((10**6, 10**6, 10**6)) + bytes(64))
    _refused(path, "shape")
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:  # 8 MB promised, 64 B present
        z.writestr("data.npy", _npy_header((200, 100, 100)) + bytes(64))
    _refused(path, "data", found="truncated")


@pytest.mark.parametrize("suffix", [".nii", ".nii.gz"])
def test_nifti_claiming_1e13_voxels(tmp_path, suffix):
    header = nib.Nifti1Header()
    header.set_data_shape((32767, 32767, 32767))
    raw = header.binaryblock + b"\x00" * 4 + bytes(64)
    path = tmp_path / f"huge{suffix}"
    path.write_bytes(gzip.compress(raw) if suffix == ".nii.gz" else raw)
    _refused(path, "dim[1..3]", found=str(32767**3))


def test_nifti2_claiming_1e18_voxels(tmp_path):
    header = nib.Nifti2Header()
    header.set_data_shape((10**6, 10**6, 10**6))
    path = tmp_path / "huge.nii"
    path.write_bytes(header.binaryblock + b"\x00" * 4 + bytes(64))
    _refused(path, "dim[1..3]", found="1000000000000000000")


@pytest.mark.parametrize(("dim0", "what"), [(-5, "dim[0]"), (9, "dim[0]"), (3, "dim[2]")])
def test_nifti_bad_dims_named(tmp_path, dim0, what):
    block = bytearray(nib.Nifti1Header().binaryblock)
    block[40:56] = struct.pack("<8h", dim0, 2, 0 if what == "dim[2]" else 2, 2, 1, 1, 1, 1)
    path = tmp_path / "d.nii"
    path.write_bytes(bytes(block) + bytes(4) + bytes(16))
    _refused(path, what)


def test_nifti_gzip_under_the_limit_but_truncated_allocates_little(tmp_path, monkeypatch):
    # 2**30 voxels (under the limit, 1 GiB promised) in a stream of 64 bytes
    header = nib.Nifti1Header()
    header.set_data_shape((1024, 1024, 1024))
    path = tmp_path / "short.nii.gz"
    path.write_bytes(gzip.compress(header.binaryblock + bytes(4) + bytes(64)))
    _refused(path, "dim", found="truncated")


def test_limit_is_overridable(tmp_path, monkeypatch):
    path = save(Volume(np.zeros((4, 4, 4), np.uint8)), tmp_path / "v.nrrd")
    monkeypatch.setattr(files, "MAX_ELEMENTS", 63)
    err = _refused(path, "sizes")
    assert "SOFTVR_MAX_ELEMENTS" in str(err)


def test_inv3_shape_claiming_1e18_voxels(tmp_path):
    import io
    import plistlib
    import tarfile

    path = tmp_path / "p.inv3"
    plist = plistlib.dumps({"matrix": {"filename": "matrix.dat", "shape": [10**6, 10**6, 10**6], "dtype": "int16"},
                            "spacing": [1.0, 1.0, 1.0]})
    with tarfile.open(path, "w:gz") as tar:
        for name, blob in (("main.plist", plist), ("matrix.dat", bytes(16))):
            info = tarfile.TarInfo(name)
            info.size = len(blob)
            tar.addfile(info, io.BytesIO(blob))
    _refused(path, "matrix/shape")


# ---------------------------------------------------------------- DICOM


def test_dicom_rows_columns_frames_checked_before_decoding(tmp_path):
    import pydicom.data

    ds = pydicom.dcmread(os.path.join(os.path.dirname(pydicom.data.__file__), "test_files", "rtdose.dcm"))
    ds.NumberOfFrames = 100000
    ds.Rows = ds.Columns = 65535
    path = tmp_path / "huge.dcm"
    ds.save_as(path)
    _refused(path, "Rows x Columns x NumberOfFrames")


@pytest.mark.filterwarnings("ignore:Invalid value for VR CS")
def test_dicomdir_record_outside_its_folder(tmp_path):
    import pydicom.data

    src = os.path.join(os.path.dirname(pydicom.data.__file__), "test_files", "dicomdirtests", "DICOMDIR")
    ds = pydicom.dcmread(src)
    record = next(r for r in ds.DirectoryRecordSequence if r.DirectoryRecordType == "IMAGE")
    record.ReferencedFileID = ["..", "..", "etc", "passwd"]
    path = tmp_path / "DICOMDIR"
    ds.save_as(path)
    _refused(path, "ReferencedFileID")


def test_library_errors_are_wrapped(tmp_path):
    import pydicom.data

    good = Path(pydicom.data.__file__).parent / "test_files" / "CT_small.dcm"
    path = tmp_path / "short.dcm"
    path.write_bytes(good.read_bytes()[:-8000])  # pixel data cut short: pydicom's decoder fails
    _refused(path, "PixelData")
    path.write_bytes(b"\x00" * 128 + b"DICM" + b"\x02\x00\x10\x00UI\xff\xff")  # an element longer than the file
    _refused(path, "")
