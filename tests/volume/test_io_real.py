"""Real volumes a user has: the packages' own sample files (pydicom's and nibabel's test
data) and hand-written headers whose voxel values the test constructs, each loaded and
deformed, or refused with a message naming the file and what to do.

The truth is always independent of softvr's reader: nibabel's / pydicom's / SimpleITK's
reading of the same file, or the values the test wrote itself."""

from __future__ import annotations

import gzip
import os
import warnings

import nibabel as nib
import numpy as np
import pydicom
import pydicom.data
import pytest
import SimpleITK as sitk
from nibabel.testing import data_path as NIBABEL_DATA
from pydicom.fileset import FileSet

from softvr.errors import InputError
from softvr.volume import SUPPORTED_DTYPES, Volume, deform, grid_tet_mesh, load, save

PYDICOM_DATA = os.path.join(os.path.dirname(pydicom.data.__file__), "test_files")


def _pydicom_file(name: str) -> str:
    """A pydicom test file shipped with the package (never the download of a missing one)."""
    path = os.path.join(PYDICOM_DATA, name)
    if not os.path.isfile(path):
        pytest.skip(f"pydicom test file {name} not shipped")
    return path


def _nibabel_file(name: str) -> str:
    return os.path.join(str(NIBABEL_DATA), name)


def _deforms(vol: Volume) -> None:
    """``vol`` goes through softvr.volume.deform: a rigid shift of the embedding mesh by a
    whole number of voxels gives the same voxels on a shifted grid."""
    assert vol.dtype in SUPPORTED_DTYPES and vol.data.dtype.isnative
    nodes, tets = grid_tet_mesh(vol, cells=2)
    shift = vol.direction @ (vol.spacing * np.array([2.0, 1.0, 0.0]))
    out = deform(vol, nodes, tets, nodes + shift, device="cpu")
    assert out.dtype == vol.dtype
    np.testing.assert_allclose(out.origin, vol.origin + shift, atol=1e-6 * np.abs(vol.origin).max() + 1e-9)
    np.testing.assert_allclose(out.data.astype(np.float64), vol.data.astype(np.float64),
                               atol=1e-3 * float(np.abs(vol.data).max()) + 1e-6)


def _load_quiet(path, **kw) -> Volume:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a sample file of a deformable type converts nothing
        return load(path, **kw)


# ---------------------------------------------------------------- NIfTI (nibabel's samples)


@pytest.mark.parametrize("name", ["anatomical.nii", "reoriented_anat_moved.nii"])
def test_big_endian_nifti_loads_native_and_deforms(name):
    path = _nibabel_file(name)
    img = nib.load(path)
    assert img.header.endianness == ">"  # the sample is big-endian
    vol = _load_quiet(path)
    truth = np.asanyarray(img.dataobj)
    assert vol.dtype == truth.dtype.newbyteorder("=") and vol.data.dtype.isnative
    np.testing.assert_array_equal(vol.data, truth)
    np.testing.assert_allclose(vol.index_to_world([1, 2, 3]), img.affine[:3, :3] @ [1, 2, 3] + img.affine[:3, 3])
    _deforms(vol)


@pytest.mark.parametrize("name", ["example4d.nii.gz", "example_nifti2.nii.gz", "functional.nii"])
def test_four_d_nifti_refused_without_frame_then_each_frame_loads(name):
    path = _nibabel_file(name)
    img = nib.load(path)
    n = img.shape[3]
    with pytest.raises(InputError) as err:
        load(path)
    msg = str(err.value)
    assert err.value.source == path and err.value.what == "dim[4]"
    assert "frame=" in msg and f"0 .. {n - 1}" in msg
    truth = np.asanyarray(img.dataobj)
    for k in (0, n - 1):
        vol = load(path, frame=k)
        np.testing.assert_allclose(vol.data, truth[..., k], rtol=1e-6)
    _deforms(vol)
    with pytest.raises(InputError, match=rf"{name}.*frame.*0 \.\. {n - 1}"):
        load(path, frame=n)


def test_frame_on_a_three_d_file_is_refused():
    with pytest.raises(InputError, match=r"standard\.nii\.gz: frame: expected None"):
        load(_nibabel_file("standard.nii.gz"), frame=0)


@pytest.mark.parametrize(
    ("dtype", "values", "target", "says"),
    [
        ("int8", [-128, 0, 5, 127], np.int16, "exact"),
        ("int32", [-70000, 0, 3, 70000], np.float32, "exceed 16 bits"),
        ("int32", [-5, 0, 3, 300], np.int16, "fit"),
        ("uint32", [0, 1, 40000, 65535], np.uint16, "fit"),
        ("float64", [-1.5, 0.0, 0.25, 1e6], np.float32, "float32"),
    ],
)
def test_other_voxel_types_convert_with_one_warning_and_deform(tmp_path, dtype, values, target, says):
    data = np.resize(np.asarray(values, dtype=dtype), (4, 5, 6))
    path = tmp_path / f"{dtype}.nii"
    nib.save(nib.Nifti1Image(data, np.diag([2.0, 3.0, 4.0, 1.0])), path)  # nibabel writes it, not softvr
    with pytest.warns(UserWarning) as record:
        vol = load(path)
    assert len(record) == 1
    text = str(record[0].message)
    assert str(path) in text and dtype in text and np.dtype(target).name in text and says in text
    assert vol.dtype == target
    np.testing.assert_array_equal(vol.data, data.astype(target))
    _deforms(vol)


# ---------------------------------------------------------------- NRRD and MetaImage, hand-written


def _nrrd(path, header: str, payload: bytes) -> None:
    path.write_bytes(header.encode() + b"\n" + payload)


@pytest.mark.parametrize("encoding", ["raw", "gzip"])
def test_big_endian_int16_nrrd(tmp_path, encoding):
    truth = np.arange(-60, 60, dtype=np.int16).reshape((4, 5, 6), order="F") * 101
    payload = truth.astype(">i2").tobytes(order="F")
    path = tmp_path / "be.nrrd"
    _nrrd(path, "NRRD0004\ntype: short\ndimension: 3\nsizes: 4 5 6\nendian: big\n"
          f"encoding: {encoding}\nspace dimension: 3\nspace directions: (0,2,0) (-1.5,0,0) (0,0,3)\n"
          "space origin: (1,2,3)\n", gzip.compress(payload) if encoding == "gzip" else payload)
    vol = _load_quiet(path)
    assert vol.dtype == np.int16 and vol.data.dtype.isnative
    np.testing.assert_array_equal(vol.data, truth)
    np.testing.assert_allclose(vol.spacing, [2.0, 1.5, 3.0])
    np.testing.assert_allclose(vol.direction, [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    np.testing.assert_allclose(vol.origin, [1, 2, 3])
    import nrrd  # pynrrd's own reading of the same file agrees

    np.testing.assert_array_equal(nrrd.read(str(path), index_order="F")[0], truth)
    _deforms(vol)


@pytest.mark.parametrize("encoding", ["raw", "gzip", "bzip2"])
def test_nrrd_byte_skip_minus_one_reads_the_last_bytes(tmp_path, encoding):
    # pynrrd's samples use it to read the voxels of a NIfTI file through an .nhdr
    import bz2

    truth = np.arange(24, dtype="<u2").reshape((2, 3, 4), order="F") * 1000
    stream = b"\x07" * 352 + truth.tobytes(order="F")
    packed = {"raw": stream, "gzip": gzip.compress(stream), "bzip2": bz2.compress(stream)}[encoding]
    (tmp_path / "d.bin").write_bytes(packed)
    path = tmp_path / "skip.nhdr"
    path.write_text(f"NRRD0004\ntype: ushort\ndimension: 3\nsizes: 2 3 4\nendian: little\nencoding: {encoding}\n"
                    "byte skip: -1\ndata file: d.bin\n")
    np.testing.assert_array_equal(_load_quiet(path).data, truth)


def test_four_d_nrrd_picks_the_channel_axis(tmp_path):
    # kinds "vector domain domain domain": the channel axis is the first, fastest one
    truth = np.arange(2 * 3 * 4 * 5, dtype=np.float32).reshape((2, 3, 4, 5), order="F")
    path = tmp_path / "vec.nhdr"
    (tmp_path / "vec.raw").write_bytes(truth.astype("<f4").tobytes(order="F"))
    path.write_text("NRRD0004\ntype: float\ndimension: 4\nsizes: 2 3 4 5\nendian: little\nencoding: raw\n"
                    "kinds: vector domain domain domain\nspace dimension: 3\n"
                    "space directions: none (1,0,0) (0,1,0) (0,0,1)\ndata file: vec.raw\n")
    with pytest.raises(InputError) as err:
        load(path)
    assert err.value.what == "sizes" and "frame=" in str(err.value) and str(path) in str(err.value)
    for k in (0, 1):
        np.testing.assert_array_equal(load(path, frame=k).data, truth[k])
    _deforms(load(path, frame=1))


def test_metaimage_big_endian_int8_with_direction_agrees_with_simpleitk(tmp_path):
    truth = np.resize(np.arange(-100, 100, 7, dtype=np.int8), (3, 4, 5))
    (tmp_path / "v.raw").write_bytes(truth.tobytes(order="F"))
    path = tmp_path / "v.mhd"
    path.write_text("ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = True\n"
                    "TransformMatrix = 0 1 0 -1 0 0 0 0 1\nOffset = 5 6 7\nElementSpacing = 0.5 1 2\n"
                    "DimSize = 3 4 5\nElementType = MET_CHAR\nElementDataFile = v.raw\n")
    with pytest.warns(UserWarning, match="int8 converted to int16"):
        vol = load(path)
    np.testing.assert_array_equal(vol.data, truth)
    img = sitk.ReadImage(str(path))  # SimpleITK's reading of the same header
    np.testing.assert_allclose(vol.direction, np.reshape(img.GetDirection(), (3, 3)))
    np.testing.assert_allclose(vol.origin, img.GetOrigin())
    np.testing.assert_allclose(vol.spacing, img.GetSpacing())
    np.testing.assert_allclose(vol.index_to_world([1, 2, 3]), img.TransformContinuousIndexToPhysicalPoint((1, 2, 3)))
    _deforms(vol)


def test_detached_data_file_names_with_spaces(tmp_path):
    truth = np.arange(8, dtype=np.uint8).reshape((2, 2, 2), order="F")
    (tmp_path / "my scan.raw").write_bytes(truth.tobytes(order="F"))
    (tmp_path / "a.mhd").write_text("NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\n"
                                    "ElementDataFile = my scan.raw\n")
    (tmp_path / "a.nhdr").write_text("NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n"
                                     "data file: my scan.raw\n")
    for name in ("a.mhd", "a.nhdr"):
        np.testing.assert_array_equal(load(tmp_path / name).data, truth)


def test_metaimage_four_d_frames(tmp_path):
    truth = np.arange(3 * 4 * 5 * 2, dtype=np.uint16).reshape((3, 4, 5, 2), order="F")
    path = tmp_path / "t.mha"
    path.write_bytes(b"ObjectType = Image\nNDims = 4\nDimSize = 3 4 5 2\nElementType = MET_USHORT\n"
                     b"ElementDataFile = LOCAL\n" + truth.astype("<u2").tobytes(order="F"))
    with pytest.raises(InputError, match=r"t\.mha: DimSize: .*frame="):
        load(path)
    np.testing.assert_array_equal(load(path, frame=1).data, truth[..., 1])


# ---------------------------------------------------------------- DICOM (pydicom's samples)


@pytest.mark.parametrize("name", ["CT_small.dcm", "MR_small.dcm", "MR_small_bigendian.dcm"])
def test_single_dcm_file_is_a_one_slice_volume(name):
    path = _pydicom_file(name)
    ds = pydicom.dcmread(path)
    vol = _load_quiet(path)
    assert vol.shape == (int(ds.Columns), int(ds.Rows), 1)
    truth = ds.pixel_array.astype(np.float64) * float(ds.get("RescaleSlope", 1)) + float(ds.get("RescaleIntercept", 0))
    np.testing.assert_array_equal(vol.data[:, :, 0].T, truth)
    np.testing.assert_allclose(vol.origin, [float(v) for v in ds.ImagePositionPatient])
    np.testing.assert_allclose(vol.spacing[:2], [float(ds.PixelSpacing[1]), float(ds.PixelSpacing[0])])
    _deforms(vol)


def test_big_endian_dicom_equals_little_endian():
    little, big = load(_pydicom_file("MR_small.dcm")), load(_pydicom_file("MR_small_bigendian.dcm"))
    np.testing.assert_array_equal(little.data, big.data)


@pytest.mark.parametrize("name", ["rtdose.dcm", "rtdose_expb.dcm"])
def test_multi_frame_dicom_frames_are_slices(name):
    path = _pydicom_file(name)
    ds = pydicom.dcmread(path)
    n = int(ds.NumberOfFrames)
    vol = _load_quiet(path)
    assert vol.shape == (int(ds.Columns), int(ds.Rows), n)
    raw = ds.pixel_array  # [frames, rows, cols], uint32 (big-endian for rtdose_expb)
    assert raw.dtype.kind == "u" and raw.dtype.itemsize == 4
    np.testing.assert_allclose(vol.data, raw.transpose(2, 1, 0) * float(ds.DoseGridScaling), rtol=1e-6)
    offsets = np.asarray([float(v) for v in ds.GridFrameOffsetVector])
    assert vol.spacing[2] == pytest.approx(offsets[1] - offsets[0])
    np.testing.assert_allclose(vol.origin, [float(v) for v in ds.ImagePositionPatient])
    _deforms(vol)


def test_enhanced_multi_frame_positions_from_per_frame_groups(tmp_path):
    ds = pydicom.dcmread(_pydicom_file("rtdose.dcm"))
    n = int(ds.NumberOfFrames)
    first = np.array([float(v) for v in ds.ImagePositionPatient])
    del ds.GridFrameOffsetVector
    groups = []
    for k in range(n):  # frames stored top to bottom: the reader must sort them
        plane = pydicom.Dataset()
        plane.ImagePositionPatient = [f"{v:.5f}" for v in first + [0, 0, 2.5 * (n - 1 - k)]]
        group = pydicom.Dataset()
        group.PlanePositionSequence = [plane]
        groups.append(group)
    ds.PerFrameFunctionalGroupsSequence = groups
    path = tmp_path / "enhanced.dcm"
    ds.save_as(path)
    vol = load(path)
    assert vol.spacing[2] == pytest.approx(2.5)
    np.testing.assert_allclose(vol.origin, first)
    np.testing.assert_allclose(vol.data, ds.pixel_array[::-1].transpose(2, 1, 0) * float(ds.DoseGridScaling),
                               rtol=1e-6)


def test_dicomdir_lists_its_series_and_loads_the_one_picked():
    path = _pydicom_file("dicomdirtests/DICOMDIR")
    fs = FileSet(pydicom.dcmread(path))  # pydicom's own reading of the directory
    uids = fs.find_values("SeriesInstanceUID")
    with pytest.raises(InputError) as err:
        load(path)
    msg = str(err.value)
    assert err.value.source == path and err.value.what == "SeriesInstanceUID"
    assert f"{len(uids)} series" in msg and "series=" in msg and uids[0] in msg
    # the CT series of five 16 x 16 slices
    uid = next(u for u in uids if len(fs.find(SeriesInstanceUID=u)) == 5)
    slices = [pydicom.dcmread(i.path) for i in fs.find(SeriesInstanceUID=uid)]
    vol = load(path, series=uid)
    assert vol.shape == (16, 16, 5)
    by_z = sorted(slices, key=lambda d: float(np.asarray(d.ImagePositionPatient, float) @ vol.direction[:, 2]))
    truth = np.stack([d.pixel_array * float(d.RescaleSlope) + float(d.RescaleIntercept) for d in by_z], axis=-1)
    np.testing.assert_allclose(vol.data, truth.transpose(1, 0, 2))
    _deforms(vol)
    # the same directory read through its folder; an index into the listed series
    assert load(os.path.dirname(path), series=uid).shape == (16, 16, 5)
    with pytest.raises(InputError, match=rf"DICOMDIR: series: .*'nope'.*{len(uids)} series"):
        load(path, series="nope")


def test_folder_with_two_series_lists_them_and_picks_by_index(tmp_path):
    a = Volume(np.arange(60, dtype=np.int16).reshape(3, 4, 5), spacing=(1, 1, 2))
    b = Volume(np.arange(24, dtype=np.uint8).reshape(2, 3, 4) + 7, spacing=(1, 1, 1), origin=(0, 0, 50))
    save(a, tmp_path / "a")
    save(b, tmp_path / "b")
    both = tmp_path / "both"
    both.mkdir()
    for name in ("a", "b"):
        for f in (tmp_path / name).iterdir():
            f.rename(both / f"{name}_{f.name}")
    with pytest.raises(InputError) as err:
        load(both)
    assert "2 series" in str(err.value) and "series=" in str(err.value) and str(both) in str(err.value)
    got = sorted((load(both, series=i) for i in (0, 1)), key=lambda v: v.data.size)
    np.testing.assert_array_equal(got[0].data, b.data)
    np.testing.assert_array_equal(got[1].data, a.data)


def test_colour_dicom_refused_naming_the_field():
    path = _pydicom_file("examples_rgb_color.dcm")
    with pytest.raises(InputError, match=r"examples_rgb_color\.dcm: SamplesPerPixel.*grey-scale"):
        load(path)


# ---------------------------------------------------------------- softvr info


def test_repr_shows_the_direction_matrix():
    img = nib.load(_nibabel_file("example4d.nii.gz"))
    vol = load(_nibabel_file("example4d.nii.gz"), frame=0)
    direction = img.affine[:3, :3] / np.linalg.norm(img.affine[:3, :3], axis=0)
    text = repr(vol)
    assert "direction=" in text
    for v in np.round(direction, 4).reshape(-1)[:3]:
        assert f"{v:.4g}" in text


@pytest.mark.parametrize(("kw", "what"), [({"frame": -1}, "frame"), ({"frame": True}, "frame"),
                                          ({"frame": 1.0}, "frame"), ({"series": -2}, "series"),
                                          ({"series": 0.5}, "series")])
def test_bad_frame_and_series_options(kw, what):
    with pytest.raises(InputError) as err:
        load(_nibabel_file("example4d.nii.gz"), **kw)
    assert err.value.what == what and "example4d.nii.gz" in err.value.source


def test_series_option_only_for_dicom():
    with pytest.raises(InputError, match=r"standard\.nii\.gz: series: expected None \(only DICOM"):
        load(_nibabel_file("standard.nii.gz"), series=0)


def test_save_to_a_dcm_file_name_is_refused_with_the_folder_hint(tmp_path):
    with pytest.raises(InputError, match=r"v\.dcm: file name suffix: .*folder of slices"):
        save(Volume(np.zeros((2, 2, 2), np.int16)), tmp_path / "v.dcm")
    assert os.listdir(tmp_path) == []
