#!/usr/bin/env python3
"""Make the docs gallery's images by running every bundled demo scene for a few frames.

Each entry runs ``softvr run SCENE.toml --frames N --out TMP --size W H --quiet`` (the user's own
command, in a subprocess), then copies the contact sheet it wrote to ``docs/gallery/img/NAME.png``
(at most :data:`MAX_IMAGE_BYTES`: the repository keeps no large binaries). Videos are not kept: a
scene's old clip (``docs/gallery/clips/NAME.mp4``) is removed with its manifest entry when the
scene is run again. ``docs/gallery/manifest.json`` records for each image the command that made
it, the softvr version and commit, and the SHA-256 of every file: the docs build (docs/conf.py)
refuses an image whose hash is not the manifest's, so every image on the site is one this script
produced.

    .venv/bin/python scripts/gallery.py                 # all scenes (several minutes on 2 cores)
    .venv/bin/python scripts/gallery.py soft-cube lips  # only these; the rest of the manifest is kept
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "gallery"
SCENES = ROOT / "src" / "softvr" / "scenes"

# name -> frames. A few frames each: enough for the sheet to show the motion (the probe's press, the head's
# twist), short enough that the whole gallery runs in minutes on a CPU (the scenes' own defaults run 36-300
# frames; about 8 minutes for all of these on 2 idle cores). box-knock needs 1.6 s for the ram to pass and
# the boxes to land, candy-adhesive 1.3 s for the held candy to come off (most of an hour on 2 busy cores),
# cloth-wall 2 s for the peel and the swing back.
GALLERY = {
    "soft-cube": 24,
    "box-stack": 30,
    "box-knock": 40,
    "cloth-sphere": 30,
    "oranges": 30,
    "candy": 16,
    "candy-adhesive": 32,
    "cloth-wall": 50,
    "lips": 30,
    "probe": 30,
    "shoulder": 30,
    "shoulder-arthroscopy": 30,
    "volume": 36,
    "palpation": 40,
}


def describe(scene: Path) -> str:
    """The scene file's leading comment, which says what the demo shows."""
    lines = []
    for line in scene.read_text(encoding="utf-8").splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    return " ".join(lines)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def git_commit() -> str:
    if os.environ.get("SOFTVR_GALLERY_COMMIT"):  # a tree without .git (an exported snapshot) says its own
        return os.environ["SOFTVR_GALLERY_COMMIT"]
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    except OSError:
        return "unknown"
    return out.stdout.strip() or "unknown"


#: Largest contact sheet kept [bytes].
MAX_IMAGE_BYTES = 300_000


def run_one(name: str, frames: int, size: tuple[int, int], device: str | None) -> dict:
    scene = SCENES / f"{name}.toml"
    with tempfile.TemporaryDirectory(prefix=f"softvr-gallery-{name}-") as tmp:
        cmd = ["softvr", "run", scene.name, "--frames", str(frames), "--out", tmp,
               "--size", str(size[0]), str(size[1]), "--quiet"]
        if device:
            cmd += ["--device", device]
        t0 = time.perf_counter()
        # python -m softvr with this checkout's src first: the softvr next to this script, whatever is
        # installed or on PATH.
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"),
                                                                         os.environ.get("PYTHONPATH")]))}
        proc = subprocess.run([sys.executable, "-m", "softvr", *cmd[1:]], capture_output=True, text=True, env=env)
        seconds = time.perf_counter() - t0
        if proc.returncode != 0:
            raise SystemExit(f"gallery: {' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
        sheets = sorted(Path(tmp).glob("*_sheet.png"))
        if len(sheets) != 1:
            raise SystemExit(f"gallery: {' '.join(cmd)} wrote {len(sheets)} contact sheets, expected one")
        (OUT / "img").mkdir(parents=True, exist_ok=True)
        image = OUT / "img" / f"{name}.png"
        shutil.copyfile(sheets[0], image)
        if image.stat().st_size > MAX_IMAGE_BYTES:
            # A smooth volume rendering compresses badly as RGB; 256 median-cut colours keep the
            # picture (no dither: dithering would add the very grain the sheet is meant to show
            # absent) at about a third of the size.
            Image.open(sheets[0]).convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT,
                                                          dither=Image.Dither.NONE).save(image, optimize=True)
        size = image.stat().st_size
        if size > MAX_IMAGE_BYTES:
            image.unlink()
            raise SystemExit(f"gallery: {name}'s contact sheet is {size} bytes in 256 colours, over "
                             f"{MAX_IMAGE_BYTES}: run it smaller (--size)")
        (OUT / "clips" / f"{name}.mp4").unlink(missing_ok=True)
        entry = {
            "title": name,
            "scene": scene.name,
            "description": describe(scene),
            "command": " ".join(cmd).replace(tmp, "OUT"),
            "frames": frames,
            "seconds": round(seconds, 1),
            "image": f"img/{name}.png",
            "image_sha256": sha256(image),
        }
        return entry


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*", help=f"scenes to run (default: all of {', '.join(GALLERY)})")
    ap.add_argument("--size", nargs=2, type=int, default=(320, 240), metavar=("W", "H"))
    ap.add_argument("--frames", type=int, help="frames for every scene instead of each one's own count")
    ap.add_argument("--device", help="cpu or cuda (default: softvr's, CUDA when present)")
    args = ap.parse_args(argv)
    unknown = [n for n in args.names if n not in GALLERY]
    if unknown:
        ap.error(f"unknown scene(s) {', '.join(unknown)}; known: {', '.join(GALLERY)}")
    manifest_path = OUT / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {"entries": {}}
    import softvr  # noqa: PLC0415 - only for the version recorded with the images

    for name in args.names or list(GALLERY):
        print(f"gallery: {name} ...", end=" ", flush=True)
        entry = run_one(name, args.frames or GALLERY[name], tuple(args.size), args.device)
        entry["softvr"], entry["commit"] = softvr.__version__, git_commit()
        manifest["entries"][name] = entry
        print(f"{entry['seconds']} s")
        # Written after every scene, so an interrupted run keeps what it made.
        manifest["order"] = [n for n in GALLERY if n in manifest["entries"]]
        manifest_path.write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
