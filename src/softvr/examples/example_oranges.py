"""Oranges: soft FEM spheres bouncing and rolling on the ground (the set-up of thesis Fig. 3.7).

Four oranges, each a smooth sphere surface embedded (barycentric, thesis 5.1.2) in a coarse
co-rotational FEM mesh of ~280 tets built by :func:`softvr.volume.grid_tet_mesh` around a
sphere mask (the mesh that will later carry the orange's volume through tetrahedral
rasterization, thesis ch. 3), are thrown onto the ground with different speeds, heights and
spins; they bounce, squash and roll in parallel lanes, the last one thrown across its
neighbour's lane so that the two collide (soft-soft vertex-triangle and edge-edge contacts).
The embedded surface vertices are both the collision points and the rendered mesh. Run
``softvr run oranges`` .
"""

from __future__ import annotations

import numpy as np

from softvr.model.shapes import icosphere
from softvr.app import Player, check_run_args, record_from_args, run_parser

__all__ = ["DEFAULT_FRAMES", "Example", "orange_mesh", "main"]

#: 3 s at 25 frames per second.
DEFAULT_FRAMES = 75

#: (start x [m], start height of the centre [m], velocity x [m/s], velocity z [m/s]) per lane.
_LAUNCHES = [(-0.7, 0.35, 0.75, 0.0), (-0.6, 0.55, 0.5, 0.5), (-0.75, 0.25, 0.9, 0.0), (-0.65, 0.45, 0.6, 1.0),
             (-0.7, 0.3, 0.8, 0.3), (-0.7, 0.6, 0.4, 0.0)]
_COLORS = [(0.98, 0.55, 0.1), (0.95, 0.62, 0.12), (0.99, 0.5, 0.08), (0.93, 0.58, 0.16), (0.97, 0.66, 0.2),
           (0.96, 0.52, 0.12)]


def orange_mesh(radius: float, voxels: int = 12, cells: int = 4):
    """Tet mesh around a sphere of ``radius`` [m] centred at the origin, and the sphere's surface.

    A ``voxels``^3 grid spanning 2.4 radii holds the sphere mask; :func:`grid_tet_mesh`
    keeps the ``cells``^3 cubes touching it (5 tets each; 280 tets for the defaults). The
    rendered surface (an icosphere) has the given radius, which at most ``5 / 6`` of the mask
    radius in voxel units keeps every surface point inside a kept cube.

    Returns
    -------
    nodes [n, 3] [m], tets [m, 4], surface vertices [k, 3] [m], surface triangles [t, 3],
    mask volume fraction (sphere volume / tet mesh volume)
    """
    from softvr.volume import Volume, grid_tet_mesh
    from softvr.volume.tetmesh import tet_signed_volumes

    h = 2.4 * radius / voxels
    c = (voxels - 1) / 2
    x, y, z = np.mgrid[:voxels, :voxels, :voxels] - c
    mask = x**2 + y**2 + z**2 <= (voxels / 2) ** 2
    grid = Volume(mask.astype(np.uint8), spacing=np.full(3, h), origin=np.full(3, -c * h))
    nodes, tets = grid_tet_mesh(grid, cells, mask=mask)
    verts, tris = icosphere(2)
    fraction = 4 / 3 * np.pi * radius**3 / float(tet_signed_volumes(nodes, tets).sum())
    return nodes, tets, radius * verts, tris, fraction


class Example(Player):
    """Soft oranges thrown onto the ground.

    Parameters
    ----------
    frames : int
    width, height : int [pixels]
    count : int
        Oranges (1 to 6), one per lane.
    radius : float [m]
        Radius of the (rendered, colliding) orange surface.
    young, poisson : float [Pa], [-]
    density : float [kg/m^3]
        Density of the orange; the coarser tet mesh around it gets the orange's mass.
    alpha, beta : float [1/s], [s]
        Rayleigh damping.
    friction : float
    dt : float [s]
    steps_per_frame : int
    """

    name = "oranges"

    def __init__(self, frames: int = DEFAULT_FRAMES, width: int = 640, height: int = 480, *, count: int = 4,
                 radius: float = 0.08, young: float = 1.2e5, poisson: float = 0.3, density: float = 900.0,
                 alpha: float = 0.0, beta: float = 2e-3, friction: float = 0.6, dt: float = 0.005,
                 steps_per_frame: int = 8):
        from softvr import Scene
        from softvr.collision import Plane
        from softvr.dynamics import EmbeddedPoints, FemBody, Material, embed_in_tets
        from softvr.render import Camera

        if not 1 <= int(count) <= len(_LAUNCHES):
            from softvr.errors import InputError

            raise InputError("count", f"1 to {len(_LAUNCHES)} oranges", repr(count))
        nodes, tets, verts, self.triangles, fraction = orange_mesh(radius)
        self.plane = Plane(friction=friction)
        scene = Scene(gravity=(0.0, 0.0, -9.81), friction=friction)
        scene.add_plane(self.plane)
        self.oranges, self.surfaces = [], []
        lanes = (np.arange(count) - (count - 1) / 2) * 0.32
        material = Material(young, poisson, density * fraction, alpha=alpha, beta=beta)
        for i in range(int(count)):
            x0, z0, vx, vz = _LAUNCHES[i]
            centre = np.array([x0, lanes[i], z0])
            # The last orange of several crosses into its neighbour's lane, meeting it mid-way.
            vy = -(lanes[i] - lanes[i - 1]) / 1.2 if i == count - 1 and count > 1 else 0.0
            body = FemBody(nodes + centre, tets, material, name=f"orange {i}")
            # Rolling spin about the lane's normal: omega_y = v_x / r.
            omega = np.array([0.0, vx / radius, 0.0])
            body.v[:] = np.array([vx, vy, vz]) + np.cross(omega, body.q - centre)
            tet_index, weights = embed_in_tets(body.q, body.tets, verts + centre)
            surface = EmbeddedPoints(body, body.tets[tet_index], weights)
            scene.add_body(body, collision_points=surface, collision_triangles=self.triangles)
            self.oranges.append(body)
            self.surfaces.append(surface)
        self.radius, self.material, self.orange_density = radius, material, density
        span = abs(lanes).max() + radius
        super().__init__(scene, dt, steps_per_frame, frames, width, height,
                         bounds=(-0.8, 0.9, -span, span, 0.0, 0.3),
                         camera=Camera("back", azimuth=-25, elevation=25, zoom=1.15))

    def penetration(self) -> float:
        lowest = min(float(s.positions()[:, 2].min()) for s in self.surfaces)
        return max(0.0, -lowest)

    def setup_render(self, renderer) -> None:
        renderer.add_plane(size=4.0, tiles=16, color=(0.5, 0.56, 0.5))
        self._meshes = [renderer.add_mesh(s.positions(), self.triangles, color=_COLORS[i], feature_angle=None)
                        for i, s in enumerate(self.surfaces)]

    def update_render(self, renderer) -> None:
        for h, s in zip(self._meshes, self.surfaces):
            renderer.update(h, s.positions())

    def describe(self) -> dict:
        m = self.material
        return {**super().describe(), "oranges": len(self.oranges), "radius_m": self.radius,
                "tets_each": len(self.oranges[0].tets), "surface_vertices_each": len(self.surfaces[0].nodes),
                "young_pa": m.young, "poisson": m.poisson, "orange_density_kg_m3": self.orange_density,
                "mass_kg_each": float(self.oranges[0].mass.sum()), "friction": self.plane.friction}


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Run the oranges demo to ``<out>/oranges.mp4``, ``_sheet.png`` and ``_metrics.json``."""
    parser = run_parser(prog or "softvr run oranges", __doc__.splitlines()[0], DEFAULT_FRAMES)
    parser.add_argument("--count", type=int, default=4, help="oranges, 1 to 6 (default 4)")
    args = parser.parse_args(argv)
    check_run_args(parser, args)
    with Example(frames=args.frames, width=args.size[0], height=args.size[1], count=args.count) as example:
        record_from_args(example, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
