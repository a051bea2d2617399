"""Compiled contact generation of the rigid bodies on whole-scene node arrays.

A rigid body is two nodes (linear velocity v, world angular velocity omega), and a point fixed
in it at world offset r from its centre moves with ``v + omega x r`` (thesis 5.1.2, ``J = [I,
-[r]x]``). A contact's stencil (:mod:`softvr.collision._node_kernels`) carries the linear node
with the point's weight; its rigid sides carry the angular node with the lever arm: contact
``c`` has up to two (``rigid_node[c, s]``, ``rigid_lever[c, s]``), and its relative velocity is

    sum_k w_k v[node_k] + sum_s omega[rigid_node[c, s]] x rigid_lever[c, s],

the lever of a side weighted as its points are (minus a triangle's barycentric share of its
vertices' offsets, an edge's ends by where the closest point lies). Rigid collision points are
placed each step from the body's pose; box and sphere primitives meet planes and each other
through the rigid path's detection (:mod:`softvr.collision._primitive_kernels`), whose contacts
are appended here as node contacts of kind PRIMITIVE.
"""

from __future__ import annotations

import warp as wp

from softvr.collision._node_kernels import (EDGE_EDGE, PRIMITIVE, VERTEX_TRIANGLE, NodeContactOut, add_node,
                                           start_contact)
from softvr.collision._primitive_kernels import angular, body_rotation, linear

#: Rigid sides a contact holds (one per side).
RIGID_SIDES = 2


@wp.kernel
def rigid_points(point_index: wp.array(dtype=wp.int32), point_rigid: wp.array(dtype=wp.int32),
                 point_local: wp.array(dtype=wp.vec3d), position: wp.array(dtype=wp.vec3d),
                 orientation: wp.array(dtype=wp.vec4d), free_velocity: wp.array(dtype=wp.spatial_vectord),
                 point_x: wp.array(dtype=wp.vec3d), point_x32: wp.array(dtype=wp.vec3),
                 point_u: wp.array(dtype=wp.vec3d), point_lever: wp.array(dtype=wp.vec3d)):
    """Rigid collision point ``k`` (global point ``point_index[k]`` of rigid body
    ``point_rigid[k]``, at ``point_local[k]`` [m] in the body frame): its position [m] (also in
    single precision), world offset from the centre [m] and predicted velocity [m/s] from the
    unconstrained ``free_velocity`` (``v + omega x r``), over what the node stencil gave."""
    k = wp.tid()
    p = point_index[k]
    r = point_rigid[k]
    lever = body_rotation(orientation[r]) * point_local[k]
    x = position[r] + lever
    v = free_velocity[r]
    point_x[p] = x
    point_x32[p] = wp.vec3(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))
    point_u[p] = linear(v) + wp.cross(angular(v), lever)
    point_lever[p] = lever


@wp.func
def add_rigid(c: int, node: int, lever: wp.vec3d, rigid_node: wp.array2d(dtype=wp.int32),
              rigid_lever: wp.array2d(dtype=wp.vec3d)):
    """Add ``lever`` [m] of angular node ``node`` to contact ``c``'s rigid sides (summed if the
    node is already one)."""
    for s in range(RIGID_SIDES):
        if rigid_node[c, s] == node:
            rigid_lever[c, s] = rigid_lever[c, s] + lever
            return
        if rigid_node[c, s] < 0:
            rigid_node[c, s] = node
            rigid_lever[c, s] = lever
            return


@wp.func
def add_rigid_point(c: int, p: int, scale: wp.float64, point_angular: wp.array(dtype=wp.int32),
                    point_lever: wp.array(dtype=wp.vec3d), rigid_node: wp.array2d(dtype=wp.int32),
                    rigid_lever: wp.array2d(dtype=wp.vec3d)):
    node = point_angular[p]
    if node >= 0:
        add_rigid(c, node, scale * point_lever[p], rigid_node, rigid_lever)


@wp.func
def rigid_side_of(c: int, kind: wp.array(dtype=wp.int32), point: wp.array(dtype=wp.int32),
                  face: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec3d), triangles: wp.array2d(dtype=wp.int32),
                  edges: wp.array2d(dtype=wp.int32), point_angular: wp.array(dtype=wp.int32),
                  point_lever: wp.array(dtype=wp.vec3d), rigid_node: wp.array2d(dtype=wp.int32),
                  rigid_lever: wp.array2d(dtype=wp.vec3d)):
    """Contact ``c``'s rigid sides from its points, weighted as in its stencil (the gather's):
    a point +1, a triangle's vertices minus their barycentric coordinates, an edge pair's ends
    (1 - s, s) and -(1 - t, t); ``point_angular`` [p] is a point's angular node (-1: not rigid),
    ``point_lever`` [p] [m] its world offset from its body's centre."""
    for s in range(RIGID_SIDES):
        rigid_node[c, s] = -1
    one = wp.float64(1.0)
    if kind[c] == EDGE_EDGE:
        st = bary[c]
        e = point[c]
        j = face[c]
        add_rigid_point(c, edges[e, 0], one - st[0], point_angular, point_lever, rigid_node, rigid_lever)
        add_rigid_point(c, edges[e, 1], st[0], point_angular, point_lever, rigid_node, rigid_lever)
        add_rigid_point(c, edges[j, 0], st[1] - one, point_angular, point_lever, rigid_node, rigid_lever)
        add_rigid_point(c, edges[j, 1], -st[1], point_angular, point_lever, rigid_node, rigid_lever)
        return
    add_rigid_point(c, point[c], one, point_angular, point_lever, rigid_node, rigid_lever)
    if kind[c] == VERTEX_TRIANGLE:
        w = bary[c]
        for v in range(3):
            add_rigid_point(c, triangles[face[c], v], -w[v], point_angular, point_lever, rigid_node, rigid_lever)


@wp.kernel
def rigid_sides(count: wp.array(dtype=wp.int32), kind: wp.array(dtype=wp.int32), point: wp.array(dtype=wp.int32),
                face: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec3d), triangles: wp.array2d(dtype=wp.int32),
                edges: wp.array2d(dtype=wp.int32), point_angular: wp.array(dtype=wp.int32),
                point_lever: wp.array(dtype=wp.vec3d), rigid_node: wp.array2d(dtype=wp.int32),
                rigid_lever: wp.array2d(dtype=wp.vec3d), threads: int):
    """The rigid sides of contacts ``wp.tid() + threads k`` below ``count[0]`` (the rows past it
    are not read: the primitives' append writes both sides of its rows; one thread per row of
    the capacity cost ~1.5 ms a step on the candy, 188 181 rows for ~3 000 contacts)."""
    for c in range(wp.tid(), count[0], threads):
        rigid_side_of(c, kind, point, face, bary, triangles, edges, point_angular, point_lever, rigid_node,
                      rigid_lever)


@wp.kernel
def primitive_contacts(rigid_count: wp.array(dtype=wp.int32), body_a: wp.array(dtype=wp.int32),
                       body_b: wp.array(dtype=wp.int32), offset_a: wp.array(dtype=wp.vec3d),
                       offset_b: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d),
                       gap: wp.array(dtype=wp.float64), friction: wp.array(dtype=wp.float64),
                       linear_node: wp.array(dtype=wp.int32), angular_node: wp.array(dtype=wp.int32),
                       body_scene: wp.array(dtype=wp.int32), capacity: int, count: wp.array(dtype=wp.int32),
                       out: NodeContactOut, rigid_node: wp.array2d(dtype=wp.int32),
                       rigid_lever: wp.array2d(dtype=wp.vec3d)):
    """One thread, after the gather: the rigid path's primitive contacts (rows of its
    :class:`~softvr.collision.contact_buffer.ContactBuffer`, bodies numbered among the rigid
    bodies, ``body_b`` -1 for a plane) appended as node contacts of kind PRIMITIVE, cold
    started: ``column`` side a's body (scene index), ``point`` the row, ``other`` side b's body
    (-1: a plane); stencil the linear nodes (+1 for a, -1 for b), rigid sides the angular nodes
    with levers ``offset_a`` and ``-offset_b`` [m]."""
    n_out = count[0]
    zero = wp.vec3d()
    for k in range(rigid_count[0]):
        if n_out < capacity:
            a = body_a[k]
            b = body_b[k]
            other = int(-1)
            if b >= 0:
                other = body_scene[b]
            start_contact(out, n_out, PRIMITIVE, body_scene[a], k, other, -1, zero, normal[k], gap[k], friction[k],
                          zero)
            add_node(n_out, linear_node[a], wp.float64(1.0), out.stencil_count, out.stencil_nodes,
                     out.stencil_weights)
            rigid_node[n_out, 0] = angular_node[a]
            rigid_lever[n_out, 0] = offset_a[k]
            rigid_node[n_out, 1] = -1
            if b >= 0:
                add_node(n_out, linear_node[b], wp.float64(-1.0), out.stencil_count, out.stencil_nodes,
                         out.stencil_weights)
                rigid_node[n_out, 1] = angular_node[b]
                rigid_lever[n_out, 1] = -offset_b[k]
            n_out += 1
    count[0] = n_out
