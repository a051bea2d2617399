"""Couplings (thesis 5.3.2, eq. 5.4) on the whole-scene node arrays: which couplings the arrays
hold, the driven nodes of the kinematic and fixed bodies' coupling points, and the springs'
extra blocks of ``A`` and their forces as flat arrays (:class:`NodeCouplings`).

A coupling spring ties a point of side a, ``p_a = sum_i w_i q_i`` over a stencil of up to 4
nodes, to a point of side b; with the sides' stencils joined into one of up to 8 nodes whose
weights carry the sign (side b's negative), ``D = [w_0 I, ..., w_7 I]`` maps the node velocities
to the relative point velocity, and eq. 5.4 (:mod:`softvr.dynamics.couplings`) adds

    A_ij += (dt c + dt^2 k) w_i w_j I,      b_i += -dt k w_i (p_a - p_b)

for every pair of stencil nodes ``i``, ``j``. A kinematic or fixed body's coupling points are
driven nodes (no tets, velocity prescribed): their columns act through the sweeps' known
velocities, i.e. on the right-hand side, and their rows are not kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from softvr.dynamics import EmbeddedPoints, FemBody, FixedBody, KinematicBody, RigidPoints
from softvr.dynamics.node_couplings import SPRING_STENCIL

__all__ = ["NodeCouplings", "build_node_couplings", "coupling_blocks", "coupling_springs", "couplings_supported",
           "driven_points"]

#: Nodes of one side's stencil (a point embedded in a tet).
SIDE = SPRING_STENCIL // 2


@dataclass
class NodeCouplings:
    """The coupling springs of a scene on the node arrays (``S`` springs, ``cb`` blocks of ``A``
    they add to, ``cn`` nodes they pull on).

    Attributes
    ----------
    spring_count : int
    driven : dict
        Kinematic or fixed body index -> :class:`~softvr.dynamics.RigidPoints` of its driven
        nodes: its collision points, then every coupling side on it in coupling order (None for
        a body with neither).
    nodes : wp.array2d(int32) [S, SPRING_STENCIL]
        Each spring's stencil: side a's nodes, then side b's (global; -1: unused).
    weights : wp.array2d(float64) [S, SPRING_STENCIL]
        Their weights, side b's negated: ``sum_k w_k q[nodes_k] = p_a - p_b`` [m].
    stiffness : wp.array(float64) [S] [N/m]
    block : wp.array(int32) [cb]
        The blocks of ``A`` (in ``NodeModel.block_row`` order) with coupling terms; only rows of
        FEM nodes.
    block_stiffness : wp.array(float64) [cb] [N/m]; block_damping : wp.array(float64) [cb] [N s/m]
        ``sum k w_i w_j`` and ``sum c w_i w_j`` over the springs touching the block's nodes: the
        block gets ``(dt damping + dt^2 stiffness) I``.
    node : wp.array(int32) [cn]
        FEM nodes in some spring's stencil.
    entry_start : wp.array(int32) [cn + 1]; entry : wp.array(int32) [.]
        Node ``node[t]``'s stencil entries ``entry[entry_start[t] : entry_start[t + 1]]``, coded
        SPRING_STENCIL spring + slot.
    """

    spring_count: int
    driven: dict
    nodes: wp.array
    weights: wp.array
    stiffness: wp.array
    block: wp.array
    block_stiffness: wp.array
    block_damping: wp.array
    node: wp.array
    entry_start: wp.array
    entry: wp.array


def couplings_supported(scene) -> bool:
    """Whether the node arrays hold every coupling of ``scene``: each side either an FEM body's
    :class:`~softvr.dynamics.EmbeddedPoints` with stencils of at most :data:`SIDE` nodes, or a
    kinematic or fixed body's :class:`~softvr.dynamics.RigidPoints` (a rigid body's side is
    not held)."""
    for coupling in scene.couplings:
        for side in (coupling.a, coupling.b):
            kind = type(side.body)
            if kind is FemBody:
                if not isinstance(side, EmbeddedPoints) or side.nodes.shape[1] > SIDE:
                    return False
            elif kind not in (KinematicBody, FixedBody) or not isinstance(side, RigidPoints):
                return False
    return True


def _driven_sides(scene, body) -> list:
    """The coupling sides on ``body``, in coupling order (a before b)."""
    return [side for c in scene.couplings for side in (c.a, c.b) if side.body is body]


def driven_points(scene, colliders: dict) -> dict:
    """Each kinematic or fixed body's driven nodes as one :class:`RigidPoints` (its collision
    points first, then its coupling sides'), or None; ``colliders`` maps body index to its
    collider."""
    out = {}
    for i, body in enumerate(scene.bodies):
        if type(body) is FemBody:
            continue
        local = [colliders[i].points.local] if i in colliders else []
        local += [side.local for side in _driven_sides(scene, body)]
        out[i] = RigidPoints(body, np.concatenate(local)) if local else None
    return out


def coupling_springs(scene, node_start, colliders: dict) -> tuple:
    """Stencils [S, SPRING_STENCIL] (global nodes, -1 unused), signed weights [S, SPRING_STENCIL],
    stiffness [S] [N/m] and damping [S] [N s/m] of every coupling spring, over the nodes
    numbered from ``node_start`` [bodies + 1] (a driven body's: :func:`driven_points`' order)."""
    index = {id(b): i for i, b in enumerate(scene.bodies)}
    next_driven = {i: len(colliders[i].points.local) if i in colliders else 0
                   for i, b in enumerate(scene.bodies) if type(b) is not FemBody}
    nodes, weights, stiffness, damping = [], [], [], []
    for c in scene.couplings:
        count = len(c)
        n = np.full((count, SPRING_STENCIL), -1, np.int64)
        w = np.zeros((count, SPRING_STENCIL))
        for s, (side, sign) in enumerate(((c.a, 1.0), (c.b, -1.0))):
            b = index[id(side.body)]
            cols = slice(s * SIDE, (s + 1) * SIDE)
            if isinstance(side, EmbeddedPoints):
                k = side.nodes.shape[1]
                n[:, cols.start:cols.start + k] = side.nodes + node_start[b]
                w[:, cols.start:cols.start + k] = sign * side.weights
            else:
                n[:, cols.start] = node_start[b] + next_driven[b] + np.arange(count)
                w[:, cols.start] = sign
                next_driven[b] += count
        nodes.append(n)
        weights.append(w)
        stiffness.append(np.full(count, c.stiffness))
        damping.append(np.full(count, c.damping))
    empty = np.zeros((0, SPRING_STENCIL))
    return (np.concatenate([empty.astype(np.int64), *nodes]), np.concatenate([empty, *weights]),
            np.concatenate([np.zeros(0), *stiffness]), np.concatenate([np.zeros(0), *damping]))


def coupling_blocks(springs: tuple, fem_rows: np.ndarray) -> tuple:
    """The springs' terms of ``A`` by block: keys ``row n + col`` (sorted, unique; rows of FEM
    nodes only, ``fem_rows`` [n] bool), with ``sum k w_i w_j`` [N/m] and ``sum c w_i w_j``
    [N s/m] of each."""
    nodes, weights, stiffness, damping = springs
    n = len(fem_rows)
    s, i, j = np.nonzero((nodes[:, :, None] >= 0) & (nodes[:, None, :] >= 0))
    rows, cols = nodes[s, i], nodes[s, j]
    keep = fem_rows[rows]
    s, i, j, rows, cols = s[keep], i[keep], j[keep], rows[keep], cols[keep]
    ww = weights[s, i] * weights[s, j]
    keys, block = np.unique(rows * n + cols, return_inverse=True)
    return (keys, np.bincount(block, stiffness[s] * ww, len(keys)), np.bincount(block, damping[s] * ww, len(keys)))


def build_node_couplings(springs: tuple, terms: tuple, fem_rows: np.ndarray, block_keys: np.ndarray, driven: dict,
                         device: str) -> NodeCouplings:
    """The arrays of the :func:`coupling_springs` ``springs`` and their :func:`coupling_blocks`
    ``terms``; ``block_keys`` [nb] are the keys ``row n + col`` of the model's blocks (sorted),
    a superset of the terms' (the pattern is built with them); ``driven`` from
    :func:`driven_points`."""
    nodes, weights, stiffness, _ = springs
    keys, block_k, block_c = terms
    s, slot = np.nonzero(nodes >= 0)
    owner = nodes[s, slot]
    pulled = fem_rows[owner]
    s, slot, owner = s[pulled], slot[pulled], owner[pulled]
    order = np.argsort(owner, kind="stable")
    node, first = np.unique(owner[order], return_index=True)
    d = device

    def i32(values):
        return wp.array(np.ascontiguousarray(values, np.int32), dtype=wp.int32, device=d)

    def f64(values):
        return wp.array(np.ascontiguousarray(values, np.float64), dtype=wp.float64, device=d)

    return NodeCouplings(
        spring_count=len(nodes), driven=driven, nodes=i32(nodes), weights=f64(weights),
        stiffness=f64(stiffness), block=i32(np.searchsorted(block_keys, keys)), block_stiffness=f64(block_k),
        block_damping=f64(block_c), node=i32(node), entry_start=i32(np.append(first, len(owner))),
        entry=i32((SPRING_STENCIL * s + slot)[order]))
