"""Rigid bodies as node pairs of the whole-scene node arrays (:class:`softvr.sim.NodeModel`):
the launches moving velocities between the rigid path's per-body arrays
(:class:`softvr.sim.RigidModel` / :class:`softvr.sim.RigidState`, whose unconstrained step and
integration of :mod:`softvr.dynamics.rigid_arrays` they run with) and the nodes (kernels and
the derivation in :mod:`softvr.dynamics._node_rigid_kernels`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import warp as wp

from softvr.device import load_kernels, replayer
from softvr.dynamics import _node_rigid_kernels as _k

__all__ = ["isolated_rigid_nodes", "record_rigid_system", "record_rigid_velocity"]


def isolated_rigid_nodes(model) -> np.ndarray:
    """Which nodes [n] bool are a rigid body's whose rows of ``A`` (eq. 5.2 with the springs'
    terms of eq. 5.4) have blocks only on the body's own two nodes and on driven (fixed) nodes:
    a free body's, or one held only by springs to kinematic or fixed bodies (a haptic tool on
    its handle). ``D_A``'s block of such a body is all of its ``A`` over the nodes solved for,
    so a sweep's update of it is exact for the sweep's impulses, as a free rigid body's is.
    ``model`` a :class:`softvr.sim.NodeModel` (block pattern ``row_start``, ``block_col``,
    ``couplings.partner``, ``fixed``)."""
    n = model.node_count
    out = np.zeros(n, bool)
    if model.rigid is None:
        return out
    out[model.rigid.linear_node.numpy()] = True
    out[model.rigid.angular_node.numpy()] = True
    row_start, col = model.row_start.numpy(), model.block_col.numpy()
    row = np.repeat(np.arange(n), np.diff(row_start))
    partner, fixed = model.couplings.partner.numpy(), model.fixed.numpy() != 0
    other = (col != row) & (col != partner[row]) & ~fixed[col]
    out[row[other]] = False
    return out


def record_rigid_system(rigid, state) -> Callable[[], None]:
    """A replay writing the rigid nodes' ``D_A^-1`` and ``b`` (``state.d_inv``, ``state.b``)
    from ``rigid.state.free_velocity`` (run after the rigid path's unconstrained step and the
    FEM nodes' right-hand side, which it overwrites on the rigid nodes); ``rigid`` is a
    :class:`softvr.sim.NodeRigid`."""
    load_kernels(_k.rigid_system, rigid.model.device)
    return replayer(wp.launch(_k.rigid_system, dim=len(rigid.bodies), device=rigid.model.device, record_cmd=True,
                              inputs=[rigid.linear_node, rigid.angular_node, rigid.model.body_inv_mass,
                                      rigid.state.free_velocity, rigid.state.inv_inertia_world, state.b,
                                      state.d_inv]))


def record_rigid_velocity(rigid, solved: wp.array) -> Callable[[], None]:
    """A replay copying the solved node velocities ``solved`` [n] [m/s, rad/s] of the rigid
    bodies into ``rigid.state.free_velocity`` (for the rigid path's integration)."""
    load_kernels(_k.rigid_velocity, rigid.model.device)
    return replayer(wp.launch(_k.rigid_velocity, dim=len(rigid.bodies), device=rigid.model.device, record_cmd=True,
                              inputs=[rigid.linear_node, rigid.angular_node, solved, rigid.state.free_velocity]))
