"""Contact islands: bodies linked by contacts are solved together, others apart (thesis 5.3.3).

The bodies here are the solver's units: a coupling island counts as one (thesis 5.3.3: "two
coupling islands belong to the same contact island if and only if they share a contact").
"""

from __future__ import annotations

from softvr.dynamics.islands import connected_components

__all__ = ["contact_islands"]


def contact_islands(body_count: int, pairs) -> list[list[int]]:
    """Group bodies connected by contacts (union-find); static geometry links nothing.

    Parameters
    ----------
    body_count : int
    pairs : iterable of (int, int or None)
        Bodies of each contact set (``None`` for static geometry).

    Returns
    -------
    list of list of int
        Body indices per island, islands with at least one contact first, sorted.
    """
    pairs = list(pairs)
    touched = {i for pair in pairs for i in pair if i is not None}
    islands = connected_components(body_count, [(a, b) for a, b in pairs if b is not None])
    return sorted(islands, key=lambda g: not any(i in touched for i in g))
