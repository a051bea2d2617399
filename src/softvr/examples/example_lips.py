"""Lips: two soft lips pressed together stick briefly as they open (thesis Fig. 4.3).

Two FEM lips are held and driven by their outer faces (the jaws): pressed 1.5 mm together over
0.2 s, held while the wet contacts bond, then opened at 2 cm/s; the adhesion holds the inner faces
together for a few millimetres before they snap apart.

The scene is the bundled scene file ``lips.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_lips`` opens a window;
``--headless`` writes ``softvr-out/lips/lips.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run lips`` does).
"""

from __future__ import annotations

import argparse

from softvr.app import play_window, record
from softvr.scene import BUNDLED, load_scene

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "lips.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None, help="Warp device (default: cuda if present)")
    parser.add_argument("--frames", type=int, default=None, help="frames to play (default: the scene's)")
    parser.add_argument("--size", type=int, nargs=2, default=(None, None), metavar=("W", "H"), help="image size")
    parser.add_argument("--headless", action="store_true", help="write video, contact sheet and metrics; no window")
    parser.add_argument("--out", default="softvr-out/lips", help="folder of the --headless files")
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
