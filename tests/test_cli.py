"""The ``softvr`` command: help, dispatch, and clear errors instead of tracebacks."""

import subprocess
import sys

import numpy as np

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
