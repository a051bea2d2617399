"""Spheres: static spheres against points, rigid sphere bodies against planes and each other."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softvr.collision.contacts import ContactKind, Contacts, ContactSide, contact_keys, point_jacobian_blocks, rigid_side
from softvr.collision.plane import Plane
from softvr.errors import InputError

__all__ = ["Sphere", "points_vs_sphere", "sphere_vs_plane", "sphere_vs_sphere"]


@dataclass(frozen=True)
class Sphere:
    """A static solid sphere.

    Attributes
    ----------
    center : tuple of 3 float [m]
    radius : float [m]
    friction : float
    """

    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 1.0
    friction: float = 0.5

    def __post_init__(self) -> None:
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise InputError("Sphere.radius", "a finite radius > 0 [m]", repr(self.radius))


def points_vs_sphere(body_index: int, points, sphere: Sphere, *, margin: float = 0.0, velocities=None,
                     dt: float = 0.0, static_index: int = 0) -> Contacts:
    """Contacts of point entities with a static sphere (gap along the outward radial normal);
    ``static_index`` is the sphere's index among the scene's static spheres (part of the keys)."""
    c = np.asarray(sphere.center, float)
    p = points.positions()
    d = p - c
    dist = np.linalg.norm(d, axis=1)
    n = d / np.maximum(dist, 1e-12)[:, None]
    gap = dist - sphere.radius
    reach = gap.copy()
    if velocities is not None:
        reach += dt * np.minimum(np.einsum("pi,pi->p", np.asarray(velocities, float), n), 0.0)
    hit = np.flatnonzero(np.minimum(gap, reach) < margin)
    blocks, jac = point_jacobian_blocks(points, hit)
    return Contacts(
        a=ContactSide(body_index, blocks, jac),
        b=None,
        normal=n[hit],
        gap=gap[hit],
        point_a=p[hit],
        point_b=c + sphere.radius * n[hit],
        ids=contact_keys(ContactKind.POINT_SPHERE, body_index, hit, static_index, 0),
        friction=np.full(len(hit), float(sphere.friction)),
    )


def _empty(body_index: int, other: int | None, block_size: int) -> Contacts:
    side = ContactSide(body_index, np.zeros((0, 1), int), np.zeros((0, 1, 3, block_size)))
    other_side = None if other is None else ContactSide(other, np.zeros((0, 1), int), np.zeros((0, 1, 3, block_size)))
    z3 = np.zeros((0, 3))
    return Contacts(side, other_side, z3, np.zeros(0), z3, z3, np.zeros(0, np.int64), np.zeros(0))


def _cap_area(radius: float, margin: float) -> float:
    """Area [m^2] of the cap of a sphere of ``radius`` [m] within ``margin`` [m] of a tangent
    plane: 2 pi R h with the cap height h = margin (at most the whole sphere, h = 2 R)."""
    return 2.0 * np.pi * radius * min(max(margin, 0.0), 2.0 * radius)


def sphere_vs_plane(body_index: int, body, radius: float, plane: Plane, *, margin: float = 0.0, velocity=None,
                    dt: float = 0.0, static_index: int = 0) -> Contacts:
    """Contact of a rigid sphere body (centre = its position) with a plane.

    Parameters
    ----------
    body_index : int
        Index of the sphere's body in the scene.
    body : RigidBody or FixedBody or KinematicBody
    radius : float [m]
    plane : Plane
    margin : float [m]
        Detection margin: a gap below it makes the contact.
    velocity : ndarray, shape [6], optional
        The body's unconstrained velocity of the step [m/s, rad/s]: makes the contact
        speculative over ``dt``.
    dt : float [s]
    static_index : int
        Index of the plane among the scene's planes (part of the contact key).

    Notes
    -----
    The one contact carries an area for adhesion (thesis 4.3.1), by a modelling choice: a
    sphere's contact stands for the cap of its surface within the detection margin of the
    plane, ``A = 2 pi R h`` with the cap height h = ``margin`` (a smooth sphere has no mesh
    whose vertex areas could say it). With no margin it has no area, and no adhesion.
    """
    n = plane.unit_normal()
    gap = float((body.position - np.asarray(plane.point, float)) @ n) - radius
    approach = 0.0 if velocity is None else dt * min(float(np.asarray(velocity, float)[:3] @ n), 0.0)
    if min(gap, gap + approach) >= margin:
        return _empty(body_index, None, 6)
    pa = body.position - radius * n
    return Contacts(rigid_side(body_index, -radius * n), None, n[None], np.array([gap]), pa[None],
                    (pa - gap * n)[None], contact_keys(ContactKind.SPHERE_PLANE, [body_index], 0, static_index, 0),
                    np.array([float(plane.friction)]), np.array([_cap_area(radius, margin)]))


def sphere_vs_sphere(a_index: int, a, radius_a: float, b_index: int, b, radius_b: float, *, friction: float = 0.5,
                     margin: float = 0.0, velocity_a=None, velocity_b=None, dt: float = 0.0) -> Contacts:
    """Contact between two rigid sphere bodies; the normal points from b towards a.

    Its area (for adhesion) is by the same modelling choice as :func:`sphere_vs_plane`'s: the
    cap of the smaller sphere's surface within ``margin`` [m] of the other, ``2 pi R h`` with
    R the smaller radius and h = ``margin``.
    """
    d = a.position - b.position
    dist = float(np.linalg.norm(d))
    n = d / dist if dist > 1e-12 else np.array([0.0, 0.0, 1.0])
    gap = dist - radius_a - radius_b
    approach = 0.0
    if velocity_a is not None and velocity_b is not None:
        approach = dt * min(float((np.asarray(velocity_a, float)[:3] - np.asarray(velocity_b, float)[:3]) @ n), 0.0)
    if min(gap, gap + approach) >= margin:
        return _empty(a_index, b_index, 6)
    pa, pb = a.position - radius_a * n, b.position + radius_b * n
    # Both sides act at the midpoint, so the equal and opposite impulses exert no net torque
    # even while the (speculative) contact still has a gap: angular momentum is conserved.
    mid = 0.5 * (pa + pb)
    return Contacts(rigid_side(a_index, mid - a.position), rigid_side(b_index, mid - b.position), n[None],
                    np.array([gap]), pa[None], pb[None], contact_keys(ContactKind.SPHERE_SPHERE, [a_index], 0, b_index, 0),
                    np.array([float(friction)]), np.array([_cap_area(min(radius_a, radius_b), margin)]))
