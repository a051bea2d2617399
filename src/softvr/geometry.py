"""Mesh checks that several layers share: tetrahedral meshes (the volume rasterizer, FEM bodies,
the model builder) and triangle meshes (cloth): a base module, so that none of them imports
another for them. Both kinds are checked for their positions and indices by one helper."""

from __future__ import annotations

import numpy as np

from softvr.errors import InputError

__all__ = ["check_tets", "check_triangles", "tet_signed_volumes"]

#: Corners of a cell -> the words of the errors: (point, points, cell, cells, the positions' unit).
_WORDS = {3: ("vertex", "vertices", "triangle", "triangles", " [m]"), 4: ("node", "nodes", "tet", "tets", "")}


def _check_indexed(points, cells, corners: int, source: str | None, points_name: str | None = None):
    """(float64 points, integer cells as given) after checking the points' shape [n >= corners, 3]
    and finite positions, and the cells' shape [m >= 1, corners], integer type and indices in range;
    else an :class:`~softvr.errors.InputError` naming the first bad element."""
    point, plural, cell, cells_name, unit = _WORDS[corners]
    name = points_name or plural
    x = np.asarray(points)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < corners:
        raise InputError(name, f"an array [{point}_count >= {corners}, 3]{unit}", f"shape {x.shape}", source)
    x = x.astype(np.float64)
    bad = ~np.isfinite(x).all(axis=1)
    if bad.any():
        n = int(np.argmax(bad))
        raise InputError(f"{name}[{n}]", "finite coordinates", f"{x[n].tolist()} ({int(bad.sum())} such {plural})",
                         source)
    t = np.asarray(cells)
    if t.ndim != 2 or t.shape[1] != corners or t.shape[0] == 0:
        raise InputError(cells_name, f"an array [{cell}_count >= 1, {corners}] of {point} indices", f"shape {t.shape}",
                         source)
    if not np.issubdtype(t.dtype, np.integer):
        raise InputError(cells_name, f"integer {point} indices", f"dtype {t.dtype}", source)
    out = (t < 0) | (t >= x.shape[0])
    if out.any():
        e = int(np.argmax(out.any(axis=1)))
        raise InputError(f"{cells_name}[{e}]", f"{point} indices in [0, {x.shape[0] - 1}]", str(t[e].tolist()), source)
    return x, t


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
    x, t = _check_indexed(nodes, tets, 4, source, nodes_name)
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


def check_triangles(vertices, triangles, *, source: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate a triangle mesh; return (float64 vertices, int32 triangles, areas [m^2]).

    Rejects, with an :class:`~softvr.errors.InputError` naming the first bad element: wrong
    shapes, non-finite positions, indices out of range, degenerate triangles (area at most
    ``1e-12`` of the square of their longest edge, repeated vertices included), triangles listed
    twice, and vertices used by no triangle (they would have no mass).
    """
    x, t = _check_indexed(vertices, triangles, 3, source)
    t = t.astype(np.int32)
    p = x[t]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    longest = np.max(np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2), axis=1)
    degenerate = area <= 1e-12 * longest**2
    if degenerate.any():
        e = int(np.argmax(degenerate))
        raise InputError(f"triangles[{e}] = {t[e].tolist()}", "a triangle with non-zero area",
                         f"a degenerate one, area {area[e]:.3g} m^2 ({int(degenerate.sum())} of {len(t)} triangles are)",
                         source)
    keys = np.sort(t, axis=1)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    dup = first[inverse] != np.arange(len(t))
    if dup.any():
        e = int(np.argmax(dup))
        raise InputError(f"triangles[{e}] = {t[e].tolist()}", "each triangle listed once",
                         f"a repeat of triangles[{int(first[inverse[e]])}]", source)
    used = np.zeros(len(x), bool)
    used[t.ravel()] = True
    if not used.all():
        n = int(np.argmax(~used))
        raise InputError(f"vertices[{n}]", "a vertex used by at least one triangle (mass > 0)", "an unused vertex", source)
    return x, t, area
