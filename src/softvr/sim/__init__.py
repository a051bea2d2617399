"""The simulation loop: the one place that knows the order of the stages (DESIGN.md).

:class:`Scene` is the user-facing builder and stepper. A scene of rigid bodies on planes,
box and sphere primitives and rigid collision points steps as whole-scene arrays
(:class:`RigidModel`, :class:`RigidState`) through a fixed sequence of compiled launches
(:mod:`softvr.sim._rigid_step`); every other scene through the per-object path.
"""

from softvr.sim._scene import STAGES, Scene
from softvr.sim.model import RigidModel, RigidState, build_rigid_model, rigid_model_supported

__all__ = ["STAGES", "RigidModel", "RigidState", "Scene", "build_rigid_model", "rigid_model_supported"]
