"""Constraint-based frictional contact with implicit adhesion (thesis 2.2, ch. 4, 5.3.3).

:func:`solve_contacts` solves the mixed LCP of eq. 5.5 per contact island as the LCP of
eq. 5.6 on the impulses, by projected Gauss-Seidel over contacts (normal row, then the two
tangent rows), with a 4-sided Coulomb friction pyramid aligned with the unconstrained
tangential velocity. :class:`Adhesion` materials make contacts adhesive: the projection
bounds follow the implicit adhesion constraints of eq. 4.16, and :class:`AdhesionState`
evolves each contact's intensity by bonding and debonding (4.3.3).
"""

from softvr.contact.adhesion import Adhesion, AdhesionState, combine
from softvr.contact.islands import contact_islands
from softvr.contact.pgs import ContactSolution, solve_contacts

__all__ = ["Adhesion", "AdhesionState", "ContactSolution", "combine", "contact_islands", "solve_contacts"]
