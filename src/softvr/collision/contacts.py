"""Contacts between contact objects, as produced by collision detection."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from softvr.errors import InputError

__all__ = ["MAX_BODIES", "MAX_FEATURES", "ContactKind", "ContactSide", "Contacts", "contact_keys", "point_jacobian_blocks", "rigid_side",
           "stencil_side", "unpack_keys"]


class ContactKind(IntEnum):
    """What meets what in a contact: the first field of its key (:func:`contact_keys`)."""

    POINT_PLANE = 0  #: a body's collision point against a static plane
    POINT_SPHERE = 1  #: a collision point against a static sphere
    POINT_MESH = 2  #: a collision point against a static triangle mesh
    VERTEX_TRIANGLE = 3  #: a surface vertex of body a against a triangle of body b
    EDGE_EDGE = 4  #: an edge of body a against an edge of body b
    SPHERE_PLANE = 5  #: a rigid sphere primitive against a static plane
    SPHERE_SPHERE = 6  #: two rigid sphere primitives
    BOX_PLANE = 7  #: a rigid box primitive's corner against a static plane
    BOX_BOX = 8  #: a box primitive's corner (or edge pair) against another box


# Bit layout of a key, most significant first: kind 4 | body a 10 | body b 10 | feature a 20 |
# feature b 20 = 64 bits. One int64 per contact keeps matching a sort or a hash on any device.
_FIELDS = (("kind", 4), ("body_a", 10), ("body_b", 10), ("feature_a", 20), ("feature_b", 20))
_SHIFTS = {}
_shift = 64
for _name, _bits in _FIELDS:
    _shift -= _bits
    _SHIFTS[_name] = (_shift, _bits)
del _shift, _name, _bits
#: Largest body index and feature index a key holds.
MAX_BODIES = 1 << 10
MAX_FEATURES = 1 << 20


def contact_keys(kind, body_a, feature_a, body_b, feature_b) -> np.ndarray:
    """Scene-unique keys [c] (int64) of contacts: (kind, body a, feature a, body b, feature b).

    The same feature pair of the same two bodies gets the same key on every step, so warm
    starts and adhesion intensities follow it; different pairs never share one.

    Parameters
    ----------
    kind : ContactKind
    body_a : int or ndarray of int [c]
        Body index of side a in the scene.
    feature_a : int or ndarray of int [c]
        Side a's feature: a collision point, surface vertex, edge, box corner (0 for a sphere).
    body_b : int or ndarray of int [c]
        Body index of side b, or for static geometry (no side b) the static's index among the
        scene's planes, spheres or meshes (``kind`` tells which).
    feature_b : int or ndarray of int [c]
        Side b's feature: a triangle, edge, corner, or 0.

    Raises
    ------
    InputError
        If a body index reaches :data:`MAX_BODIES` or a feature :data:`MAX_FEATURES`.
    """
    # Scalars are packed as Python ints and arrays once each: this runs for every contact set
    # of every step, mostly on a handful of contacts or none.
    base, arrays = 0, []
    for (name, (shift, bits)), value in zip(_SHIFTS.items(), (kind, body_a, body_b, feature_a, feature_b)):
        if isinstance(value, (int, np.integer)):
            if not 0 <= value < (1 << bits):
                _capacity_error(name, bits, int(value))
            base |= int(value) << shift
            continue
        value = np.asarray(value)
        if value.size == 0:
            return np.zeros(value.shape, np.int64)
        low, high = value.min(), value.max()
        if low < 0 or high >= (1 << bits):
            _capacity_error(name, bits, int(low if low < 0 else high))
        arrays.append((value.astype(np.uint64), np.uint64(shift)))
    if not arrays:
        return np.array(base, np.uint64).view(np.int64)
    key: np.ndarray = np.left_shift(*arrays[0])
    for part, part_shift in arrays[1:]:
        key |= part << part_shift
    key |= np.uint64(base)
    return key.view(np.int64)


def _capacity_error(name: str, bits: int, found: int):
    raise InputError(f"contact {name}", f"an index in [0, {(1 << bits) - 1}] (the contact key's capacity)", str(found))


def unpack_keys(keys) -> dict[str, np.ndarray]:
    """The fields of contact keys [c] (:func:`contact_keys`): ``kind``, ``body_a``, ``body_b``,
    ``feature_a``, ``feature_b``, each int64 [c]."""
    k = np.asarray(keys, np.int64).view(np.uint64)
    return {name: ((k >> np.uint64(shift)) & np.uint64((1 << bits) - 1)).astype(np.int64)
            for name, (shift, bits) in _SHIFTS.items()}


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
        Local area each contact stands for: the smaller of its two primitives' areas (thesis
        4.3.1), each the surface around it projected onto the contact plane (a triangle's own,
        a third of each incident triangle's at vertices and edges:
        :meth:`~softvr.collision.surfaces.CollisionSurface.facing_vertex_area`); 0 when unknown
        (points that are not collision-surface vertices).
    ids : ndarray of int64, shape [contact_count]
        Keys unique in the scene (:func:`contact_keys`: kind, body and feature of both sides),
        the same for the same feature pair on every step: they carry warm starts and adhesion
        intensities from step to step.
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
    area: np.ndarray = field(default=None)  # type: ignore[arg-type]  # None: zeros, set in __post_init__

    def __post_init__(self) -> None:
        if self.area is None:
            self.area = np.zeros(len(self.gap))

    def __len__(self) -> int:
        return len(self.gap)

    def select(self, keep: np.ndarray) -> Contacts:
        """The contacts where ``keep`` [contact_count] (bool or indices) selects."""
        def side(s: ContactSide) -> ContactSide:
            return ContactSide(s.body, s.blocks[keep], s.jac[keep])

        return Contacts(side(self.a), None if self.b is None else side(self.b), self.normal[keep], self.gap[keep],
                        self.point_a[keep], self.point_b[keep], self.ids[keep], self.friction[keep], self.area[keep])


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
