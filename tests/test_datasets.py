"""The real datasets installed by Debian packages."""

from __future__ import annotations

import nibabel as nib
import numpy as np
import pytest

from softvr import datasets
from softvr.errors import InputError
from softvr.volume import Volume

needs = {
    "ct": pytest.mark.skipif(not datasets.HEAD_CT_PATH.is_file(), reason="apt package invesalius-examples missing"),
    "mri": pytest.mark.skipif(not datasets.CH2_PATH.is_file(), reason="apt package mricron-data missing"),
    "mri_better": pytest.mark.skipif(not datasets.CH2BETTER_PATH.is_file(), reason="apt package mricron-data missing"),
}


def test_public_api():
    assert set(datasets.__all__) >= {"head_ct", "mri_ch2", "mri_ch2better"}


@needs["ct"]
def test_head_ct():
    vol = datasets.head_ct()
    assert isinstance(vol, Volume)
    assert vol.shape == (256, 256, 108)
    assert vol.dtype == np.int16
    np.testing.assert_allclose(vol.spacing, [0.957, 0.957, 1.5], atol=1e-3)  # mm
    assert vol.data.min() <= -1000 and vol.data.max() > 1000  # air and bone in HU
    assert not vol.is_label
    assert datasets.head_ct() is not vol  # nothing cached


@needs["mri"]
def test_mri_ch2():
    vol = datasets.mri_ch2()
    assert vol.shape == (181, 217, 181)
    assert vol.dtype == np.uint8
    np.testing.assert_allclose(vol.spacing, [1.0, 1.0, 1.0])
    # same voxels and geometry as nibabel's own reading
    img = nib.load(datasets.CH2_PATH)
    np.testing.assert_array_equal(vol.data, np.asarray(img.dataobj))
    np.testing.assert_allclose(vol.origin, img.affine[:3, 3])
    np.testing.assert_allclose(vol.direction, np.eye(3))
    assert vol.data.max() > 100  # a real brain, not an empty volume


@needs["mri_better"]
def test_mri_ch2better_header_only():
    # loading 35 M voxels is too slow for the unit tests: check what mri_ch2better() will read
    img = nib.load(datasets.CH2BETTER_PATH)
    assert img.shape == (301, 370, 316)
    assert img.get_data_dtype() == np.uint8
    np.testing.assert_allclose(img.header.get_zooms(), [0.5, 0.5, 0.5])


@pytest.mark.parametrize(
    ("func", "attr", "package"),
    [
        (datasets.head_ct, "HEAD_CT_PATH", "invesalius-examples"),
        (datasets.mri_ch2, "CH2_PATH", "mricron-data"),
        (datasets.mri_ch2better, "CH2BETTER_PATH", "mricron-data"),
    ],
)
def test_missing_file_names_path_and_package(tmp_path, monkeypatch, func, attr, package):
    missing = tmp_path / "gone.dat"
    monkeypatch.setattr(datasets, attr, missing)
    with pytest.raises(InputError) as err:
        func()
    assert str(missing) in str(err.value)
    assert package in str(err.value)


def _small_ch2(folder):
    """A small NIfTI named like the dataset, written by nibabel: the values the test knows."""
    folder.mkdir(parents=True, exist_ok=True)
    data = np.arange(24, dtype=np.uint8).reshape(2, 3, 4)
    nib.save(nib.Nifti1Image(data, np.diag([2.0, 2.0, 2.0, 1.0])), folder / "ch2.nii.gz")
    return data


def test_softvr_data_folder_is_searched_first(tmp_path, monkeypatch):
    data = _small_ch2(tmp_path / "mine")
    monkeypatch.setenv("SOFTVR_DATA", str(tmp_path / "mine"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    vol = datasets.mri_ch2()  # found there even where the Debian package is installed
    np.testing.assert_array_equal(vol.data, data)
    np.testing.assert_allclose(vol.spacing, [2.0, 2.0, 2.0])


def test_cache_folder_before_the_debian_path(tmp_path, monkeypatch):
    monkeypatch.delenv("SOFTVR_DATA", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(datasets, "CH2_PATH", tmp_path / "debian" / "ch2.nii.gz")
    assert datasets.cache_folder() == tmp_path / "cache" / "softvr"
    data = _small_ch2(tmp_path / "cache" / "softvr")
    np.testing.assert_array_equal(datasets.mri_ch2().data, data)


def test_missing_everywhere_says_how_to_provide_it(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTVR_DATA", str(tmp_path / "mine"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(datasets, "HEAD_CT_PATH", tmp_path / "debian" / "Cranium.inv3")
    with pytest.raises(InputError) as err:
        datasets.head_ct()
    msg = str(err.value)
    for place in (tmp_path / "mine" / "Cranium.inv3", tmp_path / "cache" / "softvr" / "Cranium.inv3",
                  tmp_path / "debian" / "Cranium.inv3"):
        assert str(place) in msg
    assert "SOFTVR_DATA" in msg and "apt-get install invesalius-examples" in msg
