"""The simulation loop: the one place that knows the order of the stages (DESIGN.md).

:class:`Scene` is the user-facing builder and stepper. A scene of rigid bodies on planes,
box and sphere primitives and rigid collision points steps as whole-scene arrays
(:class:`RigidModel`, :class:`RigidState`) through a fixed sequence of compiled launches
(:mod:`softvr.sim._rigid_step`); a scene of FEM bodies on planes as :class:`NodeModel`,
:class:`NodeState` (:mod:`softvr.sim._node_step`), their rigid bodies as :class:`NodeRigid`; every
other scene through the per-object path.
"""

from softvr.sim._node_rigid import NodeRigid
from softvr.sim._scene import STAGES, Scene, SceneState
from softvr.sim.model import RigidModel, RigidState, build_rigid_model, rigid_model_supported
from softvr.sim.node_model import NodeContacts, NodeModel, NodeState, build_node_model, node_model_supported

__all__ = ["STAGES", "NodeContacts", "NodeModel", "NodeRigid", "NodeState", "RigidModel", "RigidState", "Scene", "SceneState",
           "build_node_model",
           "build_rigid_model", "node_model_supported", "rigid_model_supported"]
