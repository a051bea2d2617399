"""Volume deformation: the head CT pressed and twisted through its tet mesh (thesis ch. 3).

The head CT (Debian ``invesalius-examples``) is embedded in 16 x 16 x 8 cubes (10 240 tets)
whose nodes follow a keyed animation (a dent pressed into the face, then a twist of up to
35 degrees at the top); every frame the CT is rasterized through them and volume-rendered.

The scene is the bundled scene file ``volume.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_volume_deform`` opens a window;
``--headless`` writes ``softvr-out/volume/volume.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run volume`` does).
"""

from __future__ import annotations

import argparse

from softvr.app import play_window, record
from softvr.scene import BUNDLED, load_scene

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "volume.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None, help="Warp device (default: cuda if present)")
    parser.add_argument("--frames", type=int, default=None, help="frames to play (default: the scene's)")
    parser.add_argument("--size", type=int, nargs=2, default=(None, None), metavar=("W", "H"), help="image size")
    parser.add_argument("--headless", action="store_true", help="write video, contact sheet and metrics; no window")
    parser.add_argument("--out", default="softvr-out/volume", help="folder of the --headless files")
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
