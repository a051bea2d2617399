"""A simulated tool driven by a haptic device through a virtual coupling (thesis 5.4).

The device's handle enters the scene as a :class:`~softvr.dynamics.KinematicBody` placed at the
position the haptic loop read last; the tool (a rigid body with collision geometry: a finger,
a probe, an arthroscope tip) is tied to it by a zero-length spring of stiffness ``k`` (a
:class:`~softvr.dynamics.Coupling`, so the coupling is implicit and stable at any ``k``). The
tool therefore stops at tissue while the hand goes on, and the stretched spring is the force
the hand feels, ``F = k (x_tool - x_handle)``.

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

    Attributes
    ----------
    handle : KinematicBody
    coupling : Coupling
    tool_index : int
        The tool's index in ``scene.bodies``.
    """

    #: Whether its loop runs in a process of its own; set by the scene builder, from the scene file.
    haptics: bool

    def __init__(self, scene, tool, loop: HapticLoop, *, stiffness: float, damping: float = 0.0, tip=(0.0, 0.0, 0.0)):
        if not isinstance(loop, HapticLoop):
            raise InputError("loop", "a softvr.haptics.HapticLoop", type(loop).__name__)
        index = [i for i, b in enumerate(scene.bodies) if b is tool]
        if not index:
            raise InputError("tool", "a body already added to the scene", repr(getattr(tool, "name", tool)))
        if not hasattr(tool, "position"):
            raise InputError("tool", "a rigid body (RigidBody)", type(tool).__name__)
        self.scene, self.tool, self.loop, self.tool_index = scene, tool, loop, index[0]
        self.handle = KinematicBody(self._handle_pose, t0=scene.time, name="haptic handle")
        scene.add_body(self.handle)
        self.coupling = Coupling(RigidPoints(tool, np.asarray(tip, float)[None, :]),
                                 RigidPoints(self.handle, np.zeros((1, 3))), stiffness, damping=damping,
                                 name="virtual coupling")
        scene.add_coupling(self.coupling)

    def _handle_pose(self, t: float):
        return self.loop.handle_position(), np.array([1.0, 0.0, 0.0, 0.0])

    def force(self) -> np.ndarray:
        """Force on the hand now [3] [N]: ``k (x_tip - x_handle)``."""
        return self.coupling.stiffness * self.coupling.stretch()[0]

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
                            stiffness=-self.coupling.stiffness * (basis.T @ basis))
        self.loop.publish(model, time=self.scene.time)
        return model
