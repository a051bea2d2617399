"""Constraint-based frictional contact (thesis 2.2, 5.3.3).

:func:`solve_contacts` solves the mixed LCP of eq. 5.5 per contact island as the LCP of
eq. 5.6 on the impulses, by projected Gauss-Seidel on 3x3 contact blocks, with a 4-sided
Coulomb friction pyramid aligned with the unconstrained tangential velocity.
"""

from softvr.contact.islands import contact_islands
from softvr.contact.pgs import ContactSolution, solve_contacts

__all__ = ["ContactSolution", "contact_islands", "solve_contacts"]
