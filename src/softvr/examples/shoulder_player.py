"""The procedural shoulder built in Python and palpated through a 1 kHz haptic loop (thesis ch. 5).

The procedural shoulder of :mod:`softvr.examples.shoulder_anatomy` (the structure of thesis
Table 5.1) goes through the model pipeline (``softvr build-model``: collision meshes, tet
meshes, embeddings, couplings, collision-free start) into a scene of coupled rigid and soft
parts: couplings to the fixed scapula and the scripted humerus make one coupling island per
soft part (or per chain of coupled parts), contacts join them into contact islands.

* ``palpation``: two fingers linked by a skin spring (thesis 5.4): the outer one presses on
  the deltoid, the inner one, behind the skin, on the anatomy under it.
* ``arthroscopy``: a probe reaches under the acromion and presses the rotator cuff.

The tool is a rigid sphere on a virtual coupling to the handle of a haptic device
(:class:`softvr.haptics.HapticTool`); the device follows a scripted palpation path in
simulated time, and a :class:`softvr.haptics.HapticLoop` thread renders its force at 1 kHz
(``haptics=False`` drives the handle without the thread). Per frame the metrics hold the force
on the hand, the deepest contact gap and the haptic loop's period; ``shoulder_force.png``
plots them.

The demo is the bundled scene file ``shoulder.toml`` (``shoulder-arthroscopy.toml``), which
``softvr demo shoulder`` plays; its handle's keyframes sample :func:`palpation_path` every 50 ms.
This Python construction remains for ``softvr bench shoulder`` alone, which reads what a scene
file's player does not report (the hand's force per frame, the coupling islands) at its own steps;
``example_shoulder.py`` plays the scene file.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from softvr import Scene
from softvr.app import Player
from softvr.dynamics import Coupling, RigidBody, RigidPoints
from softvr.examples.shoulder_anatomy import write_shoulder_parts
from softvr.haptics import HapticLoop, HapticTool, ScriptedDevice
from softvr.model import build_model
from softvr.model.shapes import icosphere
from softvr.render import Camera
from softvr.render.figure import save_figure

__all__ = ["DEFAULT_FRAMES", "ShoulderPlayer", "palpation_path"]

#: 12 s at 25 frames per second (the test runs 60 s of it).
DEFAULT_FRAMES = 300

_COLORS = {"scapula": (0.92, 0.9, 0.82), "humerus": (0.92, 0.9, 0.82), "biceps_tendon": (0.95, 0.95, 0.9),
           "transverse_humeral": (0.95, 0.95, 0.9), "labrum": (0.75, 0.78, 0.9), "labrum_tendon": (0.85, 0.85, 0.95)}
_MUSCLE_COLOR = (0.72, 0.3, 0.3)


def palpation_path(variant: str, t: float) -> np.ndarray:
    """The scripted hand [3] [m] at time ``t`` [s]: in over 1 s, then pressing in and out
    (period 2 s) while sliding (periods 6 and 9 s): on the deltoid (palpation), on the
    supraspinatus under the acromion (arthroscopy)."""
    approach = min(t, 1.0)
    press = 0.5 - 0.5 * np.cos(2 * np.pi * max(t - 1.0, 0.0) / 2.0)
    if variant == "palpation":
        return np.array([0.09 - 0.02 * approach - 0.01 * press,
                         0.02 * np.sin(2 * np.pi * t / 9.0), -0.02 + 0.025 * np.sin(2 * np.pi * t / 6.0)])
    # Arthroscopy: in under the acromion (whose collision with the probe is off: the portal),
    # then pressing the supraspinatus from above and sweeping along it.
    return np.array([0.075 - 0.05 * approach + 0.006 * np.sin(2 * np.pi * t / 6.0),
                     -0.009 + 0.008 * np.sin(2 * np.pi * t / 9.0), 0.048 - 0.006 * press])


class ShoulderPlayer(Player):
    """The procedural shoulder palpated by a haptic tool.

    Parameters
    ----------
    frames : int
    width, height : int [pixels]
    variant : str
        ``"palpation"`` or ``"arthroscopy"``.
    haptics : bool
        Run the 1 kHz :class:`~softvr.haptics.HapticLoop` thread (else the handle is read
        once per step).
    coupling_stiffness : float [N/m]
        Virtual coupling between hand and tool.
    skin_stiffness : float [N/m]
        The skin spring between the two fingers (palpation).
    dt : float [s]
        20 ms: the thesis' 50 steps per second.
    steps_per_frame : int
    pgs_iterations : int
        Most PGS sweeps per step: an interactive budget, as the thesis' fixed iteration count
        (the packed anatomy's redundant soft-soft contacts converge slowly; 100 sweeps leave
        overlaps of micrometres).
    model_dir : path, optional
        Where to write the parts and the model (a temporary folder by default).
    """

    name = "shoulder"

    def __init__(self, frames: int = DEFAULT_FRAMES, width: int = 640, height: int = 480, *,
                 variant: str = "palpation", haptics: bool = True, coupling_stiffness: float = 300.0,
                 skin_stiffness: float = 150.0, dt: float = 0.02, steps_per_frame: int = 2, pgs_iterations: int = 100,
                 model_dir=None):
        self._tmp = None
        if model_dir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="softvr-shoulder-")
            model_dir = self._tmp.name
        self.variant = variant
        self.model = build_model(write_shoulder_parts(model_dir, variant), progress=False)
        scene = Scene(gravity=(0.0, 0.0, -9.81), friction=0.3, contact_margin=0.002, pgs_iterations=pgs_iterations)
        scene, self.bodies, self.render_points = self.model.build_scene(scene)
        self.anatomy = list(self.bodies)
        index = {name: i for i, name in enumerate(self.anatomy)}
        unit, self.sphere_triangles = icosphere(2)
        # The outer finger (palpation) or the probe tip (arthroscopy), driven by the device.
        radius = 0.008 if variant == "palpation" else 0.004
        start = palpation_path(variant, 0.0)
        tool = RigidBody.sphere(radius, 1000.0, position=start, name="finger" if variant == "palpation" else "probe")
        tool_index = scene.add_body(tool, collision_points=RigidPoints(tool, unit * radius),
                                    collision_triangles=self.sphere_triangles)
        self.tools = [(tool, unit * radius)]
        touches = {"deltoid"} if variant == "palpation" else set(self.anatomy) - {"scapula", "humerus"}
        for name in self.anatomy:
            if name not in touches:
                scene.disable_collision(tool_index, index[name])
        if variant == "palpation":
            # The inner finger, 1.5 cm deeper, behind the skin: it meets the anatomy under the
            # deltoid; the skin spring ties it to the outer one.
            inner_radius = 0.006
            inner = RigidBody.sphere(inner_radius, 1000.0, position=start - [0.015, 0.0, 0.0], name="inner finger")
            inner_index = scene.add_body(inner, collision_points=RigidPoints(inner, unit * inner_radius),
                                         collision_triangles=self.sphere_triangles)
            scene.add_coupling(Coupling(RigidPoints(tool, [[-0.015, 0.0, 0.0]]), RigidPoints(inner, [[0.0, 0.0, 0.0]]),
                                        skin_stiffness, damping=1.0, name="skin"))
            for name in ("deltoid", "scapula"):
                scene.disable_collision(inner_index, index[name])
            self.tools.append((inner, unit * inner_radius))
        self.device = ScriptedDevice(lambda t: palpation_path(variant, t))
        # Its own process, as the thesis gives it its own core; the hand follows simulated time.
        self.loop = HapticLoop(self.device, max_force=8.0, process=True)
        self.device.clock = self.loop.simulation_clock
        self.tool = HapticTool(scene, tool, self.loop, stiffness=coupling_stiffness, damping=2.0)
        self.haptics = haptics
        self._forces: list[np.ndarray] = []  # the force on the hand [3] [N] at each step of this frame
        self._gap = 0.0
        super().__init__(scene, dt, steps_per_frame, frames, width, height,
                         bounds=(-0.05, 0.1, -0.07, 0.07, -0.12, 0.08),
                         camera=Camera("front", azimuth=-60, elevation=15, zoom=1.1))

    # -- physics -------------------------------------------------------------------------
    def start(self) -> None:
        if self.haptics:
            self.loop.start()  # with the first frame: a shoulder built and never played starts no process

    def haptic_tick(self) -> None:
        if not self.haptics:
            self.loop.tick()  # one device reading per step instead of the thread's thousand per second

    def sense(self, solution) -> None:
        self._forces.append(self.tool.publish(solution).force)
        gaps = [g.min() for g in solution.gaps_after if len(g)]
        self._gap = min(self._gap, min(gaps, default=0.0))

    def penetration(self) -> float:
        """Deepest contact overlap after the step's solve [m] (from the contacts' end gaps)."""
        return max(0.0, -self._gap)

    def frame_metrics(self) -> dict:
        force = np.mean(self._forces, axis=0) if self._forces else np.zeros(3)
        self._forces, self._gap = [], 0.0
        stats = self.loop.period_stats()
        return {"hand_force_n": float(np.linalg.norm(force)), "hand_position_m": self.loop.handle_position().tolist(),
                "haptic_p50_ms": stats["p50_ms"], "haptic_p99_ms": stats["p99_ms"]}

    def close(self) -> None:
        self.loop.stop()
        super().close()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    # -- rendering -----------------------------------------------------------------------
    def setup_render(self, renderer) -> None:
        self._meshes = []
        for name, points in self.render_points.items():
            part = self.model.part(name)
            color = _COLORS.get(name, _MUSCLE_COLOR)
            opacity = 0.45 if name == "deltoid" else 1.0
            self._meshes.append((renderer.add_mesh(points.positions(), part.render_triangles, color=color,
                                                   feature_angle=None, opacity=opacity), points))
        self._tool_meshes = [renderer.add_mesh(body.position + local, self.sphere_triangles, color=(0.9, 0.75, 0.6),
                                               feature_angle=None) for body, local in self.tools]

    def update_render(self, renderer) -> None:
        for handle, points in self._meshes:
            renderer.update(handle, points.positions())
        for handle, (body, local) in zip(self._tool_meshes, self.tools):
            renderer.update(handle, body.position + local @ body.rotation.T)

    def write_plots(self, doc: dict, out: Path) -> list[Path]:
        """``shoulder_force.png``: force on the hand and the deepest contact overlap per frame."""
        import matplotlib  # noqa: PLC0415

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # noqa: PLC0415

        frames = doc["frames"]
        t = [f["sim_time_s"] for f in frames]
        fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
        top.plot(t, [f["hand_force_n"] for f in frames], color="tab:red")
        top.set_ylabel("force on the hand [N]")
        top.set_title(f"Shoulder, {self.variant}: scripted palpation through the haptic loop")
        bottom.plot(t, [1e3 * f["max_penetration_m"] for f in frames], color="tab:blue")
        bottom.set_ylabel("deepest overlap [mm]")
        bottom.set_xlabel("time [s]")
        fig.tight_layout()
        return [save_figure(fig, Path(out) / f"{self.name}_force.png")]

    def describe(self) -> dict:
        soft = [p for p in self.model.parts if p.soft]
        return {**super().describe(), "variant": self.variant, "soft_parts": len(soft),
                "tets": int(sum(len(p.tets) for p in soft)), "couplings": len(self.scene.couplings),
                "coupling_springs": int(sum(len(c) for c in self.scene.couplings)),
                "coupling_islands": sum(1 for u in self.scene.solve_units()[0] if hasattr(u, "members")),
                "haptic_loop": self.haptics, "model_crossings": self.model.crossings}

