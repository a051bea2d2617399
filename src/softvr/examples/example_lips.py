"""Lips: two soft lips pressed together stick briefly as they open (thesis Fig. 4.3).

Two soft FEM slabs, their inner faces bulging towards each other, are held by their outer faces
(the driven boundary nodes of :attr:`softvr.dynamics.FemBody.fixed_velocity`, the jaws): pressed
together, held while the adhesive contacts bond (eq. 4.11, saturating at p0), then pulled apart
at a constant speed. The implicit adhesion (eq. 4.16) holds the inner faces together while the
lips stretch; debonding (eq. 4.12) peels them from the corners inwards until they snap apart, a
few millimetres after dry lips would have separated. Per frame the metrics hold the opening of
the jaws, the contact force between the lips (negative: adhesion pulls) and the bonded contacts;
``lips_force.png`` plots them. Run ``softvr run lips`` (``--dry`` for no adhesion).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softvr.app import Player, check_run_args, record_from_args, run_parser

__all__ = ["DEFAULT_FRAMES", "LIPS_ADHESION", "Example", "main"]

#: 1.2 s at 50 frames per second: press 0.2 s, hold 0.2 s, open.
DEFAULT_FRAMES = 60

#: Wet mucosa, exaggerated so that the sticking shows: debonding starts at sqrt(W C beta^3) =
#: 2 kPa of traction, about what a 10 % stretch of the 20 kPa lip tissue carries, and the
#: viscosity lets it run over that for a while; new contacts start at beta0 = 0.3 and bond to 1
#: within ~0.1 s under the ~1 kPa press (r (c - beta p0)). Measured with the defaults: dry
#: lips part 1.0 mm into the opening, these at 4.2 mm, pulling with up to 2.3 N.
LIPS_ADHESION = dict(stiffness=1e7, max_energy=0.4, viscosity=0.2, bonding_rate=0.01, saturation=1000.0,
                     initial=0.3, debond_gap=0.003)


def lip_mesh(length: float, depth: float, thickness: float, cells, bulge: float):
    """Tet mesh of one lip: a slab [-length/2, length/2] x [-depth/2, depth/2] x [0, thickness]
    whose inner face z = 0 bulges by ``bulge`` [m] to -bulge at its centre, rounding to 0 at the
    corners (the outer face z = thickness stays flat). Returns nodes [n, 3] [m], tets [m, 4]."""
    from softvr.volume import Volume, grid_tet_mesh  # noqa: PLC0415

    size = np.array([length, depth, thickness])
    spacing = size / np.asarray(cells)
    nodes, tets = grid_tet_mesh(Volume(np.zeros(tuple(cells), np.uint8), spacing=spacing, origin=spacing / 2),
                                tuple(cells))
    nodes = nodes - [length / 2, depth / 2, 0.0]
    profile = (1 - (2 * nodes[:, 0] / length) ** 2) * (1 - 0.5 * (2 * nodes[:, 1] / depth) ** 2)
    nodes[:, 2] -= bulge * profile * (1 - nodes[:, 2] / thickness)
    return nodes, tets


class Example(Player):
    """Two soft lips pressed together and opened.

    Parameters
    ----------
    frames : int
    width, height : int [pixels]
    length, depth, thickness : float [m]
        Size of each lip (x across the mouth, y front to back, z the lip's height).
    cells : tuple of 3 int
        Grid cells per lip (5 tets each).
    gap : float [m]
        Distance between the flat parts of the inner faces at the start.
    bulge : float [m]
        How far each inner face bulges at its centre (the lips touch there first).
    young, poisson : float [Pa], [-]
    density : float [kg/m^3]
    alpha, beta : float [1/s], [s]
        Rayleigh damping.
    press : float [m]
        How far each jaw moves towards the other.
    press_time, hold_time : float [s]
        Duration of the press and of the hold before opening.
    open_speed : float [m/s]
        Speed of each jaw while opening.
    adhesion : dict or None
        :class:`softvr.contact.Adhesion` parameters of the lip surfaces (None: dry lips).
    friction : float
    dt : float [s]
    steps_per_frame : int
    """

    name = "lips"

    def __init__(self, frames: int = DEFAULT_FRAMES, width: int = 640, height: int = 480, *, length: float = 0.05,
                 depth: float = 0.02, thickness: float = 0.012, cells=(8, 3, 3), gap: float = 0.002,
                 bulge: float = 0.001, young: float = 2e4, poisson: float = 0.4, density: float = 1100.0,
                 alpha: float = 2.0, beta: float = 0.001, press: float = 0.0015, press_time: float = 0.2,
                 hold_time: float = 0.2, open_speed: float = 0.02, adhesion: dict | None = LIPS_ADHESION,
                 friction: float = 0.5, dt: float = 0.004, steps_per_frame: int = 5):
        from softvr import Scene
        from softvr.contact import Adhesion
        from softvr.dynamics import EmbeddedPoints, FemBody, Material
        from softvr.render import Camera
        from softvr.volume import boundary_faces

        nodes, tets = lip_mesh(length, depth, thickness, cells, bulge)
        self.triangles = boundary_faces(tets)
        material = Material(young, poisson, density, alpha=alpha, beta=beta)
        sticky = None if adhesion is None else Adhesion(**adhesion)
        # No gravity: the lips hang in the face, their weight is carried by the face, not the jaws.
        scene = Scene(gravity=(0.0, 0.0, 0.0), friction=friction, contact_margin=0.001)
        self.lips, self.jaws = [], []
        flip = np.diag([1.0, -1.0, -1.0])  # the lower lip: the upper one turned about x
        for name, transform in (("upper lip", np.eye(3)), ("lower lip", flip)):
            q = (nodes + [0.0, 0.0, gap / 2]) @ transform.T
            jaw = np.isclose(np.abs(q[:, 2]), gap / 2 + thickness)
            body = FemBody(q, tets, material, fixed=jaw, name=name)
            points = EmbeddedPoints(body, np.arange(len(q))[:, None], np.ones((len(q), 1)))
            scene.add_body(body, collision_points=points, collision_triangles=self.triangles, adhesion=sticky)
            self.lips.append(body)
            self.jaws.append(jaw)
        self.gap, self.thickness = gap, thickness
        self.press, self.press_time, self.hold_time, self.open_speed = press, press_time, hold_time, open_speed
        self.material, self.adhesion = material, adhesion
        self._force: list[float] = []  # the z force on lip 0 [N] at each step of this frame
        span = length / 2 + 0.01
        super().__init__(scene, dt, steps_per_frame, frames, width, height,
                         bounds=(-span, span, -depth, depth, -0.03, 0.03),
                         camera=Camera("front", azimuth=-35, elevation=20, zoom=1.2))

    # -- physics -------------------------------------------------------------------------
    def drive(self) -> None:
        # Driven over the step [t, t + dt] by its mean speed, so the jaws land on their path.
        t, dt = self.scene.time, self.dt
        speed = (self._jaw_travel(t + dt) - self._jaw_travel(t)) / dt
        for lip, jaw, side in zip(self.lips, self.jaws, (1.0, -1.0)):
            lip.fixed_velocity[jaw, 2] = side * speed

    def _jaw_travel(self, t: float) -> float:
        """Distance [m] each jaw has moved away from the other by time ``t`` (negative: in)."""
        pressed = -self.press * min(t, self.press_time) / self.press_time
        return pressed + self.open_speed * max(0.0, t - self.press_time - self.hold_time)

    def sense(self, solution) -> None:
        self._force.append(float(solution.force_on(0, self.dt)[2]))

    def opening(self) -> float:
        """Distance [m] between the jaws minus their distance at the start (negative: pressed)."""
        upper, lower = (lip.q[jaw, 2].mean() for lip, jaw in zip(self.lips, self.jaws))
        return float(upper - lower) - (self.gap + 2 * self.thickness)

    def lip_gap(self) -> float:
        """Smallest vertical distance [m] between the lips' surfaces (negative: overlap)."""
        return float(self.lips[0].q[:, 2].min() - self.lips[1].q[:, 2].max())

    def bonded(self) -> int:
        """Adhesive contacts with intensity > 0."""
        return int(sum(1 for beta in self.scene.adhesion_state.intensity.values() if beta > 0))

    def penetration(self) -> float:
        # The lips' vertex-triangle contacts keep them apart; the overlap of the closest nodes
        # in z bounds the penetration from above.
        return max(0.0, -self.lip_gap())

    def frame_metrics(self) -> dict:
        # The force is averaged over the frame's steps: one step's impulses swing between the
        # two sides' redundant contacts, their sum over a frame does not.
        force = float(np.mean(self._force)) if self._force else 0.0
        self._force = []
        return {"opening_m": self.opening(), "lip_gap_m": self.lip_gap(), "lip_force_n": force,
                "bonded_contacts": self.bonded()}

    # -- rendering -----------------------------------------------------------------------
    def setup_render(self, renderer) -> None:
        self._meshes = [renderer.add_mesh(lip.q, self.triangles, color=color, feature_angle=None)
                        for lip, color in zip(self.lips, ((0.78, 0.36, 0.38), (0.72, 0.3, 0.33)))]

    def update_render(self, renderer) -> None:
        for handle, lip in zip(self._meshes, self.lips):
            renderer.update(handle, lip.q)

    def write_plots(self, doc: dict, out: Path) -> list[Path]:
        """``lips_force.png``: contact force between the lips and bonded contacts against time,
        with the jaw opening."""
        import matplotlib  # noqa: PLC0415

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # noqa: PLC0415

        from softvr.render.figure import save_figure  # noqa: PLC0415

        frames = doc["frames"]
        t = [f["sim_time_s"] for f in frames]
        fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
        top.plot(t, [f["lip_force_n"] for f in frames], color="tab:red")
        top.axhline(0.0, color="0.6", lw=0.8)
        top.set_ylabel("force on upper lip [N]\n(+ pushes apart, - adhesion)")
        top.set_title("Lips " + ("with adhesion" if self.adhesion else "without adhesion"))
        bottom.plot(t, [f["bonded_contacts"] for f in frames], color="tab:blue", label="bonded contacts")
        bottom.set_ylabel("bonded contacts")
        bottom.set_xlabel("time [s]")
        twin = bottom.twinx()
        twin.plot(t, [1e3 * f["opening_m"] for f in frames], color="tab:green", ls="--")
        twin.set_ylabel("jaw opening [mm]", color="tab:green")
        for ax in (top, bottom):
            ax.axvspan(0, self.press_time, color="0.92")
            ax.axvspan(self.press_time, self.press_time + self.hold_time, color="0.85")
        fig.tight_layout()
        return [save_figure(fig, Path(out) / f"{self.name}_force.png")]

    def describe(self) -> dict:
        m = self.material
        return {**super().describe(), "tets_each": len(self.lips[0].tets), "young_pa": m.young,
                "poisson": m.poisson, "adhesion": self.adhesion, "press_m": self.press,
                "open_speed_m_per_s": self.open_speed}


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Run the lips demo to ``<out>/lips.mp4``, ``_sheet.png``, ``_metrics.json`` and ``_force.png``."""
    parser = run_parser(prog or "softvr run lips", __doc__.splitlines()[0], DEFAULT_FRAMES)
    parser.add_argument("--dry", action="store_true", help="no adhesion (plain frictional contact)")
    args = parser.parse_args(argv)
    check_run_args(parser, args)
    example = Example(frames=args.frames, width=args.size[0], height=args.size[1],
                      adhesion=None if args.dry else LIPS_ADHESION)
    with example:
        record_from_args(example, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
