"""A frame's metrics of a rigid scene read off its whole-scene arrays (the
:class:`~softvr.sim._rigid_step.RigidStepper`'s state) by one recorded launch instead of from
the body objects: what :class:`softvr.app.Player` reports per frame (penetration after every
step, energies after the frame's last) while the scene steps on the arrays.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from softvr.device import replayer
from softvr.dynamics import RigidBody
from softvr.dynamics.rigid_arrays import record_frame_metrics
from softvr.sim._rigid_step import RigidStepper

__all__ = ["RigidFrameMetrics", "rigid_stepper"]


def rigid_stepper(scene) -> RigidStepper | None:
    """The scene's :class:`RigidStepper` while its arrays hold the scene (it steps on rigid
    arrays and has not changed since the stepper was built), else None."""
    stepper = getattr(scene, "_stepper", None)
    if isinstance(stepper, RigidStepper) and scene.rigid_arrays and stepper.still_valid():
        return stepper
    return None


class RigidFrameMetrics:
    """A frame's metrics read off a :class:`RigidStepper`'s state arrays by one recorded launch
    (:func:`~softvr.dynamics.rigid_arrays.record_frame_metrics`, ~1 us a replay) instead of from
    the body objects (~45 us a penetration and ~75 us the energies of the box stack's five
    boxes). Each reading is of the current state (a pose or velocity the user assigned since
    the last step included), whenever it is asked for.

    Parameters
    ----------
    stepper : RigidStepper
    points : list of (int, array_like [m, 3])
        (body index, points [m] in that body's frame: a drawn surface's vertices, ``c + R p`` in
        the world) whose depth below ``planes`` :meth:`penetration` reports.
    planes : list of (array_like [3], float)
        (unit outward normal, offset ``n . point`` [m]) of each plane.
    """

    def __init__(self, stepper: RigidStepper, points=(), planes=()):
        model, device = stepper.model, stepper.model.device
        n = model.body_count
        by_body: list[list[np.ndarray]] = [[] for _ in range(n)]
        for body, local in points:
            by_body[body].append(np.asarray(local, float).reshape(-1, 3))
        local = np.concatenate([p for ps in by_body for p in ps] or [np.zeros((0, 3))])
        start = np.concatenate([[0], np.cumsum([sum(len(p) for p in ps) for ps in by_body])])
        mass = [0.0 if b.infinite_mass or not isinstance(b, RigidBody) else float(b.mass) for b in stepper.scene.bodies]
        f64, v3 = wp.float64, wp.vec3d
        self._stepper = stepper
        self._gravity = wp.zeros(1, dtype=v3, device=device)
        out = [wp.zeros(k, dtype=f64, device=device) for k in (1, n, n)]
        inputs = [wp.array(mass, dtype=f64, device=device), self._gravity,
                  wp.array(start, dtype=wp.int32, device=device), wp.array(local, dtype=v3, device=device),
                  wp.array(np.asarray([p[0] for p in planes], float).reshape(-1, 3), dtype=v3, device=device),
                  wp.array([float(p[1]) for p in planes], dtype=f64, device=device), *out]
        self._arrays = inputs  # the recorded launch points into them: they live as long as it
        self._gravity_view = self._gravity.numpy()
        self._deepest, self._kinetic, self._potential = (a.numpy() for a in out)
        self._replay = replayer(record_frame_metrics(model, stepper.state, *inputs))

    def _launch(self) -> None:
        self._stepper._sync_in()  # what the user assigned since the last step is the state now
        self._replay()

    def penetration(self) -> float:
        """Deepest of the points below any of the planes [m] now (0 when none is below)."""
        self._deepest[0] = 0.0
        self._launch()
        return float(self._deepest[0])

    def energies(self, gravity) -> tuple[float, float]:
        """(kinetic, kinetic + gravitational) energy [J] now of the movable bodies under
        ``gravity`` [3] [m/s^2] (potential zero at the origin: :func:`softvr.app.gravity_potential`)."""
        self._gravity_view[0] = gravity
        self._launch()
        kinetic = float(self._kinetic.sum())
        return kinetic, kinetic + float(self._potential.sum())
