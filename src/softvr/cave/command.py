"""``softvr cave``: run a scene on a CAVE, a PowerWall or a tiled wall.

``softvr cave preview DISPLAY SCENE``        every screen rendered here, unfolded into one picture
``softvr cave master DISPLAY SCENE``         the master: input, clock, simulation, streaming
``softvr cave node DISPLAY --node NAME``     one render node per screen (needs no scene: it gets
                                             everything from the master's snapshot)
``softvr cave local DISPLAY SCENE``          master + every node as processes on this machine
``softvr cave keys [DIR]``                   CURVE keys (made on first use anyway): the master's,
                                             ``--display`` / ``--nodes``: and these nodes' here (one
                                             host), ``--node NAME``: only this node's (on its host)

DISPLAY is a display file (TOML, ``softvr-display 1``) or a preset name (single-wall, cube,
rave-wall, rave-cube, rave-amphitheatre, powerwall-2x2); it may be left out when SCENE is a
scene file with a ``[display]`` section. SCENE is ``sheet`` (an analytic rippling sheet with
10 K vertices and a turning box), a bundled scene by name (box-stack, soft-cube, ...) or a scene
file (TOML, or glTF / GLB with softvr properties) simulated on the master and streamed to the
nodes, or a glTF / GLB (or OBJ, STL, PLY) file without softvr properties shown as a static
scene to walk through.

Master and nodes use CURVE (encryption, and only nodes whose public keys the master holds may
join, each under its own name) with keys from ``--keys DIR`` (default ``$SOFTVR_CAVE_KEYS`` or
``~/.config/softvr/cave-keys``), made there on first use; ``--no-curve`` is allowed on loopback
endpoints only. A node that hears nothing of its master for ``--master-timeout`` seconds joins
whichever master answers next and ends (exit status 3) when none does within
``--master-wait``; the nodes of ``cave local`` end with it.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from softvr.app import add_device_option
from softvr.cave.app import FrameBuilder, PlayerSource, SceneFileSource, WavingSheet, user_pose_facing
from softvr.cave.cluster import ClusterConfig, Master, Node
from softvr.cave.display import PRESETS, load_display, preset
from softvr.cave.keys import default_folder, make_keys
from softvr.cave.navigation import KeyboardNavigation
from softvr.cave.preview import preview_image
from softvr.cave.render import StateRenderer
from softvr.cave.rig import CameraRig
from softvr.cave.tracking import FixedTracker, OscTracker
from softvr.device import resolve_device
from softvr.errors import InputError
from softvr.files import write_json
from softvr.render.contact_sheet import save_png
from softvr.render.video import write_mp4
from softvr.scene import has_softvr_bodies, load_scene, read_any
from softvr.scene.build import scene_path

if TYPE_CHECKING:  # vtk loads with the first window
    from vtkmodules.vtkRenderingCore import vtkRenderWindowInteractor

__all__ = ["main"]

_DEFAULT_PUBLISH = "tcp://127.0.0.1:5560"
_DEFAULT_CONTROL = "tcp://127.0.0.1:5561"


def load_display_arg(text: str):
    """A display from a preset name or a display file path."""
    if text in PRESETS:
        return preset(text)
    if not Path(text).exists():
        raise InputError("DISPLAY", f"a display file or one of the presets {', '.join(PRESETS)}",
                         f"{text!r} (no such file)")
    return load_display(text)


def make_source(scene: str, frames: int, device: str | None = None):
    """The master's frame source for a scene name (module docstring): ``sheet``, a scene file
    or bundled scene by name (:func:`softvr.scene.build.scene_path`: ``box-stack``,
    ``box-stack.toml``), or a glTF / mesh file without softvr bodies, shown static."""
    if device is not None:
        resolve_device(device)  # cuda where none is present: an InputError naming the device
    if scene == "sheet":
        return WavingSheet()
    path = Path(scene)
    suffix = path.suffix.lower()
    # A mesh file, or a glTF without softvr bodies: a static scene to walk through.
    if suffix in (".obj", ".stl", ".ply") or (suffix in (".gltf", ".glb") and path.is_file()
                                               and not has_softvr_bodies(scene)):
        if not path.is_file():
            raise InputError("SCENE", "an existing scene file", f"{scene!r} (no such file)")
        return SceneFileSource(scene)
    player = load_scene(scene_path(scene), frames=frames, width=64, height=48, device=device)
    if player.volume is not None:
        player.close()
        raise InputError("SCENE", "a scene of surfaces (a [volume] is not streamed to render nodes yet)",
                         f"{scene!r} with a volume")
    return PlayerSource(player)


@contextlib.contextmanager
def _released(source):
    """A simulated scene's player stopped (its haptic processes) when the run ends, however it ends."""
    try:
        yield source
    finally:
        if isinstance(source, PlayerSource):
            source.close()


def resolve_places(args) -> None:
    """``[DISPLAY] SCENE`` into ``args.display`` and ``args.scene``: without DISPLAY, the scene
    file's ``[display]``."""
    places = args.places
    if len(places) == 2:
        args.display, args.scene = places
        return
    if len(places) != 1:
        raise InputError("[DISPLAY] SCENE", "a scene, after a display unless the scene file names one",
                         " ".join(places))
    args.scene = places[0]
    display = None
    try:
        path = scene_path(args.scene)
    except InputError:  # sheet, or no scene file: no display of its own
        path = None
    if path is not None and (path.suffix.lower() == ".toml" or (path.suffix.lower() in (".gltf", ".glb")
                                                                and has_softvr_bodies(path))):
        display = read_any(path).display
    if display is None:
        raise InputError("DISPLAY", "a display file or preset (the scene file has no [display] section)",
                         f"only the scene {args.scene!r}")
    args.display = display


def scripted_navigation(source):
    """The master's default input: the user entity slowly swings around the scene's centre
    (which it shows 1.2 m in front of the viewer at table height) and the head sways 15 cm
    side to side; a ``toggle highlight`` event every 5 s."""
    bounds = np.asarray(source.bounds()).reshape(3, 2)
    center = bounds.mean(axis=1)

    def navigation(n: int, t: float):
        user = user_pose_facing(center, 0.35 * math.sin(0.25 * t))
        head = [0.15 * math.sin(0.7 * t), 0.0, 1.7, 1.0, 0.0, 0.0, 0.0]
        fps = float(getattr(source, "fps", 60.0))
        events = [("toggle", ("highlight",))] if n and n % max(int(5 * fps), 1) == 0 else []
        return user, head, events

    return navigation


def _tracker(spec: str | None):
    if not spec or spec == "scripted":
        return None
    if spec == "fixed":
        return FixedTracker()
    if spec.startswith("osc:") and spec[4:].isdigit():
        return OscTracker(int(spec[4:]))
    raise InputError("--tracker", "scripted | fixed | osc:PORT", repr(spec))


# ------------------------------------------------------------------------------- subcommands
def _preview(args) -> int:
    display = load_display_arg(args.display)
    source = make_source(args.scene, args.frames, args.device)
    frames = FrameBuilder(source, navigation=scripted_navigation(source))
    with _released(source):
        for _ in range(args.frames):
            frames.next_packet(0)
    state = frames.state
    images = {}
    for screen in display.screens:
        renderer = StateRenderer(screen, display.eye_separation, scale=args.scale)
        images[screen.name] = renderer(state)
        renderer.close()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = save_png(preview_image(display, images), out / "cave_preview.png")
    print(f"wrote {path}")
    return 0


def _config(args):
    extra = {}
    if getattr(args, "master_timeout", None) is not None:
        extra["master_timeout_s"] = args.master_timeout
    if getattr(args, "master_wait", None) is not None:
        extra["master_wait_s"] = args.master_wait or None
    return ClusterConfig(publish=args.publish, control=args.control, barrier=not args.no_barrier, keys=args.keys,
                         curve=not args.no_curve, **extra)


def _master(args, on_bound=None) -> dict:
    display = load_display_arg(args.display)
    source = make_source(args.scene, args.frames, args.device)
    nodes = [s.node or s.name for s in display.screens]
    tracker = _tracker(args.tracker)
    navigation = scripted_navigation(source)
    window = None
    if getattr(args, "window", False):
        navigation = KeyboardNavigation(navigation(0, 0.0)[0])
        window = _MasterWindow(display.screen(CameraRig(display).master), display.eye_separation, navigation)
    with _released(source), Master(source, nodes, _config(args), navigation=navigation, tracker=tracker) as master:
        if on_bound is not None:
            on_bound(master.config)
        if not args.quiet:
            print(f"cave master: publishing on {master.config.publish}, control on {master.config.control}; "
                  f"waiting for {', '.join(nodes)}", flush=True)
        if master.unauthorized and not on_bound:
            print(f"cave master: no public key yet for {', '.join(master.unauthorized)}: copy each node's "
                  f"nodes/NAME.key to {master.config.key_folder()}/authorized/NAME.key", file=sys.stderr, flush=True)
        master.wait_for_nodes(args.join_timeout)
        summary = master.run(args.frames, fps=args.fps, progress=not args.quiet,
                             on_frame=None if window is None else lambda _record: window.show(master.state))
        if args.out:
            out = Path(args.out)
            out.mkdir(parents=True, exist_ok=True)
            write_json({"summary": summary, **master.log}, out / "master.json")
    for closing in (tracker, window):
        if closing is not None:
            closing.close()
    return summary


class _MasterWindow:
    """The master's own view: its master screen in a window whose keys and mouse navigate
    (:class:`~softvr.cave.navigation.KeyboardNavigation`)."""

    def __init__(self, screen, separation: float, navigation):
        self.view = StateRenderer(screen, separation, scale=min(1.0, 800 / screen.pixels[0]), onscreen=True)
        self.navigation = navigation
        self.interactor: vtkRenderWindowInteractor | None = None  # made when first shown

    def show(self, state) -> None:
        from vtkmodules.vtkRenderingCore import vtkRenderWindowInteractor  # noqa: PLC0415

        self.view(state)
        if self.interactor is None:
            self.interactor = vtkRenderWindowInteractor()
            self.interactor.SetRenderWindow(self.view.window)
            self.interactor.Initialize()
            self.navigation.attach(self.interactor)
        self.interactor.ProcessEvents()

    def close(self) -> None:
        if self.interactor is not None:
            self.interactor.SetRenderWindow(None)  # type: ignore[arg-type]  # lets go (VTK's stubs omit None)
        self.view.close()


def _node(args) -> int:
    display = load_display_arg(args.display)
    screens = [s for s in display.screens if (s.node or s.name) == args.node]
    if not screens:
        raise InputError("--node", f"one of {[s.node or s.name for s in display.screens]}", repr(args.node))
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    renderer = None if args.no_render else StateRenderer(screens[0], display.eye_separation, scale=args.scale)

    def present(state) -> None:
        if out and renderer is not None and args.save_every and state.n % args.save_every == 0:
            assert renderer.image is not None  # a state is rendered before it is presented
            save_png(renderer.image, out / f"{args.node}_{state.n:06d}.png")

    node = Node(args.node, _config(args), render=renderer, present=present, drop_rate=args.drop_rate,
                seed=args.seed)
    signal.signal(signal.SIGTERM, lambda *_: setattr(node, "finished", True))
    try:
        summary = node.run(max_seconds=args.max_seconds)
    finally:
        node.close()
    if out:
        if renderer is not None and renderer.image is not None:
            save_png(renderer.image, out / f"{args.node}_last.png")
        write_json({**summary, "presented_frames": node.log.presented}, out / f"{args.node}.json")
    if renderer is not None:
        renderer.close()
    if not args.quiet:
        print(json.dumps({k: summary[k] for k in ("node", "presented", "last_frame", "counters")}))
    if node.error:
        print(f"softvr cave node: {node.error}", file=sys.stderr)
        return 3
    return 0


def node_command(display: str, node: str, publish: str, control: str, *, out=None, extra=()) -> list[str]:
    """The command line that starts a render node process."""
    cmd = [sys.executable, "-m", "softvr", "cave", "node", display, "--node", node, "--publish", publish,
           "--control", control, "--quiet"]
    if out:
        cmd += ["--out", str(out)]
    return cmd + list(extra)


_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def _die_with(parent: int):
    """A ``preexec_fn`` for a child that must end with process ``parent``: on Linux the
    kernel sends it SIGTERM when the parent dies (prctl PR_SET_PDEATHSIG), even by SIGKILL."""
    if not sys.platform.startswith("linux"):
        return None
    libc = ctypes.CDLL(None, use_errno=True)

    def arm() -> None:
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:  # the parent died before the signal was armed
            os._exit(1)

    return arm


def _local(args) -> int:
    display = load_display_arg(args.display)
    nodes = [s.node or s.name for s in display.screens]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    processes = []
    extra = ["--scale", str(args.scale), "--save-every", str(args.save_every)]
    if args.keys:
        extra += ["--keys", args.keys]
    for flag in ("no_barrier", "no_curve"):
        if getattr(args, flag):
            extra.append("--" + flag.replace("_", "-"))

    def start_nodes(config) -> None:
        for name in nodes:
            processes.append(subprocess.Popen(node_command(args.display, name, config.publish, config.control,
                                                           out=out, extra=extra), preexec_fn=_die_with(os.getpid())))

    args.publish, args.control = "tcp://127.0.0.1:0", "tcp://127.0.0.1:0"
    # A SIGTERM ends the master like Ctrl-C does, through the cleanup below.
    previous = signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))
    finished = False
    try:
        summary = _master(args, on_bound=start_nodes)
        finished = True
    finally:
        signal.signal(signal.SIGTERM, previous)
        deadline = time.monotonic() + (30.0 if finished else 5.0)  # after bye the nodes end by themselves
        for p in processes:
            if not finished:
                p.terminate()
            try:
                p.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                p.kill()
    _compose_previews(display, out)
    print(json.dumps({k: summary[k] for k in ("frames", "mismatches", "joins", "evictions", "sync_ms")}))
    return 0 if summary["mismatches"] == 0 else 1


def _compose_previews(display, out: Path) -> None:
    """``cave_preview.png`` from every node's last image, and ``cave_preview.mp4`` from the
    frames every node saved."""
    import imageio.v3 as iio  # noqa: PLC0415


    def images(suffix: str) -> dict | None:
        found = {s.name: out / f"{s.node or s.name}_{suffix}.png" for s in display.screens}
        if not all(p.exists() for p in found.values()):
            return None
        return {name: iio.imread(p)[..., :3] for name, p in found.items()}

    last = images("last")
    if last is None:
        return
    save_png(preview_image(display, last), out / "cave_preview.png")
    first = display.screens[0].node or display.screens[0].name
    numbers = sorted(p.stem.rsplit("_", 1)[1] for p in out.glob(f"{first}_[0-9]*.png"))
    frames = [preview_image(display, imgs) for n in numbers if (imgs := images(n)) is not None]
    if len(frames) > 1:
        write_mp4(frames, out / "cave_preview.mp4", fps=10)


def _keys(args) -> int:
    folder = Path(args.folder or default_folder())
    if args.node:
        if args.display or args.nodes:
            raise InputError("--node", "alone (a node's host makes its own key only)", "with --display / --nodes")
        make_keys(folder, [args.node], master=False)
        print(f"made the CURVE key of node {args.node} in {folder}/nodes (its secret stays here). On the master's "
              f"host copy {folder}/nodes/{args.node}.key to KEYS/authorized/{args.node}.key, and bring the master's "
              f"master.key here to {folder}/master.key")
        return 0
    nodes = list(args.nodes or [])
    if args.display:
        nodes += [s.node or s.name for s in load_display_arg(args.display).screens]
    make_keys(folder, nodes)
    made = f"master and {', '.join(nodes)}" if nodes else "master"
    print(f"CURVE keys of {made} in {folder} (secret keys mode 0600). Nodes on other hosts: run "
          f"'softvr cave keys --node NAME' there and copy only public keys (master.key there, NAME.key to "
          f"{folder}/authorized/)")
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="softvr cave", description=__doc__.splitlines()[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n".join(__doc__.splitlines()[2:]))
    sub = p.add_subparsers(dest="command", required=True)

    def common(q, scene: bool) -> None:
        if scene:
            q.add_argument("places", nargs="+", metavar="[DISPLAY] SCENE",
                           help="display file (TOML) or preset name (optional when the scene file has a "
                                "[display]); sheet, a bundled scene's name, or a scene file")
            add_device_option(q)
        else:
            q.add_argument("display", metavar="DISPLAY", help="display file (TOML) or preset name")
        q.add_argument("--quiet", action="store_true", help="no progress output")

    def network(q) -> None:
        q.add_argument("--publish", default=_DEFAULT_PUBLISH, help=f"master's frame endpoint ({_DEFAULT_PUBLISH})")
        q.add_argument("--control", default=_DEFAULT_CONTROL, help=f"master's control endpoint ({_DEFAULT_CONTROL})")
        q.add_argument("--keys", help="CURVE key folder (default $SOFTVR_CAVE_KEYS or ~/.config/softvr/cave-keys)")
        q.add_argument("--no-curve", action="store_true", help="no encryption nor authentication (loopback only)")
        q.add_argument("--no-barrier", action="store_true", help="no software swap barrier (hardware genlock)")

    def master_options(q) -> None:
        q.add_argument("--frames", type=int, default=300, help="frames to run (default 300)")
        q.add_argument("--fps", type=float, default=60.0, help="frame rate to pace at, 0: as fast as possible")
        q.add_argument("--tracker", default="scripted", help="head: scripted | fixed | osc:PORT (default scripted)")
        q.add_argument("--join-timeout", type=float, default=60.0, help="seconds to wait for every node")

    q = sub.add_parser("preview", help="every screen rendered here, unfolded into one picture")
    common(q, True)
    q.add_argument("--frames", type=int, default=30, help="frames to simulate first (default 30)")
    q.add_argument("--scale", type=float, default=0.25, help="pixel scale of the screens (default 0.25)")
    q.add_argument("--out", default="softvr-out/cave", metavar="DIR", help="output folder (default ./softvr-out/cave)")

    q = sub.add_parser("master", help="the master process")
    common(q, True)
    network(q)
    master_options(q)
    q.add_argument("--out", help="write master.json (per-frame digests, joins, timings) here")
    q.add_argument("--window", action="store_true",
                   help="show the master screen in a window; keys (w a s d, arrows, q e, r f) and mouse drags navigate")

    q = sub.add_parser("node", help="one render node")
    common(q, False)
    network(q)
    q.add_argument("--node", required=True, help="this node's name (a screen's node in DISPLAY)")
    q.add_argument("--out", help="write <node>.json, <node>_last.png and saved frames here")
    q.add_argument("--scale", type=float, default=1.0, help="pixel scale of the screen (default 1)")
    q.add_argument("--save-every", type=int, default=0, help="save every K-th presented frame as PNG")
    q.add_argument("--no-render", action="store_true", help="follow the state without drawing")
    q.add_argument("--drop-rate", type=float, default=0.0, help="drop this fraction of frames (testing)")
    q.add_argument("--seed", type=int, default=None, help="seed of the dropped frames")
    q.add_argument("--max-seconds", type=float, default=None, help="stop after this long")
    q.add_argument("--master-timeout", type=float, default=None,
                   help="seconds of silence after which the master counts as lost (default 2)")
    q.add_argument("--master-wait", type=float, default=None,
                   help="seconds to wait for a (new) master before ending with status 3 (default 60, 0: for ever)")

    q = sub.add_parser("local", help="master and all nodes on this machine")
    common(q, True)
    master_options(q)
    q.add_argument("--keys", help="CURVE key folder (default $SOFTVR_CAVE_KEYS or ~/.config/softvr/cave-keys)")
    q.add_argument("--no-curve", action="store_true", help="no encryption nor authentication")
    q.add_argument("--no-barrier", action="store_true", help="no software swap barrier")
    q.add_argument("--out", default="softvr-out/cave", metavar="DIR", help="output folder (default ./softvr-out/cave)")
    q.add_argument("--scale", type=float, default=0.25, help="pixel scale of the screens (default 0.25)")
    q.add_argument("--save-every", type=int, default=10, help="save every K-th frame per node (default 10)")

    q = sub.add_parser("keys", help="make CURVE keys for a cluster")
    q.add_argument("folder", metavar="DIR", nargs="?", help="key folder (default $SOFTVR_CAVE_KEYS or "
                                                            "~/.config/softvr/cave-keys)")
    q.add_argument("--display", help="also a key for every node of this display (all on this host)")
    q.add_argument("--nodes", nargs="*", help="also keys for these nodes (on this host)")
    q.add_argument("--node", help="only this node's key (run on the node's host)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if hasattr(args, "places"):
        resolve_places(args)
    if getattr(args, "frames", 1) < 1:
        raise InputError("--frames", "at least 1", repr(args.frames))
    if getattr(args, "scale", 1.0) <= 0 or not math.isfinite(getattr(args, "scale", 1.0)):
        raise InputError("--scale", "a positive number", repr(args.scale))
    if args.command == "master":
        args.fps = args.fps or None
        summary = _master(args)
        print(json.dumps({k: summary[k] for k in ("frames", "mismatches", "joins", "evictions", "sync_ms")}))
        return 0
    if args.command == "local":
        args.fps = args.fps or None
    return {"preview": _preview, "node": _node, "local": _local, "keys": _keys}[args.command](args)


if __name__ == "__main__":
    raise SystemExit(main())
