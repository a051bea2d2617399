"""The options every command that plays a scene takes, and where its files go."""

from __future__ import annotations

import argparse
from pathlib import Path

from softvr.app._record import output_name, record
from softvr.app._window import VIEW_LAYERS
from softvr.device import resolve_device

__all__ = ["DEFAULT_OUT", "add_device_option", "add_view_options", "check_run_args", "out_folder", "record_from_args",
           "run_parser", "shown_layers"]

#: The one default output folder: a run of scene NAME writes into ``softvr-out/NAME/``.
DEFAULT_OUT = Path("softvr-out")


def add_device_option(parser: argparse.ArgumentParser) -> None:
    """``--device cpu|cuda``: the Warp device of the kernels that take one (default: CUDA when
    present, else the CPU)."""
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None,
                        help="Warp device of the kernels (default: cuda when present, else cpu)")


def out_folder(out, name: str) -> Path:
    """The folder a run of ``name`` writes into: ``out`` when given, else ``softvr-out/NAME``
    (:func:`~softvr.app.output_name`)."""
    return Path(out) if out is not None else DEFAULT_OUT / output_name(name)


def run_parser(prog: str, description: str, frames: int | None, size=(640, 480)) -> argparse.ArgumentParser:
    """The options of every headless run: ``--frames``, ``--out``, ``--size W H``, ``--quiet``,
    ``--png-every K`` and ``--device``.

    Parameters
    ----------
    prog : str
        The command as typed (``softvr run soft-cube``).
    description : str
    frames : int or None
        Default frame count (None: the scene's own).
    size : (int, int) [pixels] or None
        Default image size (None: the scene's own).
    """
    p = argparse.ArgumentParser(prog=prog, description=description)
    p.add_argument("--frames", type=int, default=frames,
                   help=f"frames to simulate and render (default {frames if frames else 'per scene'})")
    p.add_argument("--out", default=None, metavar="DIR",
                   help=f"output folder (default ./{DEFAULT_OUT}/NAME); files are NAME.mp4, NAME_sheet.png, "
                        "NAME_metrics.json")
    p.add_argument("--size", type=int, nargs=2, default=None if size is None else tuple(size), metavar=("W", "H"),
                   help="image size in pixels (default " + ("the scene's" if size is None else f"{size[0]} {size[1]}")
                   + ")")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--png-every", type=int, default=0, metavar="K",
                   help="also write every K-th frame as a PNG into DIR/NAME_frames (default 0: none)")
    add_device_option(p)
    return p


def check_run_args(parser: argparse.ArgumentParser, args) -> None:
    """Reject a frame count below 1, a negative ``--png-every`` and image sizes outside
    [1, 16384] (exits with status 2, naming the option), and a ``--device`` this machine lacks
    (:class:`~softvr.errors.InputError`)."""
    if args.frames is not None and args.frames < 1:
        parser.error(f"--frames: expected an integer >= 1, got {args.frames}")
    if getattr(args, "png_every", 0) < 0:
        parser.error(f"--png-every: expected an integer >= 0, got {args.png_every}")
    if args.size is not None and not all(1 <= s <= 16384 for s in args.size):
        parser.error(f"--size: expected two pixel counts in [1, 16384], got {args.size[0]} {args.size[1]}")
    if getattr(args, "device", None) is not None:
        resolve_device(args.device)  # cuda where none is present: an InputError naming the device


def record_from_args(player, args) -> dict:
    """:func:`~softvr.app.record` ``player`` as the parsed :func:`run_parser` options say:
    into ``--out`` (else ``softvr-out/NAME``), ``--quiet``, ``--png-every``."""
    return record(player, out_folder(args.out, player.name), progress=not args.quiet, png_every=args.png_every)


def add_view_options(parser: argparse.ArgumentParser) -> None:
    """The window options of every ``softvr view``: ``--seconds``, ``--screenshot``, ``--show``,
    ``--hide``."""
    parser.add_argument("--seconds", type=float, default=None, help="close the window after this long")
    parser.add_argument("--screenshot", metavar="PNG", help="save the window when it closes")
    keys = ", ".join(f"{k} {name}" for name, k in VIEW_LAYERS.items())
    parser.add_argument("--show", nargs="*", default=[], choices=list(VIEW_LAYERS),
                        help=f"layers shown at the start besides render and contacts (keys toggle them: {keys})")
    parser.add_argument("--hide", nargs="*", default=[], choices=list(VIEW_LAYERS), help="layers hidden at the start")
    add_device_option(parser)


def shown_layers(args) -> tuple:
    """The layers shown at the start: render and contacts, plus ``--show``, less ``--hide``."""
    shown = ({"render", "contacts"} | set(args.show)) - set(args.hide)
    return tuple(name for name in VIEW_LAYERS if name in shown)
