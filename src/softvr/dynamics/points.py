"""Point entities: surface vertices bound to a contact object (thesis 5.1.2).

A point's position is a function of its body's state, ``p = f(q)``, and its velocity is
linear in the body's velocity, ``p_dot = J v``; forces on points become generalized forces
``F_q = J^T F_p``. Render and collision meshes are separate representations whose vertices
are such points (vectorized here: one object holds many points of one body).

* :class:`RigidPoints` on rigid, fixed and kinematic bodies: ``p = c + R r`` with ``r`` in the
  body frame; ``J = [I, -[R r]x]`` for ``v = (linear, angular world)``.
* :class:`EmbeddedPoints` in deformable bodies (FEM nodes, cloth vertices): ``p = sum_i w_i
  q_i`` with barycentric weights of an enclosing tetrahedron (or any fixed node stencil).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from softvr.errors import InputError

__all__ = ["EmbeddedPoints", "RigidPoints", "embed_in_tets"]


def _skew(a: np.ndarray) -> np.ndarray:
    """Cross-product matrices [k, 3, 3] with skew(a) b = a x b."""
    s = np.zeros(a.shape[:-1] + (3, 3))
    s[..., 0, 1], s[..., 0, 2] = -a[..., 2], a[..., 1]
    s[..., 1, 0], s[..., 1, 2] = a[..., 2], -a[..., 0]
    s[..., 2, 0], s[..., 2, 1] = -a[..., 1], a[..., 0]
    return s


class RigidPoints:
    """Points fixed in a rigid (or fixed / kinematic) body.

    Parameters
    ----------
    body : object with ``position`` [3] [m], ``rotation`` [3, 3] and ``v`` [6]
        A :class:`~softvr.dynamics.RigidBody`, ``FixedBody`` or ``KinematicBody``.
    local : array_like, shape [point_count, 3] [m]
        Point positions in the body frame (relative to the centre of mass).
    """

    def __init__(self, body, local):
        r = np.asarray(local, float)
        if r.ndim != 2 or r.shape[1] != 3 or not np.isfinite(r).all():
            raise InputError("local", "finite body-frame points [point_count, 3] [m]", f"shape {r.shape}")
        self.body = body
        self.local = r

    @classmethod
    def from_world(cls, body, points) -> "RigidPoints":
        """Bind world points [point_count, 3] [m] at the body's current pose."""
        p = np.asarray(points, float)
        return cls(body, (p - body.position) @ body.rotation)

    def offsets(self) -> np.ndarray:
        """World-frame offsets ``R r`` [point_count, 3] [m]."""
        return self.local @ self.body.rotation.T

    def positions(self) -> np.ndarray:
        """``p = c + R r`` [point_count, 3] [m]."""
        return self.body.position + self.offsets()

    def velocities(self, v=None) -> np.ndarray:
        """``p_dot = v_lin + w x (R r)`` [point_count, 3] [m/s] for body velocity ``v`` [6] (default current)."""
        v = self.body.v if v is None else np.asarray(v, float)
        return v[:3] + np.cross(v[3:], self.offsets())

    def generalized_forces(self, forces) -> np.ndarray:
        """``J^T F``: total force and torque about the centre of mass, [6] [N, N m]."""
        f = np.asarray(forces, float).reshape(-1, 3)
        return np.concatenate([f.sum(axis=0), np.cross(self.offsets(), f).sum(axis=0)])

    def jacobian(self) -> np.ndarray:
        """``J`` [3 point_count, 6]: rows of point velocity, columns of body velocity."""
        k = len(self.local)
        j = np.zeros((k, 3, 6))
        j[:, :, :3] = np.eye(3)
        j[:, :, 3:] = -_skew(self.offsets())
        return j.reshape(3 * k, 6)


class EmbeddedPoints:
    """Points interpolated from the nodes of a deformable body: ``p = sum_i w_i q_i``.

    Parameters
    ----------
    body : object with ``q`` and ``v`` of shape [node_count, 3]
        A :class:`~softvr.dynamics.FemBody` or cloth body.
    nodes : array_like of int, shape [point_count, k]
        Node stencil of each point (4 tet nodes for embedding, 1 for a node itself).
    weights : array_like, shape [point_count, k]
        Interpolation weights (barycentric coordinates), summing to 1 per point.
    """

    def __init__(self, body, nodes, weights):
        idx = np.asarray(nodes)
        w = np.asarray(weights, float)
        n = len(body.q)
        if idx.ndim != 2 or w.shape != idx.shape:
            raise InputError("weights", f"an array of the nodes' shape {idx.shape}", f"shape {w.shape}")
        if not np.issubdtype(idx.dtype, np.integer) or (idx < 0).any() or (idx >= n).any():
            raise InputError("nodes", f"node indices in [0, {n - 1}]", f"range {idx.min()}..{idx.max()}")
        off = np.abs(w.sum(axis=1) - 1.0) > 1e-6
        if off.any() or not np.isfinite(w).all():
            e = int(np.argmax(off | ~np.isfinite(w).all(axis=1)))
            raise InputError(f"weights[{e}]", "finite weights summing to 1", str(w[e].tolist()))
        self.body = body
        self.nodes = idx
        self.weights = w

    def positions(self) -> np.ndarray:
        """``p = sum w_i q_i`` [point_count, 3] [m]."""
        return np.einsum("pk,pkc->pc", self.weights, self.body.q[self.nodes])

    def velocities(self, v=None) -> np.ndarray:
        """``p_dot = sum w_i v_i`` [point_count, 3] [m/s] for node velocities ``v`` (default current)."""
        v = self.body.v if v is None else np.asarray(v, float).reshape(-1, 3)
        return np.einsum("pk,pkc->pc", self.weights, v[self.nodes])

    def generalized_forces(self, forces) -> np.ndarray:
        """``J^T F``: node forces [node_count, 3] [N] from point forces [point_count, 3]."""
        f = np.asarray(forces, float).reshape(-1, 3)
        out = np.zeros_like(self.body.q, dtype=float)
        np.add.at(out, self.nodes.ravel(), (self.weights[:, :, None] * f[:, None, :]).reshape(-1, 3))
        return out

    def jacobian(self) -> sp.csr_matrix:
        """``J`` sparse [3 point_count, 3 node_count]: blocks ``w_i I`` at the stencil nodes."""
        p, k = self.nodes.shape
        rows = (3 * np.arange(p)[:, None, None] + np.arange(3)[None, None, :]).repeat(k, axis=1)
        cols = 3 * self.nodes[:, :, None] + np.arange(3)
        vals = np.broadcast_to(self.weights[:, :, None], rows.shape)
        return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * p, 3 * len(self.body.q)))


def embed_in_tets(nodes, tets, points, *, tolerance: float = 1e-6, candidates: int = 16):
    """Barycentric embedding of points in a tetrahedral mesh (thesis 5.1.2, 5.2.2).

    Each point gets the tet that contains it (the one whose smallest barycentric coordinate
    is largest). Points outside the mesh by more than ``tolerance`` (in barycentric units)
    are rejected, naming the first one.

    Parameters
    ----------
    nodes : ndarray, shape [node_count, 3] [m]
    tets : ndarray, shape [tet_count, 4]
    points : ndarray, shape [point_count, 3] [m]
    tolerance : float
        Allowed negative barycentric coordinate (points on or just outside the hull).
    candidates : int
        Tets tried per point, nearest centroids first; all tets are tried for points that
        none of those contains.

    Returns
    -------
    tet_index : ndarray of int, shape [point_count]
    weights : ndarray, shape [point_count, 4]
        Barycentric coordinates in ``tets[tet_index]``.
    """
    x = np.asarray(nodes, float)
    t = np.asarray(tets)
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
        raise InputError("points", "finite points [point_count, 3] [m]", f"shape {p.shape}")
    corner = x[t]
    inv = np.linalg.inv((corner[:, 1:] - corner[:, :1]).transpose(0, 2, 1))

    def bary(tet_idx, pts):
        lam = np.einsum("...ij,...j->...i", inv[tet_idx], pts - corner[tet_idx, 0])
        return np.concatenate([1.0 - lam.sum(axis=-1, keepdims=True), lam], axis=-1)

    k = min(candidates, len(t))
    _, near = cKDTree(corner.mean(axis=1)).query(p, k=k)
    near = near.reshape(len(p), k)
    b = bary(near, p[:, None, :])
    best = b.min(axis=-1).argmax(axis=1)
    tet_index = near[np.arange(len(p)), best]
    weights = b[np.arange(len(p)), best]
    missed = np.flatnonzero(weights.min(axis=1) < -tolerance)
    for i in missed:  # slow path: every tet
        all_b = bary(np.arange(len(t)), np.broadcast_to(p[i], (len(t), 3)))
        j = int(all_b.min(axis=1).argmax())
        tet_index[i], weights[i] = j, all_b[j]
    outside = weights.min(axis=1) < -tolerance
    if outside.any():
        bad = int(np.argmax(outside))
        raise InputError(f"points[{bad}]", "a point inside the tetrahedral mesh",
                         f"{p[bad].tolist()}, outside by barycentric {weights[bad].min():.3g} "
                         f"({int(outside.sum())} such points)")
    return tet_index, weights
