"""Contact generation of the rigid bodies on whole-scene node arrays (:class:`softvr.sim.NodeModel`
with its :class:`softvr.sim.NodeRigid`), as recorded launches run inside
:func:`softvr.collision.node_detection.record_node_detection`: rigid collision points placed
from their bodies' poses, the rigid sides (angular node, lever arm) of every contact, and the
box / sphere primitives' contacts of the rigid path's detection
(:func:`softvr.collision.rigid_detection.record_detection`) appended as node contacts (kernels
and the Jacobian in :mod:`softvr.collision._node_rigid_kernels`)."""

from __future__ import annotations

from collections.abc import Callable

import warp as wp

from softvr.collision import _node_kernels as _nk
from softvr.collision import _node_rigid_kernels as _k
from softvr.collision.rigid_detection import record_detection
from softvr.device import load_kernels, replayer, stride_threads

__all__ = ["CONTACT_THREADS", "record_rigid_contacts", "record_rigid_points"]

#: Threads of a once-a-step launch over the step's contacts (the rigid sides, the coarse
#: sides) on CUDA, each striding them up to the count: one per row of the contact buffer's
#: capacity was ~60 times the contacts on the candy (188 181 rows, ~3 000 contacts). One on the
#: CPU (:func:`softvr.device.stride_threads`).
CONTACT_THREADS = 1024


def record_rigid_points(model, state) -> Callable[[], None]:
    """A replay placing the rigid bodies' collision points (``state.point_x``, ``point_x32``,
    ``point_u``, ``model.rigid.point_lever``) from ``model.rigid.state``'s poses and
    unconstrained velocities; run after the node stencils' ``point_motion``."""
    rigid = model.rigid
    load_kernels(_k.rigid_points, model.device)
    return replayer(wp.launch(_k.rigid_points, dim=rigid.point_index.shape[0], device=model.device, record_cmd=True,
                              inputs=[rigid.point_index, rigid.point_rigid, rigid.point_local,
                                      rigid.state.body_position, rigid.state.body_orientation,
                                      rigid.state.free_velocity, state.point_x, state.point_x32, state.point_u,
                                      rigid.point_lever]))


def record_rigid_contacts(model, state, dt: float) -> Callable[[], None]:
    """A replay run after the node contacts' gather: their rigid sides, then the primitives'
    contacts (the rigid path's detection over ``dt`` [s] into ``model.rigid.state.contacts``)
    appended."""
    rigid, c, d = model.rigid, state.contacts, model.device
    for kernel in (_k.rigid_sides, _k.primitive_contacts):
        load_kernels(kernel, d)
    threads = stride_threads(d, min(c.capacity, CONTACT_THREADS))
    sides = replayer(wp.launch(_k.rigid_sides, dim=threads, device=d, record_cmd=True,
                               inputs=[c.count, c.kind, c.point, c.face, c.bary, model.triangles, model.edges,
                                       rigid.point_angular, rigid.point_lever, c.rigid_node, c.rigid_lever,
                                       threads]))
    detection = record_detection(rigid.model, rigid.state, dt)
    out = _nk.contact_out(c)
    p = rigid.state.contacts
    append = replayer(wp.launch(_k.primitive_contacts, dim=1, device=d, record_cmd=True,
                                inputs=[p.count, p.body_a, p.body_b, p.offset_a, p.offset_b, p.normal, p.gap,
                                        p.friction, rigid.linear_node, rigid.angular_node, rigid.body_scene,
                                        c.capacity, c.count, out, c.rigid_node, c.rigid_lever]))

    def contacts() -> None:
        sides()
        detection.launch()  # into a buffer the rigid unconstrained step emptied
        append()

    return contacts
