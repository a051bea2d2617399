"""Points against static triangle meshes, discrete and continuous (first time of impact).

Built on Warp's ``wp.Mesh`` (a BVH over the triangles): ``mesh_query_point_no_sign`` finds
points within the contact margin of the surface, ``mesh_query_ray`` sweeps each point along its
unconstrained motion over the step (CCD), so a small fast object cannot pass through a thin
sheet between two steps.
"""

from __future__ import annotations

from typing import no_type_check

import numpy as np
import warp as wp

from softvr.collision.contacts import ContactKind, Contacts, ContactSide, contact_keys, point_jacobian_blocks
from softvr.device import resolve_device, upload
from softvr.errors import InputError

__all__ = ["NORMAL_FROM_OFFSET", "TriangleMesh", "points_vs_mesh", "query_points"]

#: Distance [m] below which a contact takes the face's normal rather than the direction from
#: the closest point: the BVH runs in single precision, so a point resting on a face is some
#: 1e-8 m off it in a random direction (a pressed block's nodes got normals 80 degrees off
#: and slid into the plate); a micrometre is far above that rounding within ~10 m of the
#: origin and far below any contact margin.
NORMAL_FROM_OFFSET = wp.constant(1.0e-6)


@wp.func
@no_type_check  # Warp's builtins (mesh queries, vector types) are not typed for Python
def query_point(mesh: wp.uint64, p: wp.vec3, d: wp.vec3, reach: float, thickness: float, ccd: int, closed: int):
    """Point ``p`` against a Warp mesh: the closest surface point within ``reach`` or, sweeping
    ``d`` (the displacement over the step), the first crossing. Returns (hit (0 / 1), normal,
    gap [m], surface point [m]). Normals face the point's side; for a ``closed`` (watertight,
    outward) surface a point inside gets the outward normal and a negative gap (its penetration
    depth), and a sweep only counts when it enters the solid: a point inside moving out meets
    the surface from behind, and a contact on that side would pull it back in. Inside or
    outside comes from the closest feature's angle-weighted pseudo normal: Warp's default vote
    of three axis-aligned rays is a coin toss for a point resting on a face, whose rays run
    along it (a block's nodes under a pressing plate flipped sides and were pushed into it)."""
    travel = wp.length(d)
    if ccd != 0 and travel > 0.0:
        direction = d / travel
        ray = wp.mesh_query_ray(mesh, p, direction, travel + reach)
        if ray.result and (closed == 0 or wp.dot(ray.normal, direction) < 0.0):
            n = ray.normal
            if wp.dot(n, direction) > 0.0:
                n = -n
            return int(1), n, ray.t * wp.abs(wp.dot(n, direction)) - thickness, p + ray.t * direction
    if closed != 0:
        q = wp.mesh_query_point_sign_normal(mesh, p, reach + thickness)
        if q.result:
            c = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
            offset = p - c
            dist = wp.length(offset)
            n = wp.mesh_eval_face_normal(mesh, q.face)
            if dist > NORMAL_FROM_OFFSET:
                n = offset / dist * q.sign
            return int(1), n, dist * q.sign - thickness, c
        return int(0), wp.vec3(), float(0.0), wp.vec3()
    q = wp.mesh_query_point_no_sign(mesh, p, reach + thickness)
    if q.result:
        c = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        offset = p - c
        dist = wp.length(offset)
        n = wp.mesh_eval_face_normal(mesh, q.face)
        if dist > NORMAL_FROM_OFFSET:
            n = offset / dist
        return int(1), n, dist - thickness, c
    return int(0), wp.vec3(), float(0.0), wp.vec3()


@wp.kernel
@no_type_check  # Warp's annotations (wp.array(dtype=...)) are not Python types
def _query_points(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    motion: wp.array(dtype=wp.vec3),
    reach: float,
    thickness: float,
    ccd: int,
    closed: int,
    hit: wp.array(dtype=wp.int32),
    normal: wp.array(dtype=wp.vec3),
    gap: wp.array(dtype=float),
    surface: wp.array(dtype=wp.vec3),
):
    """Per point: :func:`query_point`."""
    i = wp.tid()
    h, n, g, c = query_point(mesh, points[i], motion[i], reach, thickness, ccd, closed)
    hit[i] = h
    if h != 0:
        normal[i] = n
        gap[i] = g
        surface[i] = c


def _query_outputs(n: int, device: str, buffers: dict | None):
    """Output arrays of :func:`query_points` for ``n`` points, and its two input arrays (points,
    motion): new ones, or the ones kept in ``buffers`` for this count (the kernel writes
    ``hit`` of every point and the rest where it hits, and only those are read, so old
    contents do no harm)."""
    out = None if buffers is None else buffers.get(n)
    if out is None:
        out = (wp.empty(n, dtype=wp.int32, device=device), wp.empty(n, dtype=wp.vec3, device=device),
               wp.empty(n, dtype=float, device=device), wp.empty(n, dtype=wp.vec3, device=device),
               wp.empty(n, dtype=wp.vec3, device=device), wp.empty(n, dtype=wp.vec3, device=device))
        if buffers is not None:
            if len(buffers) > 16:  # many point counts: forget the old ones
                buffers.clear()
            buffers[n] = out
    return out


def query_points(mesh_id, device: str, points: np.ndarray, motion: np.ndarray, reach: float, thickness: float,
                 ccd: bool, *, closed: bool, buffers: dict | None = None):
    """Run the proximity / sweep query of every point against a Warp mesh.

    Returns
    -------
    which : ndarray of int
        Points with a contact.
    normal : ndarray, shape [len(which), 3]
    gap : ndarray, shape [len(which)] [m]
    surface : ndarray, shape [len(which), 3] [m]
        The contact point on the mesh.
    """
    n = len(points)
    hit, normal, gap, surface, points_in, motion_in = _query_outputs(n, device, buffers)
    upload(points_in, points)
    upload(motion_in, motion)
    wp.launch(_query_points, dim=n, device=device,
              inputs=[mesh_id, points_in, motion_in, float(reach), float(thickness), int(ccd), int(closed), hit, normal,
                      gap, surface])
    which = np.flatnonzero(hit.numpy())
    return (which, normal.numpy()[which].astype(float), gap.numpy()[which].astype(float),
            surface.numpy()[which].astype(float))


class TriangleMesh:
    """A static triangle mesh collider (a thin sheet, a wall, an organ surface).

    Parameters
    ----------
    vertices : array_like, shape [vertex_count, 3] [m]
    triangles : array_like, shape [triangle_count, 3]
    thickness : float [m]
        Half thickness of the sheet: contacts keep points this far from the surface.
    friction : float
    device : str, optional
        Warp device of the BVH.
    """

    def __init__(self, vertices, triangles, *, thickness: float = 0.001, friction: float = 0.5,
                 device: str | None = None):
        v = np.asarray(vertices, float)
        t = np.asarray(triangles)
        if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
            raise InputError("vertices", "finite positions [vertex_count, 3] [m]", f"shape {v.shape}")
        if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0 or t.min() < 0 or t.max() >= len(v):
            raise InputError("triangles", f"[triangle_count, 3] indices in [0, {len(v) - 1}]", f"shape {t.shape}")
        if not thickness >= 0:
            raise InputError("thickness", "a half thickness >= 0 [m]", repr(thickness))
        self.device = resolve_device(device)
        self.vertices, self.triangles = v, t.astype(np.int32)
        self.thickness, self.friction = float(thickness), float(friction)
        self._points: wp.array = wp.array(v, dtype=wp.vec3, device=self.device)
        self._mesh = wp.Mesh(points=self._points, indices=wp.array(self.triangles.ravel(), dtype=wp.int32,
                                                                        device=self.device))
        self._query_buffers: dict[int, tuple] = {}  # output arrays of the point queries, by point count

    def signed_distance(self, points, *, closed: bool = True, normals: bool = False):
        """Distance [point_count] [m] of ``points`` [point_count, 3] [m] to the surface (BVH
        query); for a ``closed`` (watertight, outward) mesh negative inside. With ``normals``
        also the unit direction [point_count, 3] from the closest surface point outward (the
        face normal where the point lies on the surface)."""
        p = np.asarray(points, float)
        if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
            raise InputError("points", "finite points [point_count, 3] [m]", f"shape {p.shape}")
        reach = 2.0 * float(np.linalg.norm(np.ptp(np.vstack([self.vertices, p]), axis=0))) + 1.0
        which, normal, gap, _ = query_points(self._mesh.id, self.device, p, np.zeros_like(p), reach, 0.0, False,
                                             closed=closed, buffers=self._query_buffers)
        out = np.full(len(p), np.inf)
        out[which] = gap
        if not normals:
            return out
        n = np.zeros_like(p)
        n[which] = normal
        return out, n


def points_vs_mesh(body_index: int, points, mesh: TriangleMesh, *, margin: float = 0.0, velocities=None,
                   dt: float = 0.0, ccd: bool = True, static_index: int = 0) -> Contacts:
    """Contacts of point entities with a static triangle mesh.

    Parameters
    ----------
    body_index : int
    points : RigidPoints or EmbeddedPoints
    mesh : TriangleMesh
    margin : float [m]
        Proximity within which points become contacts.
    velocities : ndarray, shape [point_count, 3] [m/s], optional
        Unconstrained point velocities of the step (for CCD).
    dt : float [s]
    ccd : bool
        Sweep each point over ``velocities * dt`` and take the first crossing.
    static_index : int
        Index of the mesh among the scene's static meshes (part of the contact keys).
    """
    p = points.positions()
    motion = np.zeros_like(p) if velocities is None else np.asarray(velocities, float) * dt
    which, normal, gap, surface = query_points(mesh._mesh.id, mesh.device, p, motion, margin, mesh.thickness, ccd,
                                               closed=False, buffers=mesh._query_buffers)
    blocks, jac = point_jacobian_blocks(points, which)
    k = len(which)
    return Contacts(
        a=ContactSide(body_index, blocks, jac),
        b=None,
        normal=normal,
        gap=gap,
        point_a=p[which],
        point_b=surface,
        # A point has one contact per mesh (its closest point or first crossing), so the point alone
        # names it; the triangle it meets changes as it slides, and must not restart its adhesion.
        ids=contact_keys(ContactKind.POINT_MESH, body_index, which, static_index, 0),
        friction=np.full(k, mesh.friction),
    )
