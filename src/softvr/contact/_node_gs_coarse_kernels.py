"""Compiled coarse correction of the multicolour Gauss-Seidel sweeps (thesis eq. 5.6, its outer
iteration made two-level; :mod:`softvr.contact.node_gs_coarse` records them). One source for CPU
and CUDA.

After a symmetric Gauss-Seidel sweep has written ``v^`` (forward colours, the contact nodes'
damped update and the contact PGS, backward colours), each aggregate ``g`` of a held body's free
nodes (:func:`softvr.contact.node_coarse.coarse_aggregates`) takes the rigid motion that solves
its Galerkin system over the residual the sweep left:

    r = b - A v^                                    (the aggregates' rows, whole)
    y_g = (P_g^T A P_g)^-1 P_g^T r                  P_g,i = [I, -[rho_i]x]
    v^_i += y_lin + y_ang x rho_i                   (i in g)

over the aggregate's nodes that are not contact nodes (``rho_i`` the node's offset from their
mass centre at the step's start). The contact nodes are held: their velocities are the PGS's
projection, and moving them would undo it (the fixed point stays eq. 5.5's ``A v = b + J^T
lambda``: at it ``r`` vanishes on every non-contact row, so ``y`` = 0). The aggregates' solves
are independent (block-diagonal, one thread each), all from the same ``v^``, then applied.

Without contacts the sweep's error operator becomes ``(I - Q A)(I - M^-1 A)``, ``Q = sum_g
P_g (P_g^T A P_g)^-1 P_g^T`` and ``M = (D + L) D^-1 (D + U)``: both factors are self-adjoint in
the ``A`` inner product and the second is positive semidefinite, so its eigenvalues are real
and the Chebyshev weights over bounds of the spectrum of ``I`` minus it stay sound
(:func:`softvr.contact.node_gs_coarse.gauss_seidel_coarse_spectrum` estimates them). The
aggregates' rigid motions are the smooth modes that the node sweeps remove slowest (the
shoulder's deltoid and tendons); Toselli and Widlund, Domain Decomposition Methods (2005),
ch. 2, for the two-level multiplicative Schwarz iteration.
"""

from __future__ import annotations

import warp as wp

from softvr.contact._node_coarse_kernels import store_inverse
from softvr.contact._node_jacobi_kernels import row_residual

#: Fewest free nodes (not contact nodes) an aggregate needs to take a coarse correction: its
#: six rigid motions must move them independently.
MIN_FREE = 4


@wp.kernel
def prepare_aggregates(start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32),
                       q: wp.array(dtype=wp.vec3d), mass: wp.array(dtype=wp.float64),
                       row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                       blocks: wp.array(dtype=wp.mat33d), node_aggregate: wp.array(dtype=wp.int32),
                       contact_node: wp.array(dtype=wp.int32), centre: wp.array(dtype=wp.vec3d),
                       ll: wp.array(dtype=wp.mat33d), la: wp.array(dtype=wp.mat33d), aa: wp.array(dtype=wp.mat33d),
                       active: wp.array(dtype=wp.int32)):
    """Aggregate ``g`` (nodes ``nodes[start[g]:start[g + 1]]``, ``node_aggregate`` [n] each
    node's): the mass centre [m] of its nodes that are not ``contact_node``, and the blocks of
    ``(P_g^T A P_g)^-1`` over them (``ll`` [1/kg], ``la`` [1/(kg m)], ``aa`` [1/(kg m^2)]) from
    this step's ``blocks`` by the Schur complement of the linear block; ``active[g]`` 0 where
    fewer than :data:`MIN_FREE` such nodes remain or their rotations are degenerate (the
    Schur complement's determinant under 1e-9 of its scale)."""
    g = wp.tid()
    active[g] = 0
    total = wp.float64(0.0)
    c = wp.vec3d()
    count = int(0)
    for t in range(start[g], start[g + 1]):
        i = nodes[t]
        if contact_node[i] == 0:
            total = total + mass[i]
            c = c + mass[i] * q[i]
            count = count + 1
    if count < MIN_FREE:
        return
    c = c / total
    centre[g] = c
    sll = wp.mat33d()
    sla = wp.mat33d()
    saa = wp.mat33d()
    for t in range(start[g], start[g + 1]):
        i = nodes[t]
        if contact_node[i] == 0:
            ri = wp.skew(q[i] - c)
            for k in range(row_start[i], row_start[i + 1]):
                j = block_col[k]
                if node_aggregate[j] == g and contact_node[j] == 0:
                    a = blocks[k]
                    rj = wp.skew(q[j] - c)
                    sll = sll + a
                    sla = sla - a * rj
                    saa = saa - ri * a * rj
    schur = saa - wp.transpose(sla) * wp.inverse(sll) * sla
    scale = wp.trace(schur) / wp.float64(3.0)
    if not (wp.determinant(schur) > wp.float64(1e-9) * scale * scale * scale):
        return
    store_inverse(g, sll, sla, saa, ll, la, aa)
    active[g] = 1


@wp.kernel
def coarse_velocities(start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                      row_start: wp.array(dtype=wp.int32), block_col: wp.array(dtype=wp.int32),
                      blocks: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                      contact_node: wp.array(dtype=wp.int32), centre: wp.array(dtype=wp.vec3d),
                      ll: wp.array(dtype=wp.mat33d), la: wp.array(dtype=wp.mat33d), aa: wp.array(dtype=wp.mat33d),
                      active: wp.array(dtype=wp.int32), v_hat: wp.array(dtype=wp.vec3d),
                      y_lin: wp.array(dtype=wp.vec3d), y_ang: wp.array(dtype=wp.vec3d)):
    """Aggregate ``g``'s coarse velocity ``y = (P^T A P)^-1 P^T r`` (``y_lin`` [m/s], ``y_ang``
    [rad/s]) from the residual ``r = b - A v^`` [kg m/s] of its nodes that are not contact nodes:
    their force and torque about the centre, solved (0 where not ``active``)."""
    g = wp.tid()
    force = wp.vec3d()
    torque = wp.vec3d()
    if active[g] != 0:
        c = centre[g]
        for t in range(start[g], start[g + 1]):
            i = nodes[t]
            if contact_node[i] == 0:
                r = row_residual(i, row_start, block_col, blocks, b, v_hat)
                force = force + r
                torque = torque + wp.cross(q[i] - c, r)
    y_lin[g] = ll[g] * force + la[g] * torque
    y_ang[g] = wp.transpose(la[g]) * force + aa[g] * torque


@wp.kernel
def apply_coarse(start: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32), q: wp.array(dtype=wp.vec3d),
                 contact_node: wp.array(dtype=wp.int32), centre: wp.array(dtype=wp.vec3d),
                 active: wp.array(dtype=wp.int32), y_lin: wp.array(dtype=wp.vec3d), y_ang: wp.array(dtype=wp.vec3d),
                 v_hat: wp.array(dtype=wp.vec3d)):
    """``v^_i += y_lin + y_ang x rho_i`` [m/s] over aggregate ``g``'s nodes that are not contact
    nodes (after every aggregate's :func:`coarse_velocities` read the same ``v^``)."""
    g = wp.tid()
    if active[g] == 0:
        return
    c = centre[g]
    for t in range(start[g], start[g + 1]):
        i = nodes[t]
        if contact_node[i] == 0:
            v_hat[i] = v_hat[i] + y_lin[g] + wp.cross(y_ang[g], q[i] - c)
