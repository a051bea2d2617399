"""Deforming triangle surfaces of two bodies: vertex-triangle contacts, discrete and swept.

Each body's collision surface is a triangle mesh whose vertices are point entities of the body
(thesis 5.1.2). Every step its Warp BVH is refitted to the current vertex positions; the
vertices of one surface are then queried against the other's triangles: within the contact
margin (closest point) or, sweeping the vertex over its motion relative to the other body
during the step, at the first crossing (CCD). The contact point on the triangle moves with the
three triangle vertices' stencils (barycentric), so the two sides' impulses are equal and
opposite. Edge-edge contacts are in :mod:`softvr.collision.edges`.
"""

from __future__ import annotations

from typing import no_type_check

import numpy as np
import warp as wp

from softvr.collision.contacts import ContactKind, Contacts, ContactSide, contact_keys, point_jacobian_blocks, stencil_side
from softvr.collision.edges import EdgeSet
from softvr.collision.mesh import query_points
from softvr.device import resolve_device, upload
from softvr.errors import InputError

__all__ = ["CollisionSurface", "surface_vs_surface"]


class CollisionSurface:
    """The collision mesh of one body: triangles over point entities.

    Parameters
    ----------
    body_index : int
    points : RigidPoints or EmbeddedPoints
        One point entity per surface vertex.
    triangles : array_like, shape [triangle_count, 3]
        A closed, outward-oriented surface over those vertices (vertices of the other body
        inside it are pushed out along the outward normal). An open one (border edges: a
        cloth) touches with both sides (:attr:`two_sided`, for the contact areas).
    device : str, optional
    """

    def __init__(self, body_index: int, points, triangles, *, device: str | None = None):
        t = np.asarray(triangles)
        n = len(points.positions())
        if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0 or t.min() < 0 or t.max() >= n:
            raise InputError("collision_triangles", f"[triangle_count, 3] vertex indices in [0, {n - 1}]",
                             f"shape {t.shape}")
        self.body_index = body_index
        self.points = points
        self.triangles = t.astype(np.int32)
        self.device = resolve_device(device)
        self._vertices: wp.array = wp.array(points.positions(), dtype=wp.vec3, device=self.device)
        self._mesh = wp.Mesh(points=self._vertices, indices=wp.array(self.triangles.ravel(), dtype=wp.int32,
                                                                      device=self.device))
        self.edge_set = EdgeSet(self.triangles, points.positions(), self.device)
        # Vertex -> incident triangles (CSR), so that a contact's vertex area is summed over its
        # triangles without a loop: triangles of vertex v are _vertex_faces[_vertex_first[v]:][:_incident[v]].
        self._incident = np.bincount(self.triangles.ravel(), minlength=n)
        self._vertex_faces = np.argsort(self.triangles.ravel(), kind="stable") // 3
        self._vertex_first = np.concatenate([[0], np.cumsum(self._incident)[:-1]])
        # A closed surface touches only with its outside; an open one (a cloth, a lone face) has
        # no inside, and either of its sides can touch.
        self.two_sided = bool((self.edge_set.adjacent[:, 1] < 0).any())
        self._query_buffers: dict[int, tuple] = {}  # this surface's vertex queries reuse their outputs
        self._locate_buffers: dict[int, tuple] = {}  # and the closest-face queries on it theirs
        self._update_areas(points.positions())

    def refit(self) -> None:
        """Move the triangle and edge BVHs (and the triangle areas and normals) to the current vertex positions."""
        p = self.points.positions()
        upload(self._vertices, p)
        self._mesh.refit()
        self.edge_set.refit(p)
        self._update_areas(p)

    def _update_areas(self, p: np.ndarray) -> None:
        """Triangle areas ``triangle_area`` [triangle_count] [m^2] and unit normals
        ``triangle_normal`` [triangle_count, 3] (0 for a degenerate triangle) at vertex
        positions ``p`` [vertex_count, 3] [m]."""
        v = p[self.triangles]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        size = np.linalg.norm(n, axis=1)
        self.triangle_area = 0.5 * size
        self.triangle_normal = n / np.maximum(size, 1e-300)[:, None]

    def _facing(self, faces: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Projected area [k] [m^2] of triangles ``faces`` [k] on planes of unit normals
        ``normals`` [k, 3] pointing from the other side of each contact into this surface:
        A_t |n_t . n| on a two-sided surface, and on a closed one only its outside facing the
        contact, A_t max(-n_t . n, 0) (the faces turned away project onto the same patch of the
        contact plane from behind, and would count it twice)."""
        cosine = np.einsum("kx,kx->k", self.triangle_normal[faces], normals)
        return self.triangle_area[faces] * (np.abs(cosine) if self.two_sided else np.maximum(-cosine, 0.0))

    def facing_vertex_area(self, vertices, normals) -> np.ndarray:
        """Contact area of vertices: their share of the surface projected onto each contact plane.

        Every triangle gives a third of its area to each of its vertices, projected onto the
        contact plane (:meth:`_facing`): a flat grid's vertex areas sum to its area at any
        resolution, and a vertex on a crease carries only the faces that meet the contact (the
        bottom rim of a closed box, not its sides). Departs from the thesis' mean of the
        incident triangles' areas (4.3.1), which made the pull-off force depend on the mesh
        (docs/adhesion.md).

        Parameters
        ----------
        vertices : array_like of int, shape [c]
            Surface vertices in contact.
        normals : array_like, shape [c, 3]
            Unit contact normals, pointing from the other side into this surface's body.

        Returns
        -------
        ndarray, shape [c] [m^2]
            0 for a vertex without triangles.
        """
        vertices = np.asarray(vertices, np.int64)
        counts = self._incident[vertices]
        row = np.repeat(np.arange(len(vertices)), counts)  # the contact of each (contact, triangle) pair
        # Position of each pair in the CSR: its vertex's first slot plus its rank within the contact.
        slot = np.arange(len(row)) + np.repeat(self._vertex_first[vertices] - (np.cumsum(counts) - counts), counts)
        faces = self._vertex_faces[slot]
        share = self._facing(faces, np.asarray(normals, float).reshape(-1, 3)[row]) / 3.0
        return np.bincount(row, weights=share, minlength=len(vertices))

    def facing_edge_area(self, edges, normals) -> np.ndarray:
        """Contact area [c] [m^2] of edges [c] (indices into ``edge_set.edges``): a third of each
        adjacent triangle's area projected onto the contact plane of unit normal ``normals``
        [c, 3] (pointing into this surface's body), as :meth:`facing_vertex_area`."""
        edges = np.asarray(edges, np.int64)
        normals = np.asarray(normals, float).reshape(-1, 3)
        first, second = self.edge_set.adjacent[edges].T
        border = second < 0  # one triangle: an open border
        area = self._facing(first, normals) + np.where(border, 0.0, self._facing(np.maximum(second, 0), normals))
        return area / 3.0


def surface_vs_surface(a: CollisionSurface, b: CollisionSurface, *, margin: float, friction: float = 0.5,
                       dt: float = 0.0, ccd: bool = True, velocities_a=None, velocities_b=None) -> Contacts:
    """Contacts of a's vertices with b's triangles (normal from b towards a).

    ``velocities_a`` [vertex_count_a, 3] and ``velocities_b`` [vertex_count_b, 3] [m/s] are the
    unconstrained vertex velocities of the step; the sweep uses a's motion relative to b's
    (b's mean surface velocity, exact for translating b).
    """
    p = a.points.positions()
    motion = np.zeros_like(p)
    if velocities_a is not None and dt > 0:
        rel = np.asarray(velocities_a, float)
        if velocities_b is not None:
            rel = rel - np.asarray(velocities_b, float).mean(axis=0)
        motion = rel * dt
    which, normal, gap, at = query_points(b._mesh.id, b.device, p, motion, margin, 0.0, ccd, closed=True,
                                          buffers=a._query_buffers)
    faces, bary = _locate(b, at)
    side_a = ContactSide(a.body_index, *point_jacobian_blocks(a.points, which))
    # A vertex has one contact per surface (closest point or first crossing), so the vertex
    # names it; the triangle under it changes as it slides, and must not restart its adhesion.
    ids = contact_keys(ContactKind.VERTEX_TRIANGLE, a.body_index, which, b.body_index, 0)
    # Local area: the vertex's, projected onto the contact plane (the normal points into a).
    # Not the smaller of it and its triangle's (thesis 4.3.1): on a face-to-face patch each way's
    # vertex areas tile the patch, and one way bonds (softvr.contact.AdhesionState.stiffnesses).
    area = a.facing_vertex_area(which, normal)
    return Contacts(side_a, stencil_side(b.body_index, b.points, b.triangles[faces], bary), normal, gap, p[which], at, ids,
                    np.full(len(which), float(friction)), area)


def _locate(surface: CollisionSurface, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangle and barycentric coordinates [c, 3] of surface points (closest-point queries)."""
    if len(at) == 0:
        return np.zeros(0, int), np.zeros((0, 3))
    n = len(at)
    buffers = surface._locate_buffers
    if n not in buffers:
        if len(buffers) > 16:  # many contact counts: forget the old ones
            buffers.clear()
        buffers[n] = (wp.empty(n, dtype=wp.vec3, device=surface.device),
                      wp.empty(n, dtype=wp.int32, device=surface.device), wp.empty(n, dtype=wp.vec2, device=surface.device))
    points, out_face, out_uv = buffers[n]  # the kernel writes every entry
    upload(points, at)
    wp.launch(_closest_face, dim=n, device=surface.device, inputs=[surface._mesh.id, points, out_face, out_uv])
    uv = out_uv.numpy().astype(float)
    return out_face.numpy(), np.column_stack([uv[:, 0], uv[:, 1], 1.0 - uv[:, 0] - uv[:, 1]])


@wp.kernel
@no_type_check  # Warp's annotations (wp.array(dtype=...)) are not Python types
def _closest_face(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), face: wp.array(dtype=wp.int32),
                  uv: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    q = wp.mesh_query_point_no_sign(mesh, points[i], 1.0e6)
    face[i] = q.face
    uv[i] = wp.vec2(q.u, q.v)
