"""Compiled contact generation for the collision points of FEM bodies against static planes:
the array form of :func:`softvr.collision.points_vs_plane` for :class:`EmbeddedPoints`
(``p = sum_k w_k q_k``), over every point and plane of a scene in one launch.

A point makes a contact with a plane when its gap, or the gap its predicted velocity would
leave after the step, is below its body's margin. The contact starts with last step's impulse
of the same (point, plane) pair (its key), read from and cleared in the carried table, so a
pair that is no longer in contact forgets it.
"""

from __future__ import annotations

import warp as wp

STENCIL = 4


@wp.func
def plane_frame(n: wp.vec3d) -> wp.mat33d:
    """Rows: the unit normal and two unit tangents (any pair: friction is a disc)."""
    helper = wp.vec3d(wp.float64(1.0), wp.float64(0.0), wp.float64(0.0))
    if wp.abs(n[0]) > wp.float64(0.9):
        helper = wp.vec3d(wp.float64(0.0), wp.float64(1.0), wp.float64(0.0))
    t1 = wp.normalize(wp.cross(n, helper))
    t2 = wp.cross(n, t1)
    return wp.mat33d(n[0], n[1], n[2], t1[0], t1[1], t1[2], t2[0], t2[1], t2[2])


@wp.kernel
def points_vs_planes(q: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d),
                     point_nodes: wp.array2d(dtype=wp.int32), point_weights: wp.array2d(dtype=wp.float64),
                     point_margin: wp.array(dtype=wp.float64), plane_normal: wp.array(dtype=wp.vec3d),
                     plane_offset: wp.array(dtype=wp.float64), plane_friction: wp.array(dtype=wp.float64),
                     gravity: wp.vec3d, dt: wp.float64, capacity: int, carried: wp.array2d(dtype=wp.vec3d),
                     count: wp.array(dtype=wp.int32), point: wp.array(dtype=wp.int32),
                     plane: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.mat33d),
                     gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
                     impulse: wp.array(dtype=wp.vec3d)):
    """One thread: every (point, plane) pair in order, so contacts come out in the per-object
    path's order (by plane, then point) on every device. The predicted velocity is the
    explicit one, ``v + dt g`` [m/s] (the implicit step's is not known before the contact
    solve, which here also solves eq. 5.2)."""
    n_out = int(0)
    for s in range(plane_normal.shape[0]):
        normal = plane_normal[s]
        for p in range(point_nodes.shape[0]):
            x = wp.vec3d()
            u = wp.vec3d()
            for k in range(STENCIL):
                node = point_nodes[p, k]
                if node >= 0:
                    x = x + point_weights[p, k] * q[node]
                    u = u + point_weights[p, k] * v[node]
            g = wp.dot(normal, x) - plane_offset[s]
            reach = g + dt * wp.min(wp.dot(u + dt * gravity, normal), wp.float64(0.0))
            last = carried[p, s]
            carried[p, s] = wp.vec3d()
            if wp.min(g, reach) < point_margin[p] and n_out < capacity:
                f = plane_frame(normal)
                point[n_out] = p
                plane[n_out] = s
                frame[n_out] = f
                gap[n_out] = g
                friction[n_out] = plane_friction[s]
                lam = f * last
                # A pushing contact only: the normal impulse of a warm start is >= 0.
                impulse[n_out] = wp.vec3d(wp.max(lam[0], wp.float64(0.0)), lam[1], lam[2])
                n_out += 1
    count[0] = n_out


@wp.kernel
def carry_impulses(count: wp.array(dtype=wp.int32), point: wp.array(dtype=wp.int32),
                   plane: wp.array(dtype=wp.int32), frame: wp.array(dtype=wp.mat33d),
                   impulse: wp.array(dtype=wp.vec3d), carried: wp.array2d(dtype=wp.vec3d)):
    """The step's impulses (world [N s]) into the carried table for the next step's warm start."""
    for c in range(count[0]):
        carried[point[c], plane[c]] = wp.transpose(frame[c]) * impulse[c]
