"""Collision detection: geometry of contact objects in, :class:`Contacts` out.

So far: points (of any contact object, through point entities) against static half-spaces
and spheres, rigid spheres against planes and each other, and rigid boxes against planes
and each other (corner-face). Points against static
triangle meshes use Warp's BVH, discretely and by CCD (first time of impact). Deforming
surfaces of two bodies meet vertex-triangle (BVH refit each step, discrete and swept) and
edge-edge (BVH over edges, speculative).
"""

from softvr.collision.box import box_corners, box_vs_box, box_vs_plane
from softvr.collision.contacts import Contacts, ContactSide
from softvr.collision.edges import edges_vs_edges
from softvr.collision.mesh import TriangleMesh, points_vs_mesh
from softvr.collision.plane import Plane, points_vs_plane
from softvr.collision.sphere import Sphere, points_vs_sphere, sphere_vs_plane, sphere_vs_sphere
from softvr.collision.surfaces import CollisionSurface, surface_vs_surface

__all__ = [
    "CollisionSurface",
    "ContactSide",
    "box_corners",
    "box_vs_box",
    "box_vs_plane",
    "Contacts",
    "edges_vs_edges",
    "Plane",
    "Sphere",
    "TriangleMesh",
    "points_vs_mesh",
    "points_vs_plane",
    "points_vs_sphere",
    "sphere_vs_plane",
    "sphere_vs_sphere",
    "surface_vs_surface",
]
