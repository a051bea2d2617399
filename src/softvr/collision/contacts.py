"""Contacts between contact objects, as produced by collision detection."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ContactSide", "Contacts", "point_jacobian_blocks", "rigid_side", "stencil_side"]


@dataclass
class ContactSide:
    """One side of a set of contacts: which velocity blocks of which body the points move with.

    Point velocity of contact c is ``sum_k jac[c, k] @ v_blocks[blocks[c, k]]`` (thesis 5.1.2,
    ``p_dot = J v``).

    Attributes
    ----------
    body : int
        Index of the body in the simulation's body list.
    blocks : ndarray of int, shape [contact_count, k]
        Velocity blocks of the body each point depends on (nodes; 0 for a rigid body).
    jac : ndarray, shape [contact_count, k, 3, block_size]
        Jacobian blocks mapping block velocities to world point velocity [m/s per unit].
    """

    body: int
    blocks: np.ndarray
    jac: np.ndarray


@dataclass
class Contacts:
    """Contacts of one body pair kind (side ``a`` against ``b``; ``b`` None = static geometry).

    Attributes
    ----------
    a, b : ContactSide, ContactSide or None
    normal : ndarray, shape [contact_count, 3]
        Unit normal pointing from b towards a.
    gap : ndarray, shape [contact_count] [m]
        Signed distance along the normal (negative: penetration depth).
    point_a, point_b : ndarray, shape [contact_count, 3] [m]
        Contact points P on a and P' on b.
    area : ndarray, shape [contact_count] [m^2]
        Local area each contact stands for: the smaller of its two primitives' areas, a
        triangle's own and the mean of the incident triangles' at vertices and edges (thesis
        4.3.1); 0 when unknown (points that are not collision-surface vertices).
    ids : ndarray of int64, shape [contact_count]
        Stable identifiers (same feature pair -> same id across steps) for warm starts.
    friction : ndarray, shape [contact_count]
        Coulomb coefficient mu.
    """

    a: ContactSide
    b: ContactSide | None
    normal: np.ndarray
    gap: np.ndarray
    point_a: np.ndarray
    point_b: np.ndarray
    ids: np.ndarray
    friction: np.ndarray
    area: np.ndarray = field(default=None)

    def __post_init__(self) -> None:
        if self.area is None:
            self.area = np.zeros(len(self.gap))

    def __len__(self) -> int:
        return len(self.gap)

    def select(self, keep: np.ndarray) -> Contacts:
        """The contacts where ``keep`` [contact_count] (bool or indices) selects."""
        sides = [None if s is None else ContactSide(s.body, s.blocks[keep], s.jac[keep]) for s in (self.a, self.b)]
        return Contacts(*sides, self.normal[keep], self.gap[keep], self.point_a[keep], self.point_b[keep],
                        self.ids[keep], self.friction[keep], self.area[keep])


def point_jacobian_blocks(points, which: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Velocity blocks [c, k] and 3 x block_size Jacobian blocks [c, k, 3, bs] of the selected
    point entities (``EmbeddedPoints``: w_i I per stencil node; ``RigidPoints``: [I, -[R r]x])."""
    if hasattr(points, "weights"):  # EmbeddedPoints: p = sum w_i q_i
        blocks = points.nodes[which]
        jac = points.weights[which][:, :, None, None] * np.eye(3)
        return blocks, jac
    # RigidPoints: p_dot = v + w x (R r) = [I, -[R r]x] (v, w)
    return np.zeros((len(which), 1), int), _rigid_jacobian(points.offsets()[which])


def _rigid_jacobian(offsets: np.ndarray) -> np.ndarray:
    """[c, 1, 3, 6] blocks J = [I, -[r]x] of body-fixed points at world offsets r [c, 3]."""
    r = np.asarray(offsets, float).reshape(-1, 3)
    jac = np.zeros((len(r), 1, 3, 6))
    jac[:, 0, :, :3] = np.eye(3)
    jac[:, 0, 0, 4], jac[:, 0, 0, 5] = r[:, 2], -r[:, 1]
    jac[:, 0, 1, 3], jac[:, 0, 1, 5] = -r[:, 2], r[:, 0]
    jac[:, 0, 2, 3], jac[:, 0, 2, 4] = r[:, 1], -r[:, 0]
    return jac


def rigid_side(body_index: int, offsets) -> ContactSide:
    """Contact side of points fixed in a rigid body at world offsets [c, 3] from its centre."""
    jac = _rigid_jacobian(offsets)
    return ContactSide(body_index, np.zeros((len(jac), 1), int), jac)


def stencil_side(body_index: int, points, vertices: np.ndarray, weights: np.ndarray) -> ContactSide:
    """Contact side of points ``sum_v weights[c, v] p[vertices[c, v]]`` on a surface of point
    entities (a triangle's barycentric point, an edge's interpolated point).

    Parameters
    ----------
    body_index : int
    points : RigidPoints or EmbeddedPoints
        The surface vertices.
    vertices : ndarray of int, shape [contact_count, k]
    weights : ndarray, shape [contact_count, k]
        Summing to 1 per contact.
    """
    if hasattr(points, "weights"):  # embedded: combine the vertices' node stencils
        nodes = points.nodes[vertices]  # [c, k, s]
        w = points.weights[vertices] * weights[:, :, None]
        c, k = len(vertices), nodes.shape[1] * nodes.shape[2]
        return ContactSide(body_index, nodes.reshape(c, k), w.reshape(c, k)[:, :, None, None] * np.eye(3))
    # rigid: the velocity of the body-fixed point at the contact position
    at = np.einsum("cv,cvx->cx", weights, points.positions()[vertices])
    return rigid_side(body_index, at - points.body.position)
