"""``softvr check SCENE``, ``softvr run SCENE.toml`` and ``softvr view SCENE.toml``.

SCENE is a scene file's path or a bundled scene's name, with or without its suffix
(``candy``, ``candy.toml``): :func:`softvr.scene.build.scene_path`.
"""

from __future__ import annotations

import argparse

from softvr.app import add_view_options, check_run_args, play_window, record_from_args, run_parser, shown_layers
from softvr.device import resolve_device
from softvr.errors import InputError, raise_all
from softvr.render import require_display
from softvr.scene import SceneExample, load_scene
from softvr.scene.build import read_any_with_problems, scene_path

__all__ = ["SCENE_SUFFIXES", "add_variant_option", "check_main", "is_scene_file", "run_main", "view_main"]

#: Suffixes of scene files: TOML, glTF, GLB.
SCENE_SUFFIXES = (".toml", ".gltf", ".glb")


def is_scene_file(text: str) -> bool:
    """Whether a command-line word names a scene file (by its suffix) rather than a demo."""
    return text.lower().endswith(SCENE_SUFFIXES)


def add_variant_option(parser: argparse.ArgumentParser) -> None:
    """``--variant NAME``: apply the scene file's ``[variant.NAME]`` (repeatable, applied in order)."""
    parser.add_argument("--variant", action="append", default=[], metavar="NAME",
                        help="apply the scene file's [variant.NAME] table (repeat for more, applied in order)")


def check_main(argv: list[str] | None = None) -> int:
    """Validate a scene file: a summary, or every problem (exit status 2)."""
    p = argparse.ArgumentParser(prog="softvr check", description="Validate a scene file; all its errors at once.")
    p.add_argument("scene", metavar="SCENE",
                   help="scene file (TOML, softvr-scene 1; or glTF / GLB with softvr extras), or a bundled one's name")
    add_variant_option(p)
    args = p.parse_args(argv)
    scene, problems = read_any_with_problems(scene_path(args.scene), args.variant)
    # The geometry too, of what is valid: bodies that start inside each other or below the
    # ground, reported with the file's other problems.
    if scene.bodies or scene.models or scene.volume is not None:
        try:
            with SceneExample(scene, frames=1) as example:
                problems = problems + example.start_problems()
                for moved, obstacle, displacement in example.separation:
                    print(f"collision-free start: {moved!r} pushed out of {obstacle!r} (its nodes moved up to "
                          f"{displacement * 1e3:.2f} mm)")
        except InputError as exc:
            # Reported as the scene file's problem; a file it names that is at fault (a mesh) is named too.
            other = f" (in {exc.source})" if exc.source and exc.source != str(scene.path) else ""
            problems = problems + [(what, expected, f"{found}{other}") for what, expected, found in exc.problems]
    raise_all(problems, str(scene.path), "scene file")
    kinds: dict[str, int] = {}
    for b in scene.bodies:
        kinds[b.type] = kinds.get(b.type, 0) + 1
    parts = scene.model_parts()
    bodies = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items())) or "no bodies"
    if scene.volume is not None:
        bodies += f" + a volume body {scene.volume['name']!r}"
    if parts:
        bodies += f" + {len(parts)} model parts ({sum(k == 'soft' for k in parts.values())} soft)"
    print(f"{scene.path}: ok — {bodies}; {len(scene.planes)} planes, {len(scene.spheres)} spheres, "
          f"{len(scene.materials)} materials, {len(scene.adhesions)} adhesions, {len(scene.filters)} filters, "
          f"{len(scene.couplings)} couplings; "
          f"{scene.simulation['frames']} frames of {scene.simulation['steps_per_frame']} x "
          f"{scene.simulation['dt']:g} s")
    return 0


def run_main(argv: list[str] | None = None) -> int:
    """``softvr run SCENE.toml [--variant NAME] [--frames N] [--out DIR] [--size W H] [--quiet] [--device D]``."""
    p = run_parser("softvr run", "Run a scene file headless: MP4, PNG contact sheet and JSON metrics.", None,
                   size=None)
    p.add_argument("scene", metavar="SCENE.toml", help="scene file (TOML, glTF / GLB) or a bundled one's name")
    add_variant_option(p)
    args = p.parse_args(argv)
    check_run_args(p, args)
    size = args.size or (None, None)
    with load_scene(scene_path(args.scene), args.variant, frames=args.frames, width=size[0], height=size[1],
                    device=args.device) as example:
        record_from_args(example, args)
    return 0


def view_main(argv: list[str] | None = None) -> int:
    """``softvr view SCENE.toml [--seconds S] [--screenshot PNG] [--show ...] [--hide ...]``."""
    p = argparse.ArgumentParser(prog="softvr view", description="Play a scene file live in a window.")
    p.add_argument("scene", metavar="SCENE.toml", help="scene file (TOML, glTF / GLB) or a bundled one's name")
    add_variant_option(p)
    add_view_options(p)
    args = p.parse_args(argv)
    path = scene_path(args.scene)
    if args.device is not None:
        resolve_device(args.device)  # cuda where none is present: named before a window opens
    require_display()
    with load_scene(path, args.variant, device=args.device) as example:
        play_window(example, timeout_s=args.seconds, screenshot=args.screenshot, overlays=shown_layers(args))
    return 0
