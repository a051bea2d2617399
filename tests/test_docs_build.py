"""The docs site (issue 20): every bundled demo has a gallery image made by scripts/gallery.py, and the
site builds with warnings as errors."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GALLERY_DIR = ROOT / "docs" / "gallery"


def gallery_names() -> list[str]:
    spec = importlib.util.spec_from_file_location("softvr_gallery_script", ROOT / "scripts" / "gallery.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return list(module.GALLERY)


def test_every_demo_scene_is_in_the_gallery():
    scenes = sorted(p.stem for p in (ROOT / "src" / "softvr" / "scenes").glob("*.toml"))
    assert sorted(gallery_names()) == scenes, (
        "each bundled scene has a gallery page: add it to GALLERY in scripts/gallery.py, run scripts/gallery.py NAME")


def test_gallery_images_are_the_scripts():
    entries = json.loads((GALLERY_DIR / "manifest.json").read_text())["entries"]
    for name in gallery_names():
        assert name in entries, f"run scripts/gallery.py {name}"
        e = entries[name]
        assert e["command"].startswith(f"softvr run {name}.toml --frames ")
        for key in ("image", "clip"):
            if key in e:
                data = (GALLERY_DIR / e[key]).read_bytes()
                assert hashlib.sha256(data).hexdigest() == e[f"{key}_sha256"], f"{e[key]} changed by hand"
        assert (GALLERY_DIR / e["image"]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_docs_build_without_warnings(tmp_path):
    if importlib.util.find_spec("sphinx") is None or importlib.util.find_spec("myst_parser") is None:
        pytest.skip("the docs extra is not installed (pip install -e '.[docs]' or scripts/setup.sh docs)")
    # A copy of docs/ and what its pages include, so that parallel runs do not share the generated api/
    # and gallery pages; softvr itself is the installed one (the copy has no src/).
    docs = tmp_path / "docs"
    shutil.copytree(ROOT / "docs", docs, ignore=shutil.ignore_patterns("_build", "api"))
    for name in ("CHANGELOG.md", "LICENSE", "NOTICE", "scripts/gallery.py"):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        shutil.copyfile(ROOT / name, tmp_path / name)
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-E", "-q", "-b", "html",
                           str(docs), str(tmp_path / "html")],
                          capture_output=True, text=True, timeout=580)
    assert proc.returncode == 0, proc.stderr[-6000:]
    html = (tmp_path / "html" / "gallery" / "soft-cube.html").read_text()
    assert "soft-cube.png" in html and "soft-cube.mp4" in html
    assert (tmp_path / "html" / "api" / "softvr.volume.html").exists()
