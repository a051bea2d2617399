"""The coarse correction of the node sweeps (thesis eq. 5.6's outer Jacobi made two-level): every
free FEM body's rigid motions solved exactly each sweep, for scenes whose small stiff bodies
make plain node-block Jacobi slow (the candies: 75-82 Chebyshev sweeps per decade, 18 with the
coarse correction). Kernels and the derivation in :mod:`softvr.contact._node_coarse_kernels`.
Works on :class:`softvr.sim.NodeModel` / :class:`softvr.sim.NodeState` or any objects with
those attributes.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

from softvr.contact import _node_coarse_kernels as _k
from softvr.device import load_kernels, replayer

__all__ = ["CoarseSpace", "coarse_bodies", "coarse_spectrum"]

#: Fewest nodes of a body the coarse space takes (its six rigid motions must be independent).
MIN_NODES = 4


def coarse_bodies(model) -> np.ndarray:
    """[B, 2] first and last (exclusive) node of each body the coarse space takes: FEM bodies
    whose nodes all have blocks of ``A`` and none is fixed (a held body's rigid motions are
    not slow modes of the sweeps), with at least :data:`MIN_NODES` nodes."""
    start = np.asarray(model.body_node_start)
    row_start = model.row_start.numpy()
    has_blocks = row_start[1:] > row_start[:-1]
    fixed = model.fixed.numpy() != 0
    rigid = np.zeros(model.node_count, bool)
    if model.rigid is not None:
        rigid[model.rigid.linear_node.numpy()] = True
        rigid[model.rigid.angular_node.numpy()] = True
    keep = [(a, b) for a, b in zip(start[:-1], start[1:])
            if b - a >= MIN_NODES and has_blocks[a:b].all() and not fixed[a:b].any() and not rigid[a:b].any()]
    return np.asarray(keep, dtype=np.int64).reshape(-1, 2)


def _basis(bodies: np.ndarray, q: np.ndarray, mass: np.ndarray, solved: np.ndarray) -> sp.csr_matrix:
    """``P`` [3 k, 6 B]: each coarse body's rigid motions (linear, then angular about its mass
    centre) over the solved nodes' velocities (``solved`` [n] which nodes those are)."""
    index = np.cumsum(solved) - 1
    rows, cols, vals = [], [], []
    for b, (first, last) in enumerate(bodies):
        nodes = np.arange(first, last)
        rho = q[nodes] - (mass[nodes, None] * q[nodes]).sum(0) / mass[nodes].sum()
        for k in range(3):
            for d in range(3):  # translation along k; rotation about k: e_k x rho
                rows.append(3 * index[nodes] + d)
                cols.append(np.full(len(nodes), 6 * b + k))
                vals.append(np.full(len(nodes), float(k == d)))
                rows.append(3 * index[nodes] + d)
                cols.append(np.full(len(nodes), 6 * b + 3 + k))
                vals.append(np.cross(np.eye(3)[k], rho)[:, d])
    size = 3 * int(solved.sum())
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(size, 6 * len(bodies)))


def coarse_spectrum(a: sp.csr_matrix, solved: np.ndarray, bodies: np.ndarray, q: np.ndarray,
                    mass: np.ndarray) -> tuple[float, float]:
    """Bounds (lo, hi) of the eigenvalues of ``M^-1 A`` with the two-level ``M^-1 = D_A^-1 +
    P (P^T A P)^-1 P^T`` (no margins): ``a`` [3 k, 3 k] ``A`` over the solved nodes
    (``solved`` [n]), ``bodies`` from :func:`coarse_bodies`, ``q`` [n, 3] [m] and ``mass`` [n]
    [kg] the nodes'. ``M^-1 A`` is similar to the symmetric ``M^-1/2 A M^-1/2`` but ``M^-1/2``
    is not at hand, so the bounds come from Arnoldi (ARPACK) on ``M^-1 A``, whose eigenvalues
    are real."""
    k = a.shape[0] // 3
    blocks = a.tobsr(blocksize=(3, 3))
    rows = np.repeat(np.arange(k), np.diff(blocks.indptr))
    diagonal = np.zeros((k, 3, 3))
    diagonal[rows[rows == blocks.indices]] = blocks.data[rows == blocks.indices]
    d_inv = sp.bsr_matrix((np.linalg.inv(diagonal), np.arange(k), np.arange(k + 1)), shape=a.shape).tocsr()
    p = _basis(bodies, q, mass, solved)
    coarse = np.linalg.inv((p.T @ a @ p).toarray())

    def apply(x: np.ndarray) -> np.ndarray:
        r = a @ x
        return d_inv @ r + p @ (coarse @ (p.T @ r))

    op = spla.LinearOperator(a.shape, matvec=apply, dtype=float)
    # A fixed start vector: the same scene steps the same way in every run.
    start = np.random.default_rng(0).standard_normal(a.shape[0])
    hi = float(spla.eigs(op, k=1, which="LR", return_eigenvectors=False, tol=1e-3, v0=start)[0].real)
    shifted = spla.LinearOperator(a.shape, matvec=lambda x: hi * x - apply(x), dtype=float)
    lo = hi - float(spla.eigs(shifted, k=1, which="LR", return_eigenvectors=False, tol=1e-4, v0=start)[0].real)
    return lo, hi


class CoarseSpace:
    """The recorded coarse launches of the node sweeps (:mod:`softvr.contact._node_coarse_kernels`)
    over ``bodies`` ([B, 2] node ranges, :func:`coarse_bodies`; none: every contact's coarse
    sides stay empty and the sweeps are plain node-block Jacobi).

    Attributes
    ----------
    arrays : Coarse
        The struct the sweep kernels take.
    """

    def __init__(self, model, state, bodies: np.ndarray):
        d = model.device
        n, count = model.node_count, len(bodies)
        for kernel in (_k.prepare_bodies, _k.contact_sides, _k.coarse_residual):
            load_kernels(kernel, d)
        node_body = np.full(n, -1, np.int32)
        for b, (first, last) in enumerate(bodies):
            node_body[first:last] = b
        capacity = state.contacts.capacity
        co = _k.Coarse()
        co.node_body = wp.array(node_body, dtype=wp.int32, device=d)
        for name in ("centre", "y_lin", "y_ang"):
            setattr(co, name, wp.zeros(max(count, 1), dtype=wp.vec3d, device=d))
        for name in ("ll", "la", "aa"):
            setattr(co, name, wp.zeros(max(count, 1), dtype=wp.mat33d, device=d))
        co.side = wp.full((capacity, 2), -1, dtype=wp.int32, device=d)
        co.weight = wp.zeros((capacity, 2), dtype=wp.float64, device=d)
        co.lever = wp.zeros((capacity, 2), dtype=wp.vec3d, device=d)
        self.arrays = co
        self.count = count
        self._prepare: list[Callable[[], None]] = []
        self.residual: list[Callable[[], None]] = []
        if not count:
            return
        first = wp.array(bodies[:, 0].astype(np.int32), dtype=wp.int32, device=d)
        last = wp.array(bodies[:, 1].astype(np.int32), dtype=wp.int32, device=d)
        rows, cols = model.block_row.numpy(), model.block_col.numpy()
        diagonal = np.zeros(n, np.int32)  # each node's diagonal block
        diagonal[rows[rows == cols]] = np.flatnonzero(rows == cols)
        self._diagonal: wp.array = wp.array(diagonal, dtype=wp.int32, device=d)
        c = state.contacts
        self._prepare = [
            replayer(wp.launch(_k.prepare_bodies, dim=count, device=d, record_cmd=True,
                               inputs=[first, last, state.q, model.mass, model.row_start, model.block_col,
                                       state.blocks, co])),
            replayer(wp.launch(_k.contact_sides, dim=capacity, device=d, record_cmd=True,
                               inputs=[c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights, state.q, co]))]
        self.residual = [replayer(wp.launch(_k.coarse_residual, dim=count, device=d, record_cmd=True,
                                            inputs=[first, last, state.q, model.row_start, self._diagonal,
                                                    state.blocks, v, state.v_hat, co]))
                         for v in state.sweep_buffers]

    def prepare(self) -> None:
        """The bodies' centres and coarse inverses from this step's ``A``, and the contacts'
        coarse sides (once a step, after detection)."""
        for launch in self._prepare:
            launch()
