"""Box stack: five rigid boxes stacked on the ground, resting through box-box contacts.

Five 0.2 x 0.2 x 0.1 m pine boxes (500 kg/m^3) start stacked 0.1 mm apart and settle onto each
other and the ground (friction 0.6, dt 10 ms, four steps a frame).

The scene is the bundled scene file ``box-stack.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_box_stack`` opens a window;
``--headless`` writes ``softvr-out/box-stack/box-stack.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run box-stack`` does).
"""

from __future__ import annotations

import argparse

from softvr.app import play_window, record
from softvr.scene import BUNDLED, load_scene

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "box-stack.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None, help="Warp device (default: cuda if present)")
    parser.add_argument("--frames", type=int, default=None, help="frames to play (default: the scene's)")
    parser.add_argument("--size", type=int, nargs=2, default=(None, None), metavar=("W", "H"), help="image size")
    parser.add_argument("--headless", action="store_true", help="write video, contact sheet and metrics; no window")
    parser.add_argument("--out", default="softvr-out/box-stack", help="folder of the --headless files")
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
