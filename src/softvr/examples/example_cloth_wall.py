"""Cloth on a wall: a swinging cloth hits an adhesive wall, sticks, and slowly peels off (thesis Fig. 4.2).

A square mass-spring cloth hangs from its pinned top edge 12 cm in front of a vertical wall
(the plane x = 0), swung towards it. It slaps onto the wall and the implicit adhesion
(thesis eq. 4.16) holds it there; its weight, pulling down along the wall and peeling at the
line where the cloth leaves it, debonds the contacts (eq. 4.12) from the bottom up until the
cloth swings free. The thesis shows that this behaviour varies little with the mesh
resolution; ``quads`` sets it (the spring constants of a regular spring grid give the same
membrane stiffness at any resolution). Run ``softvr run cloth-wall``.
"""

from __future__ import annotations

import numpy as np

from softvr.app import Player, check_run_args, record_from_args, run_parser

__all__ = ["DEFAULT_FRAMES", "WALL_ADHESION", "Example", "main"]

#: 4 s at 25 frames per second.
DEFAULT_FRAMES = 100

#: The wall's (and cloth's) adhesion. Debonding starts at p* = sqrt(W C) = 7 Pa of traction, a
#: little below the 9.8 Pa that the weight of a 1 kg/m^2 cloth puts on the bonded part. Slapped
#: on, the pressed contacts slide at their limit instead of tearing (:mod:`softvr.contact.adhesion`);
#: hanging, the bonds are pulled off the wall and carry the weight past p*, so they stretch and
#: debond by eq. 4.12, beta_dot = (W - p^2 / (C beta^3)) / eta: at tractions set by the load the
#: time to debond grows as eta. Measured at 12 quads it is ~33 s per J s/m^2 of eta (0.72 s at
#: 0.02, 1.0 s at 0.03, 1.32 s at 0.04, 1.92 s at 0.06), so eta = 0.04 peels in ~1.4 s: 52
#: vertices bonded on impact, 63 at most, still 63 after 0.3 s, 58 after 0.7 s, 46 after 1 s,
#: none after 1.32 s (8 quads: 1.36 s, 16 quads: 1.24 s). Under the thesis' tangential damper
#: eta was 0.012; with the spring on the slip and no slide at the limit the landing tore every
#: bond within 0.3 s, at any eta that still let the cloth peel.
WALL_ADHESION = dict(stiffness=1e6, max_energy=5e-5, viscosity=0.04, initial=1.0, debond_gap=0.004)


class Example(Player):
    """A cloth swung against an adhesive wall.

    Parameters
    ----------
    frames : int
    width, height : int [pixels]
    size : float [m]
        Side of the square cloth.
    quads : int
        Quads per side.
    offset : float [m]
        Distance of the pinned top edge from the wall.
    swing : float [m/s]
        Initial speed of the cloth's bottom edge towards the wall (linear along the cloth).
    density : float [kg/m^2]
    stretch, shear, bend : float [N/m]
    alpha : float [1/s]
        Air drag (mass-proportional damping).
    adhesion : dict or None
        :class:`softvr.contact.Adhesion` parameters of the wall and the cloth (None: no adhesion).
    friction : float
    dt : float [s]
    steps_per_frame : int
    """

    name = "cloth_wall"

    def __init__(self, frames: int = DEFAULT_FRAMES, width: int = 640, height: int = 480, *, size: float = 0.5,
                 quads: int = 12, offset: float = 0.12, swing: float = 2.5, density: float = 1.0,
                 stretch: float = 300.0, shear: float = 30.0, bend: float = 0.05, alpha: float = 0.2,
                 adhesion: dict | None = WALL_ADHESION, friction: float = 0.3, dt: float = 0.004,
                 steps_per_frame: int = 10):
        from softvr import Scene
        from softvr.collision import Plane
        from softvr.contact import Adhesion
        from softvr.dynamics import ClothBody, EmbeddedPoints
        from softvr.render import Camera

        top = 1.2
        # Hanging straight down from the pinned top edge (y across, -z down the cloth).
        self.cloth = ClothBody.grid(size, size, quads, quads, origin=(offset, -size / 2, top - size),
                                    u_axis=(0.0, 1.0, 0.0), v_axis=(0.0, 0.0, 1.0), density=density,
                                    stretch=stretch, shear=shear, bend=bend, alpha=alpha, name="cloth")
        q = self.cloth.q
        self.cloth.fixed[:] = np.isclose(q[:, 2], top)
        # Swung towards the wall: speed grows linearly from the pinned edge to the bottom.
        self.cloth.v[:, 0] = -swing * (top - q[:, 2]) / size
        n = len(q)
        self.points = EmbeddedPoints(self.cloth, np.arange(n)[:, None], np.ones((n, 1)))
        sticky = None if adhesion is None else Adhesion(**adhesion)
        self.wall = Plane(point=(0.0, 0.0, 0.0), normal=(1.0, 0.0, 0.0), friction=friction)
        scene = Scene(gravity=(0.0, 0.0, -9.81), friction=friction, contact_margin=0.002)
        scene.add_body(self.cloth, collision_points=self.points, collision_triangles=self.cloth.triangles,
                       adhesion=sticky)
        scene.add_plane(self.wall, adhesion=sticky)
        self.size, self.top = size, top
        super().__init__(scene, dt, steps_per_frame, frames, width, height,
                         bounds=(-0.05, 0.6, -0.4, 0.4, top - size - 0.35, top + 0.02),
                         camera=Camera("front", azimuth=-30, elevation=15, zoom=1.3))

    # -- physics -------------------------------------------------------------------------
    def penetration(self) -> float:
        """Deepest cloth vertex behind the wall [m]."""
        return max(0.0, -float(self.cloth.q[:, 0].min()))

    def on_wall(self) -> int:
        """Vertices bonded to the wall (tracked adhesive contacts with intensity > 0)."""
        return int(sum(1 for beta in self.scene.adhesion_state.intensity.values() if beta > 0))

    # -- rendering -----------------------------------------------------------------------
    def setup_render(self, renderer) -> None:
        # Drawn 3 mm behind the contact plane, so that the bonded cloth does not z-fight with it.
        renderer.add_plane(point=(-0.003, 0.0, self.top - self.size / 2), normal=(1.0, 0.0, 0.0), size=1.6, tiles=8,
                           color=(0.72, 0.7, 0.65))
        self._mesh = renderer.add_mesh(self.cloth.q, self.cloth.triangles, color=(0.2, 0.45, 0.85),
                                       feature_angle=None)

    def update_render(self, renderer) -> None:
        renderer.update(self._mesh, self.cloth.q)

    def describe(self) -> dict:
        return {**super().describe(), "quads": int(np.sqrt(len(self.cloth.triangles) // 2)),
                "vertices": len(self.cloth.q), "size_m": self.size}


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Run the cloth-wall demo to ``<out>/cloth_wall.mp4``, ``_sheet.png`` and ``_metrics.json``."""
    parser = run_parser(prog or "softvr run cloth-wall", __doc__.splitlines()[0], DEFAULT_FRAMES)
    parser.add_argument("--quads", type=int, default=12, help="quads per cloth side (default 12)")
    args = parser.parse_args(argv)
    check_run_args(parser, args)
    with Example(frames=args.frames, width=args.size[0], height=args.size[1], quads=args.quads) as example:
        record_from_args(example, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
