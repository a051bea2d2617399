"""``softvr run SCENE``: the physics demos, headless, to an MP4, a PNG contact sheet and JSON metrics.

Scenes (each an ``example_<topic>.py`` with an ``Example`` class and its own ``main``):

=============  ==============================================================================
soft-cube      a soft co-rotational FEM cube dropped on the ground (friction 0.5, dt 5 ms)
box-stack      five rigid boxes stacked on the ground (box-box contacts, dt 10 ms)
cloth-sphere   a mass-spring cloth draped over a static sphere and the ground
oranges        soft FEM spheres bouncing and rolling on the ground (thesis Fig. 3.7 flavour)
candy          soft and hard candies fall on a Jell-O block (thesis Fig. 4.1 scale: 10 K tets, 25 K tris)
cloth-wall     a swinging cloth sticks to an adhesive wall and peels off (thesis Fig. 4.2)
lips           two soft lips pressed together stick briefly as they open (thesis Fig. 4.3)
probe          a probe pressed into soft tissue and pulled back: force against displacement
shoulder       coupled anatomy palpated through a 1 kHz haptic loop (thesis ch. 5; also ``softvr demo shoulder``)
=============  ==============================================================================

Every demo writes ``<out>/<name>.mp4``, ``<out>/<name>_sheet.png`` and
``<out>/<name>_metrics.json`` (default ``<out>``: ``softvr-out/<name>``) through
:func:`softvr.app.record`; ``softvr view NAME`` plays it through :func:`softvr.app.play_window`.
This module is a leaf: the demos' names (:data:`SCENES`) and the two commands.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from softvr.app import add_view_options, check_run_args, play_window, shown_layers
from softvr.render import require_display

__all__ = ["SCENES", "main", "module", "view_main"]

#: ``softvr run`` scene name -> example module (``softvr.examples.example_<module>``).
SCENES = {
    "soft-cube": "soft_cube",
    "box-stack": "box_stack",
    "cloth-sphere": "cloth_sphere",
    "oranges": "oranges",
    "candy": "candy",
    "cloth-wall": "cloth_wall",
    "lips": "lips",
    "probe": "probe",
    "shoulder": "shoulder",
}


def module(name: str):
    """The example module of demo ``name`` (a key of :data:`SCENES`)."""
    return importlib.import_module(f"softvr.examples.example_{SCENES[name]}")


def view_main(argv: list[str] | None = None) -> int:
    """``softvr view NAME [--frames N] [--size W H] [--seconds S] [--screenshot PNG] [--show ...]``:
    a demo played live in a window."""
    names = ", ".join(SCENES)
    p = argparse.ArgumentParser(prog="softvr view", description="Play a physics demo live in a window.")
    p.add_argument("scene", metavar="NAME", help=f"one of: {names}")
    p.add_argument("--frames", type=int, default=None, help="frames to simulate (default per scene)")
    p.add_argument("--size", type=int, nargs=2, default=(900, 700), metavar=("W", "H"))
    add_view_options(p)
    args = p.parse_args(argv)
    if args.scene not in SCENES:
        p.error(f"unknown scene {args.scene!r}; choose one of: {names}")
    demo = module(args.scene)
    args.frames = demo.DEFAULT_FRAMES if args.frames is None else args.frames
    check_run_args(p, args)
    require_display()  # before building a large scene
    with demo.Example(frames=args.frames, width=args.size[0], height=args.size[1]) as example:
        play_window(example, timeout_s=args.seconds, screenshot=args.screenshot, overlays=shown_layers(args))
    return 0


def main(argv: list[str] | None = None) -> int:
    """``softvr run NAME [--frames N] [--out DIR] [--size W H] [scene options]``; returns the
    exit code. Everything but NAME goes to the demo's own ``main`` (``softvr run candy
    --adhesion``; ``softvr run NAME --help`` lists the demo's options)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    names = ", ".join(SCENES)
    named = [a for a in argv if a in SCENES]
    if named:
        rest = list(argv)
        rest.remove(named[0])
        return module(named[0]).main(rest, prog=f"softvr run {named[0]}")
    p = argparse.ArgumentParser(prog="softvr run", description="Run a physics demo or a scene file headless: MP4, "
                                "PNG contact sheet and JSON metrics.",
                                epilog=f"Demos: {names}; each has its own options (softvr run NAME --help). "
                                       "Scene files: TOML or glTF / GLB, bundled by name (soft-cube.toml) or a path.")
    p.add_argument("scene", metavar="SCENE", nargs="?", help=f"a scene file or one of: {names}")
    args, _ = p.parse_known_args(argv)
    if args.scene is None:
        p.error("expected a SCENE: a scene file or one of " + names)
    looks_like_file = any(c in args.scene for c in "/\\") or Path(args.scene).suffix != ""
    if looks_like_file:
        p.error(f"{args.scene!r}: scene files are TOML (.toml) or glTF (.gltf, .glb). Demos: {names}")
    p.error(f"unknown scene {args.scene!r}; choose a scene file or one of: {names}")
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
