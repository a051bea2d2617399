"""Collision detection: geometry of contact objects in, :class:`Contacts` out.

So far: points (of any contact object, through point entities) against static half-spaces
(:func:`points_vs_plane`). Mesh-mesh detection with Warp BVHs and CCD comes next.
"""

from softvr.collision.contacts import Contacts, ContactSide
from softvr.collision.plane import Plane, points_vs_plane

__all__ = ["ContactSide", "Contacts", "Plane", "points_vs_plane"]
