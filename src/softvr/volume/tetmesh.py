"""Embedding tetrahedral meshes: a regular 5-tets-per-cube grid, user meshes (their validation,
:func:`check_tets`, is :mod:`softvr.geometry`'s, shared with the FEM bodies)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softvr.errors import InputError
from softvr.files import atomic_output
from softvr.geometry import check_tets, tet_signed_volumes
from softvr.volume._volume import Volume

__all__ = ["TET_MESH_SUFFIXES", "boundary_faces", "check_tets", "grid_tet_mesh", "load_tet_mesh", "save_tet_mesh",
           "tet_edges", "tet_signed_volumes"]

#: Tet mesh files :func:`load_tet_mesh` reads (through meshio): VTK XML and legacy, Gmsh,
#: Medit, Abaqus, XDMF, MED — what TetGen, fTetWild, Gmsh and ParaView write.
TET_MESH_SUFFIXES = (".vtu", ".vtk", ".msh", ".mesh", ".inp", ".xdmf", ".med")

# Corner c = (a, b, c) of a unit cube has index a + 2 b + 4 c. A cube splits into the centre
# tet of its 4 "odd" corners and the 4 corner tets of its "even" corners; mirrored cubes
# (odd i + j + k) swap the roles, so that the diagonals on shared faces match.
_EVEN_SPLIT = np.array([[0, 1, 2, 4], [3, 1, 2, 7], [5, 1, 4, 7], [6, 2, 4, 7], [1, 2, 4, 7]])
_ODD_SPLIT = np.array([[1, 0, 3, 5], [2, 0, 3, 6], [4, 0, 5, 6], [7, 3, 5, 6], [0, 3, 5, 6]])


def _cells3(cells, name: str = "cells") -> np.ndarray:
    c = np.broadcast_to(np.asarray(cells), (3,)).copy() if np.ndim(cells) == 0 else np.asarray(cells)
    if c.shape != (3,) or not np.issubdtype(c.dtype, np.integer) or np.any(c < 1):
        raise InputError(name, "a positive int or three positive ints", repr(cells))
    return c.astype(np.int64)


def grid_tet_mesh(
    volume: Volume, cells=8, *, mask: np.ndarray | None = None, threshold: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A regular tetrahedral mesh embedding a volume: cubes split into 5 tets each.

    The grid spans the volume's footprint, the box from half a voxel before voxel
    (0, 0, 0) to half a voxel past the last voxel, with ``cells`` cubes per axis, so that
    every voxel centre lies strictly inside the mesh. Neighbouring cubes are split with alternating
    orientation so that their shared faces carry the same diagonal (a conforming mesh).
    With ``mask`` or ``threshold`` only cubes holding a selected voxel are kept, and
    unused nodes are dropped.

    Parameters
    ----------
    volume : Volume
        The volume to embed.
    cells : int or (int, int, int)
        Cubes along x, y, z.
    mask : ndarray of bool, shape [nx, ny, nz], optional
        Keep cubes that contain at least one True voxel.
    threshold : float, optional
        Keep cubes that contain at least one voxel >= threshold (an iso-surface hull).

    Returns
    -------
    nodes : ndarray, shape [node_count, 3], float64
        Rest positions [volume spacing units, world frame].
    tets : ndarray, shape [tet_count, 4], int32
        Positively oriented tetrahedra; ``tet_count = 5 * kept cubes``.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.volume import Volume, grid_tet_mesh
    >>> nodes, tets = grid_tet_mesh(Volume(np.zeros((9, 9, 9), np.uint8)), cells=2)
    >>> nodes.shape, tets.shape
    ((27, 3), (40, 4))
    """
    c = _cells3(cells)
    gx, gy, gz = (np.linspace(-0.5, n - 0.5, int(m) + 1) for n, m in zip(volume.shape, c))
    ijk = np.stack(np.meshgrid(gx, gy, gz, indexing="ij"), axis=-1).reshape(-1, 3)
    nodes = volume.index_to_world(ijk)

    ci, cj, ck = np.meshgrid(*(np.arange(m) for m in c), indexing="ij")
    ci, cj, ck = ci.ravel(), cj.ravel(), ck.ravel()
    if mask is not None or threshold is not None:
        sel = _selection(volume, mask, threshold)
        keep = _cubes_with_selection(sel, c, ci, cj, ck)
        ci, cj, ck = ci[keep], cj[keep], ck[keep]
        if ci.size == 0:
            raise InputError("mask" if mask is not None else "threshold", "at least one selected voxel", "none")
    ny, nz = c[1] + 1, c[2] + 1
    corner = np.stack(
        [((ci + a) * ny + (cj + b)) * nz + (ck + d) for d in (0, 1) for b in (0, 1) for a in (0, 1)], axis=1
    )
    odd = ((ci + cj + ck) % 2 == 1)[:, None, None]
    tets = np.where(odd, corner[:, _ODD_SPLIT], corner[:, _EVEN_SPLIT]).reshape(-1, 4)
    neg = tet_signed_volumes(nodes, tets) < 0  # a left-handed direction matrix flips all
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    used, tets = np.unique(tets, return_inverse=True)
    return nodes[used], tets.reshape(-1, 4).astype(np.int32)


def _selection(volume: Volume, mask, threshold) -> np.ndarray:
    if mask is not None:
        sel = np.asarray(mask, dtype=bool)
        if sel.shape != volume.shape:
            raise InputError("mask", f"a boolean array of the volume's shape {volume.shape}", f"shape {sel.shape}")
        return sel
    return volume.data >= threshold


def _cubes_with_selection(sel: np.ndarray, c: np.ndarray, ci, cj, ck) -> np.ndarray:
    """Whether each cube (ci, cj, ck) holds a selected voxel centre (cube bounds inclusive)."""
    keep = np.zeros(ci.size, dtype=bool)
    bounds = [np.linspace(-0.5, n - 0.5, int(m) + 1) for n, m in zip(sel.shape, c)]
    lo = [np.maximum(np.ceil(b[:-1] - 1e-9).astype(int), 0) for b in bounds]
    hi = [np.floor(b[1:] + 1e-9).astype(int) for b in bounds]
    for n, (a, b, d) in enumerate(zip(ci, cj, ck)):
        keep[n] = sel[lo[0][a] : hi[0][a] + 1, lo[1][b] : hi[1][b] + 1, lo[2][d] : hi[2][d] + 1].any()
    return keep


def load_tet_mesh(path, *, fix_orientation: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Read a tetrahedral mesh with meshio (VTK/VTU, Gmsh, Medit, Abaqus, XDMF, ...).

    Parameters
    ----------
    path : str or Path
        Mesh file holding ``tetra`` cells.
    fix_orientation : bool
        Swap two nodes of negatively oriented tets instead of rejecting them.

    Returns
    -------
    nodes : ndarray, shape [node_count, 3], float64
    tets : ndarray, shape [tet_count, 4], int32
    """
    import meshio

    p = Path(path)
    if not p.exists():
        raise InputError("path", "an existing mesh file", "no such file", str(p))
    try:
        mesh = meshio.read(p)
    except Exception as exc:
        raise InputError("file", "a mesh file meshio can read", f"{type(exc).__name__}: {exc}", str(p)) from None
    blocks = [c.data for c in mesh.cells if c.type == "tetra"]
    if not blocks:
        kinds = sorted({c.type for c in mesh.cells}) or ["none"]
        raise InputError("cells", "tetra cells", f"cell types {kinds}", str(p))
    nodes = np.asarray(mesh.points, dtype=np.float64)
    if nodes.shape[1] == 2:
        raise InputError("points", "3-D points", "2-D points", str(p))
    tets = np.concatenate(blocks).astype(np.int64)
    if fix_orientation:
        neg = tet_signed_volumes(nodes, tets) < 0
        tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return check_tets(nodes, tets, source=str(p))


def save_tet_mesh(path, nodes, tets) -> Path:
    """Write nodes [node_count, 3] and tets [tet_count, 4] (checked as :func:`check_tets`
    does) to a mesh file whose format follows the suffix (``.vtu`` for ParaView and softvr
    scenes, ``.msh``, ...; through meshio), atomically: a failed write leaves an existing file
    as it was. Returns the path."""
    import meshio

    nodes, tets = check_tets(nodes, tets, source=str(path))
    path = Path(path)
    with atomic_output(path, path.suffix) as tmp:
        meshio.write(tmp, meshio.Mesh(nodes, [("tetra", tets)]))
    return path


def boundary_faces(tets) -> np.ndarray:
    """Faces of a tet mesh that belong to one tet only, oriented outward.

    Parameters
    ----------
    tets : array_like, shape [tet_count, 4]
        Positively oriented tetrahedra.

    Returns
    -------
    ndarray of int32, shape [face_count, 3]
        Triangles whose right-handed normal points out of the mesh.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.volume import Volume, grid_tet_mesh
    >>> nodes, tets = grid_tet_mesh(Volume(np.zeros((2, 2, 2), np.uint8)), cells=1)
    >>> boundary_faces(tets).shape  # 6 cube faces, 2 triangles each
    (12, 3)
    """
    t = np.asarray(tets)
    if t.ndim != 2 or t.shape[1] != 4 or not np.issubdtype(t.dtype, np.integer):
        raise InputError("tets", "an integer array [tet_count, 4]", f"shape {t.shape}, dtype {t.dtype}")
    # Face opposite vertex k, ordered so that its normal points away from vertex k.
    faces = np.concatenate([t[:, [1, 2, 3]], t[:, [0, 3, 2]], t[:, [0, 1, 3]], t[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[np.sort(first[counts == 1])].astype(np.int32)


def tet_edges(tets) -> np.ndarray:
    """The edges [e, 2] of tetrahedra [m, 4], each once (lower node index first)."""
    t = np.asarray(tets)
    pairs = np.concatenate([t[:, [a, b]] for a, b in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))])
    return np.unique(np.sort(pairs, axis=1), axis=0)
