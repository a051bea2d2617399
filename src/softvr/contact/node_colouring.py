"""A colouring of the nodes of a whole scene for multicolour block Gauss-Seidel sweeps: no two
nodes of one colour share a 3x3 block of the step matrix ``A`` (thesis eq. 5.2), so the nodes of
a colour update in parallel and the sweep is still Gauss-Seidel (each node sees every neighbour
updated earlier in the sweep). Computed once per model from ``A``'s block pattern.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["NodeColouring", "colour_nodes"]


@dataclass(frozen=True)
class NodeColouring:
    """Nodes grouped by colour (``n`` nodes, ``C`` colours).

    Attributes
    ----------
    colour : ndarray of int32 [n]
        Each node's colour, 0 .. C - 1.
    order : ndarray of int32 [n]
        The nodes sorted by colour (ascending node index within a colour).
    start : ndarray of int32 [C + 1]
        Colour ``c``'s nodes are ``order[start[c] : start[c + 1]]``.
    """

    colour: np.ndarray
    order: np.ndarray
    start: np.ndarray

    @property
    def count(self) -> int:
        """Number of colours C."""
        return len(self.start) - 1


def colour_nodes(row_start: np.ndarray, block_col: np.ndarray) -> NodeColouring:
    """Greedy colouring of the block graph of ``A`` (block-CSR pattern: node ``i``'s blocks are
    ``block_col[row_start[i] : row_start[i + 1]]`` [n + 1], [nb]), nodes taken by descending
    degree (Welsh-Powell: at most max degree + 1 colours, usually far fewer; a tet mesh's node
    has ~15-30 neighbours and takes ~10-20 colours). The pattern must be symmetric, as ``A``'s
    is. Nodes without blocks (driven collision points) get colour 0."""
    row_start = np.asarray(row_start, np.int64)
    block_col = np.asarray(block_col, np.int64)
    n = len(row_start) - 1
    if n < 0 or (len(block_col) and (block_col.min() < 0 or block_col.max() >= n)):
        raise ValueError(f"block pattern: row_start of {n + 1} entries with columns in [0, {n}) expected, found "
                         f"columns {block_col.min() if len(block_col) else '-'}..{block_col.max() if len(block_col) else '-'}")
    degree = np.diff(row_start)
    colour = np.full(n, -1, np.int64)
    # A colour is taken when some neighbour has it: mark them in a scratch row, stamped by node.
    stamp = np.full(int(degree.max(initial=0)) + 2, -1, np.int64)
    for i in np.argsort(-degree, kind="stable"):
        neighbours = colour[block_col[row_start[i]:row_start[i + 1]]]
        stamp[neighbours[neighbours >= 0]] = i
        colour[i] = int(np.argmax(stamp != i))
    count = int(colour.max(initial=-1)) + 1
    order = np.argsort(colour, kind="stable")
    start = np.searchsorted(colour[order], np.arange(count + 1))
    return NodeColouring(colour.astype(np.int32), order.astype(np.int32), start.astype(np.int32))
