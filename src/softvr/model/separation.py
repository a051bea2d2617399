"""A collision-free start for parts that intersect at rest (thesis 5.2.3).

Modelled anatomy overlaps: a ligament's surface dips into the bone it wraps. The thesis
deforms each tet mesh with a cage (mean value coordinates) until the collision meshes are
apart, and starts the simulation from that deformed state. :func:`push_apart` does the
equivalent relaxation on the part's own tet mesh: the surface vertices inside the obstacle
(or closer than ``margin``) must move out along the obstacle's outward normal; the node
displacement ``u`` that does so most smoothly solves

    (L + w W_p^T W_p + eps I) u = w W_p^T delta,

with ``L`` the graph Laplacian of the tet edges (smoothness), ``W_p`` the barycentric rows of
the penetrating vertices and ``delta`` their push-out, ``eps`` keeping far nodes in place
(a screened, local bulge). Repeated until no vertex is inside and no triangles cross, or the
iteration budget is spent; the crossing pairs that remain are reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from softvr.collision import TriangleMesh
from softvr.errors import InputError
from softvr.model.intersections import intersecting_triangle_pairs

__all__ = ["SeparationReport", "push_apart"]


@dataclass
class SeparationReport:
    """What :func:`push_apart` did.

    Attributes
    ----------
    iterations : int
    vertices_inside : int
        Surface vertices still inside the obstacle (or within the margin) at the end.
    crossing_pairs : ndarray of int, shape [k, 2]
        Triangle pairs (part, obstacle) that still cross at the end.
    max_displacement : float [m]
        Largest node displacement.
    """

    iterations: int
    vertices_inside: int
    crossing_pairs: np.ndarray
    max_displacement: float

    @property
    def clean(self) -> bool:
        return self.vertices_inside == 0 and len(self.crossing_pairs) == 0


def _tet_laplacian(node_count: int, tets: np.ndarray) -> sp.csr_matrix:
    pairs = np.concatenate([tets[:, [a, b]] for a in range(4) for b in range(a + 1, 4)])
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    adjacency = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(node_count, node_count))
    adjacency = (adjacency + adjacency.T).tocsr()
    return (sp.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()


def push_apart(nodes, tets, embedding, surface_triangles, obstacle_vertices, obstacle_triangles, *,
               margin: float = 1e-4, iterations: int = 20, locality: float = 0.05):
    """Deform a part's tet mesh until its surface is out of a closed obstacle (module docstring).

    Parameters
    ----------
    nodes : ndarray, shape [node_count, 3] [m]
    tets : ndarray, shape [tet_count, 4]
    embedding : (tet_index [n], weights [n, 4])
        The part's surface vertices in its tets (:func:`softvr.model.embed_surface`).
    surface_triangles : ndarray, shape [t, 3]
        The part's surface over those vertices.
    obstacle_vertices, obstacle_triangles
        The closed, outward surface to get out of (held fixed).
    margin : float [m]
        Clearance to leave.
    iterations : int
    locality : float
        ``eps`` relative to the Laplacian's mean diagonal: the bulge fades over about
        ``1 / sqrt(locality)`` tet edges (4-5 by default).

    Returns
    -------
    nodes : ndarray, shape [node_count, 3] [m]
        The deformed nodes (the surface follows through the embedding).
    report : SeparationReport
    """
    x0 = np.asarray(nodes, float)
    t = np.asarray(tets)
    index, weights = embedding
    if len(index) != len(weights) or np.asarray(weights).shape[1:] != (4,):
        raise InputError("embedding", "(tet_index [n], weights [n, 4])", f"{np.shape(index)}, {np.shape(weights)}")
    if not (np.isfinite(margin) and margin >= 0):
        raise InputError("margin", "a clearance >= 0 [m]", repr(margin))
    n = len(x0)
    rows = np.repeat(np.arange(len(index)), 4)
    w_all = sp.csr_matrix((np.asarray(weights, float).ravel(), (rows, t[index].ravel())), shape=(len(index), n))
    obstacle = TriangleMesh(np.asarray(obstacle_vertices, float), np.asarray(obstacle_triangles))
    laplacian = _tet_laplacian(n, t)
    scale = float(laplacian.diagonal().mean())
    x = x0.copy()
    done = 0
    for done in range(1, iterations + 1):
        surface = w_all @ x
        distance, normal = obstacle.signed_distance(surface, normals=True)
        inside = np.flatnonzero(distance < margin)
        if not len(inside):
            break
        w_p = w_all[inside]
        # Push a little past the margin so that the next round's linearization lands outside.
        delta = (1.5 * margin - distance[inside])[:, None] * normal[inside]
        penalty = 10.0 * scale
        system = (laplacian + penalty * (w_p.T @ w_p) + locality * scale * sp.identity(n)).tocsc()
        solve = spla.factorized(system)
        rhs = penalty * (w_p.T @ delta)
        u = np.column_stack([solve(rhs[:, k]) for k in range(3)])
        x = x + u
    surface = w_all @ x
    distance = obstacle.signed_distance(surface)
    pairs = intersecting_triangle_pairs(surface, surface_triangles, obstacle.vertices, obstacle.triangles)
    report = SeparationReport(iterations=done, vertices_inside=int((distance < 0).sum()), crossing_pairs=pairs,
                              max_displacement=float(np.linalg.norm(x - x0, axis=1).max()))
    return x, report
