"""Cloth bodies (:class:`~softvr.dynamics.ClothBody`, mass-spring) on the whole-scene node
arrays: a cloth's vertices are free nodes like an FEM body's, and its springs are blocks of
``A`` (thesis eq. 5.2, the spring stiffness and damping linearized at the step's start, as
per object; :mod:`softvr.dynamics._node_cloth_kernels`): each spring ``(i, j)`` adds its 3x3
block to ``A_ii`` and ``A_jj`` and subtracts it from ``A_ij`` and ``A_ji``, as the coupling
springs of eq. 5.4 add theirs (:mod:`softvr.sim._node_couplings`). This module lists the
springs, the blocks of ``A`` they need and, per block and per node, the springs that add to it
(:class:`NodeCloth`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from softvr.dynamics import ClothBody, FemBody

__all__ = ["NODE_BODIES", "NodeCloth", "build_node_cloth", "cloth_block_keys", "cloth_springs"]

#: Bodies whose vertices are free nodes of the arrays (their own ``q``, ``v``, ``mass``,
#: ``fixed`` and ``fixed_velocity``), stiffened by tets or by springs.
NODE_BODIES = (FemBody, ClothBody)


@dataclass
class NodeCloth:
    """The cloth springs of a scene on the node arrays (``S`` springs, ``cb`` blocks of ``A``
    they add to, ``cn`` nodes they pull on).

    Attributes
    ----------
    spring_count : int
    springs : wp.array2d(int32) [S, 2]
        Each spring's two nodes (global).
    rest_length : wp.array(float64) [S] [m]; stiffness : wp.array(float64) [S] [N/m];
    damping : wp.array(float64) [S] [N s/m]
    spring_block : wp.array(mat33d) [S] [kg]; spring_force : wp.array(vec3d) [S] [N]
        Written every step: each spring's block ``S`` of ``A`` and its force on its first node.
    block : wp.array(int32) [cb]
        The blocks of ``A`` (in ``NodeModel.block_row`` order) the springs add to.
    block_entry_start : wp.array(int32) [cb + 1]; block_entry : wp.array(int32) [.]
        Block ``block[t]`` adds the springs ``block_entry[block_entry_start[t] :
        block_entry_start[t + 1]]``, coded 2 spring (+ 1 off the diagonal: subtracted).
    node : wp.array(int32) [cn]
        Nodes some spring pulls on.
    node_entry_start : wp.array(int32) [cn + 1]; node_entry : wp.array(int32) [.]
        Node ``node[t]``'s springs, coded 2 spring (+ 1 where it is the second end).
    """

    spring_count: int
    springs: wp.array
    rest_length: wp.array
    stiffness: wp.array
    damping: wp.array
    spring_block: wp.array
    spring_force: wp.array
    block: wp.array
    block_entry_start: wp.array
    block_entry: wp.array
    node: wp.array
    node_entry_start: wp.array
    node_entry: wp.array


def cloth_springs(scene, node_start) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every cloth spring of ``scene``: its nodes [S, 2] (global, numbered from ``node_start``
    [bodies + 1]), rest length [S] [m], stiffness [S] [N/m] and damping [S] [N s/m]."""
    cloths = [(i, b) for i, b in enumerate(scene.bodies) if isinstance(b, ClothBody)]
    pairs = [np.asarray(b.springs, np.int64) + node_start[i] for i, b in cloths]
    return (np.concatenate([np.zeros((0, 2), np.int64)] + pairs),
            np.concatenate([np.zeros(0)] + [b.rest_length for _, b in cloths]),
            np.concatenate([np.zeros(0)] + [b.spring_stiffness for _, b in cloths]),
            np.concatenate([np.zeros(0)] + [np.full(len(b.springs), b.damping) for _, b in cloths]))


def cloth_block_keys(scene, node_start, pairs: np.ndarray) -> np.ndarray:
    """Keys ``row n + col`` of the blocks of ``A`` the cloths need: every cloth node's diagonal
    block (its mass, even where no spring reaches it) and each spring's four."""
    n = int(node_start[-1])
    nodes = [np.arange(node_start[i], node_start[i + 1]) for i, b in enumerate(scene.bodies)
             if isinstance(b, ClothBody)]
    diagonal = np.concatenate([np.zeros(0, np.int64)] + nodes) * (n + 1)
    i, j = pairs[:, 0], pairs[:, 1]
    return np.concatenate([diagonal, i * n + j, j * n + i])


def _grouped(keys: np.ndarray, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct ``keys`` (sorted), and the ``codes`` grouped by key (starts, codes)."""
    order = np.argsort(keys, kind="stable")
    distinct, first = np.unique(keys[order], return_index=True)
    return distinct, np.append(first, len(keys)), codes[order]


def build_node_cloth(springs: tuple, n: int, block_keys: np.ndarray, device: str) -> NodeCloth:
    """The arrays of the :func:`cloth_springs` ``springs`` over ``n`` nodes; ``block_keys`` [nb]
    are the keys ``row n + col`` of the model's blocks (sorted), a superset of
    :func:`cloth_block_keys`' (the pattern is built with them)."""
    pairs, rest, stiffness, damping = springs
    count = len(pairs)
    i, j = pairs[:, 0], pairs[:, 1]
    s = np.arange(count, dtype=np.int64)
    keys, block_start, block_entry = _grouped(np.concatenate([i * (n + 1), j * (n + 1), i * n + j, j * n + i]),
                                              np.concatenate([2 * s, 2 * s, 2 * s + 1, 2 * s + 1]))
    node, node_start, node_entry = _grouped(np.concatenate([i, j]), np.concatenate([2 * s, 2 * s + 1]))
    d = device

    def i32(values):
        return wp.array(np.ascontiguousarray(values, np.int32), dtype=wp.int32, device=d)

    def f64(values):
        return wp.array(np.ascontiguousarray(values, np.float64), dtype=wp.float64, device=d)

    return NodeCloth(
        spring_count=count, springs=i32(pairs.reshape(-1, 2)), rest_length=f64(rest), stiffness=f64(stiffness),
        damping=f64(damping), spring_block=wp.zeros(count, dtype=wp.mat33d, device=d),
        spring_force=wp.zeros(count, dtype=wp.vec3d, device=d), block=i32(np.searchsorted(block_keys, keys)),
        block_entry_start=i32(block_start), block_entry=i32(block_entry), node=i32(node),
        node_entry_start=i32(node_start), node_entry=i32(node_entry))
