"""Contact generation of the FEM bodies of a whole scene against its planes, one recorded
launch (kernels in :mod:`softvr.collision._node_kernels`; works on :class:`softvr.sim.NodeModel`
/ :class:`softvr.sim.NodeState` or any objects with those attributes)."""

from __future__ import annotations

import numpy as np
import warp as wp

from softvr.collision import _node_kernels as _k
from softvr.device import load_kernels

__all__ = ["record_carry", "record_node_detection"]


def record_node_detection(model, state, dt: float, gravity) -> wp.Launch:
    """The launch filling ``state.contacts`` (points vs planes, warm-started from
    ``state.contacts.carried``) from the step's start ``q``, ``v`` and ``gravity`` [m/s^2]."""
    c = state.contacts
    load_kernels(_k.points_vs_planes, model.device)
    return wp.launch(_k.points_vs_planes, dim=1, device=model.device, record_cmd=True,
                     inputs=[state.q, state.v, model.point_nodes, model.point_weights, model.point_margin,
                             model.plane_normal, model.plane_offset, model.plane_friction,
                             wp.vec3d(*np.asarray(gravity, float)), float(dt), c.capacity, c.carried, c.count,
                             c.point, c.plane, c.frame, c.gap, c.friction, c.impulse])


def record_carry(model, state) -> wp.Launch:
    """The launch storing the step's impulses as the next step's warm starts."""
    c = state.contacts
    load_kernels(_k.carry_impulses, model.device)
    return wp.launch(_k.carry_impulses, dim=1, device=model.device, record_cmd=True,
                     inputs=[c.count, c.point, c.plane, c.frame, c.impulse, c.carried])
