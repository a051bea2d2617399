"""Compiled coupling terms of thesis eq. 5.4 on the whole-scene node arrays: each spring ties
``p_a = sum w q`` over side a's stencil to side b's, ``D = [w_k I]`` over the joined stencil
(side b's weights negated), and adds

    A_ij += (dt c + dt^2 k) w_i w_j I,      b_i += -dt k w_i (p_a - p_b)

(backward Euler about the step's start; the damping is wholly implicit, as on the per-object
path). Both are gathers through precomputed lists (one thread per block or node, no atomics).
"""

from __future__ import annotations

import warp as wp

#: Nodes in a spring's joined stencil: up to 4 of side a, then up to 4 of side b.
SPRING_STENCIL = wp.constant(8)


@wp.kernel
def coupling_blocks(block: wp.array(dtype=wp.int32), block_stiffness: wp.array(dtype=wp.float64),
                    block_damping: wp.array(dtype=wp.float64), block_row: wp.array(dtype=wp.int32),
                    block_col: wp.array(dtype=wp.int32), dt: wp.float64, blocks: wp.array(dtype=wp.mat33d),
                    d_inv: wp.array(dtype=wp.mat33d)):
    """Adds ``(dt sum c w_i w_j + dt^2 sum k w_i w_j) I`` [kg] to block ``block[t]`` of ``A``
    (written by the element assembly before); a diagonal block also rewrites ``D_A^-1``."""
    t = wp.tid()
    k = block[t]
    s = dt * block_damping[t] + dt * dt * block_stiffness[t]
    m = blocks[k] + wp.mat33d(s, wp.float64(0.0), wp.float64(0.0), wp.float64(0.0), s, wp.float64(0.0),
                              wp.float64(0.0), wp.float64(0.0), s)
    blocks[k] = m
    if block_row[k] == block_col[k]:
        d_inv[block_row[k]] = wp.inverse(m)


@wp.kernel
def coupling_forces(node: wp.array(dtype=wp.int32), entry_start: wp.array(dtype=wp.int32),
                    entry: wp.array(dtype=wp.int32), nodes: wp.array2d(dtype=wp.int32),
                    weights: wp.array2d(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
                    q: wp.array(dtype=wp.vec3d), dt: wp.float64, b: wp.array(dtype=wp.vec3d)):
    """Adds ``-dt sum k w_i (p_a - p_b)`` [kg m/s] to ``b`` of node ``node[t]``; ``entry[e]`` =
    SPRING_STENCIL spring + slot: the node is that slot of the spring's stencil."""
    t = wp.tid()
    f = wp.vec3d()
    for e in range(entry_start[t], entry_start[t + 1]):
        s = entry[e] // SPRING_STENCIL
        stretch = wp.vec3d()
        for k in range(SPRING_STENCIL):
            j = nodes[s, k]
            if j >= 0:
                stretch = stretch + weights[s, k] * q[j]
        f = f - (stiffness[s] * weights[s, entry[e] % SPRING_STENCIL]) * stretch
    i = node[t]
    b[i] = b[i] + dt * f
