"""Couplings (thesis 5.3.2, eq. 5.4) on the whole-scene node arrays: which couplings the arrays
hold, the driven nodes of the kinematic and fixed bodies' coupling points, and the springs'
extra blocks of ``A`` and their forces as flat arrays (:class:`NodeCouplings`).

A coupling spring ties a point of side a, ``p_a = sum_i w_i q_i`` over a stencil of up to 4
nodes, to a point of side b; with the sides' stencils joined into one of up to 8 nodes whose
weights carry the sign (side b's negative), ``D = [B_0, ..., B_7]`` maps the node velocities
to the relative point velocity, and eq. 5.4 (:mod:`softvr.dynamics.couplings`) adds

    A_ij += (dt c + dt^2 k) B_i^T B_j,      b_i += -dt k B_i^T (p_a - p_b)

for every pair of stencil nodes ``i``, ``j``: ``B = w I`` on an FEM or driven node, and on a
rigid body's side (a point at the world offset ``r`` from its centre, moving at
``v + omega x r``) ``w I`` on its linear node and ``-w [r]x`` on its angular node, summed every
step as ``r`` turns (:mod:`softvr.dynamics._node_coupling_kernels`). A kinematic or fixed
body's coupling points are driven nodes (no tets, velocity prescribed): their columns act
through the sweeps' known velocities, i.e. on the right-hand side, and their rows are not kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import warp as wp

from softvr.dynamics import EmbeddedPoints, FemBody, FixedBody, KinematicBody, RigidBody, RigidPoints
from softvr.dynamics.node_couplings import SPRING_STENCIL
from softvr.sim._node_cloth import NODE_BODIES
from softvr.sim._node_rigid import rigid_bodies

__all__ = ["NodeCouplings", "block_jacobi_factor", "build_node_couplings", "coupling_blocks", "coupling_springs",
           "couplings_supported", "driven_points"]

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
        Their weights, side b's negated: ``sum_k w_k q[nodes_k] = p_a - p_b`` [m] (a rigid
        side: ``w`` in its linear and angular slots, the point is ``x + r``).
    rigid : wp.array2d(int32) [S, 2]
        Each side's rigid body (numbered as ``NodeModel.rigid``; -1: not rigid); a rigid side
        holds its linear node in the side's first slot, its angular node in the second.
    local : wp.array2d(vec3d) [S, 2] [m]
        A rigid side's body-frame point.
    stiffness : wp.array(float64) [S] [N/m]; damping : wp.array(float64) [S] [N s/m]
    lever : wp.array2d(vec3d) [S, 2] [m]; stretch : wp.array(vec3d) [S] [m]
        Written every step: the rigid sides' world offsets ``r`` and ``p_a - p_b`` at the
        step's start.
    block : wp.array(int32) [cb]
        The blocks of ``A`` (in ``NodeModel.block_row`` order) with coupling terms; only rows of
        FEM and rigid nodes.
    block_rigid : wp.array(int32) [cb]
        1 where the block's row is a rigid node (no element terms: the block is the springs'
        terms, on the diagonal plus ``m I`` or ``I_w``).
    block_entry_start : wp.array(int32) [cb + 1]; block_entry : wp.array(int32) [.]
        Block ``t`` sums the pairs ``block_entry[block_entry_start[t] : block_entry_start[t + 1]]``,
        coded ``SPRING_STENCIL^2 spring + SPRING_STENCIL i + j`` (``B_i^T B_j`` of the spring).
    node : wp.array(int32) [cn]
        FEM and rigid nodes in some spring's stencil.
    entry_start : wp.array(int32) [cn + 1]; entry : wp.array(int32) [.]
        Node ``node[t]``'s stencil entries ``entry[entry_start[t] : entry_start[t + 1]]``, coded
        SPRING_STENCIL spring + slot.
    partner : wp.array(int32) [n]
        The other node of a spring-held rigid body's pair (its angular node for its linear one
        and back; -1: none): the pair is one 6x6 block of ``D_A``.
    pair_node : wp.array2d(int32) [P, 2]
        Each spring-held rigid body's (linear, angular) node.
    pair_block : wp.array2d(int32) [P, 4]
        The blocks (linear, linear), (linear, angular), (angular, linear), (angular, angular) of
        ``A`` of each pair (in ``NodeModel.block_row`` order).
    cross : wp.array(mat33d) [n] [1/(kg m), the mixed unit of the 6x6 inverse]
        Written every step: ``(D^-1)_{i, partner(i)}``, the off-diagonal 3x3 block of a pair's
        6x6 inverse (``D_A^-1`` holds its diagonal blocks); zero off pairs.
    """

    spring_count: int
    driven: dict
    nodes: wp.array
    weights: wp.array
    rigid: wp.array
    local: wp.array
    stiffness: wp.array
    damping: wp.array
    lever: wp.array
    stretch: wp.array
    block: wp.array
    block_rigid: wp.array
    block_entry_start: wp.array
    block_entry: wp.array
    node: wp.array
    entry_start: wp.array
    entry: wp.array
    partner: wp.array
    pair_node: wp.array
    pair_block: wp.array
    cross: wp.array


def couplings_supported(scene) -> bool:
    """Whether the node arrays hold every coupling of ``scene``: each side either an FEM body's
    :class:`~softvr.dynamics.EmbeddedPoints` with stencils of at most :data:`SIDE` nodes, a
    kinematic, fixed or rigid body's :class:`~softvr.dynamics.RigidPoints`."""
    for coupling in scene.couplings:
        for side in (coupling.a, coupling.b):
            kind = type(side.body)
            if kind is FemBody:
                if not isinstance(side, EmbeddedPoints) or side.nodes.shape[1] > SIDE:
                    return False
            elif kind not in (RigidBody, KinematicBody, FixedBody) or not isinstance(side, RigidPoints):
                return False
    return True


def block_jacobi_factor(model, state, solved: np.ndarray) -> sp.csr_matrix:
    """``L^-1`` [3 k, 3 k] with ``L L^T = D_A`` over the ``k`` nodes ``solved`` [n] bool, ``D_A``
    the block diagonal of this step's ``A`` (``state.blocks``) the sweeps invert: 3x3 node
    blocks, and each spring-held rigid body's two nodes as one 6x6 block
    (``model.couplings.pair_node``)."""
    n = model.node_count
    rows, cols = model.block_row.numpy(), model.block_col.numpy()
    blocks = state.blocks.numpy()
    diag = np.tile(np.eye(3), (n, 1, 1))
    diag[rows[rows == cols]] = blocks[rows == cols]
    # Only the solved nodes' blocks: a fixed node's may be left unassembled (zero; fixed_only).
    l_inv = np.linalg.inv(np.linalg.cholesky(diag[solved]))
    index = np.cumsum(solved) - 1
    block_rows, block_cols, values = [index[solved]], [index[solved]], [l_inv]
    pairs = model.couplings.pair_node.numpy()
    if len(pairs):
        full = np.zeros((len(pairs), 2, 3, 2, 3))
        for x, nodes_x in enumerate(pairs.T):
            for y, nodes_y in enumerate(pairs.T):
                key = np.searchsorted(rows * n + cols, nodes_x * n + nodes_y)
                full[:, x, :, y, :] = blocks[key]
        pair_inv = np.linalg.inv(np.linalg.cholesky(full.reshape(-1, 6, 6))).reshape(-1, 2, 3, 2, 3)
        # The pairs' own 3x3 factors are replaced by the 6x6 one's blocks (lower triangular).
        keep = ~np.isin(np.arange(n)[solved], pairs.ravel())
        block_rows, block_cols, values = [block_rows[0][keep]], [block_cols[0][keep]], [values[0][keep]]
        for x, y in ((0, 0), (1, 0), (1, 1)):
            block_rows.append(index[pairs[:, x]])
            block_cols.append(index[pairs[:, y]])
            values.append(pair_inv[:, x, :, y, :])
    r, c, v = np.concatenate(block_rows), np.concatenate(block_cols), np.concatenate(values)
    k = int(solved.sum())
    dof = np.arange(3)
    at = (np.broadcast_to(3 * r[:, None, None] + dof[None, :, None], v.shape).ravel(),
          np.broadcast_to(3 * c[:, None, None] + dof[None, None, :], v.shape).ravel())
    return sp.csr_matrix((v.ravel(), at), shape=(3 * k, 3 * k))


def _driven_sides(scene, body) -> list:
    """The coupling sides on ``body``, in coupling order (a before b)."""
    return [side for c in scene.couplings for side in (c.a, c.b) if side.body is body]


def driven_points(scene, colliders: dict) -> dict:
    """Each kinematic or fixed body's driven nodes as one :class:`RigidPoints` (its collision
    points first, then its coupling sides'), or None; ``colliders`` maps body index to its
    collider."""
    out = {}
    for i, body in enumerate(scene.bodies):
        if isinstance(body, (*NODE_BODIES, RigidBody)):
            continue
        local = [colliders[i].points.local] if i in colliders else []
        local += [side.local for side in _driven_sides(scene, body)]
        out[i] = RigidPoints(body, np.concatenate(local)) if local else None
    return out


def coupling_springs(scene, node_start, colliders: dict) -> tuple:
    """Stencils [S, SPRING_STENCIL] (global nodes, -1 unused), signed weights [S, SPRING_STENCIL],
    rigid sides [S, 2] (rigid body numbered as :func:`~softvr.sim._node_rigid.rigid_bodies`, or
    -1) with their body-frame points [S, 2, 3] [m], stiffness [S] [N/m] and damping [S]
    [N s/m] of every coupling spring, over the nodes numbered from ``node_start`` [bodies + 1]
    (a driven body's: :func:`driven_points`' order; a rigid body's: linear, angular)."""
    index = {id(b): i for i, b in enumerate(scene.bodies)}
    rigid_index = {i: r for r, i in enumerate(rigid_bodies(scene))}
    next_driven = {i: len(colliders[i].points.local) if i in colliders else 0
                   for i, b in enumerate(scene.bodies) if not isinstance(b, NODE_BODIES)}
    nodes, weights, rigid, local, stiffness, damping = [], [], [], [], [], []
    for c in scene.couplings:
        count = len(c)
        n = np.full((count, SPRING_STENCIL), -1, np.int64)
        w = np.zeros((count, SPRING_STENCIL))
        r = np.full((count, 2), -1, np.int64)
        x = np.zeros((count, 2, 3))
        for s, (side, sign) in enumerate(((c.a, 1.0), (c.b, -1.0))):
            b = index[id(side.body)]
            cols = slice(s * SIDE, (s + 1) * SIDE)
            if isinstance(side, EmbeddedPoints):
                k = side.nodes.shape[1]
                # A node of weight 0 (a point on a tet's face, edge or node) adds nothing to the
                # spring: left out, it adds no blocks of zeros to A (727 of the shoulder's 7 880).
                n[:, cols.start:cols.start + k] = np.where(side.weights != 0, side.nodes + node_start[b], -1)
                w[:, cols.start:cols.start + k] = sign * side.weights
            elif b in rigid_index:
                n[:, cols.start:cols.start + 2] = node_start[b] + np.arange(2)
                w[:, cols.start:cols.start + 2] = sign
                r[:, s] = rigid_index[b]
                x[:, s] = side.local
            else:
                n[:, cols.start] = node_start[b] + next_driven[b] + np.arange(count)
                w[:, cols.start] = sign
                next_driven[b] += count
        nodes.append(n)
        weights.append(w)
        rigid.append(r)
        local.append(x)
        stiffness.append(np.full(count, c.stiffness))
        damping.append(np.full(count, c.damping))
    empty = np.zeros((0, SPRING_STENCIL))
    return (np.concatenate([empty.astype(np.int64), *nodes]), np.concatenate([empty, *weights]),
            np.concatenate([np.zeros((0, 2), np.int64), *rigid]), np.concatenate([np.zeros((0, 2, 3)), *local]),
            np.concatenate([np.zeros(0), *stiffness]), np.concatenate([np.zeros(0), *damping]))


def coupling_blocks(springs: tuple, solved_rows: np.ndarray) -> tuple:
    """The springs' blocks of ``A``: keys ``row n + col`` (sorted, unique; rows of FEM and rigid
    nodes only, ``solved_rows`` [n] bool), and each block's pairs of stencil entries, coded
    ``SPRING_STENCIL^2 spring + SPRING_STENCIL i + j``, grouped by block (starts [keys + 1],
    codes)."""
    nodes = springs[0]
    n = len(solved_rows)
    s, i, j = np.nonzero((nodes[:, :, None] >= 0) & (nodes[:, None, :] >= 0))
    rows, cols = nodes[s, i], nodes[s, j]
    keep = solved_rows[rows]
    s, i, j, rows, cols = s[keep], i[keep], j[keep], rows[keep], cols[keep]
    keys, block = np.unique(rows * n + cols, return_inverse=True)
    order = np.argsort(block, kind="stable")
    codes = ((s * SPRING_STENCIL + i) * SPRING_STENCIL + j)[order]
    return keys, np.searchsorted(block[order], np.arange(len(keys) + 1)), codes


def build_node_couplings(springs: tuple, terms: tuple, solved_rows: np.ndarray, rigid_rows: np.ndarray,
                         block_keys: np.ndarray, driven: dict, device: str) -> NodeCouplings:
    """The arrays of the :func:`coupling_springs` ``springs`` and their :func:`coupling_blocks`
    ``terms``; ``solved_rows`` [n] bool the FEM and rigid nodes, ``rigid_rows`` [n] bool the
    rigid ones; ``block_keys`` [nb] are the keys ``row n + col`` of the model's blocks (sorted),
    a superset of the terms' (the pattern is built with them); ``driven`` from
    :func:`driven_points`."""
    nodes, weights, rigid, local, stiffness, damping = springs
    keys, entry_start, entries = terms
    s, slot = np.nonzero(nodes >= 0)
    owner = nodes[s, slot]
    pulled = solved_rows[owner]
    s, slot, owner = s[pulled], slot[pulled], owner[pulled]
    order = np.argsort(owner, kind="stable")
    node, first = np.unique(owner[order], return_index=True)
    d = device

    def i32(values):
        return wp.array(np.ascontiguousarray(values, np.int32), dtype=wp.int32, device=d)

    def f64(values):
        return wp.array(np.ascontiguousarray(values, np.float64), dtype=wp.float64, device=d)

    n = len(solved_rows)
    sides = rigid >= 0
    pairs = np.unique(np.stack([nodes[:, ::SIDE][sides], nodes[:, 1::SIDE][sides]], axis=1).reshape(-1, 2), axis=0)
    partner = np.full(n, -1)
    partner[pairs[:, 0]], partner[pairs[:, 1]] = pairs[:, 1], pairs[:, 0]
    lin, ang = pairs[:, :1], pairs[:, 1:]
    pair_block = np.searchsorted(block_keys, np.hstack([lin * n + lin, lin * n + ang, ang * n + lin, ang * n + ang]))
    count = len(nodes)
    return NodeCouplings(
        spring_count=count, driven=driven, nodes=i32(nodes), weights=f64(weights), rigid=i32(rigid),
        local=wp.array(local.reshape(count, 2, 3), dtype=wp.vec3d, device=d), stiffness=f64(stiffness),
        damping=f64(damping), lever=wp.zeros((count, 2), dtype=wp.vec3d, device=d),
        stretch=wp.zeros(count, dtype=wp.vec3d, device=d), block=i32(np.searchsorted(block_keys, keys)),
        block_rigid=i32(rigid_rows[keys // len(solved_rows)]), block_entry_start=i32(entry_start),
        block_entry=i32(entries), node=i32(node), entry_start=i32(np.append(first, len(owner))),
        entry=i32((SPRING_STENCIL * s + slot)[order]), partner=i32(partner), pair_node=i32(pairs.reshape(-1, 2)),
        pair_block=i32(pair_block.reshape(-1, 4)), cross=wp.zeros(n, dtype=wp.mat33d, device=d))
