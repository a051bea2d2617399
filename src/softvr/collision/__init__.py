"""Collision detection: geometry of contact objects in, :class:`Contacts` out.

So far: points (of any contact object, through point entities) against static half-spaces
and spheres, and rigid sphere bodies against planes and each other. Mesh-mesh detection with
Warp BVHs and CCD comes next.
"""

from softvr.collision.contacts import Contacts, ContactSide
from softvr.collision.plane import Plane, points_vs_plane
from softvr.collision.sphere import Sphere, points_vs_sphere, sphere_vs_plane, sphere_vs_sphere

__all__ = [
    "ContactSide",
    "Contacts",
    "Plane",
    "Sphere",
    "points_vs_plane",
    "points_vs_sphere",
    "sphere_vs_plane",
    "sphere_vs_sphere",
]
