"""Points against static half-spaces (ground, walls, inclines)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softvr.collision.contacts import ContactKind, Contacts, ContactSide, contact_keys, point_jacobian_blocks
from softvr.errors import InputError

__all__ = ["Plane", "points_vs_plane"]


@dataclass(frozen=True)
class Plane:
    """The static half-space ``n . (x - point) >= 0`` (solid below).

    Attributes
    ----------
    point : tuple of 3 float [m]
        A point on the plane.
    normal : tuple of 3 float
        Outward normal (normalized on use).
    friction : float
        Coulomb coefficient mu of contacts with it.
    """

    point: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 0.0, 1.0)
    friction: float = 0.5

    def unit_normal(self) -> np.ndarray:
        n = np.asarray(self.normal, float)
        length = np.linalg.norm(n)
        if not np.isfinite(length) or length == 0:
            raise InputError("Plane.normal", "a non-zero finite vector", repr(self.normal))
        return n / length


def points_vs_plane(body_index: int, points, plane: Plane, *, margin: float = 0.0, velocities=None,
                    dt: float = 0.0, static_index: int = 0) -> Contacts:
    """Contacts of a body's point entities with a plane: points closer than ``margin``, or that
    would come that close within ``dt`` at ``velocities`` (no tunnelling at any speed). The
    contacts carry no area (0): points alone stand for no surface, and :class:`softvr.Scene`
    gives the vertices of a collision surface their area facing the contact
    (:meth:`~softvr.collision.CollisionSurface.facing_vertex_area`).

    Parameters
    ----------
    body_index : int
        Index of the points' body in the simulation's body list.
    points : RigidPoints or EmbeddedPoints
        Point entities (collision-mesh vertices) of that body.
    plane : Plane
    margin : float [m]
        Points with a gap below it become contacts (speculative contacts: the constraint
        forbids crossing, not approaching).
    velocities : ndarray, shape [point_count, 3] [m/s], optional
        Predicted point velocities (e.g. the unconstrained ones of this step).
    dt : float [s]
        Step over which ``velocities`` apply.
    static_index : int
        Index of the plane among the scene's planes: with the body and the point it makes the
        contact keys unique in the scene (:func:`~softvr.collision.contacts.contact_keys`).
    """
    n = plane.unit_normal()
    p = points.positions()
    gap = (p - np.asarray(plane.point, float)) @ n
    reach = gap.copy()
    if velocities is not None:
        reach += dt * np.minimum(np.asarray(velocities, float) @ n, 0.0)
    hit = np.flatnonzero(np.minimum(gap, reach) < margin)
    blocks, jac = point_jacobian_blocks(points, hit)
    k = len(hit)
    return Contacts(
        a=ContactSide(body_index, blocks, jac),
        b=None,
        normal=np.broadcast_to(n, (k, 3)).copy(),
        gap=gap[hit],
        point_a=p[hit],
        point_b=p[hit] - gap[hit, None] * n,
        ids=contact_keys(ContactKind.POINT_PLANE, body_index, hit, static_index, 0),
        friction=np.full(k, float(plane.friction)),
    )
