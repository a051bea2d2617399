"""The unconstrained step (thesis eq. 5.2) and the integration of every rigid body of a scene
as one compiled launch each, on whole-scene arrays (:class:`softvr.sim.RigidModel` /
:class:`softvr.sim.RigidState`: any objects with those attributes).

The launches are recorded once (``wp.launch(..., record_cmd=True)``) and replayed every step,
which costs a few microseconds instead of the tens a fresh launch takes.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from softvr.device import load_kernels
from softvr.dynamics import _rigid_kernels as _k

__all__ = ["DIVERGENCE_REASONS", "record_frame_metrics", "record_integrate", "record_unconstrained"]

#: What a nonzero ``RigidState.diverged`` entry means (the divergence report names it).
DIVERGENCE_REASONS = {_k.NAN_VELOCITY: "velocity NaN/inf", _k.TOO_FAST: "speed above max(max_rate * extent, max_speed)",
                      _k.SPINNING: "angular speed above max_rate", _k.SINGULAR: "singular rotational system matrix"}


def record_unconstrained(model, state, dt: float, gravity) -> wp.Launch:
    """The launch writing ``state.free_velocity`` [n] and ``state.inv_inertia_world`` [n] from
    ``state.body_velocity`` and ``state.external`` over a step of ``dt`` [s] under ``gravity``
    [3] [m/s^2]; it also empties ``state.contacts``."""
    load_kernels(_k.unconstrained, model.device)
    return wp.launch(_k.unconstrained, dim=model.body_count, device=model.device, record_cmd=True,
                     inputs=[state.body_orientation, state.body_velocity, model.body_inv_mass, model.body_inertia,
                             model.body_implicit_gyro, state.external, wp.vec3d(*np.asarray(gravity, float)),
                             float(dt), state.free_velocity, state.inv_inertia_world, state.diverged,
                             state.contacts.count])


def record_integrate(model, state, dt: float) -> wp.Launch:
    """The launch moving every body by its constrained velocity (``state.free_velocity`` after
    the contact solve) over ``dt`` [s] into ``state.body_position`` / ``body_orientation`` /
    ``body_velocity``; a body past its divergence thresholds is flagged in ``state.diverged``."""
    load_kernels(_k.integrate, model.device)
    return wp.launch(_k.integrate, dim=model.body_count, device=model.device, record_cmd=True,
                     inputs=[state.free_velocity, model.body_inv_mass, model.body_speed_limit, model.body_spin_limit,
                             float(dt), state.body_position, state.body_orientation, state.body_velocity,
                             state.diverged])


def record_frame_metrics(model, state, mass, gravity, point_start, point_local, plane_normal, plane_offset,
                         deepest, kinetic, potential) -> wp.Launch:
    """The launch raising ``deepest`` [1] [m] to the deepest of every body's points
    ``point_local[point_start[i]:point_start[i + 1]]`` [body frame, m] below the planes
    ``plane_normal . x = plane_offset`` (zero it before: it stays at 0 when none is below) and
    writing, per body, ``kinetic`` and ``potential`` [n] [J] (of
    ``mass`` [n] [kg], 0 for a fixed body, under ``gravity[0]`` [m/s^2]) from the state's poses
    and velocities: the frame metrics of :class:`softvr.sim.frame_metrics.RigidFrameMetrics`. Every argument
    after ``state`` is a Warp array on the model's device."""
    load_kernels(_k.frame_metrics, model.device)
    return wp.launch(_k.frame_metrics, dim=model.body_count, device=model.device, record_cmd=True,
                     inputs=[state.body_position, state.body_orientation, state.body_velocity, mass,
                             model.body_inertia, gravity, point_start, point_local, plane_normal, plane_offset,
                             deepest, kinetic, potential])
