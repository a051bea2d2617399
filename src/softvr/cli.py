"""The ``softvr`` command: one entry point, one subcommand per job.

``softvr demo [volume]``   the bundled volume-deformation scene (volume.toml), offscreen to MP4 + PNG
``softvr demo shoulder``    the procedural shoulder palpated through a 1 kHz haptic loop (shoulder.toml)
``softvr demo palpation``   the head CT pressed by a probe: FEM from the voxels, deformed CT volume-rendered
                            (palpation.toml)
``softvr build-model P``    part meshes + a parts file (TOML) -> a simulation model (thesis 5.2)
``softvr tetmesh SURFACE``  the tet mesh a scene builds for a FEM body of a surface (.vtu or .npz)
``softvr run SCENE``        a demo, i.e. a bundled scene file by name (soft-cube, box-stack, cloth-sphere, oranges,
                            candy, cloth-wall, lips, probe, shoulder, ...), or a scene file to MP4, metrics, plots
``softvr view SCENE``       a demo or scene file played live in a window (space pauses, n steps;
                            ``softvr view volume``: the bundled volume scene)
``softvr view VOLUME``      a volume file or DICOM folder in a window: drag its mesh nodes, it deforms live
``softvr bench AREA``       measurements against peers (softvr bench --help lists the areas)
``softvr cave ...``         multi-screen VR: preview, master, node, local cluster, keys (softvr cave -h)
``softvr check SCENE``      validate a scene file (every error at once, the start checked too)
``softvr blender-addon``    write softvr-blender.zip, the Blender add-on
``softvr info PATH``        what a volume file holds

One convention for all of them: ``--help`` everywhere; ``--device cpu|cuda`` where kernels run
(run, view, demo, bench, cave); ``--out DIR`` with one default, ``softvr-out/NAME/``, and one
file name rule, ``NAME.mp4``, ``NAME_sheet.png``, ``NAME_metrics.json``
(:func:`softvr.app.record`); a scene is a bundled scene's name (``candy``, ``candy.toml``) or a
file's path, options before or after it; ``softvr --version``; ``softvr --verbose CMD ...`` (before
the command, for every command) shows softvr's INFO log lines on stderr (e.g. that no CUDA driver
was found). Heavy layers are imported by the subcommand that needs them, so ``softvr --help``
starts no physics stack.

Bad input ends a command with ``softvr CMD: error: FILE: FIELD: expected ..., found ...`` and
exit status 2, never a traceback; anything else that goes wrong is a bug, reported as an
internal error (exit status 70; ``SOFTVR_DEBUG=1`` shows its traceback).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from softvr.errors import InputError, SoftvrError

__all__ = ["main"]


_DEMOS = {"volume": "the head CT pressed and twisted through its tet mesh, volume-rendered (default)",
          "shoulder": "the procedural shoulder palpated through a 1 kHz haptic loop (--variant arthroscopy)",
          "palpation": "the head CT pressed by a probe, re-rasterized where the mesh moved, volume-rendered"}


def _demo(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        p = argparse.ArgumentParser(prog="softvr demo", description="Run a bundled demo offscreen: MP4, PNG contact "
                                    "sheet and JSON metrics (softvr demo NAME --help for its options).",
                                    epilog="Demos:\n" + "\n".join(f"  {k:10s} {v}" for k, v in _DEMOS.items()),
                                    formatter_class=argparse.RawDescriptionHelpFormatter)
        p.add_argument("demo", nargs="?", choices=list(_DEMOS), default="volume", help="which demo (default volume)")
        p.print_help()
        return 0
    if argv and not argv[0].startswith("-") and argv[0] not in _DEMOS:
        raise InputError("DEMO", f"one of {', '.join(_DEMOS)}", repr(argv[0]))
    name = argv[0] if argv and argv[0] in _DEMOS else "volume"
    rest = argv[1:] if argv and argv[0] in _DEMOS else argv
    # Each demo is its bundled scene file (volume.toml, shoulder.toml, palpation.toml).
    from softvr.examples import run

    return run.main([name, *rest], prog=f"softvr demo {name}")


#: Folder of the bundled scene and parts files (``softvr.scene.BUNDLED``, without importing it).
_BUNDLED = Path(__file__).resolve().parent / "scenes"


def _bundled_file(word: str) -> str:
    """``word``, or the bundled file of that name (``shoulder_palpation.toml``, in a folder of
    the bundled scenes) when no such file is here."""
    if word.startswith("-") or Path(word).exists() or Path(word).parent != Path("."):
        return word
    found = sorted(_BUNDLED.glob(f"*/{word}"))
    return str(found[0]) if found else word


def _build_model(argv: list[str]) -> int:
    from softvr.model import build

    args = [_bundled_file(a) for a in argv]
    if args != argv and not {"-o", "--out"} & set(argv):
        # A bundled parts file: its model goes here, not into the installed package.
        bundled = next(Path(a) for a, b in zip(args, argv) if a != b)
        args += ["-o", bundled.name.removesuffix(".toml") + ".model.npz"]
    return build.main(args)


def _tetmesh(argv: list[str]) -> int:
    from softvr.model import command

    return command.tetmesh_main(argv)


def _demo_named(argv: list[str]) -> bool:
    """Whether ``argv`` names a demo: a bundled scene file by its name (``softvr run candy``),
    unless a file of that name is here."""
    from softvr.examples.run import SCENES

    return any(a in SCENES and not Path(a).exists() for a in argv)


def _run(argv: list[str]) -> int:
    # A demo (a bundled scene by name), else a scene file's path (or nothing: the scene command's help).
    if _demo_named(argv):
        from softvr.examples import run

        return run.main(argv)
    from softvr.scene import command

    return command.run_main(argv)


def _view(argv: list[str]) -> int:
    # A demo (a bundled scene by name: ``softvr view volume`` plays volume.toml), a volume file or
    # DICOM folder (the drag viewer: its embedding mesh's nodes dragged with the mouse), else a
    # scene file's path (or nothing: the scene command's help).
    from softvr.scene.command import is_scene_file

    path = next((a for a in argv if not a.startswith("-")), None)
    if path is not None and not _demo_named([path]) and Path(path).exists() and not is_scene_file(path):
        from softvr.render import viewer

        return viewer.main(argv)
    if _demo_named(argv):
        from softvr.examples import run

        return run.view_main(argv)
    from softvr.scene import command

    return command.view_main(argv)


_BENCH_AREAS = {"volume": "rasterizer vs VTK vtkProbeFilter + SciPy and SimpleITK (thesis Figs. 3.5 / 3.6)",
                "contact": "soft cube vs MuJoCo, PyBullet, Newton; the thesis' candy scene at its scale",
                "adhesion": "the candy scene with and without adhesion (thesis Fig. 4.4)",
                "shoulder": "the shoulder, both variants: ms per step, contacts, haptic loop period",
                "cave": "render-cluster sync overhead and bytes per frame, 2 ... 16 nodes on loopback",
                "palpation": "the palpation frame: FEM step, full and incremental rasterization, rendering",
                "scene": "every bundled scene: read, build, start check, step and render ms"}

#: Benches whose kernels take a device (the physics benches: the node arrays, ``softvr.Scene.device``);
#: the others step on the CPU (the rigid arrays, the per-object path).
_BENCH_DEVICE = ("volume", "palpation", "contact", "shoulder")


def _bench(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="softvr bench", description="Measure softvr against its peers "
                                "(softvr bench AREA --help for an area's options).",
                                epilog="Areas:\n" + "\n".join(f"  {k:10s} {v}" for k, v in _BENCH_AREAS.items()),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("area", choices=list(_BENCH_AREAS), help="what to measure")
    if not argv or argv[0] in ("-h", "--help"):
        p.print_help()
        return 0 if argv else 2
    area = p.parse_args(argv[:1]).area
    rest = argv[1:]
    if area not in _BENCH_DEVICE and "--device" in rest:
        # One option everywhere; where the kernels run only on the CPU, only cpu is accepted.
        i = rest.index("--device")
        value = rest[i + 1] if i + 1 < len(rest) else ""
        if value != "cpu":
            raise InputError("--device", f"cpu (softvr bench {area} steps its physics on the CPU)", repr(value))
        del rest[i:i + 2]
    return importlib.import_module(f"softvr.bench.{area}").main(rest)


def _cave(argv: list[str]) -> int:
    from softvr.cave import command

    return command.main(argv)


def _check(argv: list[str]) -> int:
    from softvr.scene import command

    return command.check_main(argv)


def _blender_addon(argv: list[str]) -> int:
    from softvr.blender import build_addon

    p = argparse.ArgumentParser(prog="softvr blender-addon",
                                description="Write softvr-blender.zip, the Blender (>= 4.2) add-on, for "
                                            "Edit > Preferences > Add-ons > Install from Disk.")
    p.add_argument("-o", "--out", default=".", help="folder to write it into (default: here)")
    args = p.parse_args(argv)
    print(f"wrote {build_addon(args.out)}")
    return 0


def _info(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="softvr info", description="Print what a volume file holds.")
    parser.add_argument("path")
    args = parser.parse_args(argv)
    from softvr.volume import load

    vol = load(args.path)
    print(f"{args.path}: {vol!r}")
    print(f"  value range {vol.data.min()} .. {vol.data.max()}, extent {vol.extent.round(3).tolist()}")
    return 0


_COMMANDS = {"demo": _demo, "run": _run, "view": _view, "bench": _bench, "info": _info, "build-model": _build_model,
             "tetmesh": _tetmesh,
             "cave": _cave, "check": _check, "blender-addon": _blender_addon}


def _version() -> str:
    """The installed distribution's version (pyproject.toml is its one source)."""
    try:
        return version("softvr")
    except PackageNotFoundError:  # run from a checkout that was never installed
        return "unknown (not installed)"


#: The handler ``--verbose`` puts on the ``softvr`` logger (one, however often main() runs in a process).
_VERBOSE_HANDLER: logging.Handler | None = None


def _log_verbosely() -> None:
    """Show the INFO lines of softvr's loggers on stderr; other libraries' loggers stay as they are."""
    global _VERBOSE_HANDLER
    logger = logging.getLogger("softvr")
    if _VERBOSE_HANDLER is not None:
        logger.removeHandler(_VERBOSE_HANDLER)
    _VERBOSE_HANDLER = logging.StreamHandler(sys.stderr)  # the stderr of now (tests replace it)
    _VERBOSE_HANDLER.setFormatter(logging.Formatter("%(name)s: %(levelname)s: %(message)s"))
    logger.addHandler(_VERBOSE_HANDLER)
    logger.setLevel(logging.INFO)


def main(argv: list[str] | None = None) -> int:
    """Run the ``softvr`` command line; returns the process exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    # --verbose is a top-level option, before the command: what follows the command is the command's.
    while argv and argv[0] in ("-v", "--verbose"):
        argv.pop(0)
        _log_verbosely()
    parser = argparse.ArgumentParser(
        prog="softvr",
        description="softvr: deformable anatomy for VR training (volume deformation, contact, CAVE).",
        epilog="Run 'softvr COMMAND --help' for a command's options.",
    )
    parser.add_argument("command", choices=sorted(_COMMANDS), help="what to do")
    parser.add_argument("--version", action="version", version=f"softvr {_version()}")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="show softvr's INFO log lines on stderr (give it before the command)")
    if argv and argv[0] == "--version":
        print(f"softvr {_version()}")
        return 0
    if not argv or argv[0] in ("-h", "--help"):
        parser.print_help()
        return 0 if argv else 2
    args = parser.parse_args(argv[:1])
    try:
        return _COMMANDS[args.command](argv[1:])
    except SoftvrError as exc:
        print(f"softvr {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"softvr {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the last line: a bug, reported without a traceback
        if os.environ.get("SOFTVR_DEBUG"):
            raise
        print(f"softvr {args.command}: internal error, please report it (with SOFTVR_DEBUG=1 for the traceback): "
              f"{type(exc).__name__}: {str(exc)[:500]}", file=sys.stderr)
        return 70  # EX_SOFTWARE
