"""The command every leaf example shares (Newton's examples share their flags the same way):
``--device``, ``--frames``, ``--size W H``, ``--variant NAME`` (the scene file's
``[variant.NAME]``), ``--headless`` (video, contact sheet and metrics instead of a window) and
``--out``, applied to the leaf's bundled scene file."""

from __future__ import annotations

import argparse
from pathlib import Path

from softvr.app import play_window, record
from softvr.scene import load_scene
from softvr.scene.command import add_variant_option

__all__ = ["play_leaf"]


def play_leaf(scene: Path, doc: str | None, argv: list[str] | None = None):
    """Parse the leaf's command line ``argv`` (default ``sys.argv``; unknown flags are left for
    the caller) and play ``scene``: a window, or with ``--headless`` files in ``--out`` (default
    ``softvr-out/<scene stem>``, as ``softvr run`` writes them). Returns the played player."""
    parser = argparse.ArgumentParser(description=(doc or scene.stem).splitlines()[0])
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None, help="Warp device (default: cuda if present)")
    parser.add_argument("--frames", type=int, default=None, help="frames to play (default: the scene's)")
    parser.add_argument("--size", type=int, nargs=2, default=(None, None), metavar=("W", "H"), help="image size")
    parser.add_argument("--headless", action="store_true", help="write video, contact sheet and metrics; no window")
    parser.add_argument("--out", default=f"softvr-out/{scene.stem}", help="folder of the --headless files")
    add_variant_option(parser)
    args = parser.parse_known_args(argv)[0]
    player = load_scene(scene, args.variant, frames=args.frames, width=args.size[0], height=args.size[1], device=args.device)
    with player:
        if args.headless:
            record(player, args.out, progress=False)
        else:
            play_window(player)
    return player
