"""Dynamics of contact objects (thesis 5.1, 5.3.1).

So far: :class:`FemBody`, a linear co-rotational FEM soft body on tetrahedra, advanced by
backward Euler with linearized forces, ``A v = b`` (thesis eq. 5.2), solved by
preconditioned conjugate gradients. All quantities are SI: m, kg, s, Pa.
"""

from softvr.dynamics.body import ContactObject
from softvr.dynamics.fem import FemBody, Material

__all__ = ["ContactObject", "FemBody", "Material"]
