"""The player: a built :class:`softvr.Scene` advanced frame by frame, its per-step hooks in one
declared order (:data:`STEP_ORDER`), its metrics recorded per frame, its state drawn."""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from softvr.app._drawables import Drawable, SurfaceDrawing
from softvr.render.surfaces import SurfaceRenderer
from softvr.sim import STAGES
from softvr.sim.frame_metrics import RigidFrameMetrics, rigid_stepper

__all__ = ["FRAME_ORDER", "STEP_ORDER", "Player", "Sensor", "gravity_potential"]

#: What one sub-step does (after :meth:`Player.start`, once before the first frame), in this
#: order: the scripted boundaries move (driven nodes, keyframed events: :meth:`Player.drive`),
#: the haptic devices are read (:meth:`Player.haptic_tick`), the physics steps
#: (:meth:`softvr.Scene.step`), the step's contact solution is read (sensors, the haptic tool's
#: force: :meth:`Player.sense`). Driving first puts the boundaries' velocities into the step
#: that moves them; reading the devices before the step gives the tool the newest handle position.
STEP_ORDER = ("drive", "haptics", "physics", "sense")

#: What follows a frame's last sub-step, in this order: the volume follows its body
#: (:meth:`Player.update_volume`), then the frame's metrics are taken (:meth:`Player.frame_metrics`).
FRAME_ORDER = ("volume", "metrics")


@dataclass(frozen=True)
class Sensor:
    """A vector read after each frame's last step into the frame's metrics (``sensors``) and
    plotted against time by :func:`~softvr.app.record`.

    Attributes
    ----------
    name : str
    kind : str
        What it reads (``contact_force``, ...), for the metrics file.
    unit : str
        Its SI unit ("N", "m").
    read : callable
        ``read(solution)`` -> [3] in ``unit``, ``solution`` the last step's contact solution
        (:class:`softvr.contact.ContactSolution`).
    """

    name: str
    kind: str
    unit: str
    read: Callable[..., np.ndarray]


def gravity_potential(body, gravity) -> float:
    """Gravitational potential energy ``-sum m g . x`` [J] of a body (zero at the origin).

    Parameters
    ----------
    body : RigidBody or a node body
        A rigid body (scalar ``mass`` [kg], ``position`` [3] [m]) or a node body (``mass``
        [n] [kg], ``q`` [n, 3] [m]).
    gravity : array_like, shape [3] [m/s^2]
    """
    g = np.asarray(gravity, float)
    if hasattr(body, "position") and np.ndim(getattr(body, "mass", 0.0)) == 0:  # (no mass: 0-d too)
        return -float(body.mass) * float(np.asarray(body.position) @ g)
    return -float(np.sum(np.asarray(body.mass) * (np.asarray(body.q) @ g)))


class Player:
    """A :class:`softvr.Scene` played ``steps_per_frame`` sub-steps of ``dt`` per frame, drawn
    with a :class:`~softvr.render.SurfaceRenderer`.

    A scene to play subclasses it: it builds ``scene``, defines :meth:`penetration` and
    :meth:`drawables` (what it shows, as plain data: the window, the offscreen render and the
    cave cluster all read them), and overrides the hooks it needs (:data:`STEP_ORDER`,
    :data:`FRAME_ORDER`). A player that draws what drawables cannot say (lights, a volume)
    extends :meth:`setup_render` and :meth:`update_render`.
    :func:`~softvr.app.record` writes its frames to files, :func:`~softvr.app.play_window`
    plays it in a window.

    Parameters
    ----------
    scene : softvr.Scene
    dt : float [s]
        Physics step.
    steps_per_frame : int
        Sub-steps per frame; ``dt * steps_per_frame = 1 / fps``.
    frames : int
        Frames to play (at least 1).
    width, height : int [pixels]
        Image size.
    bounds : array_like, shape [6] [m], optional
        (xmin, xmax, ymin, ymax, zmin, zmax) the camera frames.
    camera : str or Camera, optional
        Camera of the renderer (default the class's ``camera``).

    Attributes
    ----------
    name : str
        Output name (``soft-cube``, ...): the files are ``<out>/<name>.mp4``, ...
    fps : float
        Frames per second of the video.
    metrics : list of dict
        One record per frame, its times [ms] of wall clock: ``frame``, ``sim_time_s``,
        ``step_ms`` (the frame's sub-steps with their hooks, on whichever thread they ran: with
        :attr:`overlap` the worker's, beside the previous frame's render), ``stage_ms`` (the
        physics by stage, summed over the frame's steps: :data:`softvr.sim.STAGES`; the rest of
        ``step_ms`` is the hooks), ``render_ms`` (the drawing: :meth:`update_render` and the
        render, not the next frame's start), ``wall_ms`` (the calling thread's time in the
        frame's :meth:`step` and :meth:`render` calls: sequential, about step + frame hooks +
        render; with :attr:`overlap`, the wait for the step ahead + frame hooks + render + the
        next frame's start, so the frames' ``wall_ms`` add up to a loop's time in the player and
        a frame's is the loop's period), ``latency_ms`` (from the frame's first input read to
        its image: :attr:`overlap`),
        ``max_penetration_m`` (deepest over the frame's steps), ``contacts`` and
        ``active_contacts`` (normal impulse > 0) of the frame's last step, ``pgs_iterations``
        (most sweeps in one step of the frame), ``pgs_residual_m_per_s``, ``kinetic_energy_j``,
        ``energy_j`` (kinetic + gravitational, zero at z = 0; elastic energy not included, so
        for dissipative physics it never exceeds the initial value), and with :attr:`sensors`
        ``sensors`` (name -> [3] in the sensor's unit, after the frame's last step); the timings
        (and sensors) only where :attr:`frame_measures` is False.
    sensors : list of Sensor
        What is read every frame (none by default).
    """

    name = "physics"
    camera = "iso"
    #: False: the frame records hold the timings only (``frame``, ``sim_time_s``, ``step_ms``,
    #: ``stage_ms``, ``render_ms``, ``wall_ms``, the scene's own :meth:`frame_metrics` and sensors):
    #: :meth:`penetration`, the contacts, sweeps and energies are not read. A headless bench that
    #: reads its own measures sets it: the energies cost ~0.5 ms a frame on the contact bench's
    #: 729-node cube (8 % of its step), the contact counts ~20 us on a 35 us rigid step.
    frame_measures = True
    #: Whether :meth:`render` steps the next frame's physics on a worker thread while it draws
    #: this one (:meth:`step` then only waits for it). The picture of every frame is the
    #: sequential player's: :meth:`render` moves the renderer's surfaces and volume to this
    #: frame (:meth:`update_render`) before the step starts, and the step writes nothing the
    #: renderer reads (the rasterizer writes the volume, after the step). The frame period
    #: (``wall_ms`` of the records) becomes about max(step, render) + the frame's hooks; the
    #: latency from a frame's input (:meth:`drive`, :meth:`haptic_tick`) to its image is that
    #: period plus the render, which now runs a frame later (``latency_ms`` of the records).
    #: Off by default: on the 2-core palpation it shortened the period 1.08-1.13x but raised the
    #: latency 1.6x (40 -> 64-69 ms, docs/benchmarks.md, "Session 10"), and a lag behind the hand
    #: is what a trainer must avoid.
    overlap: bool = False

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
        self.sensors: list[Sensor] = []
        self._renderer: SurfaceRenderer | None = None
        self._drawing: SurfaceDrawing | None = None
        self._started = False
        self._on_arrays: tuple | None = None  # (stepper, its RigidFrameMetrics)
        self._worker: ThreadPoolExecutor | None = None
        self._ahead: Future | None = None  # the next frame's physics, stepping while this one is drawn
        # [s] perf_counter when the first input was read: of the frame stepping or to step, of the last finished one
        self._input_at = self._frame_input_at = 0.0
        self._step_call_ms = 0.0  # [ms] the last step() call's wall time, the start of its frame's wall_ms

    # -- the hooks, in STEP_ORDER / FRAME_ORDER ---------------------------------------------
    def start(self) -> None:
        """Start what runs beside the steps (haptic processes), once, before the first frame;
        a player that is built but never played (a start check) starts nothing."""

    def drive(self) -> None:
        """Move the scripted boundaries (driven nodes, keyframed events) for the coming step."""

    def haptic_tick(self) -> None:
        """Read the haptic devices that do not run a loop of their own (one reading per step)."""

    def sense(self, solution) -> None:
        """Read the step's contact solution (sensors, the haptic tool's force)."""

    def update_volume(self) -> dict:
        """Make the volume follow its body (once per frame, before it is drawn); returns metrics."""
        return {}

    def frame_metrics(self) -> dict:
        """Scene-specific entries of this frame's metrics record (after its last step)."""
        return {}

    # -- physics -------------------------------------------------------------------------
    def penetration(self) -> float:
        """Deepest current overlap [m] of any collision geometry (0 when nothing overlaps)."""
        raise NotImplementedError

    def penetration_geometry(self) -> tuple[list, list] | None:
        """What :meth:`penetration` measures, where the scene's rigid arrays can measure it:
        (body index, body-frame points [m, 3]) pairs and (unit normal, offset [m]) planes of
        :class:`~softvr.sim.frame_metrics.RigidFrameMetrics`; None (this default) where it is
        something else."""
        return None

    def array_metrics(self) -> RigidFrameMetrics | None:
        """The frame's metrics read off the scene's rigid arrays while it steps on them (one
        recorded launch, built once per stepper with :meth:`penetration_geometry`), else None."""
        stepper = rigid_stepper(self.scene)
        if stepper is None:
            return None
        if self._on_arrays is None or self._on_arrays[0] is not stepper:
            points, planes = self.penetration_geometry() or ((), ())
            self._on_arrays = (stepper, RigidFrameMetrics(stepper, points, planes))
        return self._on_arrays[1]

    def energies(self) -> tuple[float, float]:
        """(kinetic, kinetic + gravitational) energy [J] of all bodies (off the rigid arrays
        when the scene steps on them: :meth:`array_metrics`)."""
        metrics = self.array_metrics()
        if metrics is not None:
            return metrics.energies(self.scene.gravity)
        # Bodies of infinite mass move on a script (or not at all): no energy of their own.
        moving = [b for b in self.scene.bodies if not b.infinite_mass]
        kinetic = sum(float(b.kinetic_energy()) for b in moving)
        potential = sum(gravity_potential(b, self.scene.gravity) for b in moving)
        return kinetic, kinetic + potential

    def step(self) -> dict:
        """Advance one frame (:meth:`start` before the first, then ``steps_per_frame`` sub-steps,
        each in :data:`STEP_ORDER`, then :data:`FRAME_ORDER`); returns the frame's metrics record.
        Where :meth:`render` started the sub-steps already (:attr:`overlap`), it waits for them
        and raises what they raised."""
        called = time.perf_counter()
        if not self._started:
            self._started = True
            self.start()
        if self._ahead is not None:
            ahead, self._ahead = self._ahead, None
            physics = ahead.result()
        else:
            self._read_input()
            physics = self._physics()
        record = self._finish_frame(*physics)
        self._step_call_ms = record["wall_ms"] = (time.perf_counter() - called) * 1e3
        return record

    def _read_input(self) -> None:
        """The first sub-step's input (:data:`STEP_ORDER`'s drive and haptics), on the calling thread."""
        self._input_at = time.perf_counter()
        self.drive()
        self.haptic_tick()

    def _physics(self) -> tuple:
        """The frame's sub-steps, the first one's input already read (:meth:`_read_input`);
        returns (step_ms, stage_ms, the last solution, deepest, sweeps, residual)."""
        t0 = time.perf_counter()
        deepest, sweeps, residual, solution = 0.0, 0, 0.0, None
        stage_ms = dict.fromkeys(STAGES, 0.0)
        for k in range(self.steps_per_frame):
            if k:
                self.drive()
                self.haptic_tick()
            solution = self.scene.step(self.dt)
            self.sense(solution)
            for stage in STAGES:
                stage_ms[stage] += self.scene.stage_ms[stage]
            if self.frame_measures:
                deepest = max(deepest, self.penetration())
                sweeps = max(sweeps, int(solution.iterations))
                residual = max(residual, float(solution.residual))
        assert solution is not None  # steps_per_frame >= 1
        return (time.perf_counter() - t0) * 1e3, stage_ms, solution, deepest, sweeps, residual

    def _finish_frame(self, step_ms: float, stage_ms: dict, solution, deepest: float, sweeps: int,
                      residual: float) -> dict:
        """The frame's measures, :data:`FRAME_ORDER` and its metrics record, after its sub-steps."""
        record = {"frame": self.frame, "sim_time_s": float(self.scene.time), "step_ms": step_ms,
                  "stage_ms": stage_ms, "render_ms": 0.0, "wall_ms": 0.0}
        self._frame_input_at = self._input_at
        if self.frame_measures:
            kinetic, energy = self.energies()
            counts = getattr(solution, "contact_counts", None)  # a step on arrays counts without splitting sets
            if counts is not None:
                contacts, active = counts()
            else:
                impulses = [i for i in solution.impulses if len(i)]
                contacts, active = sum(len(i) for i in impulses), sum(int((i[:, 0] > 0).sum()) for i in impulses)
            record.update({"max_penetration_m": float(deepest), "contacts": int(contacts),
                           "active_contacts": int(active), "pgs_iterations": sweeps,
                           "pgs_residual_m_per_s": residual, "kinetic_energy_j": kinetic, "energy_j": energy})
        record.update(self.update_volume())
        record.update(self.frame_metrics())
        if self.sensors:
            record["sensors"] = {s.name: [float(x) for x in s.read(solution)] for s in self.sensors}
        self.metrics.append(record)
        self.frame += 1
        return record

    # -- rendering ----------------------------------------------------------------------
    def drawables(self) -> list[Drawable]:
        """What the scene shows now, as plain data (:class:`~softvr.app.Drawable`: vertices [m]
        in the world, triangles, colour, pose, layer), in the same order every call."""
        raise NotImplementedError(f"{type(self).__name__} does not list its drawables")

    def setup_render(self, renderer) -> None:
        """Add this scene's surfaces to ``renderer`` (called once): its :meth:`drawables`."""
        self._drawing = SurfaceDrawing(renderer, self.drawables())

    def update_render(self, renderer) -> None:
        """Move the surfaces to the current state (called before every render)."""
        assert self._drawing is not None, "setup_render first"
        self._drawing.update(self.drawables())

    @property
    def renderer(self) -> SurfaceRenderer | None:
        """The off-screen renderer of :meth:`render` (None before the first frame drawn)."""
        return self._renderer

    def renderer_options(self) -> dict:
        """Extra :class:`~softvr.render.SurfaceRenderer` arguments (background, light kit)."""
        return {}

    def render(self) -> np.ndarray:
        """Draw the current state offscreen; returns RGB uint8 [height, width, 3]. With
        :attr:`overlap`, the next frame's physics (its input read here first) steps on a worker
        thread meanwhile, up to :attr:`frames`; a render while it steps draws this frame again."""
        t0 = time.perf_counter()
        ahead_s = 0.0  # [s] of the call spent reading the next frame's input and starting it
        if self._renderer is None:
            self._renderer = SurfaceRenderer(self.width, self.height, self.camera, bounds=self.bounds,
                                             **self.renderer_options())
            self.setup_render(self._renderer)
        if self._ahead is None:
            self.update_render(self._renderer)
            started = time.perf_counter()
            self.step_ahead()
            ahead_s = time.perf_counter() - started
        image = self._renderer.render()
        self._drawn(t0, ahead_s)
        return image

    def _drawn(self, called: float, ahead_s: float = 0.0) -> None:
        """Complete the last frame's record once its image is drawn: ``called`` the
        perf_counter [s] when the drawing call began, ``ahead_s`` [s] of it spent starting the
        next frame (:meth:`step_ahead`), which is in ``wall_ms`` but not in ``render_ms``."""
        if self.metrics:
            now = time.perf_counter()
            record = self.metrics[-1]
            record["render_ms"] = (now - called - ahead_s) * 1e3
            record["wall_ms"] = self._step_call_ms + (now - called) * 1e3
            record["latency_ms"] = (now - self._frame_input_at) * 1e3

    def step_ahead(self) -> None:
        """With :attr:`overlap`, frames left and none stepping yet: read the next frame's input
        (:meth:`drive`, :meth:`haptic_tick`) and start its physics on the worker thread, for
        :meth:`step` to take. Call it once a renderer holds this frame (:meth:`update_render`):
        from then on until :meth:`step` (or :meth:`settle`) returns, the scene is being written."""
        if self._ahead is None and self._started and self.frame < self.frames and self.overlap:
            if self._worker is None:
                self._worker = ThreadPoolExecutor(1, thread_name_prefix="softvr-physics")
            self._read_input()
            self._ahead = self._worker.submit(self._physics)

    @property
    def ahead(self) -> bool:
        """Whether a frame is stepping ahead (:meth:`step_ahead`) for :meth:`step` to take."""
        return self._ahead is not None

    def settle(self) -> None:
        """Wait until the frame stepping ahead (:meth:`step_ahead`) has stepped; :meth:`step`
        still takes it (and raises its error). The scene then stays still until the next
        :meth:`step_ahead`: for what reads or changes it between frames (a mouse grab)."""
        if self._ahead is not None:
            self._ahead.exception()  # waits

    # -- what a run reports --------------------------------------------------------------
    def describe(self) -> dict:
        """Scene facts for the metrics file (subclasses add theirs)."""
        facts = {"dt_s": self.dt, "steps_per_frame": self.steps_per_frame, "fps": self.fps,
                 "bodies": [getattr(b, "name", type(b).__name__) for b in self.scene.bodies]}
        if self.sensors:
            facts["sensors"] = {s.name: {"kind": s.kind, "unit": s.unit} for s in self.sensors}
        return facts

    def summary(self) -> dict:
        """The run's summary for the metrics file: frames, simulated time, median and worst
        physics ms, median ms per stage, deepest penetration [m], most contacts and sweeps."""
        m = self.metrics
        step_ms = np.array([r["step_ms"] for r in m])
        return {
            "frames": len(m),
            "sim_time_s": m[-1]["sim_time_s"],
            "step_ms_median": float(np.median(step_ms)),
            "step_ms_max": float(step_ms.max()),
            "stage_ms_median": {k: float(np.median([r["stage_ms"][k] for r in m])) for k in STAGES},
            "max_penetration_m": max(r["max_penetration_m"] for r in m),
            "max_contacts": max(r["contacts"] for r in m),
            "max_pgs_iterations": max(r["pgs_iterations"] for r in m),
        }

    def status(self) -> str:
        """One line on the last frame for a progress bar."""
        r = self.metrics[-1]
        return f"t={r['sim_time_s']:.2f}s pen={r['max_penetration_m'] * 1e3:.2f}mm contacts={r['contacts']}"

    def write_plots(self, doc: dict, out) -> list:
        """Plots of a finished run (``doc`` the metrics document) into folder ``out``; returns
        the files written (none by default)."""
        return []

    def close(self) -> None:
        """Release the renderer (and, in subclasses, haptic processes); a frame stepping ahead
        that :meth:`step` did not take is waited for and dropped, its error with it."""
        self.settle()
        self._ahead = None
        if self._worker is not None:
            self._worker.shutdown()
            self._worker = None
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
