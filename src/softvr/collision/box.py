"""Rigid boxes: corners against planes and against other boxes' faces (vertex-face contacts)."""

from __future__ import annotations

import numpy as np

from softvr.collision.contacts import Contacts, rigid_side
from softvr.collision.plane import Plane

__all__ = ["box_corners", "box_vs_box", "box_vs_plane"]

_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)


def box_corners(body, half_extents) -> np.ndarray:
    """World positions [8, 3] [m] of a rigid box's corners (box centred on the body's centre)."""
    return body.position + (_SIGNS * np.asarray(half_extents, float)) @ body.rotation.T


def _approach(body, velocity, n: np.ndarray, points: np.ndarray, dt: float) -> np.ndarray:
    """dt times the approach speed (<= 0) along n of body points moving with ``velocity`` [6]."""
    if velocity is None or dt == 0.0:
        return np.zeros(len(points))
    v = np.asarray(velocity, float)
    vel = v[:3] + np.cross(v[3:], points - body.position)
    return dt * np.minimum(np.einsum("ci,ci->c", vel, np.broadcast_to(n, vel.shape)), 0.0)


def box_vs_plane(index: int, body, half_extents, plane: Plane, *, margin: float = 0.0, velocity=None,
                 dt: float = 0.0) -> Contacts:
    """Corner contacts of a rigid box with a static plane (``velocity`` [6]: the body's
    unconstrained velocity of the step, for speculative contacts)."""
    n = plane.unit_normal()
    p = box_corners(body, half_extents)
    gap = (p - np.asarray(plane.point, float)) @ n
    hit = np.flatnonzero(np.minimum(gap, gap + _approach(body, velocity, n, p, dt)) < margin)
    k = len(hit)
    return Contacts(rigid_side(index, p[hit] - body.position), None, np.broadcast_to(n, (k, 3)).copy(), gap[hit], p[hit],
                    p[hit] - gap[hit, None] * n, (np.int64(plane.id) << 32) | (np.int64(index) << 8) | hit,
                    np.full(k, float(plane.friction)))


def _face_contacts(a, ha, va, b, hb, vb, n, margin, dt):
    """Corners of box a against the face of box b with outward normal n (b -> a).

    gap = n . (p - c_b) - r_b, r_b the half width of b along n; a corner counts when it lies
    over the face (inside b's extent across n, plus the margin) and is within the margin.
    """
    p = box_corners(a, ha)
    r_b = np.sum(np.asarray(hb, float) * np.abs(b.rotation.T @ n))
    d = p - b.position
    gap = d @ n - r_b
    across = d - np.outer(d @ n, n)
    local = across @ b.rotation
    over = np.all(np.abs(local) <= np.asarray(hb, float) + margin + 1e-12, axis=1)
    rel = _approach(a, va, n, p, dt) - _approach(b, vb, n, p, dt)
    hit = np.flatnonzero(over & (np.minimum(gap, gap + rel) < margin))
    return p[hit], gap[hit], hit


def _separating_face_axis(a, ha, b, hb):
    """The face axis (of a or b) of largest separation (least overlap): SAT on the 6 face normals.

    Returns (normal from b to a, True if the face belongs to b). Edge-edge axes are not
    tested: resting and stacking contacts are face contacts.
    """
    d = a.position - b.position
    best = (-np.inf, None, True)
    for owner_is_b, rot in ((True, b.rotation), (False, a.rotation)):
        for k in range(3):
            u = rot[:, k]
            ra = np.sum(np.asarray(ha, float) * np.abs(a.rotation.T @ u))
            rb = np.sum(np.asarray(hb, float) * np.abs(b.rotation.T @ u))
            sep = abs(d @ u) - ra - rb
            if sep > best[0] + 1e-12:
                best = (sep, u * (1.0 if d @ u >= 0 else -1.0), owner_is_b)
    return best[1], best[2]


def box_vs_box(ia: int, a, ha, ib: int, b, hb, *, friction: float = 0.5, margin: float = 0.0,
               velocity_a=None, velocity_b=None, dt: float = 0.0) -> Contacts:
    """Vertex-face contacts between two rigid boxes.

    The contact normal is the face axis of least overlap (separating-axis test on the face
    normals, from b towards a); the corners of the other box over that face within the margin
    become contacts. Both sides act at the corner, so equal and opposite impulses exert no
    net torque.
    """
    n, face_of_b = _separating_face_axis(a, ha, b, hb)
    if face_of_b:
        points, gap, corners = _face_contacts(a, ha, velocity_a, b, hb, velocity_b, n, margin, dt)
    else:
        points, gap, corners = _face_contacts(b, hb, velocity_b, a, ha, velocity_a, -n, margin, dt)
    base = (np.int64(min(ia, ib)) << 40) | (np.int64(max(ia, ib)) << 20) | (np.int64(0 if face_of_b else 8))
    k = len(gap)
    return Contacts(rigid_side(ia, points - a.position), rigid_side(ib, points - b.position), np.broadcast_to(n, (k, 3)).copy(),
                    gap, points, points, base | corners.astype(np.int64), np.full(k, float(friction)))
