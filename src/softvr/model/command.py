"""``softvr tetmesh SURFACE --cell-size H [-o OUT]``: the tet mesh a scene gives a FEM body of
this surface (:func:`softvr.model.dynamics_mesh`: cubes of ``H`` metres touching it, 5 tets
each), to look at before simulating (the Blender add-on's *Preview tet mesh*) or to use as a
``tets = ...`` body.

OUT is a tet mesh file (``.vtu`` for ParaView and scenes, or any suffix
:func:`softvr.volume.save_tet_mesh` writes), or ``.npz`` with ``nodes`` [n, 3] [m] (float64),
``tets`` [m, 4] and ``edges`` [e, 2] (each tet edge once); written atomically.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from softvr.errors import InputError
from softvr.files import atomic_output, checked_file
from softvr.geometry import tet_signed_volumes
from softvr.model.build import load_mesh
from softvr.model.representations import dynamics_mesh
from softvr.volume import save_tet_mesh, tet_edges

__all__ = ["tetmesh_main", "write_tetmesh"]


def write_tetmesh(surface, cell_size: float, out=None) -> tuple[Path, np.ndarray, np.ndarray]:
    """The dynamics mesh of a surface file written to ``out`` (default: the surface's name
    with ``.vtu``); returns (path, nodes [n, 3] [m], tets [m, 4])."""
    surface = checked_file(surface, "SURFACE")  # a regular file: a FIFO would block the mesh reader
    if not (np.isfinite(cell_size) and cell_size > 0):
        raise InputError("--cell-size", "a cube size > 0 [m]", repr(cell_size))
    out = Path(out) if out is not None else surface.with_suffix(".vtu")
    vertices, triangles = load_mesh(surface)
    nodes, tets = dynamics_mesh(vertices, triangles, float(cell_size))
    if out.suffix.lower() == ".npz":
        with atomic_output(out, ".npz") as tmp:
            with open(tmp, "wb") as f:  # a file object: np.savez would add .npz to the name
                np.savez(f, nodes=np.asarray(nodes, np.float64), tets=np.asarray(tets, np.int64),
                         edges=tet_edges(tets).astype(np.int64))
    else:
        save_tet_mesh(out, nodes, tets)
    return out, nodes, tets


def tetmesh_main(argv: list[str] | None = None) -> int:
    """``softvr tetmesh SURFACE --cell-size H [-o OUT]``."""
    p = argparse.ArgumentParser(prog="softvr tetmesh",
                                description="The tet mesh a scene builds for a FEM body of this surface: cubes of "
                                            "H metres touching it, 5 tets each.")
    p.add_argument("surface", metavar="SURFACE", help="closed surface mesh (OBJ, STL, PLY, glTF / GLB, OFF), metres")
    p.add_argument("--cell-size", type=float, required=True, metavar="H", help="cube size [m] (a scene's cells)")
    p.add_argument("-o", "--out", help="tet mesh file (.vtu, ...) or .npz (nodes, tets, edges); "
                                       "default SURFACE with .vtu")
    args = p.parse_args(argv)
    out, nodes, tets = write_tetmesh(args.surface, args.cell_size, args.out)
    volume = np.abs(tet_signed_volumes(nodes, tets)).sum()
    print(f"wrote {out}: {len(nodes)} nodes, {len(tets)} tets of {args.cell_size:g} m cubes, "
          f"{volume * 1e6:.4g} cm^3")
    return 0
