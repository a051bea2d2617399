"""The three representations of a part (thesis 5.2.2): render, collision and dynamics meshes.

* :func:`collision_mesh`: the render surface simplified by quadric edge collapse
  (``fast-simplification``) to a target triangle count: contacts cost per triangle, the eye
  does not need them.
* :func:`dynamics_mesh`: the part's bounding box cut into regular cubes of a chosen size, five
  tets per cube (:func:`softvr.volume.grid_tet_mesh`), keeping the tets that touch the part:
  those whose centroid lies inside the closed surface or no farther from it than the tet's
  farthest corner (a superset of the touching tets that always holds every surface vertex).
* :func:`embed_surface`: render and collision vertices bound barycentrically to the tet that
  contains them (:func:`softvr.dynamics.embed_in_tets`), so the surfaces follow the FEM.

Lengths in metres.
"""

from __future__ import annotations

import numpy as np

from softvr.collision import TriangleMesh
from softvr.dynamics import embed_in_tets
from softvr.errors import InputError
from softvr.volume import Volume, grid_tet_mesh

__all__ = ["MAX_GRID_TETS", "collision_mesh", "dynamics_mesh", "embed_surface"]

#: Most tets the grid of :func:`dynamics_mesh` may have before the ones away from the part are
#: dropped (5 per cube; 2 million is a 74^3-cube grid, ~1 GB while it is built): a finer
#: ``cell_size`` for a part this large is a unit mistake, refused before anything is allocated.
MAX_GRID_TETS = 2_000_000


def _check_surface(vertices, triangles, what: str) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, float)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or not np.isfinite(v).all():
        raise InputError(f"{what} vertices", "at least 4 finite points [vertex_count, 3] [m]", f"shape {v.shape}")
    if t.ndim != 2 or t.shape[1] != 3 or len(t) < 4 or not np.issubdtype(t.dtype, np.integer) \
            or t.min() < 0 or t.max() >= len(v):
        raise InputError(f"{what} triangles", f"at least 4 triangles [triangle_count, 3] indexing {len(v)} vertices",
                         f"shape {t.shape}")
    return v, t.astype(np.int32)


def collision_mesh(vertices, triangles, target_triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """The surface simplified to about ``target_triangles`` triangles (quadric edge collapse).

    A surface already at or below the target is returned unchanged. Returns vertices [n, 3]
    [m] and triangles [t, 3] (int32), the winding kept.
    """
    import fast_simplification  # noqa: PLC0415

    v, t = _check_surface(vertices, triangles, "collision_mesh")
    if not (isinstance(target_triangles, (int, np.integer)) and target_triangles >= 4):
        raise InputError("target_triangles", "an integer >= 4", repr(target_triangles))
    if len(t) <= target_triangles:
        return v.copy(), t.copy()
    reduction = 1.0 - target_triangles / len(t)
    v2, t2 = fast_simplification.simplify(v.astype(np.float32), t, target_reduction=reduction)
    return np.asarray(v2, float), np.asarray(t2, np.int32)


def dynamics_mesh(vertices, triangles, cell_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Tets covering a closed surface: regular cubes of ``cell_size`` [m], 5 tets each, the tets
    not touching the part dropped (module docstring). Returns nodes [n, 3] [m] and tets [m, 4]."""
    v, t = _check_surface(vertices, triangles, "dynamics_mesh")
    if not (np.isfinite(cell_size) and cell_size > 0):
        raise InputError("cell_size", "a cube size > 0 [m]", repr(cell_size))
    lo, hi = v.min(axis=0), v.max(axis=0)
    # Counted in floats first: a tiny cell_size would overflow an int cast.
    per_axis = np.maximum(1.0, np.ceil((hi - lo) / cell_size - 1e-9))
    grid = float(np.prod(per_axis)) * 5
    if grid > MAX_GRID_TETS:
        size = " x ".join(f"{x:.3g}" for x in hi - lo)
        raise InputError("cell_size", f"cubes of which a {size} m part needs at most {MAX_GRID_TETS} grid tets",
                         f"{cell_size:g} m ({grid:.3g} tets)")
    cells = per_axis.astype(int)
    pad = (cells * cell_size - (hi - lo)) / 2  # centre the part in the grid
    origin = lo - pad + cell_size / 2
    nodes, tets = grid_tet_mesh(Volume(np.zeros(tuple(cells), np.uint8), spacing=np.full(3, cell_size), origin=origin),
                                tuple(cells))
    corners = nodes[tets]
    centroid = corners.mean(axis=1)
    reach = np.linalg.norm(corners - centroid[:, None, :], axis=2).max(axis=1)
    distance = TriangleMesh(v, t).signed_distance(centroid)
    keep = distance <= reach
    used, tets = np.unique(tets[keep], return_inverse=True)
    return nodes[used], tets.reshape(-1, 4).astype(np.int32)


def embed_surface(nodes, tets, vertices) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex [n, 3] [m] bound to the one tet containing it: returns ``tet_index`` [n] and
    barycentric ``weights`` [n, 4] (an error names a vertex outside the tets)."""
    return embed_in_tets(nodes, tets, vertices, tolerance=1e-9)
