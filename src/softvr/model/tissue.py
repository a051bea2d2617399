"""Tissue from voxels: FEM materials integrated from CT intensities (thesis 3.3.2).

The thesis deforms a torso CT with a FEM whose inhomogeneity comes from "standard tables to
convert opacity values into mechanical parameter values", with nodal masses and per-element
stiffness matrices integrated from per-voxel parameters. Here:

1. A :class:`TissueTable` maps intensity (Hounsfield units for CT, or any scalar the user
   calibrates) to Young's modulus E [Pa], Poisson ratio nu and density rho [kg/m^3],
   piecewise linearly between its rows. :data:`CT_TISSUE` is the documented default.
2. Every voxel goes to the tetrahedron that contains its centre (:func:`voxel_owners`; a
   conforming mesh gives each voxel exactly one owner, ties on shared faces broken by a
   fixed sub-voxel shift).
3. Per tet, the element stiffness of a linear tetrahedron is ``K_e = B^T (int_e C dV) B``
   (B is constant in a linear tet) and C is linear in the Lamé parameters, so the exact
   integral of a voxel-wise C is C of the voxel-averaged ``lambda`` and ``mu``: the tet gets
   ``lambda_e = mean(lambda_v)``, ``mu_e = mean(mu_v)`` (and the E, nu they make), and
   ``rho_e = mean(rho_v)``; lumped nodal masses are a quarter of each incident tet's
   ``rho_e V_e``. A homogeneous volume gives exactly the homogeneous FEM; the total mass is
   the integral of the voxels' density up to voxelization (voxels cut by the mesh surface).

Lengths: the volume's own units (millimetres for DICOM / NIfTI CT) times ``unit`` [m per
volume unit] become metres for the FEM.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from softvr.device import load_kernels, resolve_device
from softvr.dynamics import FemBody, Material
from softvr.errors import InputError, raise_all
from softvr.geometry import check_tets
from softvr.model._tissue_kernels import voxel_owner_kernel
from softvr.volume import Volume

__all__ = ["CT_TISSUE", "TetTissue", "TissueTable", "tet_tissue", "tissue_fem_body", "voxel_owners"]


@dataclass(frozen=True)
class TissueTable:
    """Intensity -> (E [Pa], nu, rho [kg/m^3]), piecewise linear between rows, constant past
    the ends.

    Attributes
    ----------
    intensity : tuple of float, increasing
        Row keys (HU for CT).
    young : tuple of float [Pa]
    poisson : tuple of float, each in (-1, 0.5)
    density : tuple of float [kg/m^3]
    """

    intensity: tuple
    young: tuple
    poisson: tuple
    density: tuple

    def __post_init__(self) -> None:
        keys = np.asarray(self.intensity, float)
        n = len(keys)
        problems = []
        if n < 1 or not np.all(np.diff(keys) > 0) or not np.isfinite(keys).all():
            problems.append(("intensity", "increasing finite keys", repr(self.intensity)))
        for name, low, high in (("young", 0.0, np.inf), ("poisson", -1.0, 0.5), ("density", 0.0, np.inf)):
            v = np.asarray(getattr(self, name), float)
            if v.shape != (n,) or not np.isfinite(v).all() or not np.all((v > low) & (v < high)):
                problems.append((name, f"{n} finite values in ({low:g}, {high:g})", repr(getattr(self, name))))
        if problems:
            raise_all(problems, "TissueTable", "tissue table")

    def __call__(self, values) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(E [Pa], nu, rho [kg/m^3]) of ``values`` (any shape; float32 arrays of that shape)."""
        v = np.asarray(values, np.float32)
        k = np.asarray(self.intensity, np.float32)
        young, poisson, density = (np.interp(v, k, np.asarray(getattr(self, f), np.float32)).astype(np.float32)
                                   for f in ("young", "poisson", "density"))
        return young, poisson, density


#: Default CT table (HU). Air and lung are kept soft but not void (the mesh stays solvable);
#: fat, muscle / organ and bone values are of the order given in the soft-tissue and bone
#: mechanics literature (fat ~ 3 kPa, muscle and organs ~ 10-30 kPa in palpation, nearly
#: incompressible; cortical bone ~ 10 GPa, clamped here to 10 MPa — bone is effectively rigid
#: at palpation forces and an interactive implicit solve stays well conditioned; density
#: from the usual HU-density calibration).
CT_TISSUE = TissueTable(
    intensity=(-1000.0, -400.0, -100.0, 40.0, 300.0, 1500.0),
    young=(1.0e3, 2.0e3, 3.0e3, 2.0e4, 1.0e6, 1.0e7),
    poisson=(0.30, 0.35, 0.45, 0.45, 0.35, 0.30),
    density=(1.2, 600.0, 920.0, 1050.0, 1200.0, 1900.0),
)


# An irrational-ish sub-voxel shift of the sample points: no voxel centre of a mesh whose nodes
# sit on rational coordinates (grid meshes) lies on a face, so each has exactly one owner.
_SHIFT = (1.37e-6 * np.sqrt(2.0), 1.37e-6 * np.sqrt(3.0), 1.37e-6 * np.sqrt(5.0))


def voxel_owners(volume: Volume, nodes, tets, *, device: str | None = None) -> np.ndarray:
    """The tet containing each voxel centre, -1 for none: int32 [nx, ny, nz].

    Parameters
    ----------
    volume : Volume
    nodes : array_like, shape [node_count, 3]
        Mesh nodes in the volume's world frame (its own units).
    tets : array_like, shape [tet_count, 4]
    """
    nodes, tets = check_tets(nodes, tets)
    device = resolve_device(device)
    load_kernels(voxel_owner_kernel, device)
    index = volume.world_to_index(nodes)
    owner = wp.full(int(np.prod(volume.shape)), -1, dtype=wp.int32, device=device)
    wp.launch(voxel_owner_kernel, dim=len(tets), device=device,
              inputs=[wp.array(index, dtype=wp.vec3d, device=device), wp.array(tets, dtype=wp.int32, device=device),
                      wp.vec3i(*volume.shape), wp.vec3d(*_SHIFT), owner])
    return owner.numpy().reshape(volume.shape)


@dataclass
class TetTissue:
    """Per-tet materials integrated from voxels (module docstring).

    Attributes
    ----------
    young : ndarray [tet_count] [Pa]
    poisson : ndarray [tet_count]
    density : ndarray [tet_count] [kg/m^3]
    voxels : ndarray [tet_count] int
        Voxel centres inside each tet (0: the tet took the voxel nearest its centroid).
    """

    young: np.ndarray
    poisson: np.ndarray
    density: np.ndarray
    voxels: np.ndarray


def tet_tissue(volume: Volume, nodes, tets, table: TissueTable = CT_TISSUE, *, device: str | None = None) -> TetTissue:
    """Integrate the table's per-voxel materials over each tet (module docstring, step 3)."""
    if not isinstance(table, TissueTable):
        raise InputError("table", "a softvr.model.TissueTable", type(table).__name__)
    nodes, tets = check_tets(nodes, tets)
    owner = voxel_owners(volume, nodes, tets, device=device).ravel()
    young, poisson, density = table(volume.data.ravel())
    lam = young * poisson / ((1 + poisson) * (1 - 2 * poisson))
    mu = young / (2 * (1 + poisson))
    inside = owner >= 0
    m = len(tets)
    count = np.bincount(owner[inside], minlength=m).astype(float)
    sums = [np.bincount(owner[inside], weights=x[inside].astype(float), minlength=m) for x in (lam, mu, density)]
    empty = count == 0
    if empty.any():
        # Tets smaller than a voxel: the voxel nearest their centroid.
        centroid = volume.world_to_index(nodes[tets[empty]].mean(axis=1))
        ijk = np.clip(np.rint(centroid).astype(int), 0, np.asarray(volume.shape) - 1)
        flat = np.ravel_multi_index(ijk.T, volume.shape)
        for s, x in zip(sums, (lam, mu, density)):
            s[empty] = x[flat]
    mean = [s / np.maximum(count, 1) for s in sums]
    lam_e, mu_e, rho_e = mean
    young_e = mu_e * (3 * lam_e + 2 * mu_e) / (lam_e + mu_e)
    poisson_e = lam_e / (2 * (lam_e + mu_e))
    return TetTissue(young=young_e, poisson=poisson_e, density=rho_e, voxels=count.astype(int))


def tissue_fem_body(volume: Volume, nodes, tets, table: TissueTable = CT_TISSUE, *, unit: float = 1e-3,
                    alpha: float = 0.0, beta: float = 0.0, fixed=None, fix_denser_than: float | None = None,
                    name: str = "tissue", device: str | None = None):
    """A :class:`~softvr.dynamics.FemBody` of the tissue in ``volume`` embedded in (``nodes``
    [node_count, 3] in the volume's units, ``tets`` [tet_count, 4]): per-tet E, nu, rho from
    :func:`tet_tissue`, nodes in metres (times ``unit`` [m per volume unit]), Rayleigh damping
    ``alpha`` [1/s], ``beta`` [s]. ``fixed`` [node_count] bool clamps nodes; with
    ``fix_denser_than`` [kg/m^3] the nodes of every tet denser than that are clamped too (bone
    holding the soft tissue). Returns ``(body, tissue)``."""
    if not (isinstance(unit, (int, float)) and np.isfinite(unit) and unit > 0):
        raise InputError("unit", "metres per volume unit, > 0 (1e-3 for millimetres)", repr(unit))
    nodes, tets = check_tets(nodes, tets)
    tissue = tet_tissue(volume, nodes, tets, table, device=device)
    clamp = np.zeros(len(nodes), bool) if fixed is None else np.array(fixed, bool)
    if clamp.shape != (len(nodes),):
        raise InputError("fixed", f"a bool array of shape ({len(nodes)},)", f"shape {clamp.shape}")
    if fix_denser_than is not None:
        clamp[np.unique(tets[tissue.density > float(fix_denser_than)])] = True
    default = Material(float(np.median(tissue.young)), float(np.median(tissue.poisson)),
                       float(np.median(tissue.density)), alpha=alpha, beta=beta)
    body = FemBody(nodes * unit, tets, default, per_tet_young=tissue.young, per_tet_poisson=tissue.poisson,
                   per_tet_density=tissue.density, fixed=clamp, name=name)
    return body, tissue
