"""What FEM and cloth bodies share: a sparse step matrix ``A`` over free node velocities."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg import solve_triangular

from softvr.dynamics.body import StepSystem
from softvr.errors import InputError, SimulationError

__all__ = ["SparseNodeSystem"]


class SparseNodeSystem:
    """Solves and integration for node-based bodies (FEM nodes, cloth vertices).

    Expects ``self.fixed`` (bool [node_count]), ``self.fixed_velocity`` [node_count, 3] [m/s],
    ``self.rest`` [node_count, 3], ``self.q``, ``self.v``, ``cg_tolerance``,
    ``cg_max_iterations``, ``_node_word`` ("node", "vertex") for reports and
    ``_step_matrices(dt, gravity, external) -> (A, b)`` (eq. 5.2, over all velocities). Each
    ``unconstrained_velocity`` keeps ``self._a_free`` (A over the free velocities),
    ``self._precond`` and ``self._free`` (bool mask of free velocities).

    Fixed nodes are Dirichlet boundary nodes: they move at ``fixed_velocity`` (0: clamped),
    which no force or contact impulse changes; the free nodes feel that motion through the
    off-diagonal blocks of ``A`` (a jaw, a hand or a clamp driving the body).
    """

    if TYPE_CHECKING:  # what the bodies (FemBody, ClothBody, CouplingIsland) and ContactObject provide
        fixed: np.ndarray
        fixed_velocity: np.ndarray
        rest: np.ndarray
        q: np.ndarray
        v: np.ndarray
        cg_tolerance: float
        cg_max_iterations: int
        step_count: int

        def _step_matrices(self, dt: float, gravity, external) -> tuple: ...

        @staticmethod
        def _check_dt(dt: float) -> float: ...

        def _diverged(self, what: str) -> SimulationError: ...

    # Kept between steps (see _factor): the LU, its fill order, where the last velocities sit in it.
    _lu: Any
    _fill_order: np.ndarray
    _corner_position: np.ndarray | None  # None: the corner inverse belongs to an older order

    _node_word = "node"
    #: Solve by sparse LU until a factorization exists, then by CG preconditioned with the last
    #: one (falling back to LU if CG does not converge): coupling islands, whose stiff springs
    #: make Jacobi-preconditioned CG crawl.
    direct_solve = False

    def _solve_step(self, a, b: np.ndarray) -> np.ndarray:
        """Keep this step's ``A`` (free rows / columns) and return the velocities [n, 3] solving
        ``A v = b`` (thesis eq. 5.2) with the fixed ones at ``fixed_velocity``."""
        self._free = ~np.repeat(self.fixed, 3)
        self._factor_age = getattr(self, "_factor_age", 0) + 1
        a = a.tocsr()
        self._a_free = a[self._free][:, self._free].tocsr()
        self._precond = self._lagged_factor_preconditioner() or sp.diags(1.0 / self._a_free.diagonal())
        b = np.array(b, float).ravel()
        driven = self._checked_fixed_velocity().ravel()
        moving = ~self._free & (driven != 0.0)
        if moving.any():
            # A v = b with v_fixed given: A_ff v_f = b_f - A_fd v_d.
            b[self._free] -= a[self._free][:, moving] @ driven[moving]
        lagged = getattr(self, "_lu", None) is not None and self._lu.shape[0] == self._a_free.shape[0]
        if self.direct_solve and not lagged:
            self._factor(np.zeros(0, int))
            v = self._lu_solve(b.reshape(-1, 1)).reshape(-1, 3)
        else:
            v = self._cg(b, self.v.ravel())
            if self.direct_solve and not self.last_cg_converged:
                self._factor(np.zeros(0, int))
                v = self._lu_solve(b.reshape(-1, 1)).reshape(-1, 3)
        v.reshape(-1)[~self._free] = driven[~self._free]
        return v

    def step_system(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> StepSystem:
        """This step's ``A v = b`` (eq. 5.2) with the fixed velocities prescribed."""
        a, b = self._step_matrices(dt, gravity, external)
        return StepSystem(a, b, np.repeat(self.fixed, 3), self._checked_fixed_velocity().ravel().copy())

    def unconstrained_velocity(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> np.ndarray:
        """Velocities [n, 3] [m/s] solving ``A v = b`` (thesis eq. 5.2), the fixed ones at
        ``fixed_velocity``; also prepares :meth:`solve` for this step. ``external`` [n, 3] [N]
        adds forces."""
        return self._solve_step(*self._step_matrices(dt, gravity, external))

    def _checked_fixed_velocity(self) -> np.ndarray:
        vf = np.asarray(self.fixed_velocity, float)
        if vf.shape != self.v.shape:
            raise InputError("fixed_velocity", f"an array of shape {self.v.shape} [m/s]", f"shape {vf.shape}")
        bad = ~np.isfinite(vf).all(axis=1)
        if bad.any():
            n = int(np.argmax(bad))
            raise InputError(f"fixed_velocity[{n}]", "finite values [m/s]", repr(vf[n].tolist()))
        return vf

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A^-1 rhs`` [n, 3] for this step's ``A`` (fixed nodes give 0): by the step's
        factorization once :meth:`compliance` made one, else by CG."""
        if not hasattr(self, "_a_free"):
            raise InputError("solve", "a call after unconstrained_velocity() of this step", "no step prepared")
        rhs = np.asarray(rhs, float)
        if rhs.size != self.v.size:
            raise InputError("rhs", f"an array of shape {self.v.shape}", f"shape {rhs.shape}")
        if self._factor_is_current():
            return self._lu_solve(rhs.reshape(-1, 1)).reshape(self.v.shape)
        return self._cg(rhs.ravel(), None)

    def _lagged_factor_preconditioner(self):
        """The last step's factorization as the preconditioner of this step's CG, or None.

        ``A`` changes little between steps (the element rotations turn a little), so the exact
        inverse of the previous ``A`` makes CG converge in a few iterations where the Jacobi
        preconditioner needs hundreds; a body in contact has that factorization anyway
        (:meth:`compliance`). Both are symmetric positive definite, as PCG requires.
        """
        lu, order = getattr(self, "_lu", None), getattr(self, "_lu_order", None)
        n = self._a_free.shape[0]
        if lu is None or lu.shape[0] != n:
            return None

        def apply(r):
            x = np.empty(n)
            x[order] = lu.solve(np.ascontiguousarray(np.ravel(r)[order]))
            return x

        return spla.LinearOperator((n, n), matvec=apply, dtype=float)

    def _cg(self, b: np.ndarray, x0) -> np.ndarray:
        """Preconditioned CG on the free velocities (the last step's factorization, or Jacobi);
        fixed ones stay 0. Returns [n, 3]."""
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

    def immovable(self, blocks: np.ndarray) -> np.ndarray:
        """Fixed nodes among ``blocks`` (bool, the shape of ``blocks``)."""
        return self.fixed[np.asarray(blocks, int)]

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
        velocities are 0)."""
        cols = np.asarray(columns, float)
        if not self._factor_is_current():
            self._factor(np.zeros(0, int))
        return self._lu_solve(cols)

    def compliance(self, blocks: np.ndarray) -> np.ndarray:
        """Rows and columns of ``A^-1`` at the velocities of nodes ``blocks`` [k]:
        shape [3k, 3k] [m/s per N s] (the per-object block of the Delassus operator, eq. 5.6).

        ``A`` is factored with those velocities eliminated last; then
        ``(A^-1)_CC = U_CC^-1 L_CC^-1`` is the inverse of the trailing corner of the factors, and
        no solve with the ``3k`` unit columns is needed (they cost ~10x the factorization).
        Rows and columns of fixed nodes are 0.

        The factorization is kept over steps (:attr:`compliance_is_exact` turns False): while
        this step's CG, preconditioned by it, needs at most :attr:`lag_iterations` iterations
        (``A`` has hardly changed), it is younger than :attr:`max_factor_age` steps and its
        trailing corner holds every requested velocity, the block comes from the kept corner
        inverse. The contact solver then corrects with the exact ``A^-1`` (eq. 5.6's outer loop
        with the kept ``A`` as ``D_A``). A refactorization keeps the previous corner's
        velocities in the corner too, so contacts that come and go do not refactor each step.
        """
        blocks = np.asarray(blocks, int).ravel()
        if len(np.unique(blocks)) != len(blocks) or (blocks < 0).any() or (blocks >= len(self.v)).any():
            raise InputError("blocks", f"distinct node indices in [0, {len(self.v) - 1}]", str(blocks.tolist()[:8]))
        dofs = (3 * blocks[:, None] + np.arange(3)).ravel()
        free_index = np.cumsum(self._free) - 1  # velocity -> row of the free system
        keep = self._free[dofs]
        last = free_index[dofs[keep]]
        n = self._a_free.shape[0]
        if not self._corner_reusable(last, n):
            corner = getattr(self, "_corner_last", None)
            if corner is not None and getattr(self, "_lu", None) is not None and self._lu.shape[0] == n \
                    and len(np.union1d(corner, last)) <= 2 * len(last) + 24:
                last_all = np.concatenate([corner, np.setdiff1d(last, corner)])
            else:
                last_all = last
            self._factor(last_all)
            k = len(last_all)
            lower = self._lu.L[n - k :, n - k :].toarray()
            upper = self._lu.U[n - k :, n - k :].toarray()
            self._corner_inv = solve_triangular(upper, solve_triangular(lower, np.eye(k), lower=True, unit_diagonal=True))
            self._corner_last = last_all
            self._corner_position = np.full(n, -1)
            self._corner_position[last_all] = np.arange(k)
        assert self._corner_position is not None  # reusable, or made just now
        at = self._corner_position[last]
        inv = self._corner_inv if np.array_equal(at, np.arange(len(self._corner_inv))) \
            else self._corner_inv[np.ix_(at, at)]
        if keep.all():
            return inv.copy()
        out = np.zeros((len(dofs), len(dofs)))
        out[np.ix_(keep, keep)] = inv
        return out

    #: Most CG iterations of a step's unconstrained solve (preconditioned by the kept
    #: factorization) with which :meth:`compliance` still reuses that factorization.
    lag_iterations = 4
    #: Most steps a factorization is kept for :meth:`compliance`.
    max_factor_age = 16

    @property
    def compliance_is_exact(self) -> bool:
        """Whether :meth:`compliance` of this step is this step's ``A^-1`` (else the kept one's)."""
        return self._factor_is_current()

    def discard_kept_factorization(self) -> None:
        """Make the next :meth:`compliance` refactor (the contact solver found the kept ``A``
        too far from this step's to converge in a few outer passes)."""
        self._factor_age = self.max_factor_age

    def _corner_reusable(self, last: np.ndarray, n: int) -> bool:
        """Whether the kept factorization can give the compliance of the free velocities ``last``."""
        lu, at = getattr(self, "_lu", None), getattr(self, "_corner_position", None)
        if lu is None or at is None or lu.shape[0] != n or len(at) != n:
            return False
        if self._factor_age >= self.max_factor_age or self.last_cg_iterations > self.lag_iterations:
            return False
        return bool((at[last] >= 0).all())

    def _factor_is_current(self) -> bool:
        return getattr(self, "_lu_matrix", None) is self._a_free

    def _factor(self, last: np.ndarray) -> None:
        """Sparse LU of the step's free ``A`` with the free velocities ``last`` eliminated last.

        ``A`` is symmetric positive definite, so pivots stay on the diagonal (no pivoting) and
        one symmetric fill-reducing order (SuperLU's minimum degree on A + A^T, found once: the
        pattern does not change) serves every step, with ``last`` moved to its end.
        """
        n = self._a_free.shape[0]
        if getattr(self, "_fill_order", None) is None or len(self._fill_order) != n:
            lu = spla.splu(self._a_free.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options={"SymmetricMode": True})
            self._fill_order = np.argsort(lu.perm_c)  # velocities in elimination order
        moved = np.zeros(n, bool)
        moved[last] = True
        order = np.concatenate([self._fill_order[~moved[self._fill_order]], last])
        self._lu = spla.splu(self._a_free[order][:, order].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                             options={"SymmetricMode": True})
        if not (np.array_equal(self._lu.perm_c, np.arange(n)) and np.array_equal(self._lu.perm_r, np.arange(n))):
            raise self._diverged("step matrix A needed pivoting: it is not positive definite")
        self._lu_order = order
        self._lu_matrix = self._a_free
        self._factor_age = 0
        self._corner_position = None  # the corner inverse belongs to the previous order

    def _lu_solve(self, cols: np.ndarray) -> np.ndarray:
        """``A^-1 C`` [velocity_size, k] with the current factorization (fixed rows 0)."""
        out = np.zeros_like(cols)
        if cols.shape[1] and self._free.any():
            free_cols = cols[self._free]
            x = np.empty_like(free_cols)
            x[self._lu_order] = self._lu.solve(np.ascontiguousarray(free_cols[self._lu_order]))
            out[self._free] = x
        return out
