"""The contact solve of a scene of held FEM bodies with a factorization cached once (thesis eq.
5.2 and 5.5): ``A v = b + J^T lambda`` with the contacts' complementarity, for scenes whose node
sweeps need hundreds of sweeps a contact step (the head CT of palpation.toml: ~180 sweeps of
coarse-corrected Jacobi, ~40 ms, against 2 off contact: the probe's push has to travel through a
stiff clamped body one node ring a sweep).

The step matrix ``A`` of the scene's first step is factored once (SciPy's SuperLU, a symmetric
fill-reducing ordering) and kept: ``A_0``. A co-rotated body's ``A`` changes with its elements'
rotations (eq. 5.2 with ``R_e K_e R_e^T``), so every step iterates the splitting ``A = P - (P -
A)`` with ``P`` the factored matrix turned to the nodes' rotations since (``R``, block diagonal:
Muller and Gross's stiffness warping) and corrected where the tets under a contact are squeezed
(``D``, a few tens of nodes, by Woodbury's identity):

    P = R (A_0 + D) R^T,   D = (R^T A R - A_0) on those nodes
    u^k+1      = v^k + P^-1 (b - A v^k)                                    (eq. 5.2's residual)
    lambda^k+1 = LCP(W, J u^k+1):  0 <= lambda _|_ J v - c >= 0, friction   (eq. 5.5)
    v^k+1      = u^k+1 + P^-1 J^T lambda^k+1

with the Delassus operator ``W = J P^-1 J^T`` over the step's contacts (small and dense: the
probe makes tens), solved by projected Gauss-Seidel with the node sweeps' own projection
(:func:`softvr.contact._node_jacobi_kernels.pgs_update`), and the iterates Anderson-accelerated.
At its fixed point ``A v = b + J^T lambda`` and every contact meets eq. 5.5 in ``v``: the same
solution as the sweeps'. The head CT pressed 5 mm by the probe: the eigenvalues of ``A_0^-1 A``
spread over 0.22-3.3, of ``(R A_0 R^T)^-1 A`` over 0.35-1.8; one to six iterations a step (one
sparse triangular solve pair each) against the sweeps' ~180. Where the deformation makes it
slow (:data:`REFACTOR_AFTER` iterations in a step), ``A_0`` is factored again at that step's
``A``. The columns of ``A_0^-1`` at the contacts' and the correction's nodes are solved once per
node and kept while the factorization is.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

from softvr.contact import _node_factored_kernels as _k
from softvr.contact import _node_jacobi_kernels as _jk
from softvr.device import ITEMS_A_CPU_THREAD, blocked_replayer, load_kernels, replayer

__all__ = ["FactoredSolve", "factored_eligible", "factored_work", "free_matrix"]

#: Fill-reducing ordering of the factorization: SuperLU's minimum degree on ``A + A^T`` with
#: symmetric pivoting (``A`` is SPD): half COLAMD's fill on the head CT (204 K against 422 K
#: entries), a solve in 0.4 ms against 0.7 (SuperLU's; the factors' 3 x 3 blocks in Warp,
#: :func:`_node_factored_kernels.factor_solve`, 0.14 ms).
ORDERING = "MMD_AT_PLUS_A"
#: Outer iterations of a step after which ``P`` is factored again at the step's ``A``.
REFACTOR_AFTER = 12
#: Largest ratio of successive changes at which the outer iteration's error is estimated from
#: its geometric tail (:func:`_error`) rather than taken as the last change.
CONTRACTION = 0.5
#: Iterates the outer iteration's Anderson acceleration remembers.
ANDERSON_MEMORY = 5
#: The local correction (:meth:`FactoredSolve._local`) takes the nodes where ``R^T A R - A_0``
#: has a block over this share of ``A_0``'s diagonal block, at most :data:`LOCAL_NODES` of them.
LOCAL_THRESHOLD = 0.05
LOCAL_NODES = 120
#: Nodes whose columns of ``A_0^-1`` are kept, above which a step starts by dropping those the
#: last step did not use (an outer iteration multiplies all kept columns; a probe moved over a
#: body would otherwise gather them until the next factorization).
KEPT_NODES = 120
#: Steps between refreshes of each of ``P``'s two turned parts, the nodes' rotations ``R`` and the
#: local correction (``D``, :meth:`FactoredSolve._local`), which take turns: a step refreshes one
#: and keeps the other as the last step left it. ``P`` only steers the iteration (its fixed
#: point, ``A v = b + J^T lambda``, is the same for any ``P``); over palpation.toml's press a
#: part one step old costs no iterations (140 in the 40 steps against 141 refreshing both), and
#: each kept part saves its ~0.2 ms (rotations) or ~0.4 ms (warp change, ``T``). 1: both every step.
REFRESH_PERIOD = 2
#: Newton iterations of the nodes' polar rotations (quadratic convergence from near a rotation).
POLAR_ITERATIONS = 3
#: PGS passes on the Delassus matrix per outer iteration, at most (each is a few microseconds
#: for tens of contacts; the warm start from the last iteration's impulses leaves few to do).
DELASSUS_PASSES = 2000
#: Share of the step's tolerance to which the PGS on the Delassus matrix converges.
DELASSUS_TOLERANCE = 0.1
#: Outer iterations a step is expected to take (the head CT: 1-2 off contact, 2-5 in contact)
#: and the decades of error the node sweeps remove in a contact step (the head CT: ~180 sweeps
#: at 38 a decade), for :func:`factored_work`.
STEP_ITERATIONS = 4.0
STEP_DECADES = 5.0


def free_matrix(model, state) -> tuple[sp.csr_matrix, np.ndarray]:
    """This step's ``A`` (``state.blocks``) over the nodes the sweeps solve for [3 k, 3 k], and
    which nodes those are [n]: the free nodes with blocks (a kinematic body's nodes have none
    and are driven; a rigid body's have none either, their D_A being all of their A, unless
    coupling springs hold the body)."""
    n = model.node_count
    rows = model.block_row.numpy()
    solved = (model.fixed.numpy() == 0) & np.isin(np.arange(n), rows)
    blocks = state.blocks.numpy()
    a = sp.bsr_matrix((blocks, model.block_col.numpy(), model.row_start.numpy()), shape=(3 * n, 3 * n)).tocsr()
    free = np.repeat(solved, 3)
    return a[free][:, free], solved


def factored_eligible(model) -> bool:
    """Whether :class:`FactoredSolve` can step the scene: on the CPU (SciPy's factorization
    works on host arrays), FEM bodies and driven nodes only (no rigid body, no coupling spring:
    their 6x6 blocks and rigid contact sides are the sweeps'; no cloth: its nodes have no tets
    to turn the kept factorization by)."""
    return (wp.get_device(model.device).is_cpu and model.rigid is None and not len(model.couplings.node)
            and not model.cloth.spring_count)


def factored_work(fill: int, blocks: int) -> float:
    """Work of a factored contact step in Jacobi sweeps over ``blocks`` blocks of ``A``, with a
    factorization of ``fill`` nonzeros in L and U: per outer iteration a product with ``A`` (a
    sweep) and two triangular solves (a multiply-add per nonzero, against nine per block of a
    sweep), :data:`STEP_ITERATIONS` of them."""
    return STEP_ITERATIONS * (1.0 + fill / (9.0 * blocks))


def sweeps_step_work(work_per_decade: float) -> float:
    """Work of a contact step of the node sweeps in Jacobi sweeps, from their work per decade
    (:func:`softvr.sim._node_sweeps.choose_sweeps`) and :data:`STEP_DECADES`."""
    return STEP_DECADES * work_per_decade


def _error(changes: list[float]) -> float:
    """Estimated velocity error [m/s] after the outer iterations whose largest changes were
    ``changes``: the geometric tail ``change rho / (1 - rho)`` with ``rho`` the larger of the
    last two ratios of changes where both are under :data:`CONTRACTION` (the iteration then
    contracts steadily), else the last change itself."""
    if len(changes) >= 3:
        rho = max(changes[-1] / max(changes[-2], 1e-300), changes[-2] / max(changes[-3], 1e-300))
        if rho < CONTRACTION:
            return changes[-1] * rho / (1.0 - rho)
    return changes[-1]


class _Anderson:
    """Anderson acceleration (type II; Walker and Ni 2011) of a fixed-point iteration x <- G(x)
    over the last ``memory`` iterates: the next iterate is G's image of the combination of the
    remembered iterates whose residuals ``G(x) - x`` combine to the least (normal equations of
    the small least-squares problem)."""

    def __init__(self, memory: int):
        self.memory = memory
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # the last residual G(x) - x and image G(x)
        # Differences of successive residuals and of images, rows of a ring (the oldest row
        # is overwritten), so that their products with a vector are one matrix product each;
        # and the residual differences' Gram matrix, one new row a call.
        self._df = self._dg = np.zeros((0, 0))
        self._count = self._slot = 0
        self._gram = np.zeros((memory, memory))

    def reset(self) -> None:
        """Forget the iterates, keeping the ring's rows for the next iteration of the same
        size: fresh rows of a step's ~45 K doubles cost their page faults (~0.03 ms a step)."""
        self._last = None
        self._count = self._slot = 0
        self._gram[:] = 0.0

    def next(self, x: np.ndarray, g: np.ndarray, f: np.ndarray | None = None) -> np.ndarray:
        """The next iterate from the iterate ``x`` [N] and its image ``g`` = G(x) [N] (and
        their difference ``f = g - x`` [N], where the caller has it)."""
        f = g - x if f is None else f
        if self._last is None:
            self._last = f, g
            if self._df.shape != (self.memory, len(x)):
                self._df, self._dg = np.zeros((self.memory, len(x))), np.zeros((self.memory, len(x)))
            return g
        s = self._slot
        np.subtract(f, self._last[0], out=self._df[s])
        np.subtract(g, self._last[1], out=self._dg[s])
        self._last = f, g
        self._slot = (s + 1) % self.memory
        k = self._count = min(self._count + 1, self.memory)
        df = self._df[:k]
        self._gram[s, :k] = self._gram[:k, s] = df @ df[s]
        gram = self._gram[:k, :k].copy()
        # A repeated residual leaves it singular; a residual that did not change at all, zero
        # on the diagonal (its gamma then 0). A least-squares solve would take 3x as long.
        gram.flat[::k + 1] = gram.diagonal() * (1.0 + 1e-10) + np.finfo(float).tiny
        gamma = np.linalg.solve(gram, df @ f)
        return g - gamma @ self._dg[:k]


def _block_rows(factor: sp.bsr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A triangular factor's 3 x 3 blocks [k, k blocks] as :func:`_node_factored_kernels.factor_solve`
    reads them: per block row where its blocks off the diagonal start [k + 1], their block
    columns [b] and values [b + 1, 3, 3], and the diagonal blocks' inverses [k + 1, 3, 3], the
    blocks transposed, each array with a last zero block (the kernel's padding lane reads it)."""
    k = factor.shape[0] // 3
    rows = np.repeat(np.arange(k), np.diff(factor.indptr))
    diagonal = rows == factor.indices
    inverse = np.zeros((k + 1, 3, 3))
    inverse[rows[diagonal]] = np.linalg.inv(factor.data[diagonal])
    start = np.concatenate([[0], np.cumsum(np.bincount(rows[~diagonal], minlength=k))])
    off = np.concatenate([factor.data[~diagonal], np.zeros((1, 3, 3))])
    return (start.astype(np.int32), factor.indices[~diagonal].astype(np.int32), off.transpose(0, 2, 1).copy(),
            inverse.transpose(0, 2, 1).copy())


class FactoredSolve:
    """The factored contact solve of one step size (module docstring), with the interface of
    :class:`softvr.contact.node_jacobi.NodeSolve`: :meth:`solve` from ``state.sweep_buffers[0]``,
    ``stats``.

    Parameters
    ----------
    model, state
        :class:`softvr.sim.NodeModel`, :class:`softvr.sim.NodeState` (this step's ``A`` in
        ``state.blocks``: it is factored).
    dt : float [s]
    max_iterations : int
        Outer iterations a step, at most.

    Attributes
    ----------
    stats : wp.array
        [3] as ``NodeSolve.stats``: [0] the last iteration's largest velocity change [m/s], [1]
        the largest normal-velocity error [m/s], [2] the contacts' largest natural residual [m/s].
    fill : int
        Nonzeros of the factorization's L and U.
    factorizations : int
        Times ``A`` was factored.
    delassus_passes : int
        PGS passes on the Delassus matrix in the last solve.
    """

    def __init__(self, model, state, dt: float, *, max_iterations: int = 100):
        for kernel in (_k.tets_moved, _k.node_rotations, _k.turned_residual, _k.factor_solve, _k.turned_update,
                       _k.warp_change, _k.dense_pgs, _jk.residual):
            load_kernels(kernel, model.device)
        self.model, self.state, self.dt = model, state, float(dt)
        self.max_iterations = int(max_iterations)
        n, d = model.node_count, model.device
        self._fixed = model.fixed.numpy() != 0
        self._fixed_velocity = state.fixed_velocity.numpy()
        self._fixed_entries = np.repeat(self._fixed[:, None], 3, axis=1)
        # The solved nodes (free, with blocks of A): the factorization's rows, in node order.
        self._solved = ~self._fixed & (np.diff(model.row_start.numpy()) > 0)
        self._solved_nodes = np.flatnonzero(self._solved)
        self._index = np.cumsum(self._solved) - 1  # node -> its row among the solved ones
        self._row_start, self._block_col = model.row_start.numpy(), model.block_col.numpy()
        self._row_count = np.diff(self._row_start)
        self._node_slot = np.full(n, -1)  # node -> its place in a small set being indexed (_local, _contacts), else -1
        k = len(self._solved_nodes)
        self._v = wp.zeros(n, dtype=wp.vec3d, device=d)
        self._r = wp.zeros(k, dtype=wp.vec3d, device=d)
        self._y = wp.zeros(k, dtype=wp.vec3d, device=d)
        self._work = wp.zeros(k + 1, dtype=wp.vec3d, device=d)  # the triangular solves' (factor_solve)
        # A node's three unit vectors (columns), whose solves are its columns of A_0^-1.
        self._unit = wp.zeros(k, dtype=wp.mat33d, device=d)
        self._columns_work = wp.zeros(k + 1, dtype=wp.mat33d, device=d)
        self._column = wp.zeros(k, dtype=wp.mat33d, device=d)
        self._rotation: wp.array = wp.array(np.tile(np.eye(3), (n, 1, 1)), dtype=wp.mat33d, device=d)  # R, per node
        self._absolute = wp.zeros(k, dtype=wp.mat33d, device=d)
        self._rotation0 = wp.zeros(k, dtype=wp.mat33d, device=d)
        solved_d: wp.array = wp.array(self._solved_nodes.astype(np.int32), dtype=wp.int32, device=d)
        index_d: wp.array = wp.array(np.where(self._solved, self._index, -1).astype(np.int32), dtype=wp.int32, device=d)
        tets, ke = model.tets.numpy(), model.ke.numpy()
        # A tet's weight in its nodes' rotations: its stiffness (trace of K_e's diagonal blocks).
        weight = np.einsum("eaii->e", ke.reshape(len(tets), 4, 4, 3, 3)[:, np.arange(4), np.arange(4)])
        self._tet_weight: wp.array = wp.array(weight, dtype=wp.float64, device=d)
        # The nodes' rotations and the warp change of their rows are recomputed only where a tet's
        # co-rotation has changed since they last were (tets_moved: each keeps the R_e it saw; a
        # rotation lag keeps most): a node's rotation is a function of its tets' R_e, its row of
        # A of theirs and its neighbours' rotations. turned: the nodes whose rotation was
        # recomputed since the last warp change.
        tets = len(model.tets)
        self._moved = [wp.zeros(n, dtype=wp.int32, device=d) for _ in range(2)]
        self._seen = [wp.zeros(tets, dtype=wp.mat33d, device=d) for _ in range(2)]
        self._turned = wp.ones(n, dtype=wp.int32, device=d)
        moved_rotations, moved_rows = (blocked_replayer(_k.tets_moved, tets, [state.rotations, seen, model.tets, moved],
                                                        d, min_chunk=1024)
                                       for seen, moved in zip(self._seen, self._moved))
        rotations = blocked_replayer(_k.node_rotations, k,
                                     [model.force_start, model.force, self._tet_weight, state.rotations, self._moved[0],
                                      solved_d, self._rotation0, POLAR_ITERATIONS, self._absolute, self._rotation,
                                      self._turned], d, min_chunk=512)
        moved = [m.numpy() for m in self._moved]

        def node_rotations() -> None:
            moved[0][:] = 0
            moved_rotations()
            rotations()

        self._rotations = node_rotations
        self._residual = blocked_replayer(_k.turned_residual, k, [model.row_start, model.block_col, state.blocks,
                                                                  state.b, solved_d, self._rotation, self._v, self._r],
                                          d, min_chunk=512)
        # u, f = u - v and the largest |f| of each thread, in turns into two sets of arrays (Anderson
        # keeps the last iteration's u and f).
        threads = -(-n // (ITEMS_A_CPU_THREAD if wp.get_device(d).is_cpu else 1))
        updated = [(wp.zeros(n, dtype=wp.vec3d, device=d), wp.zeros(n, dtype=wp.vec3d, device=d),
                    wp.zeros(threads, dtype=wp.float64, device=d)) for _ in range(2)]
        self._updates = [blocked_replayer(_k.turned_update, n, [index_d, self._rotation, self._v, self._y, *arrays], d,
                                          min_chunk=512) for arrays in updated]
        self._updated = [tuple(a.numpy() for a in arrays) for arrays in updated]
        self.stats = wp.zeros(3, dtype=wp.float64, device=d)
        capacity = state.contacts.capacity
        self._metric = wp.zeros(capacity, dtype=wp.mat33d, device=d)
        self._movable = wp.zeros(capacity, dtype=wp.int32, device=d)
        self._done = wp.zeros(1, dtype=wp.int32, device=d)
        c = state.contacts
        # Host views of the arrays the solve reads and writes (on the CPU, numpy() is a view; a
        # call costs ~30 us, and a step would make hundreds).
        self._host = {name: getattr(c, name).numpy() for name in
                      ("count", "stencil_count", "stencil_nodes", "stencil_weights", "frame", "gap", "friction",
                       "stiffness", "slip", "impulse")}
        self._host.update(v=self._v.numpy(), r=self._r.numpy(), y=self._y.numpy(),
                          stats=self.stats.numpy(), done=self._done.numpy(), metric=self._metric.numpy(),
                          movable=self._movable.numpy(), blocks=state.blocks.numpy(), unit=self._unit.numpy(),
                          column=self._column.numpy(), buffers=[b.numpy() for b in state.sweep_buffers])
        self._residual_check = replayer(wp.launch(
            _jk.residual, dim=1, device=d, record_cmd=True,
            inputs=[c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights, c.frame, c.gap, c.rigid_node,
                    c.rigid_lever, self.dt, self._v, c.impulse, c.friction, c.stiffness, c.slip, self._metric,
                    self._movable, c.gap_after, self.stats]))
        self._blocks0 = wp.zeros_like(state.blocks)  # A_0's blocks, all of them
        self._change = wp.zeros(n, dtype=wp.float64, device=d)
        solved_mask: wp.array = wp.array(self._solved.astype(np.int32), dtype=wp.int32, device=d)
        rows = blocked_replayer(_k.warp_change, n, [model.row_start, model.block_col, state.blocks, self._blocks0,
                                                    self._rotation, solved_mask, self._moved[1], self._turned,
                                                    self._change], d, min_chunk=512)

        def warp_change() -> None:
            moved[1][:] = 0
            moved_rows()
            rows()
            self._host["turned"][:] = 0

        self._warp_change = warp_change
        self._host.update(rotation=self._rotation.numpy(), change=self._change.numpy(), blocks0=self._blocks0.numpy(),
                          seen=[seen.numpy() for seen in self._seen], turned=self._turned.numpy())
        self._delassus_capacity, self._delassus_tolerance = 0, 0.0
        self.factorizations = 0
        self._steps = 0  # solves made
        self.delassus_passes = 0
        self._anderson = _Anderson(ANDERSON_MEMORY)
        self._factor()

    def _factor(self) -> None:
        """``P`` = this step's ``A`` over the solved nodes, factored; the column cache emptied."""
        a, _ = free_matrix(self.model, self.state)
        lu = spla.splu(a.tocsc(), permc_spec=ORDERING, diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        self.fill = int(lu.L.nnz + lu.U.nnz)
        self.factorizations += 1
        d = self.model.device
        perm_r_inverse = np.argsort(lu.perm_r).astype(np.int32)
        self._factors: list[wp.array] = [wp.array(perm_r_inverse, dtype=wp.int32, device=d),
                         wp.array(lu.perm_c.astype(np.int32), dtype=wp.int32, device=d)]
        for factor in (lu.L, lu.U):
            start, col, off, inverse = _block_rows(factor.tobsr(blocksize=(3, 3)))
            self._factors += [wp.array(start, dtype=wp.int32, device=d), wp.array(col, dtype=wp.int32, device=d),
                              wp.array(off, dtype=wp.mat33d, device=d), wp.array(inverse, dtype=wp.mat33d, device=d)]
        self._solve_r, self._solve_unit = (
            replayer(wp.launch(_k.factor_solve, dim=1, device=d, record_cmd=True,
                               inputs=[*self._factors, rhs, work, x]))
            for rhs, work, x in ((self._r, self._work, self._y), (self._unit, self._columns_work, self._column)))
        # R_0: the nodes' rotations now; R since is the identity. Every node's rotation and row
        # computed again at their next calls (R and A_0 are new): a NaN R_e seen is a moved one.
        for seen in self._host["seen"]:
            seen[:] = np.nan
        self._rotations()
        wp.copy(self._rotation0, self._absolute)
        self._host["rotation"][self._solved_nodes] = np.eye(3)
        self._host["seen"][0][:] = np.nan
        self._host["turned"][:] = 1
        wp.copy(self._blocks0, self.state.blocks)
        self._slot = np.full(self.model.node_count, -1, np.int64)  # node -> its columns in _columns / 3
        self._columns = np.zeros((3 * int(self._solved.sum()), 0), order="F")
        self._kept = 0  # columns of _columns in use
        self._used = np.zeros(0, np.int64)  # the columns the last step used
        # The last local correction (_local): S's rows among the solved velocities, its nodes and T.
        self._kept_local: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _local(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The step's local correction of ``P`` (Woodbury): ``R^T A R - A_0`` is large only on
        the tets under a contact, whose rotations differ from their nodes' (a squeezed tet), so
        its blocks among the nodes ``S`` where it is largest (relative to ``A_0``'s diagonal
        block, over :data:`LOCAL_THRESHOLD`, at most :data:`LOCAL_NODES`), ``D`` [3 s, 3 s],
        are added to ``A_0``: ``(A_0 + U D U^T)^-1 = A_0^-1 - C_S T C_S^T`` with ``C_S`` the
        columns of ``A_0^-1`` at ``S`` and ``T = (I + D C_SS)^-1 D``. Returns ``S``'s rows among
        the solved velocities [3 s], its columns in the kept ones (:meth:`_slots_of`) [3 s] and
        ``T`` [3 s, 3 s] (s = 0: none); kept for :meth:`_last_local`."""
        h = self._host
        self._warp_change()
        size = h["change"][self._solved_nodes]
        pick = np.flatnonzero(size > LOCAL_THRESHOLD)
        pick = pick[np.argsort(-size[pick], kind="stable")[:LOCAL_NODES]]
        # S's blocks: those of S's rows (CSR ranges) in S's columns, not a pass over all of A's.
        nodes = self._solved_nodes[pick]
        slot = self._node_slot
        slot[nodes] = np.arange(len(pick))
        first, count = self._row_start[nodes], self._row_count[nodes]
        at = np.repeat(first - np.cumsum(count) + count, count) + np.arange(count.sum())
        cols = self._block_col[at]
        bj = slot[cols]
        inside = bj >= 0
        at, cols, bj, bi = at[inside], cols[inside], bj[inside], np.repeat(np.arange(len(pick)), count)[inside]
        slot[nodes] = -1
        r = h["rotation"]
        d = np.matmul(np.matmul(r[nodes[bi]].transpose(0, 2, 1), h["blocks"][at]), r[cols]) - h["blocks0"][at]
        grid = np.zeros((len(pick), len(pick), 3, 3))
        grid[bi, bj] = d
        blocks = grid.transpose(0, 2, 1, 3).reshape(3 * len(pick), 3 * len(pick))
        dofs = (3 * pick[:, None] + np.arange(3)).ravel()
        slots = self._slots_of(self._solved_nodes[pick])
        t = np.linalg.solve(np.eye(len(dofs)) + blocks @ self._columns[np.ix_(dofs, slots)], blocks)
        self._kept_local = dofs, nodes, t
        return dofs, slots, t

    def _last_local(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The last step's local correction (:meth:`_local`) as this step uses it: its columns
        found again among the kept ones (:meth:`_forget_columns` may have moved them)."""
        assert self._kept_local is not None  # solve() makes a local correction after each factorization
        dofs, nodes, t = self._kept_local
        return dofs, self._slots_of(nodes), t

    def _slots_of(self, nodes: np.ndarray) -> np.ndarray:
        """Where the columns of ``A_0^-1`` at the solved ``nodes``' three velocity components
        each are among the kept ones [3 len(nodes)], solved for the nodes not yet kept (a
        node's three in one block solve: no multi-right-hand-side BLAS, whose threads spin on
        a loaded machine)."""
        missing = nodes[self._slot[nodes] < 0]
        if len(missing):
            self._slot[missing] = self._kept // 3 + np.arange(len(missing))
            if self._kept + 3 * len(missing) > self._columns.shape[1]:  # room for twice as many
                grown = np.zeros((self._columns.shape[0], 2 * (self._kept + 3 * len(missing))), order="F")
                grown[:, :self._kept] = self._columns[:, :self._kept]
                self._columns = grown
            unit, column = self._host["unit"], self._host["column"]
            for row in self._index[missing]:
                unit[row] = np.eye(3)
                self._solve_unit()
                unit[row] = 0.0
                self._columns[:, self._kept:self._kept + 3] = column.reshape(-1, 3)
                self._kept += 3
        return (3 * self._slot[nodes][:, None] + np.arange(3)).ravel()

    def _forget_columns(self) -> None:
        """Keep only the columns the last step used, where over :data:`KEPT_NODES` nodes' and
        over twice those are kept (a step that uses more keeps them all)."""
        if self._kept <= 3 * KEPT_NODES or self._kept <= 2 * len(self._used):
            return
        nodes = np.flatnonzero(self._slot >= 0)
        keep = nodes[np.isin(self._slot[nodes], self._used // 3)]
        columns = (3 * self._slot[keep][:, None] + np.arange(3)).ravel()
        self._columns[:, :len(columns)] = self._columns[:, columns]
        self._slot[:] = -1
        self._slot[keep] = np.arange(len(keep))
        self._kept = len(columns)

    def _contacts(self, local: tuple) -> tuple:
        """This step's contacts the impulses can move (a solved node of nonzero weight in the
        stencil): their rows [m], ``W = J P^-1 J^T`` [3 m, 3 m] in their frames, the rows of the
        nodes they move among the solved ones' velocities [3 u], ``R^T J^T`` there [3 u, 3 m],
        their columns among the kept ones [3 u], ``A_0^-1`` between ``S`` of ``local``
        (:meth:`_local`) and them [3 s, 3 u], their stencils' nodes (any; unused slots node 0)
        [m t] and ``J`` over those slots [3 m, 3 m t] (frames)."""
        h = self._host
        n = min(int(h["count"][0]), len(h["impulse"]))
        nodes, weights = h["stencil_nodes"][:n], h["stencil_weights"][:n]
        used = np.arange(nodes.shape[1]) < h["stencil_count"][:n, None]
        nodes = np.where(used, nodes, 0)
        weights = np.where(used, weights, 0.0)
        moves = used & self._solved[nodes] & (weights != 0.0)
        movable = moves.any(axis=1)
        h["movable"][:n] = movable
        rows = np.flatnonzero(movable)
        nodes, weights, moves = nodes[rows], weights[rows], moves[rows]
        frames = h["frame"][rows]
        # J over the stencils' slots (block diagonal: contact c's frame times its weights).
        each = np.arange(len(rows))
        blocks = np.zeros((len(rows), 3, len(rows), nodes.shape[1], 3))
        blocks[each, :, each] = weights[:, None, :, None] * frames[:, :, None, :]
        j = blocks.reshape(3 * len(rows), 3 * nodes.size)
        # The touched nodes in node order, and each moving slot's place among them (a mark
        # per node: np.unique's sort costs more than the whole rest for tens of slots).
        pushed = nodes[moves]
        mark = np.zeros(len(self._solved), bool)
        mark[pushed] = True
        touched = np.flatnonzero(mark)
        place = self._node_slot
        place[touched] = np.arange(len(touched))
        cell = np.nonzero(moves)[0] * len(touched) + place[pushed]
        place[touched] = -1
        # J's node weights over the touched nodes [m, u] (a node twice in a stencil: summed).
        g = np.bincount(cell, weights[moves], minlength=len(rows) * len(touched)).reshape(len(rows), len(touched))
        slots = self._slots_of(touched)
        dofs = (3 * self._index[touched][:, None] + np.arange(3)).ravel()
        jt = g.T[:, None, :, None] * frames.transpose(2, 0, 1)[None]  # J^T [touched, 3, m, 3], frames
        # R^T J^T at the touched nodes; W = J R A_0^-1 R^T J^T, Z = R A_0^-1 R^T J^T.
        rel = h["rotation"][touched]
        jt = np.einsum("uji,ujcx->uicx", rel, jt).reshape(3 * len(touched), 3 * len(rows))
        near = self._columns[np.ix_(local[0], slots)]  # A_0^-1 between S and the touched nodes
        w = jt.T @ (self._columns[np.ix_(dofs, slots)] - near.T @ local[2] @ near) @ jt
        w = 0.5 * (w + w.T)
        metric = h["metric"]
        metric[:n] = 0.0
        metric[rows] = w.reshape(len(rows), 3, len(rows), 3)[each, :, each, :]
        self._used = np.concatenate([local[1], slots])
        return rows, w, dofs, jt, slots, near, nodes.ravel(), j

    def _delassus(self, m: int, tolerance: float) -> dict:
        """Host views of the PGS launch's arrays (:func:`_node_factored_kernels.dense_pgs`) for
        ``m`` contacts, the launch recorded again where they grow or ``tolerance`` [m/s] changes."""
        if m > self._delassus_capacity or tolerance != self._delassus_tolerance:
            size, d = max(2 * m, 16, self._delassus_capacity), self.model.device
            arrays = {"count": wp.zeros(1, dtype=wp.int32, device=d),
                      "w": wp.zeros((3 * size, 3 * size), dtype=wp.float64, device=d),
                      **{name: wp.zeros(size, dtype=wp.vec3d, device=d) for name in ("u", "slip", "impulse", "rel")},
                      "frame": wp.zeros(size, dtype=wp.mat33d, device=d),
                      **{name: wp.zeros(size, dtype=wp.float64, device=d) for name in ("gap", "friction", "stiffness")}}
            self._pgs = replayer(wp.launch(
                _k.dense_pgs, dim=1, device=d, record_cmd=True,
                inputs=[arrays[name] for name in ("count", "w", "u", "frame", "gap", "friction", "stiffness", "slip")]
                + [self.dt, DELASSUS_PASSES, DELASSUS_TOLERANCE * tolerance, arrays["impulse"], arrays["rel"],
                   self._done]))
            self._delassus_arrays = {name: array.numpy() for name, array in arrays.items()}
            self._delassus_keep = arrays
            self._delassus_capacity, self._delassus_tolerance = size, tolerance
        return self._delassus_arrays

    def solve(self, tolerance: float) -> tuple[int, wp.array]:
        """Outer iterations (module docstring) from the velocities in ``state.sweep_buffers[0]``
        and the contacts' impulses, until an iteration changes no velocity by more than
        ``tolerance`` [m/s] and every contact meets eq. 5.5 within it (``stats[1]``,
        ``stats[2]``), or ``max_iterations``. Returns the iterations made ``k`` and the buffer
        holding the solved velocities (``state.sweep_buffers[k % 3]``, which the integration of
        a sweep count ``k`` reads); the contacts' impulses and ``gap_after`` are set."""
        st, h = self.state, self._host
        v, y_d, buffers = h["v"], h["y"], h["buffers"]
        v[:] = buffers[0]
        np.copyto(v, self._fixed_velocity, where=self._fixed_entries)  # a full mask: 4x faster than node indices
        # P's turned parts refreshed in turns (REFRESH_PERIOD), both after a factorization.
        self._steps += 1
        fresh = self._kept_local is None
        if fresh or self._steps % REFRESH_PERIOD == 0:
            self._rotations()
        self._forget_columns()
        local = self._local() if fresh or self._steps % REFRESH_PERIOD == 1 % REFRESH_PERIOD else self._last_local()
        rows, w, dofs, jt, slots, near, stencil, j = self._contacts(local)
        m = len(rows)
        pgs = self._delassus(m, tolerance)
        pgs["count"][0] = m
        pgs["w"][:3 * m, :3 * m] = w
        for name in ("frame", "gap", "friction", "stiffness", "slip", "impulse"):
            pgs[name][:m] = h[name][rows]
        lam, u_f = pgs["impulse"][:m], pgs["u"][:m]
        self.delassus_passes = 0
        k = restart = 0
        anderson = self._anderson
        anderson.reset()
        changes: list[float] = []
        while k < self.max_iterations:
            if k - restart == REFACTOR_AFTER:  # the deformation has taken A too far from R A_0 R^T
                self._factor()
                local = self._local()
                rows, w, dofs, jt, slots, near, stencil, j = self._contacts(local)
                pgs["w"][:3 * m, :3 * m] = w
                restart, changes = k, []
                anderson.reset()
            k += 1
            self._residual()  # R^T r
            self._solve_r()  # A_0^-1 R^T r
            y = y_d.ravel()
            # P^-1 = R (A_0^-1 - C_S T C_S^T) R^T (Woodbury); C_S^T x = (A_0^-1 x)_S, A_0 being
            # symmetric. Both corrections go through one product with the kept columns.
            spread = np.zeros(self._kept)
            at_s = y[local[0]]
            if m:
                at = y[dofs] - near.T @ (local[2] @ at_s)  # P^-1 r at the touched nodes, turned
                u_f[:] = (j @ v[stencil].ravel() + jt.T @ at).reshape(m, 3)  # J v + J P^-1 r
                self._pgs()
                self.delassus_passes += int(h["done"][0])
                pushed = jt @ lam.ravel()  # R^T J^T lambda at the touched nodes
                spread[slots] = pushed
                at_s = at_s + near @ pushed
            if len(local[0]):
                spread[local[1]] -= local[2] @ at_s
            if self._kept:
                y += self._columns[:, :self._kept] @ spread
            self._updates[k % 2]()  # u = v + R y, f = u - v
            u, f, largest = self._updated[k % 2]
            u, f = u.ravel(), f.ravel()
            change = float(largest.max())
            v[:] = anderson.next(v.ravel(), u, f).reshape(-1, 3)
            h["stats"][0] = change
            changes.append(change)
            if _error(changes) <= tolerance and self._contacts_met(rows, lam, tolerance):
                break
        else:
            self._contacts_met(rows, lam, tolerance)
        buffers[k % 3][:] = v
        return k, st.sweep_buffers[k % 3]

    def _contacts_met(self, rows: np.ndarray, lam: np.ndarray, tolerance: float) -> bool:
        """The contacts' impulses ``lam`` [m, 3] [N s] (frames) into ``state.contacts`` at
        ``rows`` and the residual of eq. 5.5 in this iteration's velocities into ``stats``
        (:func:`softvr.contact._node_jacobi_kernels.residual`, ``gap_after`` too, with the
        diagonal blocks of ``W`` as the contacts' metric): whether every contact meets it within
        ``tolerance`` [m/s]."""
        self._host["impulse"][rows] = lam
        self._residual_check()
        stats = self._host["stats"]
        return bool(stats[1] <= tolerance and stats[2] <= tolerance)
