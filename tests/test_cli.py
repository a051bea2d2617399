"""The ``softvr`` command: help, dispatch, and clear errors instead of tracebacks."""

import subprocess
import sys

import numpy as np
import pytest

from softvr.cli import main
from softvr.volume import Volume, save


def test_help_lists_commands(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for cmd in ("demo", "view", "bench", "info"):
        assert cmd in out


def test_info_prints_volume(tmp_path, capsys):
    path = save(Volume(np.arange(24, dtype=np.int16).reshape(2, 3, 4), spacing=(1, 2, 3)), tmp_path / "v.nrrd")
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "(2, 3, 4)" in out and "int16" in out


def test_bad_file_is_a_clear_error_not_a_traceback(tmp_path):
    bad = tmp_path / "volume.xyz"
    bad.write_text("nothing")
    proc = subprocess.run([sys.executable, "-m", "softvr", "info", str(bad)], capture_output=True, text=True)
    assert proc.returncode == 2
    assert "volume.xyz" in proc.stderr and "Traceback" not in proc.stderr


def test_unknown_subject_is_a_usage_error():
    proc = subprocess.run([sys.executable, "-m", "softvr", "bench", "teapot"], capture_output=True, text=True)
    assert proc.returncode != 0 and "usage" in (proc.stderr + proc.stdout)


def test_demo_shoulder_and_build_model_dispatch(tmp_path, capsys):
    """``softvr demo shoulder`` reaches the shoulder demo (not the volume one); a parts file
    with a missing mesh is a clear error naming the file and the field."""
    assert main(["demo", "shoulder", "--frames", "1", "--size", "32", "24", "--out", str(tmp_path), "--quiet",
                 "--no-haptics"]) == 0
    assert (tmp_path / "shoulder.mp4").is_file()
    parts = tmp_path / "parts.toml"
    parts.write_text('format = "softvr-parts 1"\n[[part]]\nname = "bone"\nmesh = "bone.stl"\nkind = "rigid"\n')
    assert main(["build-model", str(parts)]) == 2
    err = capsys.readouterr().err
    assert "parts.toml" in err and "part[0].mesh" in err and "Traceback" not in err


def test_a_bug_is_reported_as_an_internal_error_without_a_traceback(monkeypatch, capsys):
    """Truth: the CLI contract — bad input exits 2, anything else exits 70 with one line
    naming the exception type, and no traceback (SOFTVR_DEBUG=1 shows it)."""
    from softvr import cli

    def broken(argv):
        raise ZeroDivisionError("a bug")

    monkeypatch.setitem(cli._COMMANDS, "check", broken)
    monkeypatch.delenv("SOFTVR_DEBUG", raising=False)
    assert main(["check", "x"]) == 70
    err = capsys.readouterr().err
    assert "internal error" in err and "ZeroDivisionError: a bug" in err and "Traceback" not in err
    monkeypatch.setenv("SOFTVR_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        main(["check", "x"])


class _BigFrames:
    """A stand-in player whose frames are 1280 x 960 RGB (3.7 MB each): what softvr.app.record
    keeps in memory shows in the peak of traced allocations."""

    name, fps, frame_bytes = "big", 30.0, 1280 * 960 * 3

    def __init__(self, frames):
        self.frames, self.frame, self.metrics = frames, 0, []

    def step(self):
        self.frame += 1
        m = {"sim_time_s": self.frame / self.fps, "step_ms": 1.0, "max_penetration_m": 0.0, "contacts": 0,
             "pgs_iterations": 1, "stage_ms": {}}
        self.metrics.append(m)
        return m

    def render(self):
        return np.full((960, 1280, 3), self.frame % 256, np.uint8)

    def close(self):
        pass

    def describe(self):
        return {}

    def summary(self):
        return {"frames": len(self.metrics)}

    def status(self):
        return ""

    def write_plots(self, doc, out):
        return []


def _peak_of_run(example, out) -> int:
    """Peak traced memory [bytes] while softvr.app.record writes ``example``."""
    import tracemalloc

    from softvr.app import record

    tracemalloc.start()
    try:
        record(example, out, progress=False)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_run_streams_frames_to_the_video_instead_of_keeping_them(tmp_path):
    """Frames of 3.7 MB: 60 more frames (221 MB) raise the peak of traced memory by less than
    2 frames' worth, i.e. memory does not grow with --frames."""
    short = _peak_of_run(_BigFrames(10), tmp_path / "short")
    long = _peak_of_run(_BigFrames(70), tmp_path / "long")
    assert (tmp_path / "long" / "big.mp4").stat().st_size > 0 and (tmp_path / "long" / "big_sheet.png").is_file()
    assert long - short < 2 * _BigFrames.frame_bytes, f"peak {short / 1e6:.0f} MB -> {long / 1e6:.0f} MB"
