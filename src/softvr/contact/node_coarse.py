"""The coarse correction of the node sweeps (thesis eq. 5.6's outer Jacobi made two-level): the
rigid motions of aggregates of nodes solved each sweep. Every free FEM body is one aggregate,
its rigid motions solved exactly, for scenes whose small stiff bodies make plain node-block
Jacobi slow (the candies: 75-82 Chebyshev sweeps per decade, 18 with the coarse correction);
a held body (fixed nodes, or coupling springs) is split into spatial aggregates of about
:data:`AGGREGATE_NODES` nodes, whose rigid motions are its slow deformations (the shoulder's
sheets and tendons). Kernels and the derivation in :mod:`softvr.contact._node_coarse_kernels`.
Works on :class:`softvr.sim.NodeModel` / :class:`softvr.sim.NodeState` or any objects with
those attributes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

from softvr.collision.node_rigid_detection import CONTACT_THREADS
from softvr.contact import _node_coarse_kernels as _k
from softvr.device import chunked_replayer, in_order, load_kernels, replayer, stride_threads

__all__ = ["AGGREGATE_NODES", "Aggregates", "CoarseSpace", "aggregates_of", "coarse_aggregates", "coarse_bodies",
           "coarse_spectrum"]

#: Fewest nodes of a body the coarse space takes (its six rigid motions must be independent).
MIN_NODES = 4
#: Most nodes of an aggregate of a held body. Its six rigid motions then stand for the body's
#: smooth deformations, the modes node-block sweeps remove slowest.
AGGREGATE_NODES = 40


@dataclass(frozen=True)
class Aggregates:
    """Groups of nodes whose rigid motions the coarse space takes, as compressed rows.

    Attributes
    ----------
    start : ndarray(int64) [G + 1]
        Aggregate ``g``'s nodes are ``nodes[start[g]:start[g + 1]]``.
    nodes : ndarray(int64) [N]
        Global node indices, each in at most one aggregate.
    pairs : ndarray(int64) [P, 2] or None
        Node pairs that are one 6x6 block of ``D_A`` (a spring-held rigid body's linear and
        angular nodes, ``NodeCouplings.pair_node``), for :func:`coarse_spectrum`; None: none.
    whole : int
        How many of the aggregates, the first ones, are whole free bodies (the rest are parts
        of held bodies).
    """

    start: np.ndarray
    nodes: np.ndarray
    pairs: np.ndarray | None = None
    whole: int = 0

    def __len__(self) -> int:
        return len(self.start) - 1

    def head(self, count: int) -> Aggregates:
        """The first ``count`` aggregates."""
        return Aggregates(self.start[:count + 1], self.nodes[:self.start[count]], self.pairs,
                          min(self.whole, count))


def aggregates_of(coarse) -> Aggregates:
    """``coarse`` as :class:`Aggregates`: itself, or [B, 2] node ranges (:func:`coarse_bodies`),
    one aggregate each."""
    if isinstance(coarse, Aggregates):
        return coarse
    return _grouped([np.arange(a, b) for a, b in np.asarray(coarse, dtype=np.int64).reshape(-1, 2)])


def _grouped(groups: list[np.ndarray], pairs: np.ndarray | None = None, whole: int = 0) -> Aggregates:
    """:class:`Aggregates` of the node lists ``groups``, in that order."""
    sizes = [len(g) for g in groups]
    nodes = np.concatenate(groups).astype(np.int64) if groups else np.zeros(0, np.int64)
    return Aggregates(np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64), nodes, pairs, whole)


def _node_kinds(model) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each body's first node [bodies + 1], and per node [n]: whether it has blocks of ``A``,
    is fixed, is left out of the coarse space: a rigid body's (its ``D_A`` block is its whole
    body) or a cloth's (:func:`coarse_aggregates`)."""
    row_start = model.row_start.numpy()
    out = np.zeros(model.node_count, bool)
    if model.rigid is not None:
        out[model.rigid.linear_node.numpy()] = True
        out[model.rigid.angular_node.numpy()] = True
    cloth = getattr(model, "cloth", None)
    if cloth is not None and cloth.spring_count:
        out[cloth.node.numpy()] = True
    return np.asarray(model.body_node_start), row_start[1:] > row_start[:-1], model.fixed.numpy() != 0, out


def coarse_bodies(model) -> np.ndarray:
    """[B, 2] first and last (exclusive) node of each body the coarse space takes: FEM bodies
    whose nodes all have blocks of ``A`` and none is fixed (a held body's rigid motions are
    not slow modes of the sweeps), with at least :data:`MIN_NODES` nodes; no rigid body's or
    cloth's (:func:`_node_kinds`)."""
    start, has_blocks, fixed, out = _node_kinds(model)
    keep = [(a, b) for a, b in zip(start[:-1], start[1:])
            if b - a >= MIN_NODES and has_blocks[a:b].all() and not fixed[a:b].any() and not out[a:b].any()]
    return np.asarray(keep, dtype=np.int64).reshape(-1, 2)


def _split(nodes: np.ndarray, q: np.ndarray, size: int) -> list[np.ndarray]:
    """``nodes`` in spatial groups of at most ``size`` (recursive bisection at the median across
    the longest side of their bounding box), none under :data:`MIN_NODES`."""
    if len(nodes) <= size or len(nodes) < 2 * MIN_NODES:
        return [nodes]
    x = q[nodes]
    axis = int(np.argmax(x.max(0) - x.min(0)))
    order = nodes[np.argsort(x[:, axis], kind="stable")]
    half = len(order) // 2
    return _split(order[:half], q, size) + _split(order[half:], q, size)


def _spans_rotations(x: np.ndarray) -> bool:
    """Whether points ``x`` [k, 3] [m] move independently under the six rigid motions: they do
    not all lie on one line (the rotation about it would move none)."""
    if len(x) < MIN_NODES:
        return False
    spread = np.linalg.svd(x - x.mean(0), compute_uv=False)
    return bool(spread[1] > 1e-3 * spread[0] > 0)


def coarse_aggregates(model, q: np.ndarray, size: int = AGGREGATE_NODES) -> Aggregates:
    """The coarse space's aggregates: each body of :func:`coarse_bodies` that no coupling spring
    holds, whole (these first); the free nodes of every other FEM body (held by fixed nodes or
    by a coupling spring's stencil) in spatial groups of at most ``size`` (:func:`_split`);
    ``q`` [n, 3] [m] the node positions. A rigid body's nodes are in none (their ``D_A`` block
    is their whole body), nor a cloth's: every contact of an aggregate moves its coarse
    velocities, which couples them, and the sweep's PGS passes leave such coupled contacts
    unsolved; with a draped cloth's ~100 frictional contacts on one coarse body that error
    changed from sweep to sweep and its Chebyshev sweeps cycled (cloth-sphere.toml: its
    steps from the 37th on at 1 000 sweeps with changes of ~1e-2 m/s), while its Gauss-Seidel
    sweeps, each contact on its own node, converge (docs/physics-core.md, cloth)."""
    start, has_blocks, fixed, out = _node_kinds(model)
    coupled = np.zeros(model.node_count, bool)
    coupled[model.couplings.node.numpy()] = True
    whole = [np.arange(a, b) for a, b in coarse_bodies(model) if not coupled[a:b].any()]
    taken = {int(g[0]) for g in whole}
    groups = list(whole)
    for a, b in zip(start[:-1], start[1:]):
        if a not in taken and has_blocks[a:b].any() and not out[a:b].any():
            free = np.arange(a, b)[has_blocks[a:b] & ~fixed[a:b]]
            groups += [g for g in _split(free, q, size) if _spans_rotations(q[g])]
    return _grouped(groups, model.couplings.pair_node.numpy().astype(np.int64).reshape(-1, 2), len(whole))


def _basis(aggregates: Aggregates, q: np.ndarray, mass: np.ndarray, solved: np.ndarray) -> sp.csr_matrix:
    """``P`` [3 k, 6 G]: each aggregate's rigid motions (linear, then angular about its mass
    centre) over the solved nodes' velocities (``solved`` [n] which nodes those are)."""
    index = np.cumsum(solved) - 1
    rows, cols, vals = [], [], []
    for b in range(len(aggregates)):
        part = slice(aggregates.start[b], aggregates.start[b + 1])
        nodes = aggregates.nodes[part]
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
                         shape=(size, 6 * len(aggregates)))


def _galerkin_inverses(a: sp.csr_matrix, aggregates: Aggregates, q: np.ndarray, mass: np.ndarray,
                       solved: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """``(P, C)``: the aggregates' rigid motions ``P`` [3 k, 6 G] (:func:`_basis`) and ``C`` [6 G, 6 G]
    the block-diagonal of their Galerkin matrix ``P^T A P``, each aggregate's 6x6 inverted alone as
    the sweeps do (one thread per aggregate); ``a`` [3 k, 3 k] ``A`` over the solved nodes."""
    p = _basis(aggregates, q, mass, solved)
    galerkin = (p.T @ a @ p).toarray()
    coarse = np.zeros_like(galerkin)
    for g in range(0, len(galerkin), 6):
        coarse[g:g + 6, g:g + 6] = np.linalg.inv(galerkin[g:g + 6, g:g + 6])
    return p, coarse


def coarse_spectrum(a: sp.csr_matrix, solved: np.ndarray, bodies, q: np.ndarray,
                    mass: np.ndarray) -> tuple[float, float]:
    """Bounds (lo, hi) of the eigenvalues of ``M^-1 A`` with the two-level ``M^-1 = D_A^-1 +
    sum_g P_g (P_g^T A P_g)^-1 P_g^T`` (no margins): ``a`` [3 k, 3 k] ``A`` over the solved
    nodes (``solved`` [n]), ``bodies`` the aggregates (:func:`coarse_aggregates`, or [B, 2]
    node ranges from :func:`coarse_bodies`), ``q`` [n, 3] [m] and ``mass`` [n] [kg] the nodes'.
    ``D_A`` takes the aggregates' ``pairs`` as 6x6 blocks, as the sweeps do. ``M^-1 A`` is
    similar to the symmetric ``M^-1/2 A M^-1/2`` but ``M^-1/2`` is not at hand, so the bounds
    come from Arnoldi (ARPACK) on ``M^-1 A``, whose eigenvalues are real."""
    aggregates = aggregates_of(bodies)
    k = a.shape[0] // 3
    blocks = a.tobsr(blocksize=(3, 3))
    rows = np.repeat(np.arange(k), np.diff(blocks.indptr))
    diagonal = np.tile(np.eye(3), (k, 1, 1))
    diagonal[rows[rows == blocks.indices]] = blocks.data[rows == blocks.indices]
    pairs = (np.cumsum(solved) - 1)[aggregates.pairs] if aggregates.pairs is not None else np.zeros((0, 2), int)
    inverse = np.linalg.inv(diagonal)
    inverse[pairs.ravel()] = 0.0  # a pair's nodes take its 6x6 block's inverse instead
    d_inv = sp.bsr_matrix((inverse, np.arange(k), np.arange(k + 1)), shape=a.shape).tocsr()
    if len(pairs):
        dofs = (3 * pairs[:, :, None] + np.arange(3)).reshape(len(pairs), 6)
        pair_inv = np.linalg.inv(np.stack([a[d][:, d].toarray() for d in dofs]))
        entries = (np.repeat(dofs, 6, axis=1).ravel(), np.tile(dofs, 6).ravel())
        d_inv = d_inv + sp.coo_matrix((pair_inv.ravel(), entries), shape=a.shape).tocsr()
    p, coarse = _galerkin_inverses(a, aggregates, q, mass, solved)

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
    over ``bodies`` (:class:`Aggregates`, or [B, 2] node ranges from :func:`coarse_bodies`; none:
    every contact's coarse sides stay empty and the sweeps are plain node-block Jacobi), from
    the sweep's node residual ``residual`` [n] [kg m/s] (``b - A v``, the Jacobi kernel's);
    ``parallel``: the body sums with a thread per node (a GPU's form, :meth:`_record_parallel`).

    Attributes
    ----------
    arrays : Coarse
        The struct the sweep kernels take.
    """

    def __init__(self, model, state, bodies, residual: wp.array, parallel: bool = False):
        d = model.device
        aggregates = aggregates_of(bodies)
        n, count = model.node_count, len(aggregates)
        for kernel in (_k.prepare_bodies, _k.contact_sides, _k.coarse_residual):
            load_kernels(kernel, d)
        node_body = np.full(n, -1, np.int32)
        node_body[aggregates.nodes] = np.repeat(np.arange(count), np.diff(aggregates.start))
        capacity = state.contacts.capacity
        co = _k.Coarse()
        co.node_body = wp.array(node_body, dtype=wp.int32, device=d)
        for name in ("centre", "y_lin", "y_ang"):
            setattr(co, name, wp.zeros(max(count, 1), dtype=wp.vec3d, device=d))
        for name in ("ll", "la", "aa"):
            setattr(co, name, wp.zeros(max(count, 1), dtype=wp.mat33d, device=d))
        co.side = wp.full((capacity, _k.SIDES), -1, dtype=wp.int32, device=d)
        co.weight = wp.zeros((capacity, _k.SIDES), dtype=wp.float64, device=d)
        co.lever = wp.zeros((capacity, _k.SIDES), dtype=wp.vec3d, device=d)
        self.arrays = co
        self.count = count
        self._prepare: list[Callable[[], None]] = []
        #: The coarse velocities from the sweep's residual (a replay; none without bodies).
        self.residual: Callable[[], None] | None = None
        if not count:
            return
        start: wp.array = wp.array(aggregates.start.astype(np.int32), dtype=wp.int32, device=d)
        nodes: wp.array = wp.array(aggregates.nodes.astype(np.int32), dtype=wp.int32, device=d)
        c = state.contacts
        threads = stride_threads(d, min(capacity, CONTACT_THREADS))
        # A body a chunk, over the cores: ~0.5 ms a step on the candy's four (its blocks' 3x3 products).
        self._prepare = [
            chunked_replayer(_k.prepare_bodies, count, [start, nodes, state.q, model.mass, model.row_start,
                                                        model.block_col, state.blocks, co], d, min_chunk=1),
            replayer(wp.launch(_k.contact_sides, dim=threads, device=d, record_cmd=True,
                               inputs=[c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights, state.q, co,
                                       threads]))]
        self.residual = replayer(wp.launch(_k.coarse_residual, dim=count, device=d, record_cmd=True,
                                           inputs=[start, nodes, state.q, residual, co]))
        if parallel:
            self._record_parallel(model, state, nodes, count, residual)

    def _record_parallel(self, model, state, nodes: wp.array, count: int, residual: wp.array) -> None:
        """The body sums with a thread per node (``parallel``, a GPU's form: the kernels'
        ``*_parallel``), in place of a thread per body walking its nodes."""
        d, co, listed = model.device, self.arrays, nodes.shape[0]
        total = wp.zeros(count, dtype=wp.float64, device=d)
        vectors = [wp.zeros(count, dtype=wp.vec3d, device=d) for _ in range(2)]
        matrices = [wp.zeros(count, dtype=wp.mat33d, device=d) for _ in range(3)]

        def record(kernel, dim: int, inputs: list) -> Callable[[], None]:
            return replayer(wp.launch(kernel, dim=dim, device=d, record_cmd=True, inputs=inputs))

        self._prepare = [total.zero_, vectors[0].zero_, *(m.zero_ for m in matrices),
                         record(_k.body_mass_parallel, listed, [nodes, state.q, model.mass, co, total, vectors[0]]),
                         record(_k.body_centre_parallel, count, [total, vectors[0], co]),
                         record(_k.body_blocks_parallel, listed, [nodes, state.q, model.row_start, model.block_col,
                                                                  state.blocks, co, *matrices]),
                         record(_k.body_inverse_parallel, count, [*matrices, co]), self._prepare[-1]]
        self.residual = in_order(vectors[0].zero_, vectors[1].zero_,
                                 record(_k.residual_sums_parallel, listed, [nodes, state.q, residual, co, *vectors]),
                                 record(_k.coarse_solve_parallel, count, [*vectors, co]))

    def prepare(self) -> None:
        """The bodies' centres and coarse inverses from this step's ``A``, and the contacts'
        coarse sides (once a step, after detection)."""
        for launch in self._prepare:
            launch()
