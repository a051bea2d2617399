"""MP4, contact sheet and PNG output, including atomic replacement on failure."""

from __future__ import annotations

import imageio.v2 as imageio
import imageio.v3 as iio
import numpy as np
import pytest

from softvr.errors import InputError
from softvr.render import contact_sheet, save_png, write_mp4


def frames(n: int, h: int = 48, w: int = 64):
    for i in range(n):
        f = np.zeros((h, w, 3), np.uint8)
        f[:, : (i + 1) * w // n] = (200, 60, 20)  # a bar growing frame by frame
        yield f


def read_all(path):
    reader = imageio.get_reader(path)
    try:
        meta = reader.get_meta_data()
        return [np.asarray(f) for f in reader], meta
    finally:
        reader.close()


def test_mp4_reads_back_with_frame_count_size_and_content(tmp_path):
    path = write_mp4(frames(7), tmp_path / "clip.mp4", fps=12)
    got, meta = read_all(path)
    assert len(got) == 7
    assert got[0].shape == (48, 64, 3)
    assert meta["fps"] == pytest.approx(12)
    expected = list(frames(7))
    for a, b in zip(got, expected):  # lossy H.264: colours within a few levels away from edges
        assert np.abs(a[:, :4].astype(int) - b[:, :4]).max() <= 12
        assert np.abs(a[:, -4:].astype(int) - b[:, -4:]).max() <= 12
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]  # no temporary left


def test_mp4_pads_odd_sizes_and_rejects_bad_frames(tmp_path):
    got, _ = read_all(write_mp4(frames(3, 31, 45), tmp_path / "odd.mp4"))
    assert got[0].shape == (32, 46, 3)
    with pytest.raises(InputError, match="at least one frame"):
        write_mp4([], tmp_path / "empty.mp4")
    with pytest.raises(InputError, match="uint8"):
        write_mp4([np.zeros((8, 8, 3), np.float32)], tmp_path / "f.mp4")
    with pytest.raises(InputError, match=r"frames\[1\]"):
        write_mp4([np.zeros((8, 8, 3), np.uint8), np.zeros((8, 10, 3), np.uint8)], tmp_path / "s.mp4")
    with pytest.raises(InputError, match="fps"):
        write_mp4(frames(2), tmp_path / "r.mp4", fps=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["odd.mp4"]


def test_failed_encoding_keeps_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "clip.mp4"
    path.write_bytes(b"old video")
    real_get_writer = imageio.get_writer

    class FailingWriter:
        """The real ffmpeg writer, failing on the third frame (after ffmpeg started writing)."""

        def __init__(self, *args, **kwargs):
            self.inner = real_get_writer(*args, **kwargs)
            self.count = 0

        def append_data(self, frame):
            self.count += 1
            if self.count == 3:
                raise RuntimeError("encoder died")
            self.inner.append_data(frame)

        def close(self):
            self.inner.close()

    monkeypatch.setattr(imageio, "get_writer", FailingWriter)
    with pytest.raises(RuntimeError, match="encoder died"):
        write_mp4(frames(5), path)
    assert path.read_bytes() == b"old video"
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]


def test_failing_frame_source_keeps_the_old_file(tmp_path):
    path = tmp_path / "clip.mp4"
    path.write_bytes(b"old video")

    def source():
        yield from frames(2)
        raise ValueError("renderer crashed")

    with pytest.raises(ValueError, match="renderer crashed"):
        write_mp4(source(), path)
    assert path.read_bytes() == b"old video"
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]


def test_contact_sheet_size_layout_and_labels():
    tiles = [np.full((30, 40, 3), 10 * (i + 1), np.uint8) for i in range(6)]
    sheet = contact_sheet(tiles, columns=4, gap=4)
    assert sheet.shape == (2 * 30 + 4, 4 * 40 + 3 * 4, 3) and sheet.dtype == np.uint8
    assert (sheet[34:64, 44:84] == 60).all()  # tiles[5] is row 1, column 1
    assert (sheet[34:64, 88:] == 32).all()  # empty tiles are background
    assert contact_sheet(tiles[:2], columns=4, gap=0).shape == (30, 80, 3)
    labelled = contact_sheet(tiles, columns=3, labels=[f"t{i}" for i in range(6)], gap=0)
    assert labelled.shape == (60, 120, 3)
    plain = contact_sheet(tiles, columns=3, gap=0)
    assert (labelled != plain).any(axis=2)[:15, :20].any()  # text in the top-left corner
    assert (labelled == plain)[20:30].all()  # nowhere else
    with pytest.raises(InputError, match="labels"):
        contact_sheet(tiles, labels=["a"])
    with pytest.raises(InputError, match=r"frames\[1\]"):
        contact_sheet([tiles[0], np.zeros((30, 41, 3), np.uint8)])


def test_png_round_trip_and_atomic_failure(tmp_path, monkeypatch):
    image = np.random.default_rng(0).integers(0, 256, (20, 30, 3), dtype=np.uint8)
    path = save_png(image, tmp_path / "a.png")
    assert np.array_equal(iio.imread(path), image)

    def broken_imwrite(uri, *args, **kwargs):
        with open(uri, "wb") as f:
            f.write(b"\x89PNG partial")
        raise OSError("disk full")

    monkeypatch.setattr(iio, "imwrite", broken_imwrite)
    with pytest.raises(OSError, match="disk full"):
        save_png(np.zeros((5, 5, 3), np.uint8), path)
    assert np.array_equal(iio.imread(path), image)
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]
    with pytest.raises(InputError, match="directory"):
        save_png(image, tmp_path / "missing" / "b.png")
    with pytest.raises(InputError, match="uint8"):
        save_png(image.astype(np.float32), tmp_path / "c.png")
