"""Contact islands: bodies linked by contacts are solved together, others apart (thesis 5.3.3)."""

from __future__ import annotations

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
    parent = list(range(body_count))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    touched = set()
    for a, b in pairs:
        touched.add(a)
        if b is not None:
            touched.add(b)
            parent[find(a)] = find(b)
    groups: dict[int, list[int]] = {}
    for i in range(body_count):
        groups.setdefault(find(i), []).append(i)
    islands = sorted(groups.values())
    return sorted(islands, key=lambda g: not any(i in touched for i in g))
