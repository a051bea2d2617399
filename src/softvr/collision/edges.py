"""Edge-edge contacts between the deforming collision surfaces of two bodies.

Vertex-triangle tests (:mod:`softvr.collision.surfaces`) miss two edges that cross while no
vertex meets a face: two boxes edge on edge, a cloth fold over a ridge. Here every edge of
surface a is tested against the edges of surface b that its box (grown by the contact margin
and the step's relative motion) overlaps in a Warp BVH over b's edges, refitted every step.

Only pairs with a crease on at least one side are tested (two nearly flat edges cannot cross
while the vertices around them stay outside the other surface). For a pair whose closest
points lie inside both edges (the end regions belong to the
vertex-triangle contacts) the contact normal is ``e_a x e_b``, turned to point out of b (the
side of the mean normal of b's faces at its edge), and the gap is the distance of the closest
points along it, negative once the edges have crossed. Nearly parallel edges, and pairs whose
normal is not close to both surfaces' normals at the edges, are left to vertex-triangle
contacts (there the cross product has no reliable direction, or points along a surface).

Continuous detection is speculative: a pair whose grown boxes meet gets a contact with the
gap at the start of the step, and the velocity constraint ``n . (p_dot_a - p_dot_b) >= -gap/dt``
keeps the edges from crossing during the step to first order.
"""

from __future__ import annotations

from typing import no_type_check

import numpy as np
import warp as wp

from softvr.collision.contacts import ContactKind, Contacts, contact_keys, stencil_side
from softvr.device import load_kernels, upload

__all__ = ["EdgeSet", "edge_pair", "edges_vs_edges", "surface_edges"]

#: Pairs whose edges make less than this angle [rad] are left to vertex-triangle contacts.
MIN_EDGE_ANGLE = np.radians(10.0)
#: The normal e_a x e_b must point within acos(this) of b's mean edge normal, and against a's:
#: on a flat patch of b, or beside a steep edge of a, e_a x e_b lies along the surface and
#: would push sideways (and two such contacts can contradict each other).
MIN_NORMAL_ALIGNMENT = 0.5
#: Edges whose two triangles meet at more than this angle [rad] are creases (and open borders):
#: a pair of edges needs a crease on one side to cross without a vertex meeting a face; pairs
#: of smooth (nearly flat) edges only repeat the vertex-triangle contacts around them.
SHARP_EDGE_ANGLE = np.radians(30.0)
#: Candidate pairs kept per edge of a (the closest are not sorted: first found).
PAIRS_PER_EDGE = 2


def surface_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique edges [edge_count, 2] of a triangle mesh and their adjacent triangles
    [edge_count, 2] (-1 where an edge has one triangle, on an open border)."""
    t = np.asarray(triangles)
    pairs = np.stack([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]], axis=1).reshape(-1, 2)
    faces = np.repeat(np.arange(len(t)), 3)
    key = np.sort(pairs, axis=1)
    edges, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    adjacent = np.full((len(edges), 2), -1)
    adjacent[:, 0] = faces[first]
    second = np.ones(len(faces), bool)
    second[first] = False
    adjacent[inverse[second], 1] = faces[second]
    return edges, adjacent


class EdgeSet:
    """Edges of a collision surface with a BVH over their boxes (refitted per step).

    Parameters
    ----------
    triangles : ndarray, shape [triangle_count, 3]
    vertices : ndarray, shape [vertex_count, 3] [m]
        Initial vertex positions.
    device : str
    """

    def __init__(self, triangles: np.ndarray, vertices: np.ndarray, device: str):
        self.triangles = np.asarray(triangles, np.int32)
        self.edges, self.adjacent = surface_edges(self.triangles)
        self.device = device
        lower, upper = self._boxes(vertices)
        self._lower: wp.array = wp.array(lower, dtype=wp.vec3, device=device)
        self._upper: wp.array = wp.array(upper, dtype=wp.vec3, device=device)
        self._bvh = wp.Bvh(self._lower, self._upper)
        self.edges_wp: wp.array = wp.array(self.edges.astype(np.int32), dtype=wp.int32, device=device)
        self._pairs = None
        self.vertices_wp: wp.array = wp.empty(len(vertices), dtype=wp.vec3, device=device)
        self.normals_wp: wp.array = wp.empty(len(self.edges), dtype=wp.vec3, device=device)
        self.sharp_wp: wp.array = wp.empty(len(self.edges), dtype=wp.int32, device=device)
        self.reach_wp: wp.array = wp.empty(len(self.edges), dtype=float, device=device)
        self._upload(vertices)

    def _upload(self, vertices: np.ndarray) -> None:
        """Edge normals, crease flags and the vertices, as the kernels read them this step."""
        self.normals, self.sharp = self.edge_normals(vertices)
        upload(self.vertices_wp, vertices)
        upload(self.normals_wp, self.normals)
        upload(self.sharp_wp, self.sharp)

    def pair_outputs(self):
        """The edge-pair kernel's outputs for this set as side a (kept between calls): pair
        edge (reset to -1: no pair), (s, t), normal, gap, each [edge_count, PAIRS_PER_EDGE]."""
        if self._pairs is None:
            shape = (len(self.edges), PAIRS_PER_EDGE)
            self._pairs = (wp.empty(shape, dtype=wp.int32, device=self.device),
                           wp.empty(shape, dtype=wp.vec2, device=self.device),
                           wp.empty(shape, dtype=wp.vec3, device=self.device),
                           wp.empty(shape, dtype=float, device=self.device))
        self._pairs[0].fill_(-1)
        return self._pairs

    def _boxes(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ends = np.asarray(vertices, float)[self.edges]
        return ends.min(axis=1), ends.max(axis=1)

    def refit(self, vertices: np.ndarray) -> None:
        """Move the BVH, the edge normals and the crease flags to vertex positions
        [vertex_count, 3] [m]."""
        self._upload(vertices)
        lower, upper = self._boxes(vertices)
        upload(self._lower, lower)
        upload(self._upper, upper)
        self._bvh.refit()

    def edge_normals(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit mean normal [edge_count, 3] of the (one or two) triangles at each edge, and
        which edges are creases (bool [edge_count]: faces at more than SHARP_EDGE_ANGLE, or a border)."""
        v = np.asarray(vertices, float)[self.triangles]
        face_n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        face_n /= np.maximum(np.linalg.norm(face_n, axis=1, keepdims=True), 1e-300)
        border = self.adjacent[:, 1] < 0
        first, second = face_n[self.adjacent[:, 0]], face_n[self.adjacent[:, 1]]
        sharp = border | (np.einsum("ex,ex->e", first, second) < np.cos(SHARP_EDGE_ANGLE))
        n = first + np.where(border[:, None], 0.0, second)
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300), sharp


@wp.func
@no_type_check  # Warp's vector types are not indexable to mypy
def edge_pair(p1: wp.vec3, q1: wp.vec3, p2: wp.vec3, q2: wp.vec3, normal_a: wp.vec3, normal_b: wp.vec3,
              reach: float, min_sine: float, min_alignment: float):
    """The test of edge a (p1, q1) against edge b (p2, q2) [m] (module docstring): whether they
    make a contact, the closest points' parameters s, t along them, the normal (out of b) and
    the gap [m] along it."""
    st = wp.closest_point_edge_edge(p1, q1, p2, q2, 1.0e-9)
    s = st[0]
    t = st[1]
    ea = q1 - p1
    eb = q2 - p2
    n = wp.cross(ea, eb)
    size = wp.length(n)
    interior = s > 1.0e-3 and s < 1.0 - 1.0e-3 and t > 1.0e-3 and t < 1.0 - 1.0e-3
    aligned = int(0)
    gap = float(0.0)
    if interior and st[2] <= reach and size > min_sine * wp.length(ea) * wp.length(eb):
        n = n / size
        if wp.dot(n, normal_b) < 0.0:
            n = -n
        if wp.dot(n, normal_b) >= min_alignment and -wp.dot(n, normal_a) >= min_alignment:
            aligned = 1
            gap = wp.dot((p1 + s * ea) - (p2 + t * eb), n)
    return aligned, s, t, n, gap


@wp.kernel
@no_type_check  # Warp's annotations (wp.array(dtype=...)) are not Python types
def _edge_pairs(bvh: wp.uint64, verts_a: wp.array(dtype=wp.vec3), edges_a: wp.array2d(dtype=wp.int32),
                reach_a: wp.array(dtype=float), normals_a: wp.array(dtype=wp.vec3), sharp_a: wp.array(dtype=wp.int32),
                verts_b: wp.array(dtype=wp.vec3), edges_b: wp.array2d(dtype=wp.int32),
                normals_b: wp.array(dtype=wp.vec3), sharp_b: wp.array(dtype=wp.int32), min_sine: float,
                min_alignment: float, pair_edge: wp.array2d(dtype=wp.int32),
                pair_st: wp.array2d(dtype=wp.vec2), pair_normal: wp.array2d(dtype=wp.vec3),
                pair_gap: wp.array2d(dtype=float)):
    i = wp.tid()
    p1 = verts_a[edges_a[i, 0]]
    q1 = verts_a[edges_a[i, 1]]
    reach = reach_a[i]
    grow = wp.vec3(reach, reach, reach)
    query = wp.bvh_query_aabb(bvh, wp.min(p1, q1) - grow, wp.max(p1, q1) + grow)
    j = int(0)
    found = int(0)
    while wp.bvh_query_next(query, j):
        if found < pair_edge.shape[1] and (sharp_a[i] != 0 or sharp_b[j] != 0):
            aligned, s, t, n, gap = edge_pair(p1, q1, verts_b[edges_b[j, 0]], verts_b[edges_b[j, 1]], normals_a[i],
                                              normals_b[j], reach, min_sine, min_alignment)
            if aligned != 0:
                pair_edge[i, found] = j
                pair_st[i, found] = wp.vec2(s, t)
                pair_normal[i, found] = n
                pair_gap[i, found] = gap
                found += 1


def edges_vs_edges(a, b, *, margin: float, friction: float = 0.5, dt: float = 0.0, velocities_a=None,
                   velocities_b=None) -> Contacts:
    """Edge-edge contacts of collision surfaces ``a`` and ``b`` (normal from b towards a).

    Parameters
    ----------
    a, b : CollisionSurface
        Refitted to this step's positions (edge normals and creases are the refit's).
    margin : float [m]
        Proximity within which edge pairs become contacts.
    friction : float
    dt : float [s]
    velocities_a, velocities_b : ndarray, shape [vertex_count, 3] [m/s], optional
        Unconstrained vertex velocities: each edge's reach grows by its vertices' largest
        displacement over the step relative to b's mean motion (speculative CCD).
    """
    pa, pb = a.points.positions(), b.points.positions()
    ea, eb = a.edge_set, b.edge_set
    reach = np.full(len(ea.edges), float(margin))
    if dt > 0 and velocities_a is not None:
        rel = np.asarray(velocities_a, float)
        if velocities_b is not None:
            rel = rel - np.asarray(velocities_b, float).mean(axis=0)
        reach += dt * np.linalg.norm(rel, axis=1)[ea.edges].max(axis=1)
    device = b.device
    load_kernels(_edge_pairs, device)
    pair_edge, pair_st, pair_normal, pair_gap = ea.pair_outputs()
    upload(ea.reach_wp, reach)
    wp.launch(_edge_pairs, dim=len(ea.edges), device=device,
              inputs=[eb._bvh.id, ea.vertices_wp, ea.edges_wp, ea.reach_wp,
                      ea.normals_wp, ea.sharp_wp, eb.vertices_wp, eb.edges_wp, eb.normals_wp, eb.sharp_wp,
                      float(np.sin(MIN_EDGE_ANGLE)), float(MIN_NORMAL_ALIGNMENT), pair_edge, pair_st, pair_normal,
                      pair_gap])
    edge_b = pair_edge.numpy()
    edge_a, slot = np.nonzero(edge_b >= 0)
    # The motion-grown reach speculates on edges that are apart; an edge "behind" another by
    # more than the margin is a pair seen from the wrong side (thin parts, an edge across a
    # body), not a penetration to undo in one step: vertex-triangle contacts cover real depth.
    deep = pair_gap.numpy()[edge_a, slot] < -margin
    edge_a, slot = edge_a[~deep], slot[~deep]
    edge_b = edge_b[edge_a, slot]
    st = pair_st.numpy()[edge_a, slot].astype(float)
    normal = pair_normal.numpy()[edge_a, slot].astype(float)
    gap = pair_gap.numpy()[edge_a, slot].astype(float)
    weights_a = np.column_stack([1.0 - st[:, 0], st[:, 0]])
    weights_b = np.column_stack([1.0 - st[:, 1], st[:, 1]])
    verts_a, verts_b = ea.edges[edge_a], eb.edges[edge_b]
    point_a = np.einsum("ck,ckx->cx", weights_a, pa[verts_a])
    point_b = np.einsum("ck,ckx->cx", weights_b, pb[verts_b])
    # An edge of a meets up to PAIRS_PER_EDGE edges of b: both edges name the contact.
    ids = contact_keys(ContactKind.EDGE_EDGE, a.body_index, edge_a, b.body_index, edge_b)
    return Contacts(stencil_side(a.body_index, a.points, verts_a, weights_a),
                    stencil_side(b.body_index, b.points, verts_b, weights_b), normal, gap,
                    point_a, point_b, ids, np.full(len(gap), float(friction)),
                    # the smaller edge's area (4.3.1), each projected onto the contact plane
                    np.minimum(a.facing_edge_area(edge_a, normal), b.facing_edge_area(edge_b, -normal)))
