"""Collision detection: geometry of contact objects in, :class:`Contacts` out.

So far: points (of any contact object, through point entities) against static half-spaces
and spheres, rigid spheres against planes and each other, and rigid boxes against planes
and each other (corner-face). Mesh-mesh detection with
Warp BVHs and CCD comes next.
"""

from softvr.collision.box import box_corners, box_vs_box, box_vs_plane
from softvr.collision.contacts import Contacts, ContactSide
from softvr.collision.plane import Plane, points_vs_plane
from softvr.collision.sphere import Sphere, points_vs_sphere, sphere_vs_plane, sphere_vs_sphere

__all__ = [
    "ContactSide",
    "box_corners",
    "box_vs_box",
    "box_vs_plane",
    "Contacts",
    "Plane",
    "Sphere",
    "points_vs_plane",
    "points_vs_sphere",
    "sphere_vs_plane",
    "sphere_vs_sphere",
]
