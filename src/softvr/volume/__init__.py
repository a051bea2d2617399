"""Volume deformation by rasterizing a deformed embedding tetrahedral mesh (thesis ch. 3).

A dense CT/MRI :class:`Volume` is embedded in a tetrahedral mesh (``nodes``, ``tets``).
Moving the mesh nodes to ``deformed_nodes`` deforms the volume: :func:`deform` writes
every output voxel that lies in a deformed tetrahedron with the input value fetched at the
same barycentric coordinates in the rest tetrahedron (thesis eqs. 3.1, 3.2).

Examples
--------
>>> import numpy as np
>>> from softvr import volume as sv
>>> vol = sv.Volume(np.arange(27, dtype=np.float32).reshape(3, 3, 3), spacing=(1, 1, 1), origin=(0, 0, 0))
>>> nodes, tets = sv.grid_tet_mesh(vol, cells=1)
>>> out = sv.deform(vol, nodes, tets, nodes + (1.0, 0.0, 0.0), device="cpu")
>>> out.origin.tolist(), bool(np.allclose(out.data, vol.data, atol=1e-4))
([1.0, 0.0, 0.0], True)
"""

from softvr.volume._io import LOAD_SUFFIXES, load, save
from softvr.volume._volume import SUPPORTED_DTYPES, Volume
from softvr.volume.incremental import DeformedVolume
from softvr.volume.isosurface import iso_surface
from softvr.volume.rasterize import OutputGrid, RasterStats, Rasterizer, deform, fit_output_grid
from softvr.volume.tetmesh import (TET_MESH_SUFFIXES, boundary_faces, check_tets, grid_tet_mesh, load_tet_mesh,
                                   save_tet_mesh, tet_edges)

__all__ = [
    "DeformedVolume",
    "LOAD_SUFFIXES",
    "OutputGrid",
    "SUPPORTED_DTYPES",
    "TET_MESH_SUFFIXES",
    "RasterStats",
    "Rasterizer",
    "Volume",
    "boundary_faces",
    "check_tets",
    "deform",
    "fit_output_grid",
    "grid_tet_mesh",
    "iso_surface",
    "load",
    "load_tet_mesh",
    "save",
    "save_tet_mesh",
    "tet_edges",
]
