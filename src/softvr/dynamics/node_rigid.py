"""Rigid bodies as node pairs of the whole-scene node arrays (:class:`softvr.sim.NodeModel`):
the launches moving velocities between the rigid path's per-body arrays
(:class:`softvr.sim.RigidModel` / :class:`softvr.sim.RigidState`, whose unconstrained step and
integration of :mod:`softvr.dynamics.rigid_arrays` they run with) and the nodes (kernels and
the derivation in :mod:`softvr.dynamics._node_rigid_kernels`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import warp as wp
from scipy.sparse.csgraph import connected_components

from softvr.device import load_kernels, replayer
from softvr.dynamics import _node_rigid_kernels as _k

__all__ = ["isolated_rigid_nodes", "record_rigid_system", "record_rigid_velocity", "rigid_islands"]


def rigid_islands(model) -> list[np.ndarray]:
    """The rigid bodies' nodes that the blocks of ``A`` (eq. 5.2 with the springs' terms of
    eq. 5.4) tie together, grouped [k] into islands whose rows have blocks only on nodes of
    the island and on driven (fixed) nodes: a free body's two nodes, a body held only by
    springs to kinematic or fixed bodies (a haptic tool on its handle), or rigid bodies held
    by springs to each other and to driven nodes (the shoulder's two fingers and the skin
    between them). ``D_A``'s block over an island is all of its ``A`` over the nodes solved
    for. Rigid bodies tied to FEM nodes are in none. ``model`` a :class:`softvr.sim.NodeModel`
    (block pattern ``row_start``, ``block_col``, ``fixed``)."""
    n = model.node_count
    if model.rigid is None:
        return []
    rigid = np.zeros(n, bool)
    rigid[model.rigid.linear_node.numpy()] = True
    rigid[model.rigid.angular_node.numpy()] = True
    row_start, col = model.row_start.numpy(), model.block_col.numpy()
    row = np.repeat(np.arange(n), np.diff(row_start))
    fixed = model.fixed.numpy() != 0
    # Each body's two nodes are one island at least (a free body's have no blocks between them).
    linear, angular = model.rigid.linear_node.numpy(), model.rigid.angular_node.numpy()
    edges = np.concatenate([np.stack([row, col], axis=1)[rigid[row] & rigid[col]],
                            np.stack([linear, angular], axis=1)])
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    leaves = ~rigid[col] & ~fixed[col]  # blocks of a rigid row on FEM nodes
    open_labels = set(label[row[rigid[row] & leaves]].tolist())
    nodes = np.flatnonzero(rigid)
    return [nodes[label[nodes] == x] for x in np.unique(label[nodes]) if x not in open_labels]


def isolated_rigid_nodes(model, largest: int = 2) -> np.ndarray:
    """Which nodes [n] bool are in a :func:`rigid_islands` island of at most ``largest`` nodes
    (2: a single body's, whose 6x6 block of ``D_A`` every sweep inverts, so that a sweep's
    update of it is exact for the sweep's impulses, as a free rigid body's is)."""
    out = np.zeros(model.node_count, bool)
    for island in rigid_islands(model):
        if len(island) <= largest:
            out[island] = True
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
