"""Tetrahedral-mesh checks that several layers share (the volume rasterizer, FEM bodies, the model
builder): a base module, so that none of them imports another for them."""

from __future__ import annotations

import numpy as np

from softvr.errors import InputError

__all__ = ["check_tets", "tet_signed_volumes"]


def tet_signed_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes of tetrahedra, ``det[x1-x0, x2-x0, x3-x0] / 6``.

    Parameters
    ----------
    nodes : ndarray, shape [node_count, 3]
        Node positions [length units].
    tets : ndarray, shape [tet_count, 4]
        Node indices per tetrahedron.

    Returns
    -------
    ndarray, shape [tet_count]
        Signed volumes [length units^3]; positive for positively oriented tets.
    """
    p = np.asarray(nodes, dtype=np.float64)[np.asarray(tets)]
    return np.linalg.det(p[:, 1:] - p[:, :1]) / 6.0


def check_tets(
    nodes: np.ndarray, tets: np.ndarray, *, source: str | None = None, nodes_name: str = "nodes"
) -> tuple[np.ndarray, np.ndarray]:
    """Validate a tetrahedral mesh and return it as (float64 nodes, int32 tets).

    Rejects, with an :class:`~softvr.errors.InputError` naming the first bad element:
    wrong shapes, non-finite positions, indices out of range, and tetrahedra that are
    inverted (negative volume) or degenerate (volume below ``1e-12`` of the mesh's
    bounding-box volume scale).

    Parameters
    ----------
    nodes : array_like, shape [node_count, 3]
        Node positions [length units].
    tets : array_like, shape [tet_count, 4]
        Node indices per tetrahedron, positively oriented.
    source : str, optional
        File or argument name to put in error messages.
    """
    x = np.asarray(nodes)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < 4:
        raise InputError(nodes_name, "an array [node_count >= 4, 3]", f"shape {x.shape}", source)
    x = x.astype(np.float64)
    bad = ~np.isfinite(x).all(axis=1)
    if bad.any():
        n = int(np.argmax(bad))
        raise InputError(f"{nodes_name}[{n}]", "finite coordinates", f"{x[n].tolist()} ({int(bad.sum())} such nodes)",
                         source)
    t = np.asarray(tets)
    if t.ndim != 2 or t.shape[1] != 4 or t.shape[0] == 0:
        raise InputError("tets", "an array [tet_count >= 1, 4] of node indices", f"shape {t.shape}", source)
    if not np.issubdtype(t.dtype, np.integer):
        raise InputError("tets", "integer node indices", f"dtype {t.dtype}", source)
    out = (t < 0) | (t >= x.shape[0])
    if out.any():
        e = int(np.argmax(out.any(axis=1)))
        raise InputError(f"tets[{e}]", f"node indices in [0, {x.shape[0] - 1}]", str(t[e].tolist()), source)
    vol = tet_signed_volumes(x, t)
    scale = float(np.prod(np.maximum(np.ptp(x, axis=0), 1e-300)))
    degenerate = np.abs(vol) <= 1e-12 * scale
    inverted = (vol < 0) & ~degenerate
    for kind, sel in (("inverted (negative volume)", inverted), ("degenerate (zero volume)", degenerate)):
        if sel.any():
            e = int(np.argmax(sel))
            raise InputError(
                f"tets[{e}] = {t[e].tolist()}",
                "a positively oriented tetrahedron",
                f"an {kind} one, volume {vol[e]:.3g} ({int(sel.sum())} of {len(t)} tets are)",
                source,
            )
    return x, t.astype(np.int32)
