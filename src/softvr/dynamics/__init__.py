"""Dynamics of contact objects (thesis 5.1, 5.3.1).

Contact objects share :class:`ContactObject`: :class:`RigidBody` (centre of mass + unit
quaternion, q_dot = G v), :class:`FemBody` (linear co-rotational FEM on tetrahedra),
:class:`ClothBody` (mass-spring), and the infinite-mass :class:`FixedBody` and scripted
:class:`KinematicBody`. Each advances by backward Euler with linearized forces, ``A v = b``
(thesis eq. 5.2). Point entities (:class:`RigidPoints`, :class:`EmbeddedPoints`) bind surface
vertices: p = f(q), p_dot = J v, F_q = J^T F_p. A :class:`Coupling` ties point entities of two
bodies by zero-length springs; coupled bodies form a :class:`CouplingIsland` (thesis 5.3.2,
eq. 5.4), stepped as one system. All quantities are SI: m, kg, s, Pa.
"""

from softvr.dynamics.body import ContactObject, StepSystem
from softvr.dynamics.cloth import ClothBody, check_triangles, grid_triangle_mesh
from softvr.dynamics.couplings import Coupling
from softvr.dynamics.fem import FemBody, Material
from softvr.dynamics.islands import CouplingIsland, connected_components, coupling_islands
from softvr.dynamics.kinematic import FixedBody, KinematicBody
from softvr.dynamics.points import EmbeddedPoints, RigidPoints, embed_in_tets
from softvr.dynamics.rigid import RigidBody, RigidFrame

__all__ = [
    "ClothBody",
    "ContactObject",
    "Coupling",
    "CouplingIsland",
    "EmbeddedPoints",
    "FemBody",
    "FixedBody",
    "KinematicBody",
    "Material",
    "RigidBody",
    "RigidFrame",
    "RigidPoints",
    "StepSystem",
    "check_triangles",
    "connected_components",
    "coupling_islands",
    "embed_in_tets",
    "grid_triangle_mesh",
]
