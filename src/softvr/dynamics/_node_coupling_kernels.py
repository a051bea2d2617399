"""Compiled coupling terms of thesis eq. 5.4 on the whole-scene node arrays: each spring ties
side a's point to side b's; ``D = [B_0, ..., B_7]`` maps the nodes of the joined stencil to the
relative point velocity, with ``B_k = w_k I`` for an FEM node (a point embedded with weight
``w_k``) or a driven node, and for a rigid side (its linear and angular node, a point at the
world offset ``r`` from the centre: velocity ``v + omega x r``) ``B = w I`` on the linear node
and ``B = -w [r]x`` on the angular one (side b's ``w`` negated). Eq. 5.4 adds

    A_ij += (dt c + dt^2 k) B_i^T B_j,      b_i += -dt k B_i^T (p_a - p_b)

(backward Euler about the step's start; the damping is wholly implicit, as on the per-object
path). The rigid sides' offsets turn with the bodies, so the blocks are summed every step, each
block and node through a precomputed gather list (one thread per spring, block or node, no
atomics).
"""

from __future__ import annotations

import warp as wp

from softvr.dynamics._rigid_kernels import _rotation

#: Nodes in a spring's joined stencil: up to 4 of side a, then up to 4 of side b.
SPRING_STENCIL = wp.constant(8)
#: Nodes of one side's stencil; a rigid side holds its linear node in slot 0 and its angular
#: node in slot 1.
SIDE = wp.constant(4)


@wp.kernel
def coupling_stretch(nodes: wp.array2d(dtype=wp.int32), weights: wp.array2d(dtype=wp.float64),
                     rigid: wp.array2d(dtype=wp.int32), local: wp.array2d(dtype=wp.vec3d),
                     q: wp.array(dtype=wp.vec3d), position: wp.array(dtype=wp.vec3d),
                     orientation: wp.array(dtype=wp.vec4d), lever: wp.array2d(dtype=wp.vec3d),
                     stretch: wp.array(dtype=wp.vec3d), items: int, offset: int):
    """Spring ``s``'s ``p_a - p_b`` [m] at the step's start, and the world offsets [m] of its
    rigid sides (``rigid[s, side]``: the side's rigid body, -1 none; ``local`` its body-frame
    point [m]; ``position`` [m], ``orientation`` (w, x, y, z): the rigid bodies' poses). A
    thread takes ``items`` of the ``s``, from (thread + ``offset``) x ``items``
    (:func:`softvr.device.blocked_replayer`)."""
    begin = (wp.tid() + offset) * items
    for s in range(begin, wp.min(begin + items, stretch.shape[0])):
        d = wp.vec3d()
        for side in range(2):
            r = rigid[s, side]
            if r >= 0:
                arm = _rotation(orientation[r]) * local[s, side]
                lever[s, side] = arm
                d = d + weights[s, side * SIDE] * (position[r] + arm)
            else:
                for k in range(side * SIDE, side * SIDE + SIDE):
                    j = nodes[s, k]
                    if j >= 0:
                        d = d + weights[s, k] * q[j]
        stretch[s] = d


@wp.func
def _weight(s: int, k: int, weights: wp.array2d(dtype=wp.float64), rigid: wp.array2d(dtype=wp.int32),
            lever: wp.array2d(dtype=wp.vec3d)) -> wp.mat33d:
    """``B_k`` of spring ``s``: ``w I``, or ``-w [r]x`` on a rigid side's angular node."""
    w = weights[s, k]
    side = k // SIDE
    if rigid[s, side] >= 0 and k % SIDE == 1:
        return -w * wp.skew(lever[s, side])
    zero = wp.float64(0.0)
    return wp.mat33d(w, zero, zero, zero, w, zero, zero, zero, w)


@wp.kernel
def coupling_blocks(block: wp.array(dtype=wp.int32), block_rigid: wp.array(dtype=wp.int32),
                    block_entry_start: wp.array(dtype=wp.int32), block_entry: wp.array(dtype=wp.int32),
                    weights: wp.array2d(dtype=wp.float64), rigid: wp.array2d(dtype=wp.int32),
                    lever: wp.array2d(dtype=wp.vec3d), stiffness: wp.array(dtype=wp.float64),
                    damping: wp.array(dtype=wp.float64), block_row: wp.array(dtype=wp.int32),
                    block_col: wp.array(dtype=wp.int32), dt: wp.float64, blocks: wp.array(dtype=wp.mat33d),
                    d_inv: wp.array(dtype=wp.mat33d), items: int, offset: int):
    """Adds ``sum (dt c + dt^2 k) B_i^T B_j`` [kg] to block ``block[t]`` of ``A``; entry codes
    ``SPRING_STENCIL^2 spring + SPRING_STENCIL i + j``. A diagonal block also rewrites
    ``D_A^-1``; a rigid node's (``block_rigid[t]``) starts from this step's ``D_A`` (``m I``
    or ``I_w``, written into ``d_inv`` by the rigid bodies' system before) as the element
    assembly writes no block of it. A thread takes ``items`` of the ``t``, from (thread +
    ``offset``) x ``items`` (:func:`softvr.device.blocked_replayer`)."""
    begin = (wp.tid() + offset) * items
    for t in range(begin, wp.min(begin + items, block.shape[0])):
        k = block[t]
        m = blocks[k]
        if block_rigid[t] != 0:
            m = wp.mat33d()
            if block_row[k] == block_col[k]:
                m = wp.inverse(d_inv[block_row[k]])
        for e in range(block_entry_start[t], block_entry_start[t + 1]):
            code = block_entry[e]
            s = code // (SPRING_STENCIL * SPRING_STENCIL)
            i = (code // SPRING_STENCIL) % SPRING_STENCIL
            j = code % SPRING_STENCIL
            scale = dt * damping[s] + dt * dt * stiffness[s]
            m = m + scale * (wp.transpose(_weight(s, i, weights, rigid, lever)) * _weight(s, j, weights, rigid, lever))
        blocks[k] = m
        if block_row[k] == block_col[k]:
            d_inv[block_row[k]] = wp.inverse(m)


@wp.kernel
def coupling_forces(node: wp.array(dtype=wp.int32), entry_start: wp.array(dtype=wp.int32),
                    entry: wp.array(dtype=wp.int32), weights: wp.array2d(dtype=wp.float64),
                    rigid: wp.array2d(dtype=wp.int32), lever: wp.array2d(dtype=wp.vec3d),
                    stiffness: wp.array(dtype=wp.float64), stretch: wp.array(dtype=wp.vec3d), dt: wp.float64,
                    b: wp.array(dtype=wp.vec3d), items: int, offset: int):
    """Adds ``-dt sum k B_i^T (p_a - p_b)`` [kg m/s, or kg m^2/s on an angular node: the
    spring's torque] to ``b`` of node ``node[t]``; ``entry[e]`` = SPRING_STENCIL spring + slot:
    the node is that slot of the spring's stencil. A thread takes ``items`` of the ``t``, from
    (thread + ``offset``) x ``items`` (:func:`softvr.device.blocked_replayer`)."""
    begin = (wp.tid() + offset) * items
    for t in range(begin, wp.min(begin + items, node.shape[0])):
        f = wp.vec3d()
        for e in range(entry_start[t], entry_start[t + 1]):
            s = entry[e] // SPRING_STENCIL
            weight = _weight(s, entry[e] % SPRING_STENCIL, weights, rigid, lever)
            f = f - stiffness[s] * (wp.transpose(weight) * stretch[s])
        i = node[t]
        b[i] = b[i] + dt * f


@wp.kernel
def pair_inverse(pair_node: wp.array2d(dtype=wp.int32), pair_block: wp.array2d(dtype=wp.int32),
                 blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d), cross: wp.array(dtype=wp.mat33d)):
    """Spring-held rigid body ``p``'s two nodes as one 6x6 block ``[[A_ll, A_la], [A_al, A_aa]]``
    of ``D_A``, inverted by its Schur complement ``S = A_aa - A_al A_ll^-1 A_la``:

        (D^-1)_aa = S^-1,  (D^-1)_la = -A_ll^-1 A_la S^-1 = (D^-1)_al^T,
        (D^-1)_ll = A_ll^-1 - (D^-1)_la A_al A_ll^-1

    into ``d_inv`` [1/kg, 1/(kg m^2)] (the diagonal blocks) and ``cross`` [1/(kg m)] (the
    off-diagonal ones, ``cross[i] = (D^-1)_{i, partner}``). The springs' levers couple the
    body's translation and rotation strongly (a light body held off its centre), which the 3x3
    node blocks split: on the shoulder the finger's angular node then stopped converging."""
    p = wp.tid()
    lin = pair_node[p, 0]
    ang = pair_node[p, 1]
    a_ll_inv = wp.inverse(blocks[pair_block[p, 0]])
    a_la = blocks[pair_block[p, 1]]
    a_al = blocks[pair_block[p, 2]]
    s_inv = wp.inverse(blocks[pair_block[p, 3]] - a_al * a_ll_inv * a_la)
    p_la = -(a_ll_inv * a_la * s_inv)
    d_inv[ang] = s_inv
    d_inv[lin] = a_ll_inv - p_la * a_al * a_ll_inv
    cross[lin] = p_la
    cross[ang] = wp.transpose(p_la)
