"""DICOM series sorting and checks, softvr's own (docs/volume.md says why not SimpleITK's).

Truths: a series softvr writes from a known volume (its voxels, spacing, origin, an oblique
direction); SimpleITK's GDCM series scan as an independent sorter of the same files; a series
with one slice removed has steps of one and two slice spacings.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import SimpleITK as sitk
from scipy.spatial.transform import Rotation

from softvr.errors import InputError
from softvr.volume import Volume, load, save

SPACING = (0.6, 0.8, 1.2)
# Oblique: sorting by z alone (or by file name) would get the order wrong.
DIRECTION = Rotation.from_euler("xyz", [25.0, -40.0, 60.0], degrees=True).as_matrix()


def _series(tmp_path, slices=9):
    data = np.random.default_rng(3).integers(-1000, 1000, (7, 5, slices)).astype(np.int16)
    vol = Volume(data, spacing=SPACING, origin=(12.0, -3.0, 40.0), direction=DIRECTION)
    return vol, save(vol, tmp_path / "series")


def _shuffle_names(folder):
    files = sorted(folder.iterdir())
    for f, k in zip(files, np.random.default_rng(5).permutation(len(files))):
        f.rename(folder / f"img{k:03d}.dcm")


def test_oblique_shuffled_series_sorts_as_gdcm_does(tmp_path):
    """File names shuffled, slices along an oblique normal: softvr's order, spacing, origin and
    direction equal what it wrote, and SimpleITK's GDCM scan of the folder reads the same voxels."""
    vol, folder = _series(tmp_path)
    _shuffle_names(folder)
    back = load(folder)
    np.testing.assert_array_equal(back.data, vol.data)
    np.testing.assert_allclose(back.spacing, SPACING, atol=1e-6)
    np.testing.assert_allclose(back.origin, vol.origin, atol=1e-6)
    np.testing.assert_allclose(back.direction, DIRECTION, atol=1e-6)
    reader = sitk.ImageSeriesReader()
    reader.SetFileNames(reader.GetGDCMSeriesFileNames(str(folder)))
    np.testing.assert_array_equal(sitk.GetArrayFromImage(reader.Execute()).transpose(2, 1, 0), back.data)


def test_a_missing_slice_is_refused_not_averaged(tmp_path):
    """One slice removed: steps of 1.2 and 2.4 mm. softvr refuses (SimpleITK reads it with a
    warning and one averaged spacing, 9.6 mm / 7 = 1.37 mm here: every slice after the gap misplaced)."""
    _, folder = _series(tmp_path)
    os.remove(sorted(folder.iterdir())[4])
    with pytest.raises(InputError, match=r"uniformly spaced slices.*from 1\.2 to 2\.4"):
        load(folder)


def test_a_fifo_in_the_folder_is_skipped_unopened(tmp_path):
    """A FIFO (opening it would block) among the slices is skipped after softvr's file check;
    the series reads whole (GDCM's folder scan, handed the same folder, lists 1 of the 9)."""
    vol, folder = _series(tmp_path)
    os.mkfifo(folder / "pipe")
    np.testing.assert_array_equal(load(folder).data, vol.data)
