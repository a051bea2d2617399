"""The coarse correction of the multicolour Gauss-Seidel sweeps (thesis eq. 5.6's outer iteration
made two-level): after each symmetric sweep, every aggregate of a held body's free nodes takes the
rigid motion that solves its Galerkin system over the sweep's residual, its contact nodes held
(kernels and the derivation in :mod:`softvr.contact._node_gs_coarse_kernels`). The aggregates'
rigid motions are the smooth deformations the node sweeps remove slowest: on the shoulder's own
``A`` (step 54, dense eigenvalues) the Chebyshev sweeps a decade fall from 14.9 to 8.6.
Works on :class:`softvr.sim.NodeModel` / :class:`softvr.sim.NodeState` or any objects with
those attributes.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

from softvr.contact import _node_gs_coarse_kernels as _k
from softvr.contact.node_coarse import Aggregates, _galerkin_inverses
from softvr.device import in_order, load_kernels, replayer

__all__ = ["GaussSeidelCoarse", "gauss_seidel_coarse_spectrum"]


def gauss_seidel_coarse_spectrum(a: sp.spmatrix, order: np.ndarray, aggregates: Aggregates, solved: np.ndarray,
                                 q: np.ndarray, mass: np.ndarray) -> tuple[float, float]:
    """(lo, hi): bounds of the eigenvalues of ``I - E`` (no margins), ``E = (I - Q A)(I - M^-1 A)``
    the error operator of a symmetric block Gauss-Seidel sweep over the nodes in ``order`` (``M =
    (D + L) D^-1 (D + U)``) followed by the aggregates' coarse correction ``Q = sum_g P_g (P_g^T A
    P_g)^-1 P_g^T`` (each aggregate's 6x6 inverted alone, as the sweeps do); ``a`` [3 k, 3 k] ``A``
    over the ``k`` solved nodes (``solved`` [n] which), ``order`` [k] a permutation of them,
    ``aggregates`` (:func:`softvr.contact.node_coarse.coarse_aggregates`), ``q`` [n, 3] [m],
    ``mass`` [n] [kg]. ``E``'s eigenvalues are real (a product of two ``A``-self-adjoint operators,
    one positive semidefinite), so Arnoldi (ARPACK) on ``I - E`` finds them."""
    k = len(order)
    dofs = (3 * np.asarray(order)[:, None] + np.arange(3)).ravel()
    a = sp.csr_matrix(a)
    ordered = a[dofs][:, dofs].tocsr()
    blocks = ordered.tobsr(blocksize=(3, 3))
    rows = np.repeat(np.arange(k), np.diff(blocks.indptr))
    diagonal = np.zeros((k, 3, 3))
    diagonal[rows[rows == blocks.indices]] = blocks.data[rows == blocks.indices]
    d = sp.block_diag(list(diagonal), format="csr")
    # L: the blocks below the diagonal blocks (by node, not by dof).
    coo = ordered.tocoo()
    node_r, node_c = coo.row // 3, coo.col // 3
    lower = sp.csr_matrix((coo.data[node_r > node_c], (coo.row[node_r > node_c], coo.col[node_r > node_c])),
                          shape=ordered.shape)
    forward = spla.splu((d + lower).tocsc(), permc_spec="NATURAL")
    backward = spla.splu((d + lower.T).tocsc(), permc_spec="NATURAL")
    p, coarse = _galerkin_inverses(a, aggregates, q, mass, solved)

    def sweep_error(x: np.ndarray) -> np.ndarray:
        """``E x``, ``x`` in the solved nodes' numbering."""
        y = x[dofs]
        y = y - backward.solve(d @ forward.solve(ordered @ y))  # (I - M^-1 A) in colour order
        e = np.empty_like(y)
        e[dofs] = y
        return e - p @ (coarse @ (p.T @ (a @ e)))

    op = spla.LinearOperator(a.shape, matvec=lambda x: x - sweep_error(x), dtype=float)
    # A fixed start vector: the bounds set the Chebyshev weights, so every run must get the same.
    start = np.random.default_rng(0).standard_normal(a.shape[0])
    hi = float(spla.eigs(op, k=1, which="LR", return_eigenvectors=False, tol=1e-4, v0=start)[0].real)
    shifted = spla.LinearOperator(a.shape, matvec=lambda x: hi * x - op.matvec(x), dtype=float)
    lo = hi - float(spla.eigs(shifted, k=1, which="LR", return_eigenvectors=False, tol=1e-4, v0=start)[0].real)
    return lo, hi


class GaussSeidelCoarse:
    """The recorded coarse correction of the Gauss-Seidel sweeps over ``aggregates``
    (:class:`softvr.contact.node_coarse.Aggregates`, their nodes free FEM nodes) with the
    sweep's ``contact_node`` [n] int32 held.

    Attributes
    ----------
    prepare : callable
        Replays the aggregates' centres and Galerkin inverses over their nodes that are not
        contact nodes (once a step after the contact nodes are marked, and after a wake marks more).
    correct : callable
        Replays the correction of ``state.v_hat`` from its residual (after a sweep's node update).
    active : wp.array(int32) [G]
        Which aggregates took a correction this step (``_node_gs_coarse_kernels.prepare_aggregates``).
    """

    def __init__(self, model, state, aggregates: Aggregates, contact_node: wp.array):
        d = model.device
        count = len(aggregates)
        load_kernels(_k.prepare_aggregates, d)
        node_aggregate = np.full(model.node_count, -1, np.int32)
        node_aggregate[aggregates.nodes] = np.repeat(np.arange(count), np.diff(aggregates.start))
        start: wp.array = wp.array(aggregates.start.astype(np.int32), dtype=wp.int32, device=d)
        nodes: wp.array = wp.array(aggregates.nodes.astype(np.int32), dtype=wp.int32, device=d)
        centre, y_lin, y_ang = (wp.zeros(count, dtype=wp.vec3d, device=d) for _ in range(3))
        ll, la, aa = (wp.zeros(count, dtype=wp.mat33d, device=d) for _ in range(3))
        self.active = wp.zeros(count, dtype=wp.int32, device=d)
        self.prepare = replayer(wp.launch(
            _k.prepare_aggregates, dim=count, device=d, record_cmd=True,
            inputs=[start, nodes, state.q, model.mass, model.row_start, model.block_col, state.blocks,
                    wp.array(node_aggregate, dtype=wp.int32, device=d), contact_node, centre, ll, la, aa,
                    self.active]))
        #: The aggregates' arrays as the block form of the sweep takes them
        #: (:func:`softvr.contact._node_block_kernels.gauss_seidel_after_contacts`): start [G + 1],
        #: nodes, centre [G] [m], the inverses ``ll``, ``la``, ``aa`` [G], :attr:`active`, and the
        #: coarse velocities ``y_lin`` [G] [m/s], ``y_ang`` [G] [rad/s].
        self.block_arrays = (start, nodes, centre, ll, la, aa, self.active, y_lin, y_ang)
        self.correct = in_order(
            replayer(wp.launch(_k.coarse_velocities, dim=count, device=d, record_cmd=True,
                               inputs=[start, nodes, state.q, model.row_start, model.block_col, state.blocks, state.b,
                                       contact_node, centre, ll, la, aa, self.active, state.v_hat, y_lin, y_ang])),
            replayer(wp.launch(_k.apply_coarse, dim=count, device=d, record_cmd=True,
                               inputs=[start, nodes, state.q, contact_node, centre, self.active, y_lin, y_ang,
                                       state.v_hat])))
