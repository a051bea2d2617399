"""Candy: soft and hard candy pieces fall on a block of Jell-O (the scene of thesis Fig. 4.1).

At the thesis' scale: about 10 K tetrahedra in the deformable bodies and 28 K collision
triangles (thesis 4.4: 10 K tets, 28 K triangles, ~150 contacts on average, 8 ms steps,
Coulomb friction 0.3 everywhere). The Jell-O block is a co-rotational FEM box standing on a plate
(its bottom nodes held); its collision surface is a finer triangulation of the box embedded barycentrically in
its tets (render, collision and dynamics meshes are separate, thesis 5.1). Half of the candies
are soft (FEM balls and beans with embedded icosphere surfaces), half rigid (boxes and
balls); they rain down in a shuffled grid, bounce, squash the block and pile up on it. Every
pair of collision surfaces meets vertex-triangle and edge-edge.

With ``adhesion=True`` the Jell-O is adhesive (C = 4e7 N/m^3, the thesis'
value) and every candy has its own adhesion stiffness (1e6 to 4e7 N/m^3), so the pieces bond
to the block, and debond as it wobbles, at different rates (thesis 4.4). Without it this is
the plain contact scene of the candy-scale benchmark (``softvr bench contact``); both run in
``softvr bench adhesion``.

The demo is the bundled scene file ``candy.toml`` (``candy-adhesive.toml`` with adhesion), which
``softvr run candy`` plays. This Python construction remains for the benches alone: they build the
scene at two scales (:data:`SMALL_SCALE` for ``--quick``), and a scene file holds one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softvr import Scene
from softvr.app import Player
from softvr.collision import Plane
from softvr.contact import Adhesion
from softvr.dynamics import EmbeddedPoints, FemBody, Material, RigidBody, RigidPoints, embed_in_tets
from softvr.dynamics.rigid import quat_from_rotvec, quat_to_matrix
from softvr.model.shapes import box_surface, icosphere
from softvr.render import Camera
from softvr.volume import Volume, grid_tet_mesh
from softvr.volume.tetmesh import tet_signed_volumes

__all__ = ["CANDY_STIFFNESS", "DEFAULT_FRAMES", "JELLO_ADHESION", "CandyScale", "Example", "FULL_SCALE", "SMALL_SCALE",
           "orange_mesh"]

#: 4 s at 25 frames per second.
DEFAULT_FRAMES = 100

#: The Jell-O's adhesion (thesis 4.4: its stiffness dominates the scene's, 4e7 N/m^3).
JELLO_ADHESION = dict(stiffness=4e7, max_energy=0.05, viscosity=0.05, bonding_rate=2e-3, saturation=2000.0,
                      initial=0.5, debond_gap=0.003)
#: Adhesion stiffness of the candies in turn [N/m^3] ("diverse adhesion coefficients").
CANDY_STIFFNESS = (4e7, 1e6, 1e7, 4e6)

_JELLO = (0.95, 0.25, 0.3)
_CANDY_COLORS = [(0.98, 0.8, 0.2), (0.3, 0.7, 0.95), (0.55, 0.9, 0.35), (0.95, 0.5, 0.85), (1.0, 0.6, 0.2),
                 (0.6, 0.45, 0.95), (0.95, 0.95, 0.95), (0.2, 0.85, 0.75)]


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
    h = 2.4 * radius / voxels
    c = (voxels - 1) / 2
    x, y, z = np.mgrid[:voxels, :voxels, :voxels] - c
    mask = x**2 + y**2 + z**2 <= (voxels / 2) ** 2
    grid = Volume(mask.astype(np.uint8), spacing=np.full(3, h), origin=np.full(3, -c * h))
    nodes, tets = grid_tet_mesh(grid, cells, mask=mask)
    verts, tris = icosphere(2)
    fraction = 4 / 3 * np.pi * radius**3 / float(tet_signed_volumes(nodes, tets).sum())
    return nodes, tets, radius * verts, tris, fraction


@dataclass(frozen=True)
class CandyScale:
    """Resolution of the candy scene.

    Attributes
    ----------
    block_cells : (int, int, int)
        FEM cells of the Jell-O block (5 tets each).
    block_surface : int
        Collision-surface quads per block edge length (x, y); z gets the same spacing.
    candies : int
        Candy pieces (half soft, half rigid, alternating).
    candy_cells : int
        FEM cells per axis of a soft candy's grid (cells touching the ball are kept).
    candy_subdivisions : int
        Icosphere subdivisions of the candies' surfaces (1280 triangles at 3).
    """

    block_cells: tuple = (12, 12, 5)
    block_surface: int = 48
    candies: int = 8
    candy_cells: int = 8
    candy_subdivisions: int = 3


#: The thesis' candy scale (~10 K tets, ~28 K collision triangles).
FULL_SCALE = CandyScale()
#: A quick version for tests (~1 K tets).
SMALL_SCALE = CandyScale(block_cells=(6, 6, 3), block_surface=12, candies=4, candy_cells=4, candy_subdivisions=1)


class Example(Player):
    """Candy pieces dropped on a Jell-O block.

    Parameters
    ----------
    frames : int
    width, height : int [pixels]
    scale : CandyScale
        Mesh resolutions (:data:`FULL_SCALE` is the thesis' size).
    block_size : (float, float, float) [m]
    block_young, block_poisson, block_density : float [Pa], [-], [kg/m^3]
        The Jell-O (soft, nearly incompressible).
    candy_radius : float [m]
    candy_young : float [Pa]
        Soft candies (gummy).
    candy_density : float [kg/m^3]
    friction : float
        Coulomb coefficient of every contact (thesis: 0.3).
    dt : float [s]
        Thesis: 8 ms.
    steps_per_frame : int
    seed : int
        Shuffles the drop positions, spins and orientations.
    adhesion : bool
        Adhesive Jell-O and candies (:data:`JELLO_ADHESION`, :data:`CANDY_STIFFNESS`).
    """

    name = "candy"

    def __init__(self, frames: int = DEFAULT_FRAMES, width: int = 640, height: int = 480, *,
                 scale: CandyScale = FULL_SCALE, block_size=(0.3, 0.3, 0.12), block_young: float = 3e4,
                 block_poisson: float = 0.4, block_density: float = 1050.0, candy_radius: float = 0.03,
                 candy_young: float = 2e5, candy_density: float = 1200.0, friction: float = 0.3,
                 dt: float = 0.008, steps_per_frame: int = 5, seed: int = 7, adhesion: bool = False):
        rng = np.random.default_rng(seed)
        self.scale = scale
        self.plane = Plane(friction=friction)
        # A 2 mm contact margin: CCD sweeps cover the motion, the margin only the resting gaps.
        scene = Scene(gravity=(0.0, 0.0, -9.81), friction=friction, contact_margin=0.002)
        scene.add_plane(self.plane)
        size = np.asarray(block_size, float)
        cells = np.asarray(scale.block_cells)
        spacing = size / cells
        corner = np.array([-size[0] / 2, -size[1] / 2, 0.0])
        nodes, tets = grid_tet_mesh(Volume(np.zeros(tuple(cells), np.uint8), spacing=spacing,
                                           origin=corner + spacing / 2), tuple(cells))
        # The Jell-O stands on a plate: its bottom nodes are held (the ground contacts of the
        # embedded surface would be ~4 per bottom node, redundant rows that PGS converges on slowly).
        self.block = FemBody(nodes, tets, Material(block_young, block_poisson, block_density, alpha=2.0, beta=2e-3),
                             fixed=nodes[:, 2] < 1e-9 * size[2], name="jello")
        verts, self.block_triangles = box_surface(size, scale.block_surface)
        tet_index, weights = embed_in_tets(nodes, tets, verts + corner)
        self.block_surface = EmbeddedPoints(self.block, tets[tet_index], weights)
        self.adhesion = adhesion
        jello = Adhesion(**JELLO_ADHESION) if adhesion else None
        scene.add_body(self.block, collision_points=self.block_surface, collision_triangles=self.block_triangles,
                       adhesion=jello)

        unit, self.candy_triangles = icosphere(scale.candy_subdivisions)
        ball_nodes, ball_tets, _, _, fraction = orange_mesh(candy_radius, voxels=2 * scale.candy_cells,
                                                            cells=scale.candy_cells)
        soft = Material(candy_young, 0.35, candy_density * fraction, alpha=1.0, beta=2e-3)
        grid = max(2, int(np.ceil(np.sqrt(scale.candies))))
        slots = rng.permutation(grid * grid)[: scale.candies]
        pitch = 0.7 * size[:2].min() / max(grid - 1, 1)
        self.candies, self.candy_surfaces = [], []
        for k, slot in enumerate(slots):
            centre = np.array([(slot % grid - (grid - 1) / 2) * pitch, (slot // grid - (grid - 1) / 2) * pitch,
                               size[2] + 0.06 + 0.05 * k])
            turn = quat_from_rotvec(rng.normal(0.0, 0.6, 3))
            body: FemBody | RigidBody
            points: EmbeddedPoints | RigidPoints
            if k % 2 == 0:  # soft: a ball, or a bean (the same mesh stretched)
                stretch = np.array([1.0, 1.0, 1.0]) if k % 4 == 0 else np.array([1.35, 0.9, 0.8])
                rot = quat_to_matrix(turn)
                body = FemBody((ball_nodes * stretch) @ rot.T + centre, ball_tets, soft, name=f"soft candy {k}")
                surface_verts = (candy_radius * unit * stretch) @ rot.T + centre
                tet_index, weights = embed_in_tets(body.q, body.tets, surface_verts)
                points = EmbeddedPoints(body, body.tets[tet_index], weights)
                tris = self.candy_triangles
            else:  # rigid: a box, or a ball
                if k % 4 == 1:
                    dims = np.array([2.2, 1.4, 1.0]) * candy_radius
                    body = RigidBody.box(dims, candy_density, position=centre, orientation=turn,
                                         name=f"hard candy {k}")
                    local, tris = box_surface(dims, max(2, int(round(np.sqrt(len(self.candy_triangles) / 12)))))
                    local = local - dims / 2
                else:
                    body = RigidBody.sphere(0.8 * candy_radius, candy_density, position=centre, orientation=turn,
                                            name=f"hard candy {k}")
                    local, tris = 0.8 * candy_radius * unit, self.candy_triangles
                body.v[3:] = rng.normal(0.0, 3.0, 3)
                points = RigidPoints(body, local)
            sticky = None if not adhesion else Adhesion(**{**JELLO_ADHESION,
                                                           "stiffness": CANDY_STIFFNESS[k % len(CANDY_STIFFNESS)]})
            scene.add_body(body, collision_points=points, collision_triangles=tris, adhesion=sticky)
            self.candies.append(body)
            self.candy_surfaces.append((points, np.asarray(tris, np.int32)))
        span = 0.5 * size[:2].max() + 0.05
        super().__init__(scene, dt, steps_per_frame, frames, width, height,
                         bounds=(-span, span, -span, span, 0.0, size[2] + 0.1),
                         camera=Camera("front", azimuth=30, elevation=30, zoom=1.3))

    # -- sizes ---------------------------------------------------------------------------
    @property
    def tet_count(self) -> int:
        """Tetrahedra of all deformable bodies."""
        return len(self.block.tets) + sum(len(c.tets) for c in self.candies if hasattr(c, "tets"))

    @property
    def triangle_count(self) -> int:
        """Collision triangles of all bodies."""
        return len(self.block_triangles) + sum(len(t) for _, t in self.candy_surfaces)

    # -- physics -------------------------------------------------------------------------
    def penetration(self) -> float:
        """Deepest point of any collision surface below the ground [m] (candy-block overlaps
        are contacts' gaps: see ``scene.last_solution``)."""
        lowest = min(float(self.block_surface.positions()[:, 2].min()),
                     *(float(p.positions()[:, 2].min()) for p, _ in self.candy_surfaces))
        return max(0.0, -lowest)

    # -- rendering -----------------------------------------------------------------------
    def setup_render(self, renderer) -> None:
        renderer.add_plane(size=2.0, tiles=12, color=(0.62, 0.6, 0.55))
        self._block_mesh = renderer.add_mesh(self.block_surface.positions(), self.block_triangles, color=_JELLO,
                                             feature_angle=None)
        self._candy_meshes = [renderer.add_mesh(p.positions(), t, color=_CANDY_COLORS[k % len(_CANDY_COLORS)],
                                                feature_angle=None if hasattr(c, "tets") else 40.0)
                              for k, ((p, t), c) in enumerate(zip(self.candy_surfaces, self.candies))]

    def update_render(self, renderer) -> None:
        renderer.update(self._block_mesh, self.block_surface.positions())
        for h, (p, _) in zip(self._candy_meshes, self.candy_surfaces):
            renderer.update(h, p.positions())

    def describe(self) -> dict:
        return {**super().describe(), "tets": self.tet_count, "collision_triangles": self.triangle_count,
                "candies": len(self.candies), "friction": self.plane.friction, "adhesion": self.adhesion}

