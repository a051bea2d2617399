"""Tetrahedral meshes in files: VTK unstructured grids (``.vtu`` XML, ``.vtk`` legacy).

What TetGen, fTetWild, Gmsh (through meshio) and ParaView all write, so a dynamics mesh made
elsewhere can be a scene's FEM body (``[[body]] tets = "lip.vtu"``).

Examples
--------
>>> import numpy as np, tempfile, pathlib
>>> from softvr.model import load_tet_mesh, save_tet_mesh
>>> nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
>>> path = pathlib.Path(tempfile.mkdtemp()) / "tet.vtu"
>>> _ = save_tet_mesh(path, nodes, [[0, 1, 2, 3]])
>>> q, tets = load_tet_mesh(path)
>>> bool(np.array_equal(q, nodes)), tets.tolist()
(True, [[0, 1, 2, 3]])
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softvr.errors import InputError

__all__ = ["TET_SUFFIXES", "load_tet_mesh", "save_tet_mesh"]

TET_SUFFIXES = (".vtu", ".vtk")
_VTK_TETRA = 10


def load_tet_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Nodes [n, 3] (the file's units; scenes use metres) and tets [m, 4] int32 of a VTK
    unstructured grid holding only tetrahedra (``.vtu`` or legacy ``.vtk``).

    Raises :class:`~softvr.errors.InputError` naming the file for a missing or unreadable
    file, cells that are not tetrahedra (the first such cell and its VTK type), or a mesh
    without tets."""
    from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: PLC0415

    path = Path(path)
    if path.suffix.lower() not in TET_SUFFIXES:
        raise InputError("tet mesh", f"a VTK unstructured grid file ({', '.join(TET_SUFFIXES)})",
                         repr(path.suffix or path.name), source=str(path))
    if not path.is_file():
        raise InputError("tet mesh", "an existing file", f"no file {path}", source=str(path))
    if path.suffix.lower() == ".vtu":
        from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader as Reader  # noqa: PLC0415
    else:
        from vtkmodules.vtkIOLegacy import vtkUnstructuredGridReader as Reader  # noqa: PLC0415
    reader = Reader()
    reader.SetFileName(str(path))
    reader.Update()
    grid = reader.GetOutput()
    if grid is None or grid.GetNumberOfPoints() == 0 or grid.GetPoints() is None:
        raise InputError("tet mesh", "a VTK unstructured grid with points and tetrahedra", "no points (unreadable?)",
                         source=str(path))
    nodes = vtk_to_numpy(grid.GetPoints().GetData()).astype(float)
    types = vtk_to_numpy(grid.GetCellTypes()) if grid.GetNumberOfCells() else np.zeros(0, np.uint8)
    if len(types) == 0:
        raise InputError("tet mesh", "at least one tetrahedron", "no cells", source=str(path))
    wrong = np.flatnonzero(types != _VTK_TETRA)
    if len(wrong):
        raise InputError(f"cells[{wrong[0]}]", f"tetrahedra only (VTK cell type {_VTK_TETRA})",
                         f"VTK cell type {types[wrong[0]]} ({len(wrong)} such cells)", source=str(path))
    connectivity = vtk_to_numpy(grid.GetCells().GetConnectivityArray())
    tets = connectivity.reshape(-1, 4).astype(np.int32)
    return nodes, tets


def save_tet_mesh(path, nodes, tets) -> Path:
    """Write nodes [n, 3] and tets [m, 4] as a VTK XML unstructured grid (``.vtu``, binary,
    zlib-compressed), atomically. Returns the path."""
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray  # noqa: PLC0415
    from vtkmodules.vtkCommonCore import vtkPoints  # noqa: PLC0415
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkUnstructuredGrid  # noqa: PLC0415
    from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridWriter  # noqa: PLC0415

    from softvr.render._atomic import atomic_output  # noqa: PLC0415

    nodes = np.ascontiguousarray(nodes, float)
    tets = np.asarray(tets, np.int64)
    if nodes.ndim != 2 or nodes.shape[1] != 3:
        raise InputError("nodes", "an array [n, 3]", f"shape {nodes.shape}")
    if tets.ndim != 2 or tets.shape[1] != 4 or (len(tets) and (tets.min() < 0 or tets.max() >= len(nodes))):
        raise InputError("tets", f"an array [m, 4] of node indices in [0, {len(nodes)})", f"shape {tets.shape}")
    points = vtkPoints()
    points.SetData(numpy_to_vtk(nodes, deep=True))
    cells = vtkCellArray()
    offsets = np.arange(0, 4 * len(tets) + 1, 4, dtype=np.int64)
    cells.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
                  numpy_to_vtkIdTypeArray(np.ascontiguousarray(tets.ravel()), deep=True))
    grid = vtkUnstructuredGrid()
    grid.SetPoints(points)
    grid.SetCells(_VTK_TETRA, cells)
    path = Path(path)
    with atomic_output(path, ".vtu") as tmp:
        writer = vtkXMLUnstructuredGridWriter()
        writer.SetFileName(str(tmp))
        writer.SetInputData(grid)
        writer.SetDataModeToBinary()
        writer.SetCompressorTypeToZLib()
        if not writer.Write():
            raise OSError(f"VTK could not write {path}")
    return path
