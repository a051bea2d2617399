"""A simulated tool driven by a haptic device through a virtual coupling (thesis 5.4).

The device's handle enters the scene as a :class:`~softvr.dynamics.KinematicBody` placed at the
position the haptic loop read last; the tool (a rigid body with collision geometry: a finger,
a probe, an arthroscope tip) is tied to it by a zero-length spring of stiffness ``k`` (a
:class:`~softvr.dynamics.Coupling`, so the coupling is implicit and stable at any ``k``). The
tool therefore stops at tissue while the hand goes on, and the stretched spring is the force
the hand feels, ``F = k (x_tool - x_handle)``.

A hand holds the tool's orientation too: a stylus, a probe or a fingertip does not roll
over the tissue like a free ball. With ``angular_stiffness`` ``k_r`` > 0 the one spring at the
tip becomes six, of ``k / 6`` and ``c / 6``, at ``tip +- l e_i`` on the tool's axes and at the
same offsets (turned as the tool started) about the handle, ``l = sqrt(3 k_r / (2 k))``: the
orientation springs of a 6-dof virtual coupling [OL06] built of the thesis's zero-length springs
(eq. 5.4). Their stretches sum to six times the tip's, for any rotation, so the translation
and the hand's force ``k (x_tip - x_handle)`` are the one spring's; a turn by ``theta`` about
any axis stores ``(2/3) k l^2 (1 - cos theta)``, a restoring torque ``k_r sin theta`` damped
by ``c_r = c k_r / k``. The torque is the hand's grip, which a 3-dof device does not render
(its gimbal only reads the stylus's orientation): the hand feels the force alone, but now with
the friction a held tool meets, ``mu`` times the normal force when it slides, instead of the
free ball's rolling. (It also keeps the light tool's spin out of its contacts' iteration: see
docs/physics-core.md, "A held tool's orientation".)

After every simulation step :meth:`HapticTool.publish` gives the loop its linearization
(:class:`~softvr.haptics.HandleModel`): ``F0`` as above and ``K = -k P``, ``P`` the projector
onto the directions the tool's contacts block (the span of the normals of its pushing
contacts). Moving the hand further along a blocked direction stretches the spring one for
one; along a free one the tool follows. This is the rigid-contact limit of the handle-space
linearization of [GO09].
"""

from __future__ import annotations

import numpy as np

from softvr.dynamics import Coupling, KinematicBody, RigidPoints
from softvr.errors import InputError
from softvr.haptics.loop import HandleModel, HapticLoop

__all__ = ["HapticTool"]


class HapticTool:
    """Couple a tool body of ``scene`` to a haptic loop's handle.

    Parameters
    ----------
    scene : softvr.Scene
        Holds the tool; the handle and the coupling are added to it.
    tool : RigidBody
        The tool, already added to ``scene`` (with its collision geometry).
    loop : HapticLoop
    stiffness : float [N/m]
        Virtual coupling ``k``: the hand feels ``k`` per metre the tool lags behind it.
    damping : float [N s/m]
        Damping of the coupling (on the simulated tool; the rendered force is the spring's).
    tip : array_like, shape [3] [m]
        The point of the tool (body frame) tied to the handle.
    angular_stiffness : float [N m/rad]
        ``k_r`` holding the tool's orientation to the one it starts with (module docstring);
        0: one spring at the tip, the tool free to turn.

    Attributes
    ----------
    handle : KinematicBody
    coupling : Coupling
        One spring of ``k`` at the tip, or six of ``k / 6`` holding the orientation.
    stiffness : float [N/m]
        ``k``: what the hand feels per metre the tip lags (whatever the coupling's split).
    tool_index : int
        The tool's index in ``scene.bodies``.
    """

    #: Whether its loop runs in a process of its own; set by the scene builder, from the scene file.
    haptics: bool

    def __init__(self, scene, tool, loop: HapticLoop, *, stiffness: float, damping: float = 0.0, tip=(0.0, 0.0, 0.0),
                 angular_stiffness: float = 0.0):
        if not isinstance(loop, HapticLoop):
            raise InputError("loop", "a softvr.haptics.HapticLoop", type(loop).__name__)
        index = [i for i, b in enumerate(scene.bodies) if b is tool]
        if not index:
            raise InputError("tool", "a body already added to the scene", repr(getattr(tool, "name", tool)))
        if not hasattr(tool, "position"):
            raise InputError("tool", "a rigid body (RigidBody)", type(tool).__name__)
        for field, value, expected in (("stiffness", stiffness, "a finite value > 0 [N/m]"),
                                       ("angular_stiffness", angular_stiffness, "a finite value >= 0 [N m/rad]")):
            number = isinstance(value, (int, float, np.integer, np.floating)) and np.isfinite(value)
            if not (number and (value > 0 if field == "stiffness" else value >= 0)):
                raise InputError(field, expected, repr(value))
        self.scene, self.tool, self.loop, self.tool_index = scene, tool, loop, index[0]
        self.stiffness = float(stiffness)
        self.handle = KinematicBody(self._handle_pose, t0=scene.time, name="haptic handle")
        scene.add_body(self.handle)
        offsets = np.zeros((1, 3))
        if angular_stiffness > 0:
            offsets = np.sqrt(1.5 * angular_stiffness / stiffness) * np.concatenate([np.eye(3), -np.eye(3)])
        share = len(offsets)
        self.coupling = Coupling(RigidPoints(tool, np.asarray(tip, float) + offsets),
                                 RigidPoints(self.handle, offsets @ tool.rotation.T), stiffness / share,
                                 damping=damping / share, name="virtual coupling")
        scene.add_coupling(self.coupling)

    def _handle_pose(self, t: float):
        return self.loop.handle_position(), np.array([1.0, 0.0, 0.0, 0.0])

    def force(self) -> np.ndarray:
        """Force on the hand now [3] [N]: ``k (x_tip - x_handle)``, the sum of the coupling's
        springs (their stretches' mean is the tip's)."""
        return self.stiffness * self.coupling.stretch().mean(axis=0)

    def blocked_directions(self, solution) -> np.ndarray:
        """Orthonormal rows [m, 3] spanning the normals of the tool's pushing contacts in
        ``solution`` (m = 0..3)."""
        # Read from a step on arrays without building its sets' Jacobians (~2.5 ms a shoulder
        # step), nor (on the node arrays) splitting its contacts into sets.
        n = solution.pushing_normals(self.tool_index)
        if not len(n):
            return n
        _, s, vt = np.linalg.svd(n, full_matrices=False)
        return vt[s > 1e-3 * s[0]]

    def publish(self, solution) -> HandleModel:
        """Give the loop this step's handle model (call after every ``scene.step``)."""
        basis = self.blocked_directions(solution)
        model = HandleModel(position=self.handle.position.copy(), force=self.force(),
                            stiffness=-self.stiffness * (basis.T @ basis))
        self.loop.publish(model, time=self.scene.time)
        return model
