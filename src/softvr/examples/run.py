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
``<out>/<name>_metrics.json`` (per frame: simulated time, wall time, deepest penetration,
contact count, PGS sweeps, kinetic and total energy), all atomically.

This module also holds what the demos share: :class:`PhysicsExample` (the frame loop and its
metrics) and :func:`run_example` (frames to files).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

import numpy as np

__all__ = [
    "SCENES",
    "PhysicsExample",
    "check_run_args",
    "demo_parser",
    "gravity_potential",
    "main",
    "run_example",
    "run_module",
    "VIEW_LAYERS",
    "view_example",
    "view_main",
]

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


# ----------------------------------------------------------------------------- shared demo loop
def gravity_potential(body, gravity) -> float:
    """Gravitational potential energy ``-sum m g . x`` [J] of a body (zero at the origin)."""
    g = np.asarray(gravity, float)
    if hasattr(body, "position") and np.ndim(getattr(body, "mass", None)) == 0:
        return -float(body.mass) * float(np.asarray(body.position) @ g)
    return -float(np.sum(np.asarray(body.mass) * (np.asarray(body.q) @ g)))


class PhysicsExample:
    """Base of the physics demos: a :class:`softvr.Scene` advanced ``steps_per_frame`` steps
    of ``dt`` per frame, drawn with a :class:`~softvr.render.SurfaceRenderer`.

    Subclasses build ``self.scene`` and define :meth:`penetration`, :meth:`setup_render`
    (add surfaces, keep handles) and :meth:`update_render` (move them).

    Attributes
    ----------
    name : str
        Output file stem (``soft_cube``, ...).
    fps : float
        Frames per second of the video; ``dt * steps_per_frame = 1 / fps``.
    metrics : list of dict
        One record per frame: ``frame``, ``sim_time_s``, ``step_ms`` (physics), ``stage_ms``
        (the physics by stage, summed over the frame's steps: :data:`softvr.sim.STAGES`; the
        rest of ``step_ms`` is the example's own hooks), ``render_ms``,
        ``wall_ms`` (both), ``max_penetration_m`` (deepest over the frame's steps),
        ``contacts`` and ``active_contacts`` (normal impulse > 0) of the frame's last step,
        ``pgs_iterations`` (most sweeps in one step of the frame), ``pgs_residual_m_per_s``,
        ``kinetic_energy_j``, ``energy_j`` (kinetic + gravitational, zero at z = 0; elastic
        energy not included, so for dissipative physics it never exceeds the initial value).
    """

    name = "physics"
    camera = "iso"

    def __init__(self, scene, dt: float, steps_per_frame: int, frames: int, width: int, height: int,
                 bounds=None, camera=None):
        self.scene = scene
        self.dt = float(dt)
        self.steps_per_frame = int(steps_per_frame)
        self.fps = 1.0 / (self.dt * self.steps_per_frame)
        self.frames = max(int(frames), 1)
        self.frame = 0
        self.width, self.height = int(width), int(height)
        self.bounds = bounds
        if camera is not None:
            self.camera = camera
        self.metrics: list[dict] = []
        self._renderer = None

    # -- physics ------------------------------------------------------------------------
    def penetration(self) -> float:
        """Deepest current overlap [m] of any collision geometry (0 when nothing overlaps)."""
        raise NotImplementedError

    def energies(self) -> tuple[float, float]:
        """(kinetic, kinetic + gravitational) energy [J] of all bodies."""
        # Bodies of infinite mass move on a script (or not at all): no energy of their own.
        moving = [b for b in self.scene.bodies if not b.infinite_mass]
        kinetic = sum(float(b.kinetic_energy()) for b in moving)
        potential = sum(gravity_potential(b, self.scene.gravity) for b in moving)
        return kinetic, kinetic + potential

    def before_step(self) -> None:
        """Hook called before every physics step (scripted events, driven boundaries)."""

    def after_step(self, solution) -> None:
        """Hook called after every physics step with its contact solution (sensors)."""

    def frame_metrics(self) -> dict:
        """Scene-specific entries of this frame's metrics record (called after its last step)."""
        return {}

    def write_plots(self, doc: dict, out: Path) -> list[Path]:
        """Plots of a finished run (``doc`` the metrics document) into folder ``out``; returns
        the files written (none by default)."""
        return []

    def step(self) -> dict:
        """Advance one frame (``steps_per_frame`` physics steps); returns the frame's metrics."""
        from softvr.sim import STAGES  # noqa: PLC0415

        t0 = time.perf_counter()
        deepest, sweeps, residual, solution = 0.0, 0, 0.0, None
        stage_ms = dict.fromkeys(STAGES, 0.0)
        for _ in range(self.steps_per_frame):
            self.before_step()
            solution = self.scene.step(self.dt)
            for stage in STAGES:
                stage_ms[stage] += self.scene.stage_ms[stage]
            self.after_step(solution)
            deepest = max(deepest, self.penetration())
            sweeps = max(sweeps, int(solution.iterations))
            residual = max(residual, float(solution.residual))
        step_ms = (time.perf_counter() - t0) * 1e3
        kinetic, energy = self.energies()
        impulses = [i for i in solution.impulses if len(i)]
        record = {
            "frame": self.frame,
            "sim_time_s": float(self.scene.time),
            "step_ms": step_ms,
            "stage_ms": stage_ms,
            "render_ms": 0.0,
            "wall_ms": step_ms,
            "max_penetration_m": float(deepest),
            "contacts": int(sum(len(i) for i in impulses)),
            "active_contacts": int(sum(int((i[:, 0] > 0).sum()) for i in impulses)),
            "pgs_iterations": sweeps,
            "pgs_residual_m_per_s": residual,
            "kinetic_energy_j": kinetic,
            "energy_j": energy,
            **self.frame_metrics(),
        }
        self.metrics.append(record)
        self.frame += 1
        return record

    # -- rendering ----------------------------------------------------------------------
    def setup_render(self, renderer) -> None:
        """Add this scene's surfaces to ``renderer`` (called once)."""
        raise NotImplementedError

    def update_render(self, renderer) -> None:
        """Move the surfaces to the current state (called before every render)."""
        raise NotImplementedError

    def renderer_options(self) -> dict:
        """Extra :class:`~softvr.render.SurfaceRenderer` arguments (background, light kit) of
        this scene (none by default)."""
        return {}

    def render(self) -> np.ndarray:
        """Draw the current state; returns RGB uint8 [height, width, 3]."""
        t0 = time.perf_counter()
        if self._renderer is None:
            from softvr.render.surfaces import SurfaceRenderer  # noqa: PLC0415

            self._renderer = SurfaceRenderer(self.width, self.height, self.camera, bounds=self.bounds,
                                             **self.renderer_options())
            self.setup_render(self._renderer)
        self.update_render(self._renderer)
        image = self._renderer.render()
        if self.metrics:
            ms = (time.perf_counter() - t0) * 1e3
            self.metrics[-1]["render_ms"] = ms
            self.metrics[-1]["wall_ms"] = self.metrics[-1]["step_ms"] + ms
        return image

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def describe(self) -> dict:
        """Scene facts for the metrics file (subclasses add theirs)."""
        return {"dt_s": self.dt, "steps_per_frame": self.steps_per_frame, "fps": self.fps,
                "bodies": [getattr(b, "name", type(b).__name__) for b in self.scene.bodies]}


def run_example(example: PhysicsExample, out, *, progress: bool = True, sheet_frames: int = 8,
                png_every: int = 0) -> dict:
    """Step and render every frame of ``example``; write ``<out>/<name>.mp4``,
    ``<name>_sheet.png``, ``<name>_metrics.json`` and the example's plots
    (:meth:`PhysicsExample.write_plots`); with ``png_every`` = k > 0 also every k-th frame as
    ``<name>_frames/frame_NNNNN.png``. Returns the metrics document.

    The example is closed afterwards. ``out`` is created if missing. Frames are streamed to
    the video encoder: memory does not grow with the number of frames (the contact sheet's
    ``sheet_frames`` are kept).
    """
    from tqdm import tqdm  # noqa: PLC0415

    from softvr.render import contact_sheet, save_png, write_mp4  # noqa: PLC0415
    from softvr.render._atomic import write_json  # noqa: PLC0415
    from softvr.sim import STAGES  # noqa: PLC0415

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    name = example.name
    frames_dir = out / f"{name}_frames"
    if png_every > 0:
        frames_dir.mkdir(exist_ok=True)
    # Frames go to the video encoder as they are rendered (one frame in memory, not all of
    # them: 0.9 MB each at 640 x 480); the contact sheet's few are kept as they pass.
    total = max(example.frames - example.frame, 1)
    pick = np.linspace(0, total - 1, min(sheet_frames, total)).round().astype(int)
    kept: dict = {}
    busy = [0.0]  # [s] spent stepping and rendering (not encoding)

    def rendered():
        try:
            with tqdm(total=example.frames, desc=name, unit="frame", disable=not progress) as bar:
                i = 0
                while example.frame < example.frames:
                    t0 = time.perf_counter()
                    m = example.step()
                    image = example.render()
                    busy[0] += time.perf_counter() - t0
                    if i in pick:
                        kept[i] = image
                    if png_every > 0 and i % png_every == 0:
                        save_png(image, frames_dir / f"frame_{i:05d}.png")
                    bar.set_postfix_str(f"t={m['sim_time_s']:.2f}s pen={m['max_penetration_m'] * 1e3:.2f}mm "
                                        f"contacts={m['contacts']}", refresh=False)
                    bar.update()
                    i += 1
                    yield image
        finally:
            example.close()

    frames = rendered()
    try:
        mp4 = write_mp4(frames, out / f"{name}.mp4", fps=example.fps)
    finally:
        frames.close()  # closes the example even when encoding failed
    wall = busy[0]
    shown = [i for i in pick if i in kept]
    metrics = example.metrics
    sheet = save_png(contact_sheet([kept[i] for i in shown], columns=4,
                                   labels=[f"t = {metrics[i]['sim_time_s']:.2f} s" for i in shown]),
                     out / f"{name}_sheet.png")
    step_ms = np.array([m["step_ms"] for m in metrics])
    summary = {
        "frames": len(metrics),
        "sim_time_s": metrics[-1]["sim_time_s"],
        "wall_s": wall,
        "step_ms_median": float(np.median(step_ms)),
        "step_ms_max": float(step_ms.max()),
        "stage_ms_median": {k: float(np.median([m["stage_ms"][k] for m in metrics])) for k in STAGES},
        "max_penetration_m": max(m["max_penetration_m"] for m in metrics),
        "max_contacts": max(m["contacts"] for m in metrics),
        "max_pgs_iterations": max(m["pgs_iterations"] for m in metrics),
    }
    doc = {"scene": name, **example.describe(), "summary": summary, "frames": metrics}
    path = write_json(doc, out / f"{name}_metrics.json")
    plots = example.write_plots(doc, out)
    if png_every > 0:
        plots.append(frames_dir)
    if progress:
        print(f"{name}: {summary['frames']} frames, {summary['sim_time_s']:.2f} s simulated in {wall:.1f} s; "
              f"deepest penetration {summary['max_penetration_m'] * 1e3:.3f} mm")
        for written in (mp4, sheet, path, *plots):
            print(f"wrote {written}")
    return doc


def demo_parser(prog: str, description: str, frames: int | None, out: str = "softvr-run") -> argparse.ArgumentParser:
    """The options every physics demo takes: ``--frames``, ``--out``, ``--size W H``, ``--quiet``."""
    p = argparse.ArgumentParser(prog=prog, description=description)
    p.add_argument("--frames", type=int, default=frames,
                   help=f"frames to simulate and render (default {frames if frames else 'per scene'})")
    p.add_argument("--out", default=out, help=f"output folder (default ./{out})")
    p.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"),
                   help="image size in pixels (default 640 480)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--png-every", type=int, default=0, metavar="K",
                   help="also write every K-th frame as a PNG into <out>/<name>_frames (default 0: none)")
    return p


def check_run_args(parser: argparse.ArgumentParser, args) -> None:
    """Reject a frame count below 1 and image sizes outside [1, 16384] (exits with status 2)."""
    if args.frames < 1:
        parser.error(f"--frames: expected an integer >= 1, got {args.frames}")
    if getattr(args, "png_every", 0) < 0:
        parser.error(f"--png-every: expected an integer >= 0, got {args.png_every}")
    if not all(1 <= s <= 16384 for s in args.size):
        parser.error(f"--size: expected two pixel counts in [1, 16384], got {args.size[0]} {args.size[1]}")


def run_module(module, args, **options) -> int:
    """Build ``module.Example`` from parsed demo options (plus scene ``options``) and run it to files."""
    example = module.Example(frames=args.frames, width=args.size[0], height=args.size[1], **options)
    run_example(example, args.out, progress=not args.quiet, png_every=args.png_every)
    return 0


#: What :func:`view_example` can show, each toggled by a key: the render surfaces (and volume),
#: the collision surfaces' edges, the FEM tets' edges, the contacts, their adhesion colours.
VIEW_LAYERS = {"render": "r", "collision": "k", "tets": "t", "contacts": "c", "adhesion": "a"}


def view_example(example: PhysicsExample, *, timeout_s: float | None = None, screenshot=None,
                 overlays: tuple = ("render", "contacts")) -> int:
    """Play ``example`` live in a window: one frame per timer tick, drawn on screen.

    Mouse: the trackball camera (left rotates, right zooms, middle pans); the right button
    (or control + left) on a body grabs it and drags it with a spring
    (:class:`~softvr.examples._drag_tool.DragTool`). Keys: space pauses
    and resumes, ``n`` advances one frame while paused, ``q`` quits; ``c`` shows the contacts
    (points, normal force lines, the largest a tenth of the view across), ``a`` colours them by
    adhesion intensity; the three representations of a body (thesis 5.1): ``r`` its render
    surface, ``k`` its collision surface (edges, cyan), ``t`` its FEM tets (edges, yellow). A
    status line gives the frame, the simulated time, the frame rate and the ms of the physics
    step and of the render. The simulation stops after ``example.frames`` frames (the window
    stays open). ``overlays`` names the layers shown at the start (keys of
    :data:`VIEW_LAYERS`); ``screenshot`` (a PNG path) saves the window as it is when the loop
    ends. Returns the frames simulated.

    Raises :class:`~softvr.errors.InputError` when there is no display.
    """
    from softvr.examples._drag_tool import DragTool  # noqa: PLC0415
    from softvr.render._live import play  # noqa: PLC0415
    from softvr.render.contact_sheet import save_png  # noqa: PLC0415
    from softvr.render.overlays import ContactOverlay, LineOverlay, TextOverlay  # noqa: PLC0415
    from softvr.render.surfaces import SurfaceRenderer  # noqa: PLC0415

    renderer = SurfaceRenderer(example.width, example.height, example.camera, bounds=example.bounds, onscreen=True,
                               **example.renderer_options())
    example.setup_render(renderer)
    window = renderer.vtk_renderer.GetRenderWindow()
    unknown = sorted(set(overlays) - set(VIEW_LAYERS))
    if unknown:
        from softvr.errors import InputError  # noqa: PLC0415

        raise InputError("overlays", f"names of {', '.join(VIEW_LAYERS)}", ", ".join(unknown))
    window.SetWindowName(f"softvr: {example.name} (space: pause, n: step, "
                         + ", ".join(f"{k}: {name}" for name, k in VIEW_LAYERS.items()) + ")")
    status = TextOverlay(renderer.vtk_renderer)
    contacts = ContactOverlay(renderer.vtk_renderer)
    bounds = np.asarray(example.bounds if example.bounds is not None else (-1, 1, -1, 1, -1, 1), float)
    reach = float(np.linalg.norm(bounds[1::2] - bounds[0::2]))
    from softvr.volume import tet_edges  # noqa: PLC0415

    soft = [b for b in example.scene.bodies if hasattr(b, "tets")]
    tets = [LineOverlay(renderer.vtk_renderer, tet_edges(b.tets)) for b in soft]
    surfaces = example.scene.collision_surfaces
    collision = [LineOverlay(renderer.vtk_renderer, s.edge_set.edges, color=(0.3, 0.9, 1.0)) for s in surfaces]
    render_handles = renderer.handles("mesh") + renderer.handles("volume")
    shown = {name: name in overlays for name in VIEW_LAYERS}
    last = {"time": time.perf_counter()}

    def draw_overlays() -> None:
        solution = example.scene.last_solution
        points, normals, forces, beta = [], [], [], []
        if solution is not None and shown["contacts"]:
            intensity = example.scene.adhesion_state.intensity
            for c, impulse in zip(solution.contacts, solution.impulses):
                if len(impulse):
                    points.append(c.point_a)
                    normals.append(c.normal)
                    forces.append(impulse[:, 0] / example.dt)
                    beta.append([intensity.get(int(i), 0.0) for i in c.ids])
        cat = (lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape))
        forces = cat(forces, (0,))
        # The largest force is drawn a tenth of the view across; the others in proportion.
        contacts.scale = 0.1 * reach / max(float(forces.max(initial=0.0)), 1e-9)
        contacts.update(cat(points, (0, 3)), cat(normals, (0, 3)), forces,
                        cat(beta, (0,)) if shown["adhesion"] else None)
        contacts.show(shown["contacts"])
        for overlay, body in zip(tets, soft):
            overlay.show(shown["tets"])
            if shown["tets"]:
                overlay.update(body.q)
        for overlay, surface in zip(collision, surfaces):
            overlay.show(shown["collision"])
            if shown["collision"]:
                overlay.update(surface.points.positions())
        for handle in render_handles:
            renderer.set_visible(handle, shown["render"])
        m = example.metrics[-1] if example.metrics else {}
        drawn = example.metrics[-2] if len(example.metrics) > 1 else {}  # this frame's render is not done yet
        now = time.perf_counter()
        fps = 1.0 / max(now - last["time"], 1e-6)
        last["time"] = now
        stages = "  ".join(f"{k} {v:.1f}" for k, v in m.get("stage_ms", {}).items())
        status.set(f"frame {example.frame}/{example.frames}  t {example.scene.time:.3f} s  {fps:4.1f} fps  "
                   f"contacts {m.get('contacts', 0)}\n"
                   f"ms: step {m.get('step_ms', 0.0):.1f} ({stages})  render {drawn.get('render_ms', 0.0):.1f}")

    tool = DragTool(example.scene, renderer.vtk_renderer)

    def mouse(interactor, style) -> None:
        """Right button (or control + left) drags a body; otherwise the trackball camera."""
        def press(obj, event) -> None:
            right = event == "RightButtonPressEvent"
            if (right or interactor.GetControlKey()) and tool.press(*interactor.GetEventPosition()):
                return
            (style.OnRightButtonDown if right else style.OnLeftButtonDown)()

        def move(obj, event) -> None:
            if tool.grab is not None:
                tool.move(*interactor.GetEventPosition())
            else:
                style.OnMouseMove()

        def release(obj, event) -> None:
            if tool.grab is not None:
                tool.release()
            else:
                (style.OnRightButtonUp if event == "RightButtonReleaseEvent" else style.OnLeftButtonUp)()

        for event in ("RightButtonPressEvent", "LeftButtonPressEvent"):
            style.AddObserver(event, press)
        style.AddObserver("MouseMoveEvent", move)
        for event in ("RightButtonReleaseEvent", "LeftButtonReleaseEvent"):
            style.AddObserver(event, release)

    def advance() -> None:
        if example.frame < example.frames:
            t0 = time.perf_counter()
            tool.apply()
            example.step()
            example.update_render(renderer)
            draw_overlays()
            window.Render()
            example.metrics[-1]["render_ms"] = (time.perf_counter() - t0) * 1e3 - example.metrics[-1]["step_ms"]

    def toggle(name: str):
        def flip() -> None:
            shown[name] = not shown[name]
            draw_overlays()
        return flip

    example.update_render(renderer)
    draw_overlays()
    renderer.render()
    try:
        play(window, advance, period_ms=int(1000 / example.fps), timeout_s=timeout_s,
             keys={key: toggle(name) for name, key in VIEW_LAYERS.items()},
             on_exit=None if screenshot is None else lambda: save_png(renderer.grab(), screenshot), setup=mouse)
    finally:
        renderer.close()
    return example.frame


def view_main(argv: list[str] | None = None) -> int:
    """``softvr view SCENE [--frames N] [--size W H] [--seconds S]``: a demo played live in a window."""
    names = ", ".join(SCENES)
    p = argparse.ArgumentParser(prog="softvr view", description="Play a physics demo live in a window.")
    p.add_argument("scene", metavar="SCENE", help=f"volume, or one of: {names}")
    p.add_argument("--frames", type=int, default=None, help="frames to simulate (default per scene)")
    p.add_argument("--size", type=int, nargs=2, default=(900, 700), metavar=("W", "H"))
    p.add_argument("--seconds", type=float, default=None, help="close the window after this long")
    args = p.parse_args(argv)
    if args.scene not in SCENES:
        p.error(f"unknown scene {args.scene!r}; choose volume or one of: {names}")
    module = importlib.import_module(f"softvr.examples.example_{SCENES[args.scene]}")
    args.frames = module.DEFAULT_FRAMES if args.frames is None else args.frames
    args.out = None
    check_run_args(p, args)
    from softvr.render._backend import require_display  # noqa: PLC0415

    require_display()  # before building a large scene
    example = module.Example(frames=args.frames, width=args.size[0], height=args.size[1])
    view_example(example, timeout_s=args.seconds)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``softvr run SCENE [--frames N] [--out DIR] [--size W H] [scene options]``; returns the
    exit code. Everything after SCENE goes to the scene's own ``main`` (e.g. ``softvr run candy
    --adhesion``; ``softvr run SCENE --help`` lists the scene's options)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    names = ", ".join(SCENES)
    named = [a for a in argv if a in SCENES]
    if named and ("-h" in argv or "--help" in argv):  # the scene's own help, with its options
        rest = list(argv)
        rest.remove(named[0])
        return importlib.import_module(f"softvr.examples.example_{SCENES[named[0]]}").main(rest)
    p = demo_parser("softvr run", "Run a physics demo headless: MP4, PNG contact sheet and JSON metrics.",
                    frames=None)
    p.add_argument("scene", metavar="SCENE", help=f"one of: {names}")
    p.epilog = ("Scenes: " + names + ". Each has its own default frame count and options "
                "(softvr run SCENE --help).")
    args, _ = p.parse_known_args(argv)
    scene = args.scene
    if scene not in SCENES:
        looks_like_file = any(c in scene for c in "/\\") or Path(scene).suffix != "" or Path(scene).exists()
        if looks_like_file:
            p.error(f"{scene!r} looks like a scene file; scene files are TOML (.toml) or glTF (.gltf, .glb) "
                    f"(softvr check SCENE). Built-in scenes: {names}")
        p.error(f"unknown scene {scene!r}; choose one of: {names}")
    module = importlib.import_module(f"softvr.examples.example_{SCENES[scene]}")
    rest = list(argv)
    rest.remove(scene)
    return module.main(rest)

if __name__ == "__main__":
    raise SystemExit(main())
