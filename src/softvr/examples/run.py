"""``softvr run NAME`` and ``softvr view NAME``: a bundled scene file played by its name.

Every demo is one bundled scene file (``softvr/scenes/NAME.toml``, :data:`softvr.scene.BUNDLED`);
:data:`SCENES` lists them, each with the first line of its comment:

======================  ==============================================================================
soft-cube               a soft co-rotational FEM cube dropped, tilted, on the ground
box-stack               five rigid boxes stacked on the ground
box-knock               the same stack knocked over by a kinematic ram
cloth-sphere            a mass-spring cloth draped over a static sphere and the ground
oranges                 soft FEM spheres bouncing and rolling on the ground (thesis Fig. 3.7 flavour)
candy                   soft and hard candies fall on a Jell-O block (thesis Fig. 4.1 scale)
candy-adhesive          the same with adhesive surfaces (thesis 4.4); a hand pulls one candy off
cloth-wall              a swinging cloth sticks to an adhesive wall and peels off (thesis Fig. 4.2)
lips                    two soft lips pressed together stick briefly as they open (thesis Fig. 4.3)
probe                   a probe pressed into adhesive soft tissue and pulled back
shoulder                coupled anatomy palpated through a 1 kHz haptic loop (thesis ch. 5)
shoulder-arthroscopy    the same anatomy probed under the acromion
palpation               the head CT pressed by a probe, re-rasterized where the mesh moved
volume                  the head CT pressed and twisted through its tet mesh
======================  ==============================================================================

Every run writes ``<out>/<name>.mp4``, ``<out>/<name>_sheet.png`` and
``<out>/<name>_metrics.json`` (default ``<out>``: ``softvr-out/<name>``) through
:func:`softvr.app.record`; ``softvr view NAME`` plays it through :func:`softvr.app.play_window`.
This module is a leaf: the demos' names and the two commands; the scene files are the demos.
"""

from __future__ import annotations

import argparse
import sys

from softvr.app import add_view_options, check_run_args, play_window, record_from_args, run_parser, shown_layers
from softvr.render import require_display
from softvr.scene import BUNDLED, load_scene
from softvr.scene.command import add_variant_option

__all__ = ["SCENES", "VARIANTS", "main", "scene_file", "view_main"]

#: The demos: the bundled scene files by name (``soft-cube`` -> ``.../scenes/soft-cube.toml``).
SCENES = {p.stem: p for p in sorted(BUNDLED.glob("*.toml"))}

#: ``--variant`` of a demo of several scene files: the file it names (``softvr demo shoulder --variant
#: arthroscopy``); another demo's ``--variant NAME`` applies its file's ``[variant.NAME]``.
VARIANTS = {"shoulder": {"palpation": "shoulder", "arthroscopy": "shoulder-arthroscopy"}}


def scene_file(name: str):
    """The bundled scene file of demo ``name`` (a key of :data:`SCENES`)."""
    return SCENES[name]


def _about(name: str) -> str:
    """The first comment line of the scene file: what the demo shows."""
    for line in scene_file(name).read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            return line.lstrip("# ").strip()
    return f"the bundled scene {name}"


def _parse(parser: argparse.ArgumentParser, name: str, argv: list[str]) -> tuple[argparse.Namespace, str, list]:
    """Options of demo ``name`` (``--variant``: the scene file it names where the demo has
    several, else its file's ``[variant.NAME]`` tables; ``--no-haptics``); returns them, the
    scene the variant names and the file's variants to apply."""
    if name in VARIANTS:
        parser.add_argument("--variant", choices=list(VARIANTS[name]), default=next(iter(VARIANTS[name])),
                            help="which scene file of the demo (default %(default)s)")
    else:
        add_variant_option(parser)
    parser.add_argument("--no-haptics", action="store_true",
                        help="tools read their handle once per step instead of in a 1 kHz haptic process")
    args = parser.parse_args(argv)
    if name in VARIANTS:
        return args, VARIANTS[name][args.variant], []
    return args, name, args.variant


def _split(argv: list[str], command: str) -> tuple[str, list[str]]:
    """The demo's name (the first word that is one) and the other words."""
    named = [a for a in argv if a in SCENES]
    if not named:
        raise SystemExit(f"softvr {command}: error: expected one of: {', '.join(SCENES)}")
    rest = list(argv)
    rest.remove(named[0])
    return named[0], rest


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """``softvr run NAME [--frames N] [--out DIR] [--size W H] [--quiet] [--png-every K]
    [--device D] [--no-haptics]``: the bundled scene file NAME headless to files; returns the
    exit code."""
    name, rest = _split(list(sys.argv[1:] if argv is None else argv), "run")
    parser = run_parser(prog or f"softvr run {name}", f"Run a bundled scene headless: {_about(name)}", None, size=None)
    args, chosen, variants = _parse(parser, name, rest)
    check_run_args(parser, args)
    size = args.size or (None, None)
    with load_scene(scene_file(chosen), variants, frames=args.frames, width=size[0], height=size[1],
                    device=args.device, haptics=False if args.no_haptics else None) as player:
        record_from_args(player, args)
    return 0


def view_main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """``softvr view NAME [--frames N] [--size W H] [--seconds S] [--screenshot PNG] [--show ...]``:
    the bundled scene file NAME played live in a window."""
    name, rest = _split(list(sys.argv[1:] if argv is None else argv), "view")
    parser = argparse.ArgumentParser(prog=prog or f"softvr view {name}", description=f"Play live: {_about(name)}")
    parser.add_argument("--frames", type=int, default=None, help="frames to simulate (default the scene's)")
    parser.add_argument("--size", type=int, nargs=2, default=None, metavar=("W", "H"))
    add_view_options(parser)
    args, chosen, variants = _parse(parser, name, rest)
    check_run_args(parser, args)
    require_display()  # before building a large scene
    size = args.size or (None, None)
    with load_scene(scene_file(chosen), variants, frames=args.frames, width=size[0], height=size[1],
                    device=args.device, haptics=False if args.no_haptics else None) as player:
        play_window(player, timeout_s=args.seconds, screenshot=args.screenshot, overlays=shown_layers(args))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
