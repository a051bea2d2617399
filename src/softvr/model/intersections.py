"""Which triangles of two surfaces cross each other (the collision-free start's check, 5.2.3)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from softvr.errors import InputError

__all__ = ["intersecting_triangle_pairs"]


def _segments_cross_triangles(p0, p1, tri) -> np.ndarray:
    """Per row: does segment p0-p1 [k, 3] cross triangle tri [k, 3, 3] (Moller-Trumbore, ends
    and edges included, parallel segments not)?"""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d = p1 - p0
    h = np.cross(d, e2)
    det = np.einsum("ki,ki->k", e1, h)
    ok = np.abs(det) > 1e-15 * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1) * np.linalg.norm(d, axis=1)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p0 - tri[:, 0]
    u = inv * np.einsum("ki,ki->k", s, h)
    q = np.cross(s, e1)
    v = inv * np.einsum("ki,ki->k", d, q)
    t = inv * np.einsum("ki,ki->k", e2, q)
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def intersecting_triangle_pairs(vertices_a, triangles_a, vertices_b, triangles_b) -> np.ndarray:
    """Pairs (triangle of a, triangle of b) [k, 2] that cross: an edge of one passes through
    the other. Candidates are pairs whose bounding spheres overlap. Coplanar overlaps are not
    reported (they have no crossing edge)."""
    sides = []
    for name, v, t in (("a", vertices_a, triangles_a), ("b", vertices_b, triangles_b)):
        v, t = np.asarray(v, float), np.asarray(t)
        if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3 or (len(t) and t.max() >= len(v)):
            raise InputError(f"surface {name}", "vertices [n, 3] and triangles [t, 3] indexing them",
                             f"shapes {v.shape}, {t.shape}")
        tri = v[t]
        centre = tri.mean(axis=1)
        radius = np.linalg.norm(tri - centre[:, None], axis=2).max(axis=1) if len(t) else np.zeros(0)
        sides.append((tri, centre, radius))
    (ta, ca, ra), (tb, cb, rb) = sides
    if not len(ta) or not len(tb):
        return np.zeros((0, 2), int)
    near = cKDTree(cb).query_ball_point(ca, ra + rb.max())
    i = np.repeat(np.arange(len(ta)), [len(n) for n in near])
    j = np.concatenate([np.asarray(n, int) for n in near]) if len(i) else np.zeros(0, int)
    close = np.linalg.norm(ca[i] - cb[j], axis=1) <= ra[i] + rb[j]
    i, j = i[close], j[close]
    crossing = np.zeros(len(i), bool)
    for k in range(3):
        crossing |= _segments_cross_triangles(ta[i, k], ta[i, (k + 1) % 3], tb[j])
        crossing |= _segments_cross_triangles(tb[j, k], tb[j, (k + 1) % 3], ta[i])
    return np.stack([i[crossing], j[crossing]], axis=1)
