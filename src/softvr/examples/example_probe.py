"""Probe: a round probe pressed into soft tissue and pulled back, force against displacement.

A scripted (kinematic) sphere of radius R indents a soft FEM block clamped at its base, holds,
and withdraws at constant speed. Its force sensor is the net contact force on it
(:meth:`softvr.contact.ContactSolution.force_on`), averaged over each frame. Loading follows
the contact stiffness of the block (drawn against Hertz's half-space law F = 4/3 E* sqrt(R) d^1.5,
E* = E / (1 - nu^2), for reference: the block is finite and clamped, the mesh coarse, so the FEM
is stiffer); unloading retraces it, and with adhesion (thesis eq. 4.16) the tissue holds on to
the probe past the rest surface: the force turns tensile and the surface is lifted until the
bonds let go (eq. 4.12). ``probe_force.png`` plots the loop. Run ``softvr run probe``
(``--dry`` for no adhesion).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softvr.app import Player, check_run_args, record_from_args, run_parser

__all__ = ["DEFAULT_FRAMES", "PROBE_ADHESION", "Example", "hertz_force", "main"]

#: 1.4 s at 50 frames per second: approach and press 0.5 s, hold 0.1 s, withdraw.
DEFAULT_FRAMES = 70

#: Tacky tissue and a probe of the same material: debonding starts at sqrt(W C) = 7 kPa, and
#: the viscosity lets the bonds outlast the first millimetre of withdrawal at 10 mm/s.
PROBE_ADHESION = dict(stiffness=1e7, max_energy=5.0, viscosity=1.0, bonding_rate=0.01, saturation=1000.0,
                      initial=0.3, debond_gap=0.003)


def hertz_force(depth, radius: float, young: float, poisson: float) -> np.ndarray:
    """Hertz's force [N] of a rigid sphere of ``radius`` [m] pressed ``depth`` [m] into an
    elastic half-space: F = 4/3 E/(1 - nu^2) sqrt(R) d^1.5 (0 where d <= 0)."""
    d = np.clip(np.asarray(depth, float), 0.0, None)
    return 4.0 / 3.0 * young / (1.0 - poisson**2) * np.sqrt(radius) * d**1.5


class Example(Player):
    """A probe pressed into a clamped soft block and withdrawn.

    Parameters
    ----------
    frames : int
    width, height : int [pixels]
    size : tuple of 3 float [m]
        Block size (x, y, depth); its top face is z = 0, its clamped base z = -size[2].
    cells : tuple of 3 int
        Grid cells of the block (5 tets each).
    radius : float [m]
        Probe radius.
    depth : float [m]
        Deepest indentation below the rest surface.
    speed : float [m/s]
        Probe speed, in and out; it starts 1 mm above the surface.
    hold_time : float [s]
    young, poisson : float [Pa], [-]
    density : float [kg/m^3]
    alpha, beta : float [1/s], [s]
        Rayleigh damping of the tissue.
    adhesion : dict or None
        :class:`softvr.contact.Adhesion` parameters of the tissue and the probe (None: dry).
    friction : float
    dt : float [s]
    steps_per_frame : int
    """

    name = "probe"

    def __init__(self, frames: int = DEFAULT_FRAMES, width: int = 640, height: int = 480, *,
                 size=(0.06, 0.06, 0.03), cells=(12, 12, 6), radius: float = 0.01, depth: float = 0.004,
                 speed: float = 0.01, hold_time: float = 0.1, young: float = 2e4, poisson: float = 0.4,
                 density: float = 1000.0, alpha: float = 5.0, beta: float = 0.002,
                 adhesion: dict | None = PROBE_ADHESION, friction: float = 0.3, dt: float = 0.004,
                 steps_per_frame: int = 5):
        from softvr import Scene
        from softvr.contact import Adhesion
        from softvr.dynamics import EmbeddedPoints, FemBody, KinematicBody, Material, RigidPoints
        from softvr.model.shapes import icosphere
        from softvr.render import Camera
        from softvr.volume import Volume, boundary_faces, grid_tet_mesh

        size = np.asarray(size, float)
        spacing = size / np.asarray(cells)
        nodes, tets = grid_tet_mesh(Volume(np.zeros(tuple(cells), np.uint8), spacing=spacing, origin=spacing / 2),
                                    tuple(cells))
        nodes = nodes - [size[0] / 2, size[1] / 2, size[2]]
        self.material = Material(young, poisson, density, alpha=alpha, beta=beta)
        self.tissue = FemBody(nodes, tets, self.material, fixed=np.isclose(nodes[:, 2], -size[2]), name="tissue")
        self.tissue_triangles = boundary_faces(tets)
        sticky = None if adhesion is None else Adhesion(**adhesion)
        # No gravity: the sensor then reads the contact force alone, not the tissue's weight.
        scene = Scene(gravity=(0.0, 0.0, 0.0), friction=friction, contact_margin=0.001)
        points = EmbeddedPoints(self.tissue, np.arange(len(nodes))[:, None], np.ones((len(nodes), 1)))
        scene.add_body(self.tissue, collision_points=points, collision_triangles=self.tissue_triangles,
                       adhesion=sticky)
        self.radius, self.depth, self.speed, self.hold_time = radius, depth, speed, hold_time
        self.press_time = (depth + 0.001) / speed
        self.probe = KinematicBody(self.pose, name="probe")
        unit, self.probe_triangles = icosphere(3)
        self.probe_local = unit * radius
        self.probe_index = scene.add_body(self.probe, collision_points=RigidPoints(self.probe, self.probe_local),
                                          collision_triangles=self.probe_triangles, adhesion=sticky)
        self.adhesion = adhesion
        self._force: list[float] = []  # the z force on the probe [N] at each step of this frame
        span = size[0] / 2
        super().__init__(scene, dt, steps_per_frame, frames, width, height,
                         bounds=(-span, span, -span, span, -size[2], 0.02),
                         camera=Camera("front", azimuth=-30, elevation=25, zoom=1.3))

    # -- physics -------------------------------------------------------------------------
    def pose(self, t: float):
        """Probe centre [m] and orientation at time ``t`` [s]: down at ``speed`` from 1 mm above
        the surface to ``depth``, hold, back up at ``speed``."""
        lowest = self.radius - self.depth
        if t < self.press_time:
            z = self.radius + 0.001 - self.speed * t
        elif t < self.press_time + self.hold_time:
            z = lowest
        else:
            z = lowest + self.speed * (t - self.press_time - self.hold_time)
        return np.array([0.0, 0.0, z]), np.array([1.0, 0.0, 0.0, 0.0])

    def indentation(self) -> float:
        """Depth [m] of the probe's lowest point below the rest surface z = 0 (negative: above)."""
        return self.radius - float(self.probe.position[2])

    def sense(self, solution) -> None:
        # The tissue pushes the probe up (+z) while it presses; adhesion pulls it down (-z).
        self._force.append(float(solution.force_on(self.probe_index, self.dt)[2]))

    def penetration(self) -> float:
        """Deepest tissue node inside the probe sphere [m]."""
        inside = self.radius - np.linalg.norm(self.tissue.q - self.probe.position, axis=1)
        return max(0.0, float(inside.max()))

    def frame_metrics(self) -> dict:
        force = float(np.mean(self._force)) if self._force else 0.0
        self._force = []
        beta = self.scene.adhesion_state.intensity.values()
        return {"indentation_m": self.indentation(), "probe_force_n": force,
                "surface_lift_m": float(self.tissue.q[:, 2].max()), "bonded_contacts": sum(b > 0 for b in beta)}

    # -- rendering -----------------------------------------------------------------------
    def setup_render(self, renderer) -> None:
        self._tissue = renderer.add_mesh(self.tissue.q, self.tissue_triangles, color=(0.85, 0.55, 0.5),
                                         feature_angle=None)
        self._probe = renderer.add_mesh(self.probe_world(), self.probe_triangles, color=(0.75, 0.77, 0.8),
                                        feature_angle=None)

    def probe_world(self) -> np.ndarray:
        """Probe surface vertices [n, 3] [m] at its current pose."""
        return self.probe_local @ self.probe.rotation.T + self.probe.position

    def update_render(self, renderer) -> None:
        renderer.update(self._tissue, self.tissue.q)
        renderer.update(self._probe, self.probe_world())

    def write_plots(self, doc: dict, out: Path) -> list[Path]:
        """``probe_force.png``: force against indentation, loading and unloading, with Hertz."""
        import matplotlib  # noqa: PLC0415

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # noqa: PLC0415

        from softvr.render.figure import save_figure  # noqa: PLC0415

        frames = doc["frames"]
        t = np.array([f["sim_time_s"] for f in frames])
        d = 1e3 * np.array([f["indentation_m"] for f in frames])
        force = np.array([f["probe_force_n"] for f in frames])
        loading = t <= self.press_time + self.hold_time
        fig, ax = plt.subplots(figsize=(6.5, 4.5))
        ax.plot(d[loading], force[loading], color="tab:red", label="pressing")
        ax.plot(d[~loading], force[~loading], color="tab:blue", label="withdrawing")
        ref = np.linspace(0.0, 1e3 * self.depth, 50)
        m = self.material
        ax.plot(ref, hertz_force(ref * 1e-3, self.radius, m.young, m.poisson), color="0.5", ls=":",
                label="Hertz, half-space (reference)")
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.axvline(0.0, color="0.6", lw=0.8)
        ax.set_xlabel("indentation below the rest surface [mm]")
        ax.set_ylabel("probe force [N] (- : adhesion pulls)")
        ax.set_title(f"Probe R = {1e3 * self.radius:.0f} mm into E = {m.young / 1e3:.0f} kPa tissue, "
                     + ("adhesive" if self.adhesion else "dry"))
        ax.legend()
        fig.tight_layout()
        return [save_figure(fig, Path(out) / f"{self.name}_force.png")]

    def describe(self) -> dict:
        m = self.material
        return {**super().describe(), "tets": len(self.tissue.tets), "young_pa": m.young, "poisson": m.poisson,
                "radius_m": self.radius, "depth_m": self.depth, "speed_m_per_s": self.speed,
                "adhesion": self.adhesion}


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Run the probe demo to ``<out>/probe.mp4``, ``_sheet.png``, ``_metrics.json`` and ``_force.png``."""
    parser = run_parser(prog or "softvr run probe", __doc__.splitlines()[0], DEFAULT_FRAMES)
    parser.add_argument("--dry", action="store_true", help="no adhesion (plain frictional contact)")
    args = parser.parse_args(argv)
    check_run_args(parser, args)
    example = Example(frames=args.frames, width=args.size[0], height=args.size[1],
                      adhesion=None if args.dry else PROBE_ADHESION)
    with example:
        record_from_args(example, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
