"""Compiled spring terms of the cloth bodies on the whole-scene node arrays (thesis eq. 5.2 with
the mass-spring forces of :mod:`softvr.dynamics.cloth`): a spring between nodes ``i`` and ``j``
(``d = q_i - q_j``, ``l = |d|``, ``u = d / l``, rest length ``L``, stiffness ``k``, damping
``c``) adds, linearized at the step's start,

    S = dt^2 k [max(0, 1 - L / l) (I - u u^T) + u u^T] + dt c u u^T
    A_ii += S,  A_jj += S,  A_ij -= S,  A_ji -= S,    b_i += -dt k (l - L) u,  b_j -= the same

(the transverse term clamped under compression, Choi & Ko, as per object). One thread per
spring writes its ``S`` and force, then one per block of ``A`` and one per node gathers them
through precomputed lists (no atomics: the same sums on every device and in every run).
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def spring_terms(springs: wp.array2d(dtype=wp.int32), rest_length: wp.array(dtype=wp.float64),
                 stiffness: wp.array(dtype=wp.float64), damping: wp.array(dtype=wp.float64),
                 q: wp.array(dtype=wp.vec3d), dt: wp.float64, block: wp.array(dtype=wp.mat33d),
                 force: wp.array(dtype=wp.vec3d)):
    """Spring ``s``'s block ``S`` [kg] and its force on node ``springs[s, 0]`` [N] at ``q`` [m]
    (coincident ends: no direction, no force along one and no block, as per object)."""
    s = wp.tid()
    d = q[springs[s, 0]] - q[springs[s, 1]]
    length = wp.length(d)
    zero = wp.float64(0.0)
    if length <= zero:
        block[s] = wp.mat33d()
        force[s] = wp.vec3d()
        return
    u = d / length
    outer = wp.outer(u, u)
    one = wp.float64(1.0)
    eye = wp.mat33d(one, zero, zero, zero, one, zero, zero, zero, one)
    k = stiffness[s]
    transverse = wp.max(zero, one - rest_length[s] / length)
    block[s] = dt * dt * k * (transverse * (eye - outer) + outer) + dt * damping[s] * outer
    force[s] = -k * (length - rest_length[s]) * u


@wp.func
def _sign(code: int) -> wp.float64:
    """+1 for an entry code 2 spring, -1 for 2 spring + 1."""
    return wp.float64(1 - 2 * (code % 2))


@wp.kernel
def spring_blocks(target: wp.array(dtype=wp.int32), entry_start: wp.array(dtype=wp.int32),
                  entry: wp.array(dtype=wp.int32), spring_block: wp.array(dtype=wp.mat33d),
                  block_row: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                  blocks: wp.array(dtype=wp.mat33d), d_inv: wp.array(dtype=wp.mat33d)):
    """Adds the springs' ``S`` [kg] to block ``target[t]`` of ``A`` (``entry`` = 2 spring + 1
    off the diagonal, where it is subtracted); a diagonal block also rewrites ``D_A^-1``."""
    t = wp.tid()
    k = target[t]
    m = blocks[k]
    for e in range(entry_start[t], entry_start[t + 1]):
        m = m + _sign(entry[e]) * spring_block[entry[e] // 2]
    blocks[k] = m
    if block_row[k] == block_col[k]:
        d_inv[block_row[k]] = wp.inverse(m)


@wp.kernel
def spring_forces(node: wp.array(dtype=wp.int32), entry_start: wp.array(dtype=wp.int32),
                  entry: wp.array(dtype=wp.int32), spring_force: wp.array(dtype=wp.vec3d), dt: wp.float64,
                  b: wp.array(dtype=wp.vec3d)):
    """Adds ``dt`` times the springs' forces [N] to ``b`` [kg m/s] of node ``node[t]``
    (``entry`` = 2 spring + 1 where the node is the spring's second end: minus the force)."""
    t = wp.tid()
    f = wp.vec3d()
    for e in range(entry_start[t], entry_start[t + 1]):
        f = f + _sign(entry[e]) * spring_force[entry[e] // 2]
    i = node[t]
    b[i] = b[i] + dt * f
