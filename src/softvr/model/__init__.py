"""Model creation (thesis 5.2): from a part's surface to its render, collision and dynamics
representations, its coupling nodes, and a collision-free start.

* :func:`collision_mesh`: quadric simplification of the render surface to a triangle budget.
* :func:`dynamics_mesh`: regular cubes over the bounding box, 5 tets each, those not touching
  the part dropped; :func:`embed_surface` binds surface vertices to them barycentrically.
* :func:`nodes_near_surface`: coupling nodes, the nodes within a radius of another part.
* :func:`intersecting_triangle_pairs`: crossing triangles of two surfaces.
* :func:`push_apart`: the collision-free start, a smooth deformation of a part's tets that
  takes its surface out of an obstacle, with a :class:`SeparationReport` of what remains.
* :class:`TissueTable` / :func:`tissue_fem_body`: FEM materials integrated from voxel
  intensities (thesis 3.3.2), :func:`voxel_owners` the tet of each voxel.
* :func:`read_parts` / :func:`build_model` / :class:`Model` / :func:`load_model`: the whole
  pipeline of ``softvr build-model PARTS.toml``, from part meshes to a scene.

Lengths in metres.
"""

from softvr.model.build import Model, PartModel, build_model, load_mesh, load_model, rigid_properties
from softvr.model.couplings import nodes_near_surface
from softvr.model.parts import CouplingSpec, PartSpec, PartsFile, read_parts
from softvr.model.intersections import intersecting_triangle_pairs
from softvr.model.representations import collision_mesh, dynamics_mesh, embed_surface
from softvr.model.separation import SeparationReport, push_apart
from softvr.model.shapes import BOX_TRIANGLES, box_corners, box_surface, icosphere
from softvr.model.tissue import CT_TISSUE, TetTissue, TissueTable, tet_tissue, tissue_fem_body, voxel_owners

__all__ = ["CouplingSpec", "Model", "PartModel", "PartSpec", "PartsFile", "SeparationReport", "build_model",
           "collision_mesh", "dynamics_mesh", "embed_surface", "intersecting_triangle_pairs", "load_mesh", "load_model",
           "nodes_near_surface", "push_apart", "read_parts"]
__all__ += ["BOX_TRIANGLES", "box_corners", "box_surface", "icosphere", "rigid_properties"]
__all__ += ["CT_TISSUE", "TetTissue", "TissueTable", "tet_tissue", "tissue_fem_body", "voxel_owners"]
