"""Linear co-rotational FEM soft bodies (thesis 5.1.1, [MKN+04]) with implicit integration.

Each tetrahedron's elastic force is ``f_e = -R_e K_e (R_e^T x_e - X_e)``: the linear element
stiffness ``K_e`` acts in the element's rotated frame, ``R_e`` the rotation of the polar
decomposition of its deformation gradient, so rigid rotations produce no force. The body is
advanced by backward Euler with the forces linearized at the start of the step
(thesis eq. 5.2, with G = I for node positions):

    A v1 = b,   A = M + dt (alpha M + beta K) + dt^2 K,   b = M v0 + dt (f_elastic + f_external)
    q1 = q0 + dt v1

with ``K = sum R_e K_e R_e^T`` and Rayleigh damping ``D = alpha M + beta K``; ``A`` is solved by
conjugate gradients with a Jacobi preconditioner. The per-tet work (polar decomposition, element
forces and rotated stiffness) runs compiled, one Warp thread per tet (:mod:`._fem_kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from softvr.dynamics._fem_kernels import CorotatedElements
from softvr.dynamics._sparse_system import SparseNodeSystem
from softvr.dynamics.body import ContactObject
from softvr.errors import InputError
from softvr.geometry import check_tets

__all__ = ["FemBody", "Material"]


@dataclass(frozen=True)
class Material:
    """Isotropic linear-elastic material with Rayleigh damping.

    Attributes
    ----------
    young : float [Pa]
        Young's modulus E > 0.
    poisson : float
        Poisson ratio, -1 < nu < 0.5.
    density : float [kg/m^3]
        Mass density > 0.
    alpha : float [1/s]
        Mass-proportional Rayleigh damping.
    beta : float [s]
        Stiffness-proportional Rayleigh damping.
    """

    young: float
    poisson: float
    density: float
    alpha: float = 0.0
    beta: float = 0.0

    def __post_init__(self) -> None:
        checks = (
            ("young", self.young > 0 and np.isfinite(self.young), "a finite value > 0 [Pa]"),
            ("poisson", -1.0 < self.poisson < 0.5, "a value in (-1, 0.5)"),
            ("density", self.density > 0 and np.isfinite(self.density), "a finite value > 0 [kg/m^3]"),
            ("alpha", self.alpha >= 0, "a value >= 0 [1/s]"),
            ("beta", self.beta >= 0, "a value >= 0 [s]"),
        )
        for name, ok, expected in checks:
            if not ok:
                raise InputError(f"Material.{name}", expected, repr(getattr(self, name)))

    @property
    def lame(self) -> tuple[float, float]:
        """Lamé parameters (lambda, mu) [Pa]."""
        e, nu = self.young, self.poisson
        return e * nu / ((1 + nu) * (1 - 2 * nu)), e / (2 * (1 + nu))


def _elasticity_matrix(lam: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Isotropic 6x6 elasticity matrices in Voigt order (xx, yy, zz, xy, yz, zx), shape [m, 6, 6]."""
    c = np.zeros((len(lam), 6, 6))
    c[:, :3, :3] = lam[:, None, None]
    idx = np.arange(3)
    c[:, idx, idx] += 2 * mu[:, None]
    c[:, idx + 3, idx + 3] = mu[:, None]
    return c


def _strain_matrices(rest: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per tet: B [m, 6, 12] (engineering strain from node displacements), volume [m], Dm^-1 [m, 3, 3]."""
    x = rest[tets]
    dm = (x[:, 1:] - x[:, :1]).transpose(0, 2, 1)  # columns = rest edges
    dm_inv = np.linalg.inv(dm)
    volume = np.linalg.det(dm) / 6.0
    # Shape-function gradients: rows of Dm^-1 for nodes 1..3, minus their sum for node 0.
    grad = np.empty((len(tets), 4, 3))
    grad[:, 1:] = dm_inv
    grad[:, 0] = -dm_inv.sum(axis=1)
    b = np.zeros((len(tets), 6, 12))
    for a in range(4):
        gx, gy, gz = grad[:, a, 0], grad[:, a, 1], grad[:, a, 2]
        c = 3 * a
        b[:, 0, c], b[:, 1, c + 1], b[:, 2, c + 2] = gx, gy, gz
        b[:, 3, c], b[:, 3, c + 1] = gy, gx
        b[:, 4, c + 1], b[:, 4, c + 2] = gz, gy
        b[:, 5, c], b[:, 5, c + 2] = gz, gx
    return b, volume, dm_inv


class FemBody(SparseNodeSystem, ContactObject):
    """A soft body: linear co-rotational FEM on a tetrahedral mesh.

    Parameters
    ----------
    nodes : array_like, shape [node_count, 3] [m]
        Rest node positions (also the initial state unless ``q`` is given).
    tets : array_like, shape [tet_count, 4]
        Positively oriented tetrahedra.
    material : Material
        Uniform material, or the default for ``per_tet_young`` / ``per_tet_density``.
    per_tet_young : array_like, shape [tet_count] [Pa], optional
        Young's modulus per tet (e.g. from voxel data).
    per_tet_poisson : array_like, shape [tet_count], optional
        Poisson ratio per tet, each in (-1, 0.5).
    per_tet_density : array_like, shape [tet_count] [kg/m^3], optional
    fixed : array_like of bool, shape [node_count], optional
        Boundary nodes: held at their position (clamped), or driven at ``fixed_velocity``.
    corotational : bool
        False gives plain linear FEM (R = I), which produces spurious forces under rotation.
    name : str
        Named in divergence reports.

    Attributes
    ----------
    q : ndarray, shape [node_count, 3] [m]
        Node positions (state).
    v : ndarray, shape [node_count, 3] [m/s]
        Node velocities.
    mass : ndarray, shape [node_count] [kg]
        Lumped node masses (a quarter of each incident tet's mass).
    fixed_velocity : ndarray, shape [node_count, 3] [m/s]
        Velocity of the fixed nodes over the next step (default 0, clamped); set it to drive
        them (a jaw, a clamp). Ignored at free nodes.
    step_count : int
    last_cg_iterations : int
        CG iterations of the last solve.
    cg_tolerance : float
        CG relative residual (default 1e-8).
    """

    def __init__(self, nodes, tets, material: Material, *, per_tet_young=None, per_tet_poisson=None,
                 per_tet_density=None, fixed=None, corotational: bool = True, name: str = "fem body"):
        rest, tets = check_tets(nodes, tets)
        if not isinstance(material, Material):
            raise InputError("material", "a softvr.dynamics.Material", type(material).__name__)
        m = len(tets)
        young = _per_tet(per_tet_young, material.young, m, "per_tet_young", "Pa")
        density = _per_tet(per_tet_density, material.density, m, "per_tet_density", "kg/m^3")
        self.name = name
        self.material = material
        self.rest = rest
        self.tets = tets
        self.corotational = corotational
        nu = np.full(m, material.poisson) if per_tet_poisson is None else np.asarray(per_tet_poisson, float)
        bad = ~((nu > -1.0) & (nu < 0.5)) if nu.shape == (m,) else np.ones(1, bool)
        if bad.any():
            e = int(np.argmax(bad))
            found = repr(nu[e]) if nu.shape == (m,) else f"shape {nu.shape}"
            raise InputError(f"per_tet_poisson[{e}]", f"{m} values in (-1, 0.5)", found)
        lam, mu = young * nu / ((1 + nu) * (1 - 2 * nu)), young / (2 * (1 + nu))
        b, self.tet_volume, self._dm_inv = _strain_matrices(rest, tets)
        # Element stiffness K_e = V B^T C B, shape [m, 12, 12].
        self._ke = self.tet_volume[:, None, None] * (b.transpose(0, 2, 1) @ _elasticity_matrix(lam, mu) @ b)
        self.mass = np.zeros(len(rest))
        np.add.at(self.mass, tets.ravel(), np.repeat(density * self.tet_volume / 4.0, 4))
        if np.any(self.mass <= 0):
            n = int(np.argmax(self.mass <= 0))
            raise InputError(f"nodes[{n}]", "a node used by at least one tet (mass > 0)", "an unused node")
        self.fixed = np.zeros(len(rest), bool) if fixed is None else np.asarray(fixed, bool)
        if self.fixed.shape != (len(rest),):
            raise InputError("fixed", f"a bool array of shape ({len(rest)},)", f"shape {self.fixed.shape}")
        self.q = rest.copy()
        self.v = np.zeros_like(rest)
        self.fixed_velocity = np.zeros_like(rest)
        self.step_count = 0
        self.last_cg_iterations = 0
        self.cg_tolerance = 1e-8
        self.cg_max_iterations = 1000
        self._elements = CorotatedElements(rest, tets, self._dm_inv, self._ke)
        # Scatter of the 12x12 element blocks into the CSR matrix K: entry e of the flattened
        # blocks adds to K.data[self._k_slot[e]] (one bincount per step).
        dof = (3 * tets[:, :, None] + np.arange(3)).reshape(m, 12)
        n = 3 * len(rest)
        keys = np.repeat(dof, 12, axis=1).ravel() * n + np.tile(dof, (1, 12)).ravel()
        slots, self._k_slot = np.unique(keys, return_inverse=True)
        self._k_indices = (slots % n).astype(np.int32)
        self._k_indptr = np.searchsorted(slots // n, np.arange(n + 1)).astype(np.int32)
        self._dof = dof

    # ----------------------------------------------------------------- physics
    def rotations(self, q: np.ndarray | None = None) -> np.ndarray:
        """Per-tet rotations R_e [tet_count, 3, 3] of the current (or given) positions [m]
        (polar decomposition of the deformation gradient); I for linear FEM."""
        return self._element_terms(q)[0]

    def elastic_forces(self, q: np.ndarray | None = None) -> np.ndarray:
        """Elastic node forces [node_count, 3] [N]: f_e = -R K_e (R^T x - X) per tet."""
        return self._assemble_forces(self._element_terms(q)[1])

    def stiffness_matrix(self, q: np.ndarray | None = None) -> sp.csr_matrix:
        """K = sum R K_e R^T, sparse [3 node_count, 3 node_count] [N/m] (R held constant)."""
        return self._assemble_stiffness(self._element_terms(q)[2])

    def _element_terms(self, q):
        return self._elements.compute(self.q if q is None else np.asarray(q, float), self.corotational)

    def _assemble_forces(self, element_forces: np.ndarray) -> np.ndarray:
        f = np.bincount(self._dof.ravel(), weights=element_forces.ravel(), minlength=3 * len(self.q))
        return f.reshape(-1, 3)

    def _assemble_stiffness(self, element_stiffness: np.ndarray) -> sp.csr_matrix:
        n = 3 * len(self.rest)
        data = np.bincount(self._k_slot, weights=element_stiffness.ravel(), minlength=len(self._k_indices))
        return sp.csr_matrix((data, self._k_indices, self._k_indptr), shape=(n, n))

    def kinetic_energy(self) -> float:
        """1/2 sum m v^2 [J]."""
        return 0.5 * float(np.sum(self.mass[:, None] * self.v**2))

    def _step_matrices(self, dt: float, gravity, external):
        """``A = M + dt (alpha M + beta K) + dt^2 K`` and ``b = M v0 + dt f(q0)`` (thesis eq.
        5.2; the damping force cancels ``dt D v0``) with ``K = sum R K_e R^T`` at the current
        state; ``external`` [node_count, 3] [N] adds node forces."""
        dt = self._check_dt(dt)
        mat = self.material
        _, element_forces, element_stiffness = self._element_terms(None)
        k = self._assemble_stiffness(element_stiffness)
        m_diag = np.repeat(self.mass, 3)
        f = self._assemble_forces(element_forces) + self.mass[:, None] * np.asarray(gravity, float)
        if external is not None:
            f = f + np.asarray(external, float).reshape(f.shape)
        a = sp.diags(m_diag * (1 + dt * mat.alpha)) + (dt * mat.beta + dt * dt) * k
        return a, m_diag * self.v.ravel() + dt * f.ravel()


def _per_tet(values, default: float, m: int, name: str, unit: str) -> np.ndarray:
    if values is None:
        return np.full(m, float(default))
    arr = np.asarray(values, float)
    if arr.shape != (m,):
        raise InputError(name, f"an array of shape ({m},) [{unit}]", f"shape {arr.shape}")
    bad = ~(np.isfinite(arr) & (arr > 0))
    if bad.any():
        e = int(np.argmax(bad))
        raise InputError(f"{name}[{e}]", f"a finite value > 0 [{unit}]", repr(arr[e]))
    return arr
