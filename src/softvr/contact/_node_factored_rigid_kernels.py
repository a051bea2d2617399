"""Compiled part of the factored contact solve with rigid sides
(:mod:`softvr.contact.node_factored_rigid`): the contacts' Delassus matrix (thesis eq. 5.5)

    W_cd = sum_s sum_t B_cs X_{n(c,s) n(t,d)} B_dt^T                 [1/kg]

over each contact's slots ``s`` (its stencil's nodes and its rigid sides' angular nodes that
the solve moves), ``B_cs`` the slot's block of ``J R`` (frame rows) and ``X`` the 3 x 3 blocks
of ``R^T P^-1 R`` between the touched nodes (the kept columns of ``A_0^-1``, Woodbury's
correction applied). One thread a pair of contacts; no dense product through NumPy's BLAS
(whose threads spin on a loaded machine).
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def delassus(slot_node: wp.array2d(dtype=wp.int32), slot_block: wp.array2d(dtype=wp.mat33d),
             inverse: wp.array2d(dtype=wp.float64), w: wp.array2d(dtype=wp.float64)):
    """Block (c, d) of ``w`` [3 m, 3 m] [1/kg]: ``sum_s sum_t slot_block[c, s] X slot_block[d,
    t]^T`` with ``X`` the block of ``inverse`` [3 u, 3 u] [1/kg] at touched nodes
    ``slot_node[c, s]``, ``slot_node[d, t]`` (-1: an unused slot)."""
    c, d = wp.tid()
    acc = wp.mat33d()
    for s in range(slot_node.shape[1]):
        p = slot_node[c, s]
        if p >= 0:
            for t in range(slot_node.shape[1]):
                q = slot_node[d, t]
                if q >= 0:
                    x = wp.mat33d()
                    for i in range(3):
                        for j in range(3):
                            x[i, j] = inverse[3 * p + i, 3 * q + j]
                    acc = acc + slot_block[c, s] * x * wp.transpose(slot_block[d, t])
    for i in range(3):
        for j in range(3):
            w[3 * c + i, 3 * d + j] = acc[i, j]
