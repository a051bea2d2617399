"""What FEM and cloth bodies share: a sparse step matrix ``A`` over free node velocities."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from softvr.errors import InputError

__all__ = ["SparseNodeSystem"]


class SparseNodeSystem:
    """Solves and integration for node-based bodies (FEM nodes, cloth vertices).

    Expects ``self._a_free`` (A over the free velocities, rebuilt by each
    ``unconstrained_velocity``), ``self._precond`` (its Jacobi preconditioner), ``self._free``
    (bool mask of free velocities), ``self.rest`` [node_count, 3], ``self.q``, ``self.v``,
    ``cg_tolerance``, ``cg_max_iterations`` and ``_node_word`` ("node", "vertex") for reports.
    """

    _node_word = "node"

    def _solve_step(self, a, m_diag: np.ndarray, forces: np.ndarray, dt: float) -> np.ndarray:
        """Keep this step's ``A`` (free rows / columns) and return ``A^-1 (M v0 + dt f)`` [n, 3]
        (thesis eq. 5.2; ``b`` in this form because the damping force cancels ``dt D v0``)."""
        self._free = ~np.repeat(self.fixed, 3)
        self._a_free = a.tocsr()[self._free][:, self._free].tocsr()
        self._precond = sp.diags(1.0 / self._a_free.diagonal())
        b = m_diag * self.v.ravel() + dt * np.asarray(forces, float).ravel()
        return self._cg(b, self.v.ravel())

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A^-1 rhs`` [n, 3] for this step's ``A`` (fixed nodes give 0)."""
        if not hasattr(self, "_a_free"):
            raise InputError("solve", "a call after unconstrained_velocity() of this step", "no step prepared")
        rhs = np.asarray(rhs, float)
        if rhs.size != self.v.size:
            raise InputError("rhs", f"an array of shape {self.v.shape}", f"shape {rhs.shape}")
        return self._cg(rhs.ravel(), None)

    def _cg(self, b: np.ndarray, x0) -> np.ndarray:
        """Jacobi-preconditioned CG on the free velocities; fixed ones stay 0. Returns [n, 3]."""
        out = np.zeros_like(b)
        if self._free.any():
            iterations = [0]

            def count(_):
                iterations[0] += 1

            sol, info = spla.cg(self._a_free, b[self._free], x0=None if x0 is None else x0[self._free],
                                rtol=self.cg_tolerance, maxiter=self.cg_max_iterations, M=self._precond,
                                callback=count)
            self.last_cg_iterations = iterations[0]
            self.last_cg_converged = info == 0
            out[self._free] = sol
        return out.reshape(-1, 3)

    def integrate(self, v: np.ndarray, dt: float) -> None:
        """``q += dt v`` (G = I for node positions), after checking the step stayed finite and
        bounded (a node covering a thousand body sizes per second has blown up); counts the step."""
        dt = self._check_dt(dt)
        v1 = np.asarray(v, float).reshape(self.v.shape)
        q1 = self.q + dt * v1
        bad = ~np.isfinite(v1).all(axis=1) | ~np.isfinite(q1).all(axis=1)
        speed = np.linalg.norm(np.where(np.isfinite(v1), v1, 0.0), axis=1)
        scale = max(float(np.ptp(self.rest, axis=0).max()), 1e-9)
        exploding = speed > 1e3 * scale
        if bad.any() or exploding.any():
            n = int(np.argmax(bad | exploding))
            what = "NaN/inf" if bad[n] else f"speed {speed[n]:.3g} m/s"
            raise self._diverged(f"{self._node_word} {n}: {what}")
        self.v, self.q = v1, q1
        self.step_count += 1

    def solve_columns(self, columns: np.ndarray) -> np.ndarray:
        """``A^-1 C`` [velocity_size, k] by one sparse LU of the step's ``A`` (rows of fixed
        velocities are 0): the contact solver asks for three columns per contact, and one
        factorization serves them all where a CG per column would cost seconds."""
        if getattr(self, "_lu_matrix", None) is not self._a_free:
            # A is symmetric positive definite: a symmetric fill-reducing ordering without
            # pivoting keeps the factors ~2.5x sparser than SuperLU's default (measured).
            self._lu = spla.splu(self._a_free.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                 options={"SymmetricMode": True})
            self._lu_matrix = self._a_free
        cols = np.asarray(columns, float)
        out = np.zeros_like(cols)
        if cols.shape[1] and self._free.any():
            out[self._free] = self._lu.solve(np.ascontiguousarray(cols[self._free]))
        return out
