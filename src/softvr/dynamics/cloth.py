"""Mass-spring cloth on a triangle mesh (a thesis 5.1.1 contact object) with implicit integration.

The state ``q`` is the vertex positions and ``v`` their velocities (G = I). Three families of
linear springs, each with its rest length taken from the initial mesh, connect the vertices:

* **stretch**: every triangle edge;
* **shear**: across every interior edge that is the *strictly longest* edge of both triangles
  sharing it (the diagonal of a quad split into two triangles, as :func:`grid_triangle_mesh`
  builds), a spring between the two opposite vertices, i.e. the quad's other diagonal;
* **bend**: across every other interior edge (shared by exactly two triangles), a spring between
  the two opposite vertices. It resists folding about that edge. On a :func:`grid_triangle_mesh`
  these join vertex ``(i, j)`` to ``(i + 2, j + 1)`` or ``(i + 1, j + 2)`` across grid lines.

Edges shared by more than two triangles (non-manifold) get no shear or bend spring, and a
shear/bend pair that is already a triangle edge is not doubled. A spring between vertices ``i``
and ``j`` with ``d = q_i - q_j``, ``l = |d|``, ``d^ = d / l``, rest length ``L``, stiffness ``k``
[N/m] and damping ``c`` [N s/m] pushes vertex ``i`` with

    f_i = -k (l - L) d^ - c (d^ . (v_i - v_j)) d^,      f_j = -f_i.

Its stiffness block (``-df_i/dq_i``, the spring's energy Hessian) is

    K_s = k [ (1 - L / l) (I - d^ d^T) + d^ d^T ],

in which the transverse term is clamped at ``max(0, 1 - L / l)``: under compression the exact
block is indefinite (a compressed spring buckles sideways), and dropping that negative part keeps
``K`` positive semi-definite and the system below positive definite, the usual fix of
Choi & Ko ("Stable but responsive cloth", SIGGRAPH 2002). The damping block is ``c d^ d^T``
(the position dependence of the damping force is neglected), plus optional mass-proportional
Rayleigh damping ``alpha M``.

The body is advanced by backward Euler with the forces linearized at the start of the step
(thesis eq. 5.2 with ``K = -dF/dq``, ``D = -dF/dv``):

    A v1 = b,   A = M + dt D + dt^2 K,   b = dt F(v0, q0) + (M + dt D) v0 = M v0 + dt f(q0)
    q1 = q0 + dt v1

where ``f`` is the spring, gravity and external force (the damping force ``-D v0`` inside
``F`` cancels against ``dt D v0``). ``A`` is symmetric positive definite and is solved by
conjugate gradients with a Jacobi preconditioner, fixed vertices removed.

Examples
--------
>>> import numpy as np
>>> cloth = ClothBody.grid(1.0, 0.5, 4, 2, density=0.2, stretch=100.0, shear=10.0, bend=1.0)
>>> cloth.q.shape, cloth.triangles.shape
((15, 3), (16, 3))
>>> round(float(cloth.mass.sum()), 12)  # density * area [kg]
0.1
>>> cloth.step(0.01)
>>> np.allclose(cloth.v, [0.0, 0.0, -0.0981])  # free fall: v = g dt
True
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from softvr.dynamics._sparse_system import SparseNodeSystem
from softvr.dynamics.body import ContactObject
from softvr.errors import InputError
from softvr.geometry import check_triangles

__all__ = ["ClothBody", "check_triangles", "grid_triangle_mesh"]

_KINDS = ("stretch", "shear", "bend")


def grid_triangle_mesh(width: float, height: float, nx: int, ny: int, *, origin=(0.0, 0.0, 0.0),
                       u_axis=(1.0, 0.0, 0.0), v_axis=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A rectangle of ``nx`` x ``ny`` quads, each split into two triangles.

    Vertex ``(i, j)``, ``0 <= i <= nx``, ``0 <= j <= ny``, has index ``j (nx + 1) + i`` and lies at
    ``origin + i (width / nx) u_axis + j (height / ny) v_axis``. Quad ``(i, j)`` with corners
    ``a = (i, j)``, ``b = (i + 1, j)``, ``c = (i + 1, j + 1)``, ``d = (i, j + 1)`` gives the
    triangles ``(a, b, c)`` and ``(a, c, d)`` (counter-clockwise about ``u_axis x v_axis``), so all
    quads are split along the same diagonal ``a-c``.

    Parameters
    ----------
    width, height : float [m]
        Side lengths along ``u_axis`` and ``v_axis``, > 0.
    nx, ny : int
        Quads along each side, >= 1.
    origin : (3,) [m]
        Position of vertex ``(0, 0)``.
    u_axis, v_axis : (3,)
        Orthogonal in-plane directions (normalized here); the cloth normal is ``u_axis x v_axis``.

    Returns
    -------
    vertices : ndarray, shape [(nx + 1) (ny + 1), 3] [m]
    triangles : ndarray of int32, shape [2 nx ny, 3]
    """
    for name, value in (("width", width), ("height", height)):
        if not (np.isfinite(value) and value > 0):
            raise InputError(name, "a finite length > 0 [m]", repr(value))
    for name, value in (("nx", nx), ("ny", ny)):
        if not (isinstance(value, (int, np.integer)) and value >= 1):
            raise InputError(name, "an integer >= 1", repr(value))
    axes = []
    for name, value in (("u_axis", u_axis), ("v_axis", v_axis)):
        a = np.asarray(value, float)
        if a.shape != (3,) or not np.isfinite(a).all() or np.linalg.norm(a) == 0:
            raise InputError(name, "a finite non-zero 3-vector", repr(value))
        axes.append(a / np.linalg.norm(a))
    u, v = axes
    if abs(u @ v) > 1e-9:
        raise InputError("v_axis", "a direction orthogonal to u_axis", f"cosine {u @ v:.3g} with u_axis")
    o = np.asarray(origin, float)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise InputError("origin", "a finite 3-vector [m]", repr(origin))
    j, i = np.mgrid[0 : ny + 1, 0 : nx + 1]
    vertices = o + (i.ravel() * (width / nx))[:, None] * u + (j.ravel() * (height / ny))[:, None] * v
    qj, qi = np.mgrid[0:ny, 0:nx]
    a = (qj * (nx + 1) + qi).ravel()
    b, c, d = a + 1, a + nx + 2, a + nx + 1
    triangles = np.stack([np.stack([a, b, c], 1), np.stack([a, c, d], 1)], 1).reshape(-1, 3)
    return vertices, triangles.astype(np.int32)


def _build_springs(x: np.ndarray, t: np.ndarray, stiffness: dict[str, float]):
    """Spring pairs [s, 2], kinds [s] (index into _KINDS) and stiffness [s] [N/m]; see the module doc."""
    # Half-edges: local edge e of triangle k joins corners e and e+1; corner e+2 is opposite.
    a = t[:, [0, 1, 2]].ravel()
    b = t[:, [1, 2, 0]].ravel()
    opposite = t[:, [2, 0, 1]].ravel()
    lengths = np.linalg.norm(x[a] - x[b], axis=1).reshape(-1, 3)
    # Strictly the longest edge of its triangle (beyond round-off): a split-quad diagonal.
    others = np.stack([np.maximum(lengths[:, 1], lengths[:, 2]), np.maximum(lengths[:, 2], lengths[:, 0]),
                       np.maximum(lengths[:, 0], lengths[:, 1])], 1)
    longest = (lengths > others * (1 + 1e-9)).ravel()
    keys = np.sort(np.stack([a, b], 1), axis=1)
    edges, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    pairs = [edges]
    kinds = [np.zeros(len(edges), np.int8)]
    # Interior edges: exactly two half-edges. Sorting by edge id puts the two next to each other.
    order = np.argsort(inverse, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    interior = np.flatnonzero(counts == 2)
    h0, h1 = order[starts[interior]], order[starts[interior] + 1]
    cross = np.sort(np.stack([opposite[h0], opposite[h1]], 1), axis=1)
    cross_kind = np.where(longest[h0] & longest[h1], 1, 2).astype(np.int8)
    keep = cross[:, 0] != cross[:, 1]
    cross, cross_kind = cross[keep], cross_kind[keep]
    if len(cross):
        # Drop pairs that are already triangle edges, and repeats (possible on small closed meshes).
        edge_ids = edges[:, 0].astype(np.int64) * len(x) + edges[:, 1]
        cross_ids = cross[:, 0].astype(np.int64) * len(x) + cross[:, 1]
        fresh = ~np.isin(cross_ids, edge_ids)
        _, first = np.unique(cross_ids, return_index=True)
        unique = np.zeros(len(cross), bool)
        unique[first] = True
        cross, cross_kind = cross[fresh & unique], cross_kind[fresh & unique]
    pairs.append(cross)
    kinds.append(cross_kind)
    all_pairs = np.concatenate(pairs).astype(np.int64)
    all_kinds = np.concatenate(kinds)
    k = np.array([stiffness[name] for name in _KINDS])[all_kinds]
    keep = k > 0  # a family with zero stiffness is left out
    return all_pairs[keep], all_kinds[keep], k[keep]


class ClothBody(SparseNodeSystem, ContactObject):
    """Mass-spring cloth on a triangle mesh, advanced by linearized backward Euler (thesis eq. 5.2).

    Spring families, forces, the compression clamp of the stiffness and the step are described in
    the module documentation (:mod:`softvr.dynamics.cloth`).

    Parameters
    ----------
    vertices : array_like, shape [vertex_count, 3] [m]
        Initial vertex positions; they are also the rest shape (spring rest lengths).
    triangles : array_like of int, shape [triangle_count, 3]
        Vertex indices per triangle.
    density : float [kg/m^2]
        Areal density > 0. Each triangle lumps a third of its mass on each of its vertices.
    stretch : float [N/m]
        Stiffness of each edge spring, > 0. Spring constants are per spring, so the cloth's
        effective membrane stiffness depends on the mesh resolution.
    shear : float [N/m]
        Stiffness of each shear (other quad diagonal) spring, >= 0; 0 leaves them out.
    bend : float [N/m]
        Stiffness of each bend spring, >= 0; 0 leaves them out.
    damping : float [N s/m]
        Damping coefficient of every spring along its direction, >= 0.
    alpha : float [1/s]
        Mass-proportional Rayleigh damping, >= 0 (also slows rigid motion, like air drag).
    fixed : array_like of bool, shape [vertex_count], optional
        Vertices held at their current position (pinned), or driven at ``fixed_velocity``.
    name : str
        Named in divergence reports.

    Attributes
    ----------
    q : ndarray, shape [vertex_count, 3] [m]
        Vertex positions (state).
    v : ndarray, shape [vertex_count, 3] [m/s]
        Vertex velocities.
    rest : ndarray, shape [vertex_count, 3] [m]
        The initial (rest) positions.
    triangles : ndarray of int32, shape [triangle_count, 3]
    area : ndarray, shape [triangle_count] [m^2]
        Rest triangle areas.
    mass : ndarray, shape [vertex_count] [kg]
        Lumped vertex masses.
    springs : ndarray of int, shape [spring_count, 2]
        Vertex pairs.
    spring_kind : ndarray of str, shape [spring_count]
        ``"stretch"``, ``"shear"`` or ``"bend"``.
    spring_stiffness : ndarray, shape [spring_count] [N/m]
    rest_length : ndarray, shape [spring_count] [m]
    fixed : ndarray of bool, shape [vertex_count]
    fixed_velocity : ndarray, shape [vertex_count, 3] [m/s]
        Velocity of the fixed vertices over the next step (default 0, pinned); set it to drive
        them (a hand, a frame). Ignored at free vertices.
    step_count : int
    last_cg_iterations : int
        CG iterations of the last solve.
    last_cg_converged : bool
        Whether the last solve reached ``cg_tolerance`` within ``cg_max_iterations``.
    cg_tolerance : float
        CG relative residual (default 1e-8).
    cg_max_iterations : int
        Default 1000.
    """

    _node_word = "vertex"

    def __init__(self, vertices, triangles, *, density: float, stretch: float, shear: float = 0.0,
                 bend: float = 0.0, damping: float = 0.0, alpha: float = 0.0, fixed=None, name: str = "cloth"):
        checks = (
            ("density", density, True, "kg/m^2"),
            ("stretch", stretch, True, "N/m"),
            ("shear", shear, False, "N/m"),
            ("bend", bend, False, "N/m"),
            ("damping", damping, False, "N s/m"),
            ("alpha", alpha, False, "1/s"),
        )
        for field, value, positive, unit in checks:
            ok = isinstance(value, (int, float, np.integer, np.floating)) and np.isfinite(value)
            ok = ok and (value > 0 if positive else value >= 0)
            if not ok:
                raise InputError(field, f"a finite value {'>' if positive else '>='} 0 [{unit}]", repr(value))
        rest, tris, area = check_triangles(vertices, triangles)
        self.name = name
        self.rest = rest
        self.triangles = tris
        self.area = area
        self.density = float(density)
        self.damping = float(damping)
        self.alpha = float(alpha)
        self.mass = np.zeros(len(rest))
        np.add.at(self.mass, tris.ravel(), np.repeat(self.density * area / 3.0, 3))
        pairs, kinds, k = _build_springs(rest, tris, {"stretch": float(stretch), "shear": float(shear),
                                                      "bend": float(bend)})
        self.springs = pairs
        self.spring_kind = np.array(_KINDS)[kinds]
        self.spring_stiffness = k
        self.rest_length = np.linalg.norm(rest[pairs[:, 0]] - rest[pairs[:, 1]], axis=1)
        self.fixed = np.zeros(len(rest), bool) if fixed is None else np.asarray(fixed, bool)
        if self.fixed.shape != (len(rest),):
            raise InputError("fixed", f"a bool array of shape ({len(rest)},)", f"shape {self.fixed.shape}")
        self.q = rest.copy()
        self.v = np.zeros_like(rest)
        self.fixed_velocity = np.zeros_like(rest)
        self.step_count = 0
        self.last_cg_iterations = 0
        self.last_cg_converged = True
        self.cg_tolerance = 1e-8
        self.cg_max_iterations = 1000
        # Scatter pattern of the four 3x3 blocks (ii, jj, ij, ji) of every spring.
        dof_i = 3 * pairs[:, 0, None] + np.arange(3)
        dof_j = 3 * pairs[:, 1, None] + np.arange(3)
        rows, cols = [], []
        for r, c in ((dof_i, dof_i), (dof_j, dof_j), (dof_i, dof_j), (dof_j, dof_i)):
            rows.append(np.broadcast_to(r[:, :, None], (len(pairs), 3, 3)).ravel())
            cols.append(np.broadcast_to(c[:, None, :], (len(pairs), 3, 3)).ravel())
        self._rows = np.concatenate(rows)
        self._cols = np.concatenate(cols)

    @classmethod
    def grid(cls, width: float, height: float, nx: int, ny: int, *, origin=(0.0, 0.0, 0.0),
             u_axis=(1.0, 0.0, 0.0), v_axis=(0.0, 1.0, 0.0), **kwargs) -> "ClothBody":
        """A rectangular cloth of ``(nx + 1) (ny + 1)`` vertices and ``2 nx ny`` triangles.

        The mesh is :func:`grid_triangle_mesh` (vertex ``(i, j)`` has index ``j (nx + 1) + i``);
        each quad gets 5 edge (stretch) springs counting shared sides once, its other diagonal as
        a shear spring, and bend springs join the vertices opposite each interior grid line.

        Parameters
        ----------
        width, height : float [m]
        nx, ny : int
        origin, u_axis, v_axis : (3,)
            Placement and orientation, see :func:`grid_triangle_mesh`.
        **kwargs
            ``density``, ``stretch``, ``shear``, ``bend``, ``damping``, ``alpha``, ``fixed``,
            ``name``, as for :class:`ClothBody`.
        """
        vertices, triangles = grid_triangle_mesh(width, height, nx, ny, origin=origin, u_axis=u_axis, v_axis=v_axis)
        return cls(vertices, triangles, **kwargs)

    # ----------------------------------------------------------------- physics
    def _geometry(self, q: np.ndarray | None):
        q = self.q if q is None else np.asarray(q, float).reshape(self.rest.shape)
        d = q[self.springs[:, 0]] - q[self.springs[:, 1]]
        length = np.linalg.norm(d, axis=1)
        # Coincident end points have no direction: they get no force along a direction.
        safe = np.where(length > 0, length, 1.0)
        unit = np.where((length > 0)[:, None], d / safe[:, None], 0.0)
        return length, safe, unit

    def _scatter(self, per_spring: np.ndarray) -> np.ndarray:
        """Vertex forces [vertex_count, 3] from the force on each spring's first vertex (second: minus)."""
        n = len(self.rest)
        f = np.zeros((n, 3))
        for c in range(3):
            f[:, c] = (np.bincount(self.springs[:, 0], per_spring[:, c], n)
                       - np.bincount(self.springs[:, 1], per_spring[:, c], n))
        return f

    def elastic_forces(self, q: np.ndarray | None = None) -> np.ndarray:
        """Spring forces [vertex_count, 3] [N] at the current (or given) positions, damping excluded."""
        length, _, unit = self._geometry(q)
        return self._scatter(-(self.spring_stiffness * (length - self.rest_length))[:, None] * unit)

    def damping_forces(self, v: np.ndarray | None = None, q: np.ndarray | None = None) -> np.ndarray:
        """Damping forces [vertex_count, 3] [N]: along-spring damping plus ``-alpha M v``."""
        v = self.v if v is None else np.asarray(v, float).reshape(self.rest.shape)
        _, _, unit = self._geometry(q)
        rel = v[self.springs[:, 0]] - v[self.springs[:, 1]]
        f = self._scatter(-(self.damping * np.einsum("si,si->s", unit, rel))[:, None] * unit)
        return f - self.alpha * self.mass[:, None] * v

    def spring_energy(self, q: np.ndarray | None = None) -> float:
        """Elastic energy sum 1/2 k (l - L)^2 [J] of the current (or given) positions."""
        length, _, _ = self._geometry(q)
        return 0.5 * float(np.sum(self.spring_stiffness * (length - self.rest_length) ** 2))

    def potential_energy(self, gravity=(0.0, 0.0, -9.81), q: np.ndarray | None = None) -> float:
        """Spring energy plus gravity potential ``-sum m g . q`` (zero at the origin) [J]."""
        x = self.q if q is None else np.asarray(q, float).reshape(self.rest.shape)
        return self.spring_energy(x) - float(np.sum(self.mass * (x @ np.asarray(gravity, float))))

    def kinetic_energy(self) -> float:
        """1/2 sum m v^2 [J]."""
        return 0.5 * float(np.sum(self.mass[:, None] * self.v**2))

    def _assemble(self, blocks: np.ndarray) -> sp.csr_matrix:
        n = 3 * len(self.rest)
        data = np.concatenate([blocks, blocks, -blocks, -blocks]).ravel()
        return sp.csr_matrix((data, (self._rows, self._cols)), shape=(n, n))

    def _stiffness_blocks(self, q) -> np.ndarray:
        length, safe, unit = self._geometry(q)
        outer = unit[:, :, None] * unit[:, None, :]
        # Clamp the transverse term at 0 under compression (Choi & Ko): K stays semi-definite.
        transverse = np.maximum(0.0, 1.0 - self.rest_length / safe)
        transverse = np.where(length > 0, transverse, 0.0)
        k = self.spring_stiffness[:, None, None]
        return k * (transverse[:, None, None] * (np.eye(3) - outer) + outer)

    def stiffness_matrix(self, q: np.ndarray | None = None) -> sp.csr_matrix:
        """``K = -dF/dq`` with the compression clamp, sparse [3 vertex_count, 3 vertex_count] [N/m].

        Equal to the exact Jacobian of :meth:`elastic_forces` (negated) where every spring is
        stretched or at rest; positive semi-definite always.
        """
        return self._assemble(self._stiffness_blocks(q))

    def damping_matrix(self, q: np.ndarray | None = None) -> sp.csr_matrix:
        """``D = -dF/dv``: ``c d^ d^T`` per spring plus ``alpha M``, sparse [3 n, 3 n] [N s/m]."""
        _, _, unit = self._geometry(q)
        outer = self.damping * unit[:, :, None] * unit[:, None, :]
        return self._assemble(outer) + sp.diags(np.repeat(self.alpha * self.mass, 3))

    def _step_matrices(self, dt: float, gravity, external):
        """``A = M + dt D + dt^2 K`` and ``b = M v0 + dt (f_springs(q0) + M g + external)`` at
        the current state (thesis eq. 5.2); ``external`` [vertex_count, 3] [N] adds vertex forces."""
        dt = self._check_dt(dt)
        g = np.asarray(gravity, float)
        if g.shape != (3,) or not np.isfinite(g).all():
            raise InputError("gravity", "a finite 3-vector [m/s^2]", repr(gravity))
        for what, arr in (("velocity", self.v), ("position", self.q)):
            bad = ~np.isfinite(arr).all(axis=1)
            if bad.any():
                raise self._diverged(f"{what} of vertex {int(np.argmax(bad))} is NaN/inf")
        f = self.elastic_forces() + self.mass[:, None] * g
        if external is not None:
            ext = np.asarray(external, float)
            if ext.size != f.size:
                raise InputError("external", f"forces of shape {f.shape} [N]", f"shape {ext.shape}")
            f = f + ext.reshape(f.shape)
        blocks = dt * dt * self._stiffness_blocks(None)
        if self.damping > 0:
            _, _, unit = self._geometry(None)
            blocks = blocks + dt * self.damping * unit[:, :, None] * unit[:, None, :]
        m_diag = np.repeat(self.mass, 3)
        a = self._assemble(blocks) + sp.diags(m_diag * (1.0 + dt * self.alpha))
        return a, m_diag * self.v.ravel() + dt * f.ravel()
