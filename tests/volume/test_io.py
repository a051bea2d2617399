"""Volume file I/O: round trips, cross-checks with independent readers/writers, bad input,
atomic saves, and the real InVesalius head CT."""

from __future__ import annotations

import gzip
import io
import os
import plistlib
import tarfile

import nibabel as nib
import nrrd
import numpy as np
import pydicom
import pytest
import SimpleITK as sitk

from softvr.errors import InputError
from softvr.volume import Volume, load, save
from softvr.volume import _io

CRANIUM = "/usr/share/doc/invesalius-examples/examples/Cranium.inv3"
needs_cranium = pytest.mark.skipif(not os.path.isfile(CRANIUM), reason="apt package invesalius-examples missing")

# A rotation (x -> y, y -> -x) so that axis-order or transposition mistakes show up.
ROT = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
SPACING = np.array([0.5, 0.75, 1.25])
ORIGIN = np.array([10.0, -20.5, 3.25])
SHAPE = (5, 6, 7)  # all different: a transposed array cannot pass
FILE_SUFFIXES = [".nrrd", ".nhdr", ".nii", ".nii.gz", ".mha", ".mhd", ".npz"]
DTYPES = ["uint8", "int16", "uint16", "float32"]


def _data(dtype) -> np.ndarray:
    rng = np.random.default_rng(42)
    dt = np.dtype(dtype)
    if dt.kind == "f":
        return rng.normal(0.0, 100.0, SHAPE).astype(dt)
    info = np.iinfo(dt)
    return rng.integers(info.min, info.max, SHAPE, endpoint=True).astype(dt)


def _volume(dtype="int16", is_label=False) -> Volume:
    return Volume(_data(dtype), spacing=SPACING, origin=ORIGIN, direction=ROT, is_label=is_label)


def _assert_same(a: Volume, b: Volume, *, geometry_atol=1e-9) -> None:
    assert a.dtype == b.dtype
    assert a.shape == b.shape
    np.testing.assert_array_equal(a.data, b.data)
    np.testing.assert_allclose(a.spacing, b.spacing, atol=geometry_atol)
    np.testing.assert_allclose(a.origin, b.origin, atol=geometry_atol)
    np.testing.assert_allclose(a.direction, b.direction, atol=geometry_atol)


def _listing(folder) -> list[str]:
    return sorted(os.listdir(folder))


# ---------------------------------------------------------------- round trips


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("suffix", FILE_SUFFIXES)
def test_round_trip_files(tmp_path, suffix, dtype):
    vol = _volume(dtype)
    out = save(vol, tmp_path / f"vol{suffix}")
    assert out == tmp_path / f"vol{suffix}"
    back = load(out)
    _assert_same(back, vol)
    assert back.is_label is False
    # nothing but the file (and its detached data file) is left behind
    names = _listing(tmp_path)
    assert all(not n.startswith(".") for n in names), names


@pytest.mark.parametrize("suffix", FILE_SUFFIXES)
def test_label_flag_round_trip_and_override(tmp_path, suffix):
    vol = _volume("uint8", is_label=True)
    path = save(vol, tmp_path / f"seg{suffix}")
    assert load(path).is_label is True
    assert load(path, is_label=False).is_label is False
    plain = save(_volume("uint8"), tmp_path / f"img{suffix}")
    assert load(plain).is_label is False
    assert load(plain, is_label=True).is_label is True


@pytest.mark.parametrize("dtype", DTYPES)
def test_npy_round_trip_is_data_only(tmp_path, dtype):
    vol = _volume(dtype)
    back = load(save(vol, tmp_path / "vol.npy"))
    assert back.dtype == vol.dtype
    np.testing.assert_array_equal(back.data, vol.data)
    np.testing.assert_array_equal(back.spacing, np.ones(3))
    np.testing.assert_array_equal(back.origin, np.zeros(3))
    np.testing.assert_array_equal(back.direction, np.eye(3))
    assert load(tmp_path / "vol.npy", is_label=True).is_label


def test_npz_written_by_numpy(tmp_path):
    data = _data("int16")
    np.savez(tmp_path / "a.npz", data=data, spacing=[1, 2, 3], origin=[4, 5, 6])
    vol = load(tmp_path / "a.npz")
    np.testing.assert_array_equal(vol.data, data)
    np.testing.assert_array_equal(vol.spacing, [1, 2, 3])
    np.testing.assert_array_equal(vol.origin, [4, 5, 6])
    np.testing.assert_array_equal(vol.direction, np.eye(3))
    np.savez(tmp_path / "b.npz", data=data)
    assert load(tmp_path / "b.npz").spacing.tolist() == [1, 1, 1]


def test_bool_saved_as_uint8(tmp_path):
    vol = Volume(_data("uint8") > 128, spacing=SPACING, is_label=True)
    back = load(save(vol, tmp_path / "m.nrrd"))
    assert back.dtype == np.uint8
    np.testing.assert_array_equal(back.data, vol.data.astype(np.uint8))


@pytest.mark.parametrize("dtype", ["uint8", "int16", "uint16"])
def test_dicom_series_round_trip(tmp_path, dtype):
    vol = _volume(dtype)
    folder = save(vol, tmp_path / "series")
    assert folder.is_dir()
    files = _listing(folder)
    assert len(files) == SHAPE[2] and all(f.endswith(".dcm") for f in files)
    assert _listing(tmp_path) == ["series"]
    _assert_same(load(folder), vol, geometry_atol=1e-6)


def test_dicom_series_overwrite_and_shuffled_slices(tmp_path):
    folder = tmp_path / "series"
    save(_volume("int16"), folder)
    vol = Volume(_data("uint16")[:, :, :3], spacing=(1, 2, 3), origin=(0, 0, 0))
    save(vol, folder)  # replaces the old 7-slice series
    assert len(_listing(folder)) == 3
    # slice order comes from ImagePositionPatient, not from file names
    for i, f in enumerate(sorted(folder.iterdir())):
        f.rename(folder / f"z{9 - i}.dcm")
    _assert_same(load(folder), vol, geometry_atol=1e-6)


def test_dicom_left_handed_direction_keeps_world_geometry(tmp_path):
    flip = np.diag([1.0, 1.0, -1.0])
    vol = Volume(_data("int16"), spacing=SPACING, origin=ORIGIN, direction=flip)
    back = load(save(vol, tmp_path / "series"))
    np.testing.assert_array_equal(back.data, vol.data[:, :, ::-1])
    ijk = np.array([[0, 0, 0], [4, 5, 6], [1, 2, 3]])
    np.testing.assert_allclose(back.index_to_world(ijk), vol.index_to_world(ijk * [1, 1, -1] + [0, 0, 6]), atol=1e-9)


def test_dicom_rescale_slope_intercept(tmp_path):
    folder = save(_volume("uint16"), tmp_path / "series")
    raw = _data("uint16")
    for f in folder.iterdir():
        ds = pydicom.dcmread(f)
        ds.RescaleSlope, ds.RescaleIntercept = "1", "-1024"
        ds.save_as(f)
    # uint16 - 1024 spans [-1024, 64511]: does not fit int16 -> float32
    vol = load(folder)
    assert vol.dtype == np.float32
    np.testing.assert_array_equal(vol.data, raw.astype(np.float64) - 1024)

    small = Volume(_data("uint8").astype(np.uint16) * 4 + 1, spacing=SPACING)  # odd values
    folder = save(small, tmp_path / "ct")
    for f in folder.iterdir():
        ds = pydicom.dcmread(f)
        ds.RescaleSlope, ds.RescaleIntercept = "1", "-1024"
        ds.save_as(f)
    ct = load(folder)
    assert ct.dtype == np.int16
    np.testing.assert_array_equal(ct.data, small.data.astype(np.int32) - 1024)

    for f in folder.iterdir():
        ds = pydicom.dcmread(f)
        ds.RescaleSlope = "0.5"
        ds.save_as(f)
    half = load(folder)
    assert half.dtype == np.float32
    np.testing.assert_allclose(half.data, small.data * 0.5 - 1024)


# ---------------------------------------------------------------- independent readers / writers


def _sitk_image(data: np.ndarray) -> sitk.Image:
    img = sitk.GetImageFromArray(np.ascontiguousarray(data.transpose(2, 1, 0)))
    img.SetSpacing(SPACING.tolist())
    img.SetOrigin(ORIGIN.tolist())
    img.SetDirection(ROT.reshape(-1).tolist())
    return img


@pytest.mark.parametrize("suffix", [".nrrd", ".mha", ".mhd"])
def test_simpleitk_written_files_read_by_us(tmp_path, suffix):
    data = _data("int16")
    sitk.WriteImage(_sitk_image(data), str(tmp_path / f"a{suffix}"))
    _assert_same(load(tmp_path / f"a{suffix}"), Volume(data, SPACING, ORIGIN, ROT))


def test_simpleitk_nifti_read_by_us_as_ras(tmp_path):
    # ITK is LPS, NIfTI is RAS: ITK flips x and y when writing; we keep the affine as-is.
    data = _data("uint16")
    sitk.WriteImage(_sitk_image(data), str(tmp_path / "a.nii.gz"))
    vol = load(tmp_path / "a.nii.gz")
    lps_to_ras = np.diag([-1.0, -1.0, 1.0])
    _assert_same(vol, Volume(data, SPACING, lps_to_ras @ ORIGIN, lps_to_ras @ ROT), geometry_atol=1e-5)


@pytest.mark.parametrize("suffix", [".nrrd", ".nhdr", ".mha", ".mhd"])
def test_our_files_read_by_simpleitk(tmp_path, suffix):
    vol = _volume("float32")
    img = sitk.ReadImage(str(save(vol, tmp_path / f"a{suffix}")))
    np.testing.assert_array_equal(sitk.GetArrayFromImage(img).transpose(2, 1, 0), vol.data)
    np.testing.assert_allclose(img.GetSpacing(), SPACING)
    np.testing.assert_allclose(img.GetOrigin(), ORIGIN)
    np.testing.assert_allclose(np.reshape(img.GetDirection(), (3, 3)), ROT)


def test_our_nifti_read_by_nibabel(tmp_path):
    vol = _volume("int16")
    img = nib.load(save(vol, tmp_path / "a.nii.gz"))
    np.testing.assert_array_equal(np.asarray(img.dataobj), vol.data)
    assert img.get_data_dtype() == np.int16
    expected = np.eye(4)
    expected[:3, :3] = ROT * SPACING
    expected[:3, 3] = ORIGIN
    np.testing.assert_allclose(img.affine, expected, atol=1e-6)
    np.testing.assert_allclose(img.header.get_zooms(), SPACING)


def test_nibabel_oblique_and_scaled_nifti(tmp_path):
    c, s = np.cos(0.3), np.sin(0.3)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    affine = np.eye(4)
    affine[:3, :3] = rot * [2.0, 3.0, 4.0]
    affine[:3, 3] = [7, 8, 9]
    raw = _data("int16")
    nib.save(nib.Nifti1Image(raw, affine), tmp_path / "s.nii")
    with open(tmp_path / "s.nii", "r+b") as f:  # nibabel drops scaling it does not need: patch it in
        f.seek(112)  # scl_slope, scl_inter (float32) in the NIfTI-1 header
        f.write(np.array([2.0, -10.0], "<f4").tobytes())
    assert (nib.load(tmp_path / "s.nii").dataobj.slope, nib.load(tmp_path / "s.nii").dataobj.inter) == (2.0, -10.0)
    vol = load(tmp_path / "s.nii")
    np.testing.assert_allclose(vol.spacing, [2, 3, 4], rtol=1e-6)
    np.testing.assert_allclose(vol.direction, rot, atol=1e-6)
    np.testing.assert_allclose(vol.origin, [7, 8, 9])
    # nibabel's own scaled reading is the truth; values exceed int16 -> float32
    assert vol.dtype == np.float32
    np.testing.assert_array_equal(vol.data, nib.load(tmp_path / "s.nii").get_fdata())


def test_nifti_trailing_singleton_dimension(tmp_path):
    raw = _data("uint8")
    nib.save(nib.Nifti1Image(raw[..., None], np.eye(4)), tmp_path / "t.nii")
    np.testing.assert_array_equal(load(tmp_path / "t.nii").data, raw)


def test_pynrrd_written_nrrd_with_spacings(tmp_path):
    data = _data("float32")
    nrrd.write(str(tmp_path / "a.nrrd"), data, {"spacings": [0.5, 0.75, 1.25]}, index_order="F")
    vol = load(tmp_path / "a.nrrd")
    np.testing.assert_array_equal(vol.data, data)
    np.testing.assert_allclose(vol.spacing, SPACING)


def test_our_dicom_read_by_simpleitk(tmp_path):
    vol = _volume("int16")
    folder = str(save(vol, tmp_path / "series"))
    reader = sitk.ImageSeriesReader()
    reader.SetFileNames(reader.GetGDCMSeriesFileNames(folder))
    img = reader.Execute()
    np.testing.assert_array_equal(sitk.GetArrayFromImage(img).transpose(2, 1, 0), vol.data)
    np.testing.assert_allclose(img.GetSpacing(), SPACING, atol=1e-6)
    np.testing.assert_allclose(img.GetOrigin(), ORIGIN, atol=1e-6)
    np.testing.assert_allclose(np.reshape(img.GetDirection(), (3, 3)), ROT, atol=1e-6)


# ---------------------------------------------------------------- the real InVesalius head CT


@needs_cranium
def test_cranium_matches_direct_read_of_matrix_dat():
    vol = load(CRANIUM)
    with tarfile.open(CRANIUM, "r:gz") as tar:
        names = {os.path.basename(m.name): m for m in tar.getmembers()}
        meta = plistlib.loads(tar.extractfile(names["main.plist"]).read())
        raw = np.frombuffer(tar.extractfile(names["matrix.dat"]).read(), dtype="<i2")
    assert meta["matrix"]["shape"] == [108, 256, 256]
    direct = raw.reshape(108, 256, 256)  # [z, y, x]
    assert vol.shape == (256, 256, 108)
    assert vol.dtype == np.int16
    np.testing.assert_array_equal(vol.data, direct.transpose(2, 1, 0))
    np.testing.assert_allclose(vol.spacing, [0.9570312, 0.9570312, 1.5], atol=1e-6)
    np.testing.assert_array_equal(vol.origin, np.zeros(3))
    assert vol.is_label is False
    # plausible Hounsfield units: air about -1000 (padding -1024), soft tissue near 0..100, bone > 1000
    lo, hi = int(vol.data.min()), int(vol.data.max())
    assert -1100 <= lo <= -900 and 1500 < hi < 4000
    assert np.median(vol.data[:, :, 0]) < -900  # corner slice is mostly air
    assert 0.005 < np.mean(vol.data > 1000) < 0.1  # some, not most, voxels are bone


def _fake_inv3(path, *, shape=(3, 4, 5), spacing=(0.5, 0.6, 2.0), nbytes=None, dtype="int16"):
    data = np.arange(np.prod(shape), dtype="<i2").reshape(shape)
    payload = data.tobytes() if nbytes is None else data.tobytes()[:nbytes]
    plist = plistlib.dumps(
        {"matrix": {"dtype": dtype, "filename": "matrix.dat", "shape": list(shape)}, "spacing": list(spacing)}
    )
    with tarfile.open(path, "w:gz") as tar:
        for name, blob in (("proj/main.plist", plist), ("proj/matrix.dat", payload)):
            info = tarfile.TarInfo(name)
            info.size = len(blob)
            tar.addfile(info, io.BytesIO(blob))
    return data


def test_inv3_metadata_comes_from_the_plist(tmp_path):
    data = _fake_inv3(tmp_path / "p.inv3")
    vol = load(tmp_path / "p.inv3")
    assert vol.shape == (5, 4, 3)
    np.testing.assert_array_equal(vol.data, data.transpose(2, 1, 0))
    np.testing.assert_allclose(vol.spacing, [0.5, 0.6, 2.0])


def test_inv3_truncated_matrix(tmp_path):
    _fake_inv3(tmp_path / "p.inv3", nbytes=10)
    with pytest.raises(InputError, match=r"p\.inv3.*matrix\.dat.*120 bytes.*found 10 bytes"):
        load(tmp_path / "p.inv3")


def test_inv3_is_read_only(tmp_path):
    with pytest.raises(InputError, match="read-only"):
        save(_volume(), tmp_path / "x.inv3")


# ---------------------------------------------------------------- bad input


def test_unknown_suffix_lists_supported(tmp_path):
    (tmp_path / "vol.xyz").write_bytes(b"abc")
    with pytest.raises(InputError) as err:
        load(tmp_path / "vol.xyz")
    msg = str(err.value)
    assert "vol.xyz" in msg and "'.xyz'" in msg
    for suffix in (".nrrd", ".nii.gz", ".mha", ".npy", ".npz", ".inv3", "DICOM"):
        assert suffix in msg
    with pytest.raises(InputError, match=r"vol\.xyz.*\.nrrd"):
        save(_volume(), tmp_path / "vol.xyz")


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"nope\.nii\.gz.*no such file"):
        load(tmp_path / "nope.nii.gz")


@pytest.mark.parametrize("suffix", [".nii.gz", ".nii", ".nrrd", ".mha", ".npy", ".npz", ".inv3"])
def test_corrupt_file(tmp_path, suffix):
    path = tmp_path / f"junk{suffix}"
    path.write_bytes(np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(InputError) as err:
        load(path)
    assert str(path) in str(err.value)
    assert err.value.source == str(path)


def test_truncated_gzip_nifti(tmp_path):
    good = save(_volume(), tmp_path / "good.nii.gz").read_bytes()
    bad = tmp_path / "bad.nii.gz"
    bad.write_bytes(good[: len(good) // 2])
    with pytest.raises(InputError, match=r"bad\.nii\.gz.*NIfTI"):
        load(bad)


def test_two_d_npy_rejected_with_shape(tmp_path):
    np.save(tmp_path / "flat.npy", np.zeros((4, 5), np.float32))
    with pytest.raises(InputError, match=r"flat\.npy.*3-D.*\(4, 5\)"):
        load(tmp_path / "flat.npy")


def test_empty_npy_rejected(tmp_path):
    np.save(tmp_path / "empty.npy", np.zeros((0, 3, 3), np.float32))
    with pytest.raises(InputError, match=r"empty\.npy.*non-empty"):
        load(tmp_path / "empty.npy")


def test_four_d_nifti_rejected(tmp_path):
    nib.save(nib.Nifti1Image(np.zeros((2, 3, 4, 5), np.uint8), np.eye(4)), tmp_path / "t.nii")
    with pytest.raises(InputError, match=r"t\.nii.*\(2, 3, 4, 5\)"):
        load(tmp_path / "t.nii")


def test_two_d_metaimage_rejected(tmp_path):
    sitk.WriteImage(sitk.Image(4, 5, sitk.sitkUInt8), str(tmp_path / "flat.mha"))
    with pytest.raises(InputError, match=r"flat\.mha.*3-D"):
        load(tmp_path / "flat.mha")


def test_npz_without_data_key(tmp_path):
    np.savez(tmp_path / "a.npz", volume=np.zeros((2, 2, 2)))
    with pytest.raises(InputError, match=r"a\.npz.*'data'.*volume"):
        load(tmp_path / "a.npz")


def test_npz_bad_spacing_names_file(tmp_path):
    np.savez(tmp_path / "a.npz", data=np.zeros((2, 2, 2)), spacing=[1.0, 0.0, 1.0])
    with pytest.raises(InputError, match=r"a\.npz.*spacing.*> 0"):
        load(tmp_path / "a.npz")


def test_dicom_folder_without_slices(tmp_path):
    (tmp_path / "README.txt").write_text("not dicom")
    with pytest.raises(InputError, match="no DICOM slices"):
        load(tmp_path)


def test_dicom_inconsistent_slice_sizes(tmp_path):
    folder = save(_volume("int16"), tmp_path / "series")
    odd = Volume(np.zeros((3, 3, 1), np.int16), spacing=SPACING, origin=ORIGIN + [0, 0, 100])
    other = save(odd, tmp_path / "other")
    ds = pydicom.dcmread(next(other.iterdir()))
    ref = pydicom.dcmread(next(folder.iterdir()))
    ds.SeriesInstanceUID = ref.SeriesInstanceUID
    ds.save_as(folder / "zz_odd.dcm")
    with pytest.raises(InputError, match=r"zz_odd\.dcm.*Rows x Columns.*6 x 5.*3 x 3"):
        load(folder)


def test_dicom_duplicate_slice_positions(tmp_path):
    folder = save(_volume("int16"), tmp_path / "series")
    files = sorted(folder.iterdir())
    ds = pydicom.dcmread(files[1])
    ds.ImagePositionPatient = pydicom.dcmread(files[0]).ImagePositionPatient
    ds.save_as(files[1])
    with pytest.raises(InputError, match="one slice per position"):
        load(folder)


def test_dicom_refuses_float_data(tmp_path):
    with pytest.raises(InputError, match=r"float32"):
        save(_volume("float32"), tmp_path / "series")
    assert _listing(tmp_path) == []


def test_dicom_will_not_replace_a_folder_of_other_files(tmp_path):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("precious")
    with pytest.raises(InputError, match="notes.txt"):
        save(_volume(), folder)
    assert (folder / "notes.txt").read_text() == "precious"


def test_save_rejects_non_volume_and_missing_folder(tmp_path):
    with pytest.raises(InputError, match="Volume"):
        save(np.zeros((2, 2, 2)), tmp_path / "a.nrrd")
    with pytest.raises(InputError, match="does not exist"):
        save(_volume(), tmp_path / "no" / "a.nrrd")


def test_save_rejects_unsupported_dtype(tmp_path):
    vol = Volume(np.zeros((2, 2, 2), np.complex64))
    with pytest.raises(InputError, match="complex64"):
        save(vol, tmp_path / "a.nii")
    assert _listing(tmp_path) == []


# ---------------------------------------------------------------- atomic saves


@pytest.mark.parametrize("suffix", [".nii.gz", ".nrrd", ".nhdr", ".mha", ".mhd", ".npy", ".npz"])
def test_failed_save_keeps_old_file_and_leaves_no_temp(tmp_path, monkeypatch, suffix):
    path = tmp_path / f"vol{suffix}"
    save(_volume("int16"), path)
    before = {n: (tmp_path / n).read_bytes() for n in _listing(tmp_path)}

    real = _io._WRITERS[_io._format_of(path)]

    def half_then_fail(volume, data, tmp_file):
        real(volume, data, tmp_file)  # the new file(s) exist under their temporary name ...
        with open(tmp_file, "r+b") as f:
            f.truncate(10)
        raise OSError("disk full")  # ... when the write fails

    monkeypatch.setattr(_io, f"_write_{_io._format_of(path)}", half_then_fail)
    with pytest.raises(OSError, match="disk full"):
        save(_volume("float32"), path)
    assert {n: (tmp_path / n).read_bytes() for n in _listing(tmp_path)} == before
    np.testing.assert_array_equal(load(path).data, _data("int16"))


def test_failed_nibabel_save_keeps_old_file(tmp_path, monkeypatch):
    path = save(_volume("uint8"), tmp_path / "a.nii.gz")
    old = path.read_bytes()

    def broken_save(img, filename):
        with gzip.open(filename, "wb") as f:
            f.write(b"partial")
        raise RuntimeError("boom")

    monkeypatch.setattr(nib, "save", broken_save)
    with pytest.raises(RuntimeError, match="boom"):
        save(_volume("int16"), path)
    assert path.read_bytes() == old
    assert _listing(tmp_path) == ["a.nii.gz"]


def test_failed_dicom_save_keeps_old_series(tmp_path, monkeypatch):
    folder = save(_volume("int16"), tmp_path / "series")
    before = {f.name: f.read_bytes() for f in folder.iterdir()}

    def broken(volume, data, tmp_folder):
        (tmp_folder / "slice_0000.dcm").write_bytes(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(_io, "_write_dicom", broken)
    with pytest.raises(OSError, match="disk full"):
        save(_volume("uint8"), folder)
    assert {f.name: f.read_bytes() for f in folder.iterdir()} == before
    assert _listing(tmp_path) == ["series"]


def test_dicom_folder_skips_other_files_but_not_corrupt_dcm(tmp_path):
    vol = _volume("int16")
    folder = save(vol, tmp_path / "series")
    (folder / "README.txt").write_text("notes")
    _assert_same(load(folder), vol, geometry_atol=1e-6)
    (folder / "broken.dcm").write_bytes(b"\x00" * 50)
    with pytest.raises(InputError, match=r"broken\.dcm.*DICOM"):
        load(folder)


def test_volume_direction_must_be_orthonormal_within_1e_4():
    """``Volume.direction`` is accepted when ``d.T @ d`` is the identity within 1e-4 (as
    ``np.allclose(..., atol=1e-4)``). Truth: SciPy's rotations (proper and reflected) are
    orthonormal; a shear whose ``d.T @ d`` is off by 2e-4 is not, and one off by 5e-5 is."""
    from scipy.spatial.transform import Rotation

    data = np.zeros((2, 3, 4), np.int16)
    for d in (Rotation.random(random_state=7).as_matrix(), ROT @ np.diag([1.0, 1.0, -1.0])):
        np.testing.assert_array_equal(Volume(data, direction=d).direction, d)
    for off, ok in ((2e-4, False), (5e-5, True)):
        d = np.eye(3)
        d[0, 1] = off  # d.T @ d = I + off at (0, 1), (1, 0) and off**2 at (1, 1)
        assert np.allclose(d.T @ d, np.eye(3), atol=1e-4) == ok
        if ok:
            Volume(data, direction=d)
        else:
            with pytest.raises(InputError, match="Volume.direction.*orthonormal"):
                Volume(data, direction=d)
