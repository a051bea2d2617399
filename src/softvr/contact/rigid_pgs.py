"""The contact solve of a whole rigid scene as one compiled launch (thesis eqs. 5.5-5.6 with
the implicit adhesion of eq. 4.16, and adhesion's evolution of 4.3.3): the array form of
:func:`softvr.contact.solve_contacts` followed by :meth:`softvr.contact.AdhesionState.evolve`
for rigid bodies (:mod:`softvr.contact._rigid_pgs_kernels`). Works on
:class:`softvr.sim.RigidModel` / :class:`softvr.sim.RigidState` (or any objects with those
attributes); the launch is recorded once and replayed every step.
"""

from __future__ import annotations

import warp as wp

from softvr.contact import _rigid_pgs_kernels as _k
from softvr.device import load_kernels

__all__ = ["RigidSolve", "record_rigid_solve"]


class RigidSolve:
    """A recorded contact solve and its statistics.

    Attributes
    ----------
    launch : wp.Launch
    stats : wp.array(float64) [2]
        After a replay: PGS sweeps made, the largest normal-velocity violation [m/s].
    """

    def __init__(self, launch, stats, scratch):
        self.launch, self.stats, self._scratch = launch, stats, scratch


def record_rigid_solve(model, state, dt: float, *, max_sweeps: int = 500, tolerance: float = 1e-5,
                       accelerate: bool = True) -> RigidSolve:
    """The launch turning ``state.free_velocity`` (unconstrained in) into the constrained
    velocities (out), solving and evolving ``state.contacts`` in place over ``dt`` [s].
    ``max_sweeps`` and ``tolerance`` [m/s] as :func:`softvr.contact.solve_contacts`'s;
    ``accelerate``: the nonsmooth nonlinear conjugate gradient over the sweeps (same fixed
    point; docs/physics-core.md), off for the plain PGS of eq. 5.6."""
    c = state.contacts
    device = model.device
    load_kernels(_k.solve_rigid_contacts, device)
    # Per contact: row responses, targets, adhesive stiffness; NNCG's sweep start and direction.
    scratch = [wp.zeros(c.capacity, dtype=dtype, device=device)
               for dtype in (wp.vec3d, wp.vec3d, wp.float64, wp.vec3d, wp.vec3d)] + [int(accelerate)]
    stats = wp.zeros(2, dtype=wp.float64, device=device)
    launch = wp.launch(_k.solve_rigid_contacts, dim=1, device=device, record_cmd=True,
                       inputs=[c.count, c.key, c.body_a, c.body_b, c.offset_a, c.offset_b, c.normal, c.gap, c.area,
                               c.friction, c.material_a, c.material_b, c.impulse, c.frame, c.gap_after, c.intensity,
                               c.slip, c.carried_count, c.carried_key, c.carried_impulse, c.carried_intensity,
                               c.carried_slip, model.materials, model.body_inv_mass, state.inv_inertia_world,
                               state.free_velocity, *scratch, float(dt), int(max_sweeps), float(tolerance), stats])
    return RigidSolve(launch, stats, scratch)
