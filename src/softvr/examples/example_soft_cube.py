"""Soft cube: a co-rotational FEM cube dropped, tilted, onto the ground (thesis 5.1.1, 5.3).

A 0.3 m cube of 5-tet cubes (E = 150 kPa, nu = 0.28, 1000 kg/m^3, Rayleigh damping) falls
15 cm, lands on an edge, squashes and settles on a plane with Coulomb friction 0.5. Every
boundary node is a collision point; the contacts are solved by projected Gauss-Seidel each
5 ms step. The cube is drawn by its boundary triangles, moved every frame. Run
``softvr run soft-cube`` .
"""

from __future__ import annotations

import numpy as np

from softvr.app import Player, check_run_args, record_from_args, run_parser

__all__ = ["DEFAULT_FRAMES", "Example", "main"]

#: 3 s at 25 frames per second.
DEFAULT_FRAMES = 75


def _rotation(degrees_x: float, degrees_y: float) -> np.ndarray:
    ax, ay = np.radians(degrees_x), np.radians(degrees_y)
    rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
    return ry @ rx


class Example(Player):
    """A soft FEM cube dropped on a plane.

    Parameters
    ----------
    frames : int
        Frames to simulate (each ``steps_per_frame`` steps of ``dt``).
    width, height : int [pixels]
        Rendered image size.
    size : float [m]
        Edge length of the cube.
    cells : int
        Hexahedral cells per edge (5 tets each): 4 gives 320 tets.
    drop : float [m]
        Height of the cube's lowest point above the ground at the start.
    tilt : (float, float) [degrees]
        Initial rotation about x, then y (0, 0 lands flat on a face).
    young, poisson, density : float [Pa], [-], [kg/m^3]
    alpha, beta : float [1/s], [s]
        Rayleigh damping.
    friction : float
        Coulomb coefficient of the ground.
    dt : float [s]
    steps_per_frame : int
    """

    name = "soft_cube"

    def __init__(self, frames: int = DEFAULT_FRAMES, width: int = 640, height: int = 480, *, size: float = 0.3,
                 cells: int = 4, drop: float = 0.15, tilt=(-14.0, 9.0), young: float = 1.5e5, poisson: float = 0.28,
                 density: float = 1000.0, alpha: float = 1.0, beta: float = 2e-3, friction: float = 0.5,
                 dt: float = 0.005, steps_per_frame: int = 8):
        from softvr import Scene
        from softvr.collision import Plane
        from softvr.dynamics import EmbeddedPoints, FemBody, Material
        from softvr.render import Camera
        from softvr.volume import boundary_faces
        from softvr.volume import Volume, grid_tet_mesh

        spacing = np.full(3, size / cells)
        grid = Volume(np.zeros((cells,) * 3, np.uint8), spacing=spacing, origin=spacing / 2 - size / 2)
        nodes, tets = grid_tet_mesh(grid, cells)  # centred on the origin
        nodes = nodes @ _rotation(*tilt).T
        nodes[:, 2] += drop - nodes[:, 2].min()
        self.body = FemBody(nodes, tets, Material(young, poisson, density, alpha=alpha, beta=beta), name="soft cube")
        faces = boundary_faces(self.body.tets)
        # Surface nodes are both the collision points and the render mesh's vertices.
        self.surface_nodes, local = np.unique(faces, return_inverse=True)
        self.faces = local.reshape(-1, 3).astype(np.int32)
        self.points = EmbeddedPoints(self.body, self.surface_nodes[:, None], np.ones((len(self.surface_nodes), 1)))
        self.plane = Plane(normal=(0.0, 0.0, 1.0), friction=friction)
        scene = Scene(gravity=(0.0, 0.0, -9.81))
        scene.add_body(self.body, collision_points=self.points)
        scene.add_plane(self.plane)
        reach = 1.4 * size
        super().__init__(scene, dt, steps_per_frame, frames, width, height,
                         bounds=(-reach, reach, -reach, reach, 0.0, drop + 1.2 * size),
                         camera=Camera("iso", azimuth=-10, elevation=-12, zoom=1.15))
        self.size, self.cells, self.material = size, cells, self.body.material

    def penetration(self) -> float:
        return max(0.0, -float(self.points.positions()[:, 2].min()))

    def setup_render(self, renderer) -> None:
        renderer.add_plane(size=3.0, tiles=12)
        self._mesh = renderer.add_mesh(self.points.positions(), self.faces, color=(0.86, 0.42, 0.2))

    def update_render(self, renderer) -> None:
        renderer.update(self._mesh, self.points.positions())

    def describe(self) -> dict:
        m = self.material
        return {**super().describe(), "size_m": self.size, "tets": len(self.body.tets), "nodes": len(self.body.q),
                "collision_points": len(self.surface_nodes), "young_pa": m.young, "poisson": m.poisson,
                "density_kg_m3": m.density, "rayleigh_alpha": m.alpha, "rayleigh_beta": m.beta,
                "friction": self.plane.friction, "mass_kg": float(self.body.mass.sum())}


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Run the soft-cube demo to ``<out>/soft_cube.mp4``, ``_sheet.png`` and ``_metrics.json``."""
    parser = run_parser(prog or "softvr run soft-cube", __doc__.splitlines()[0], DEFAULT_FRAMES)
    args = parser.parse_args(argv)
    check_run_args(parser, args)
    with Example(frames=args.frames, width=args.size[0], height=args.size[1]) as example:
        record_from_args(example, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
