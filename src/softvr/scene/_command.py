"""``softvr check SCENE``, ``softvr run SCENE.toml`` and ``softvr view SCENE.toml``."""

from __future__ import annotations

import argparse

__all__ = ["check_main", "run_main", "view_main"]


def check_main(argv: list[str] | None = None) -> int:
    """Validate a scene file: a summary, or every problem (exit status 2)."""
    from softvr.scene import bundled

    p = argparse.ArgumentParser(prog="softvr check", description="Validate a scene file; all its errors at once.")
    p.add_argument("scene", metavar="SCENE",
                   help="scene file (TOML, softvr-scene 1; or glTF / GLB with softvr extras), or a bundled one's name")
    args = p.parse_args(argv)
    from softvr.errors import InputError, raise_all
    from softvr.scene import SceneExample
    from softvr.scene.build import read_any_with_problems

    scene, problems = read_any_with_problems(bundled(args.scene))
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
    kinds = {}
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
    """``softvr run SCENE.toml [--frames N] [--out DIR] [--size W H] [--quiet]``."""
    from softvr.examples.run import demo_parser, run_example
    from softvr.scene import bundled, load_scene

    p = demo_parser("softvr run", "Run a scene file headless: MP4, PNG contact sheet and JSON metrics.", None)
    p.add_argument("scene", metavar="SCENE.toml")
    args = p.parse_args(argv)
    if args.frames is not None and args.frames < 1:
        p.error(f"--frames: expected an integer >= 1, got {args.frames}")
    if args.png_every < 0:
        p.error(f"--png-every: expected an integer >= 0, got {args.png_every}")
    size = None if args.size == (640, 480) else args.size
    with load_scene(bundled(args.scene), frames=args.frames, width=size and size[0],
                    height=size and size[1]) as example:
        run_example(example, args.out, progress=not args.quiet, png_every=args.png_every)
    return 0


def view_main(argv: list[str] | None = None) -> int:
    """``softvr view SCENE.toml [--seconds S]``: the scene live in a window."""
    from softvr.examples.run import VIEW_LAYERS, view_example
    from softvr.render._backend import require_display
    from softvr.scene import bundled, load_scene

    p = argparse.ArgumentParser(prog="softvr view", description="Play a scene file live in a window.")
    p.add_argument("scene", metavar="SCENE.toml")
    p.add_argument("--seconds", type=float, default=None, help="close the window after this long")
    p.add_argument("--screenshot", metavar="PNG", help="save the window when it closes")
    keys = ", ".join(f"{k} {name}" for name, k in VIEW_LAYERS.items())
    p.add_argument("--show", nargs="*", default=[], choices=list(VIEW_LAYERS),
                   help=f"layers shown at the start besides render and contacts (keys toggle them: {keys})")
    p.add_argument("--hide", nargs="*", default=[], choices=list(VIEW_LAYERS), help="layers hidden at the start")
    args = p.parse_args(argv)
    require_display()
    shown = ({"render", "contacts"} | set(args.show)) - set(args.hide)
    with load_scene(bundled(args.scene)) as example:
        view_example(example, timeout_s=args.seconds, screenshot=args.screenshot,
                      overlays=tuple(name for name in VIEW_LAYERS if name in shown))
    return 0
