"""Soft cube: a co-rotational FEM cube dropped, tilted, onto the ground (thesis 5.1.1, 5.3).

A 0.3 m cube of 4 x 4 x 4 five-tet cubes (E = 150 kPa, nu = 0.28, 1000 kg/m^3, Rayleigh
damping) falls, lands on an edge, squashes and settles on a plane with friction 0.5 (dt 5 ms).

The scene is the bundled scene file ``soft-cube.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_soft_cube`` opens a window;
``--headless`` writes ``softvr-out/soft-cube/soft-cube.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run soft-cube`` does).
"""

from __future__ import annotations

import argparse

from softvr.app import play_window, record
from softvr.scene import BUNDLED, load_scene

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "soft-cube.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None, help="Warp device (default: cuda if present)")
    parser.add_argument("--frames", type=int, default=None, help="frames to play (default: the scene's)")
    parser.add_argument("--size", type=int, nargs=2, default=(None, None), metavar=("W", "H"), help="image size")
    parser.add_argument("--headless", action="store_true", help="write video, contact sheet and metrics; no window")
    parser.add_argument("--out", default="softvr-out/soft-cube", help="folder of the --headless files")
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
