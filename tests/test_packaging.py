"""Packaging (issue 20): one version, LICENSE and py.typed in the wheel, a lazy top-level package,
no CUDA-driver warning on a machine without one."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ADDON = ROOT / "src" / "softvr" / "blender" / "softvr_blender" / "__init__.py"
NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"


def pyproject_version() -> str:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def addon_version() -> str:
    # Blender reads bl_info with ast, without running the add-on (it imports bpy): so do we.
    tree = ast.parse(ADDON.read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "bl_info" for t in node.targets):
            return ".".join(str(v) for v in ast.literal_eval(node.value)["version"])
    raise AssertionError(f"no bl_info in {ADDON}")


def python(code: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, **env}, cwd=ROOT)


def test_one_version_everywhere():
    import softvr

    assert addon_version() == pyproject_version(), "the Blender add-on's bl_info version drifted from pyproject"
    # A stale editable install (pip install -e . not re-run after a version bump) fails here too.
    assert metadata.version("softvr") == pyproject_version(), "installed metadata is stale: pip install -e ."
    assert softvr.__version__ == pyproject_version()


def test_license_and_py_typed_present():
    assert "BSD 3-Clause" in (ROOT / "LICENSE").read_text()
    assert "GPL-2" in (ROOT / "NOTICE").read_text()
    assert (ROOT / "src" / "softvr" / "py.typed").is_file()
    assert "## [Unreleased]" in (ROOT / "CHANGELOG.md").read_text()


@pytest.mark.timeout(180)
def test_wheel_contains_license_and_py_typed(tmp_path):
    # Built from a copy of the tree, so that parallel runs do not share build/ and egg-info folders.
    src = tmp_path / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.pyc")
    shutil.copytree(ROOT / "src", src, ignore=ignore)
    for name in ("pyproject.toml", "README.md", "LICENSE", "NOTICE"):
        (tmp_path / name).write_bytes((ROOT / name).read_bytes())
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path / "dist"),
                           str(tmp_path)], capture_output=True, text=True, timeout=170)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("softvr-*.whl")
    assert wheel.name.startswith(f"softvr-{pyproject_version()}-")
    names = zipfile.ZipFile(wheel).namelist()
    assert "softvr/py.typed" in names
    info = f"softvr-{pyproject_version()}.dist-info"
    assert f"{info}/licenses/LICENSE" in names and f"{info}/licenses/NOTICE" in names, names[-12:]
    assert "softvr/scenes/soft-cube.toml" in names  # package data still ships


def test_submodule_import_does_not_load_warp():
    proc = python("import sys, softvr.errors, softvr.files; "
                  "print(sorted(m for m in ('warp', 'softvr.sim', 'vtk', 'scipy') if m in sys.modules))")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_top_level_names_still_work():
    import softvr

    assert softvr.__all__ == ["InputError", "Scene", "SimulationError", "SoftvrError", "__version__"]
    from softvr.errors import InputError
    from softvr.sim import Scene

    assert softvr.InputError is InputError and softvr.Scene is Scene
    assert set(softvr.__all__) <= set(dir(softvr))
    with pytest.raises(AttributeError, match="nosuch"):
        softvr.nosuch  # noqa: B018
    proc = python("import softvr; print(softvr.volume.Volume.__name__, softvr.errors.InputError.__name__)")
    assert proc.stdout.split() == ["Volume", "InputError"], proc.stderr  # subpackages load on first use


def test_no_cuda_driver_warning_without_a_driver():
    from softvr.device import cuda_driver_present

    if cuda_driver_present():
        pytest.skip("a CUDA driver is present: Warp has nothing to warn about")
    code = "import softvr.device as d; print(d.resolve_device())"
    quiet = python(code)
    assert quiet.returncode == 0, quiet.stderr
    assert quiet.stdout.strip() == "cpu"
    assert NO_DRIVER not in quiet.stderr and "CUDA" not in quiet.stderr, quiet.stderr
    # The verbose path keeps one line saying so.
    verbose = python("import logging; logging.basicConfig(level=logging.INFO); " + code)
    lines = [line for line in verbose.stderr.splitlines() if "CUDA driver" in line]
    assert len(lines) == 1 and NO_DRIVER not in lines[0], verbose.stderr


def test_native_stderr_is_captured_whole():
    # What native code writes to fd 2 during init is captured line by line, so that only the driver
    # warning is dropped and every other line can be written back.
    proc = python("import os, softvr.device as d\n"
                  "with d._stderr_lines(out := []):\n"
                  "    os.write(2, b'Warp CUDA warning: " + NO_DRIVER + ".\\nother line\\n')\n"
                  "print(repr(out))")
    assert proc.returncode == 0, proc.stderr
    assert "other line" in proc.stdout and proc.stderr == ""
