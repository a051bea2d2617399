"""Shoulder: coupled anatomy palpated through a 1 kHz haptic loop (thesis ch. 5, Fig. 5.6).

The procedural shoulder (the structure of thesis Table 5.1) goes through the model pipeline as the
scene loads (its bundled parts file); a finger on a virtual coupling to a scripted haptic handle,
its force rendered by a 1 kHz loop in its own process, presses and slides over the deltoid while
a second finger behind the skin meets the anatomy under it.

The scene is the bundled scene file ``shoulder.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_shoulder`` opens a window;
``--headless`` writes ``softvr-out/shoulder/shoulder.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run shoulder`` does).
"""

from __future__ import annotations

import argparse

from softvr.app import play_window, record
from softvr.scene import BUNDLED, load_scene

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "shoulder.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None, help="Warp device (default: cuda if present)")
    parser.add_argument("--frames", type=int, default=None, help="frames to play (default: the scene's)")
    parser.add_argument("--size", type=int, nargs=2, default=(None, None), metavar=("W", "H"), help="image size")
    parser.add_argument("--headless", action="store_true", help="write video, contact sheet and metrics; no window")
    parser.add_argument("--out", default="softvr-out/shoulder", help="folder of the --headless files")
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
