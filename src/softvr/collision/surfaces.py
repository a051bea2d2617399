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

import numpy as np
import warp as wp

from softvr.collision.contacts import ContactKind, Contacts, ContactSide, contact_keys, point_jacobian_blocks, stencil_side
from softvr.collision.edges import EdgeSet
from softvr.collision.mesh import query_points
from softvr.device import resolve_device
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
        inside it are pushed out along the outward normal).
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
        self._vertices = wp.array(points.positions(), dtype=wp.vec3, device=self.device)
        self._mesh = wp.Mesh(points=self._vertices, indices=wp.array(self.triangles.ravel(), dtype=wp.int32,
                                                                      device=self.device))
        self.edge_set = EdgeSet(self.triangles, points.positions(), self.device)
        self._incident = np.bincount(self.triangles.ravel(), minlength=n)  # triangles per vertex
        self._query_buffers = {}  # this surface's vertex queries reuse their output arrays
        self._update_areas(points.positions())

    def refit(self) -> None:
        """Move the triangle and edge BVHs (and the primitive areas) to the current vertex positions."""
        p = self.points.positions()
        self._vertices.assign(wp.array(p, dtype=wp.vec3, device=self.device))
        self._mesh.refit()
        self.edge_set.refit(p)
        self._update_areas(p)

    def _update_areas(self, p: np.ndarray) -> None:
        """Local contact areas of the primitives (thesis 4.3.1, with lumped vertex and edge areas).

        A triangle stands for its own area. Every triangle gives a third of its area to each of
        its vertices and a third to each of its edges, so that vertex areas, and edge areas, each
        sum to the surface's area at any resolution. The thesis' mean of the incident
        triangles' areas does not: on a regular grid it counts every interior vertex at half its
        share (a 10 x 10 face of 100 cm^2 carried 60.5 cm^2 of adhesion, a 1 x 1 face 200 cm^2),
        so tractions, and the pull-off force, depended on the mesh (docs/adhesion.md).
        A vertex on a crease still carries the share of every face at it (a scalar per vertex
        cannot tell which face touches).

        Sets ``triangle_area`` [triangle_count], ``vertex_area`` [vertex_count] and
        ``edge_area`` [edge_count] [m^2] (0 for a vertex no triangle uses).
        """
        v = p[self.triangles]
        self.triangle_area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
        third = self.triangle_area / 3.0
        self.vertex_area = np.bincount(self.triangles.ravel(), weights=np.repeat(third, 3),
                                       minlength=len(self._incident))
        adjacent = self.edge_set.adjacent
        self.edge_area = third[adjacent[:, 0]] + np.where(adjacent[:, 1] >= 0, third[adjacent[:, 1]], 0.0)


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
    # Local area: the smaller of the two primitives' (thesis 4.3.1).
    area = np.minimum(a.vertex_area[which], b.triangle_area[faces])
    return Contacts(side_a, stencil_side(b.body_index, b.points, b.triangles[faces], bary), normal, gap, p[which], at, ids,
                    np.full(len(which), float(friction)), area)


def _locate(surface: CollisionSurface, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangle and barycentric coordinates [c, 3] of surface points (closest-point queries)."""
    if len(at) == 0:
        return np.zeros(0, int), np.zeros((0, 3))
    out_face = wp.zeros(len(at), dtype=wp.int32, device=surface.device)
    out_uv = wp.zeros(len(at), dtype=wp.vec2, device=surface.device)
    wp.launch(_closest_face, dim=len(at), device=surface.device,
              inputs=[surface._mesh.id, wp.array(at, dtype=wp.vec3, device=surface.device), out_face, out_uv])
    uv = out_uv.numpy().astype(float)
    return out_face.numpy(), np.column_stack([uv[:, 0], uv[:, 1], 1.0 - uv[:, 0] - uv[:, 1]])


@wp.kernel
def _closest_face(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), face: wp.array(dtype=wp.int32),
                  uv: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    q = wp.mesh_query_point_no_sign(mesh, points[i], 1.0e6)
    face[i] = q.face
    uv[i] = wp.vec2(q.u, q.v)
