"""Palpation: the head CT pressed by a probe, its FEM built from the voxels (thesis 3.3.2).

The head CT is embedded in 16 x 16 x 8 cubes over its tissue, each tet's E, nu and rho integrated
from the voxels' Hounsfield units, bone clamped; a 12 mm probe presses 5 mm into the cheek and
withdraws, and every frame the CT is rasterized through the deformed tets and volume-rendered.

The scene is the bundled scene file ``palpation.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_palpation`` opens a window;
``--headless`` writes ``softvr-out/palpation/palpation.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run palpation`` does).
"""

from __future__ import annotations

import argparse

from softvr.app import play_window, record
from softvr.scene import BUNDLED, load_scene

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "palpation.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None, help="Warp device (default: cuda if present)")
    parser.add_argument("--frames", type=int, default=None, help="frames to play (default: the scene's)")
    parser.add_argument("--size", type=int, nargs=2, default=(None, None), metavar=("W", "H"), help="image size")
    parser.add_argument("--headless", action="store_true", help="write video, contact sheet and metrics; no window")
    parser.add_argument("--out", default="softvr-out/palpation", help="folder of the --headless files")
    args = parser.parse_known_args(argv)[0]
    player = load_scene(SCENE, frames=args.frames, width=args.size[0], height=args.size[1], device=args.device)
    with player:
        if args.headless:
            record(player, args.out, progress=False)
        else:
            play_window(player)
    return player


if __name__ == "__main__":
    main()
