"""Compiled per-body work of the rigid bodies on whole-scene node arrays: each rigid body is
two nodes, its linear velocity and its world angular velocity, whose only blocks of the step
matrix ``A`` of thesis eq. 5.2 are the diagonal ones,

    A_lin = m I,   A_ang = I_w = R I_body R^T,

so eq. 5.6's outer Jacobi with ``D_A`` the node blocks is exact on them: a sweep's update
``D_A^-1 b`` is the unconstrained velocity of :mod:`softvr.dynamics._rigid_kernels` (with its
gyroscopic term) plus ``D_A^-1 J^T lambda``. The unconstrained step and the integration are the
rigid path's kernels; these only move the velocities between its per-body arrays and the nodes.
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def rigid_system(linear_node: wp.array(dtype=wp.int32), angular_node: wp.array(dtype=wp.int32),
                 inv_mass: wp.array(dtype=wp.float64), free_velocity: wp.array(dtype=wp.spatial_vectord),
                 inv_inertia_world: wp.array(dtype=wp.mat33d), b: wp.array(dtype=wp.vec3d),
                 d_inv: wp.array(dtype=wp.mat33d)):
    """Rigid body ``r``'s nodes: ``D_A^-1`` [1/kg, 1/(kg m^2)] (``m^-1 I``, ``I_w^-1``) and
    ``b = D_A v_free`` [kg m/s, kg m^2/s] from the rigid path's unconstrained velocity
    ``free_velocity`` [m/s, rad/s] and ``inv_inertia_world``, so that ``D_A^-1 b = v_free``."""
    r = wp.tid()
    lin = linear_node[r]
    ang = angular_node[r]
    v = free_velocity[r]
    im = inv_mass[r]
    zero = wp.float64(0.0)
    d_inv[lin] = wp.mat33d(im, zero, zero, zero, im, zero, zero, zero, im)
    b[lin] = wp.vec3d(v[0], v[1], v[2]) / im
    iw_inv = inv_inertia_world[r]
    d_inv[ang] = iw_inv
    b[ang] = wp.inverse(iw_inv) * wp.vec3d(v[3], v[4], v[5])


@wp.kernel
def rigid_velocity(linear_node: wp.array(dtype=wp.int32), angular_node: wp.array(dtype=wp.int32),
                   solved: wp.array(dtype=wp.vec3d), free_velocity: wp.array(dtype=wp.spatial_vectord)):
    """The sweeps' solved velocities ``solved`` [n] of rigid body ``r``'s two nodes into the
    rigid path's ``free_velocity`` [m/s, rad/s], which its integration reads."""
    r = wp.tid()
    lin = solved[linear_node[r]]
    ang = solved[angular_node[r]]
    free_velocity[r] = wp.spatial_vectord(lin[0], lin[1], lin[2], ang[0], ang[1], ang[2])
