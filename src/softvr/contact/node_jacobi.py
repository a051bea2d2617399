"""The contact solve of the FEM bodies of a whole scene (thesis eq. 5.6: outer Jacobi over the
node velocities with D_A the 3x3 node blocks, inner PGS over the contacts), Chebyshev
accelerated, as recorded launches replayed sweep by sweep (kernels and the derivation in
:mod:`softvr.contact._node_jacobi_kernels`). Works on :class:`softvr.sim.NodeModel` /
:class:`softvr.sim.NodeState` or any objects with those attributes. No factorization: the same
sweeps also solve eq. 5.2, so there is no separate unconstrained solve.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from typing import Callable

import numpy as np
import warp as wp

from softvr.contact import _node_block_kernels as _bk
from softvr.contact import _node_jacobi_kernels as _k
from softvr.contact import _node_loop_kernels as _lk
from softvr.contact import _node_parallel_kernels as _pk
from softvr.contact._node_block_kernels import CONTACT_BLOCK_THREADS
from softvr.contact.node_coarse import Aggregates, CoarseSpace, aggregates_of
from softvr.contact.node_colouring import NodeColouring
from softvr.contact._node_contact_native import LOCAL_UPDATES
from softvr.contact.node_gauss_seidel import GaussSeidelSweep
from softvr.device import (LaunchBatch, chunked_replayer, cpu_workers, in_order, load_kernels, record_copy, replayer,
                           stride_threads)
from softvr.dynamics.node_rigid import isolated_rigid_nodes

__all__ = ["NodeSolve", "chebyshev_rate", "chebyshev_rates", "chebyshev_weights", "fell_faster", "movable_contacts",
           "observed_rate", "tail_error"]

#: Threads striding over a step's contacts in the kernels that take one contact at a time
#: independently (the screen, the contact metric) on CUDA. On the CPU they take one: the screen
#: takes ~35 us on the candy pile, less than handing half of it to a second core.
CONTACT_THREADS_CUDA = 4096

#: The Jacobi sweeps' Chebyshev weights are those of a spectral radius this much under the
#: bounds' (:class:`NodeSolve`): less momentum, so contacts changing their active set no longer
#: make the iteration cycle, and the modes inside the narrower interval (most of a warm-started
#: step's error) fall faster; the few at the ends of the bounds fall slower
#: (:func:`chebyshev_rate`), which the stop's floor and the switch to plain sweeps answer.
CHEBYSHEV_RHO_FACTOR = 0.96

#: Sweeps over which the stop measures the contraction it observes (:func:`tail_error`): two
#: checks, long enough to smooth the Chebyshev iterates' oscillation, short enough to follow a
#: change of phase (a contact settling).
RATE_SWEEPS = 4

#: Checks whose largest changes the stop's tail starts from (:func:`tail_error`), each carried
#: down at the rate: one check's change dips on contact steps. Two left a settling 4-cell cube
#: (tests/contact/test_node_chebyshev_stop.py) 1.1e-5 m/s off against a tolerance of 1e-5; three
#: hold it within 7e-6 over its steps 8-39, for 0.4 more sweeps a step on the bench cube and 1.3 on
#: the candy pile.
TAIL_CHECKS = 3

#: Sweeps over which a solve judges that its first Chebyshev sweeps have slowed below the rate
#: of the bounds' own weights (:meth:`NodeSolve.solve`), and the fewest sweeps before it does
#: (the first sweeps of a contact step contract unevenly while the contacts take their load).
SWITCH_SWEEPS = 6
SWITCH_AFTER = 12

#: Passes of the one-block contact step (:mod:`softvr.contact._node_block_kernels`: Gauss-Seidel
#: within a lane's contacts, Jacobi on split masses across lanes) per Gauss-Seidel pass of the
#: CPU's, where some node or coarse body is moved by two lanes (where none is, every lane's passes
#: are exact Gauss-Seidel over its own contacts: the CPU's count), in the thread-per-contact form
#: (:class:`NodeSolve`'s ``parallel``) of a scene whose contacts can share. Sweeps a step over the
#: candy pile's first 30 steps on the CPU with the block's 256 lanes as fibers (what a GPU runs;
#: the one-thread form: 62.3): 1: 77.5 (steps at 258 and 234), 2: 63.2 (60.1 with 2 in every
#: pass); session 18's Jacobi passes on split masses took 95.6 with 4 a pass (the landing step at
#: the 500 cap, 352 with 16). A pass costs two of the block's barriers.
PARALLEL_PASS_FACTOR = 2

#: Solves started on the bounds' own weights after which one starts on the narrower weights
#: again (:attr:`NodeSolve.start_narrow`), and the most: a solve on the bounds' weights cannot
#: see that the narrower ones would now do better (the error moved inside their interval: a
#: cloth settling on a wall, 28 against 22 sweeps a step), so they are tried again, after twice
#: as many each time they lose again.
NARROW_RETRY = (8, 64)


def chebyshev_weights(rho: float, count: int) -> np.ndarray:
    """omega_k [count] of the Chebyshev semi-iteration for an iteration of spectral radius
    ``rho`` < 1: 1, 2 / (2 - rho^2), then 4 / (4 - rho^2 omega_{k-1}) (Golub and Van Loan,
    Matrix Computations, 11.2.8; Wang 2015 for projected iterations)."""
    omega = np.ones(max(count, 1))
    for k in range(1, len(omega)):
        omega[k] = 2.0 / (2.0 - rho * rho) if k == 1 else 4.0 / (4.0 - rho * rho * omega[k - 1])
    return omega


def chebyshev_rate(rho: float, rho_weights: float) -> float:
    """The asymptotic error reduction per sweep of the slowest mode (eigenvalue ``rho`` of the
    iteration matrix, the bounds' end) under Chebyshev weights built for ``rho_weights`` <= ``rho``
    (:func:`chebyshev_weights`): the ratio of ``T_k(rho / rho_w)`` to ``T_k(1 / rho_w)`` per step,
    ``(rho + sqrt(rho^2 - rho_w^2)) / (1 + sqrt(1 - rho_w^2))`` (Golub and Van Loan 11.2.8, the
    Chebyshev polynomial outside its interval); ``rho / (1 + sqrt(1 - rho^2))``, the optimal rate,
    when ``rho_weights`` = ``rho``. Every mode of ``|mu|`` <= ``rho`` falls at least this fast."""
    if not 0.0 <= rho_weights <= rho < 1.0:
        raise ValueError(f"chebyshev_rate: expected 0 <= rho_weights <= rho < 1, found rho_weights={rho_weights!r}, "
                         f"rho={rho!r}")
    if rho == 0.0:
        return 0.0
    return float((rho + np.sqrt(rho * rho - rho_weights * rho_weights)) / (1.0 + np.sqrt(1.0 - rho_weights ** 2)))


def chebyshev_rates(rho: float, rho_weights: float, count: int) -> np.ndarray:
    """[count] the error reduction of the slowest mode (eigenvalue ``rho``) at each of the first
    ``count`` sweeps on the weights of ``rho_weights`` <= ``rho`` from their start (index
    ``k - 1`` for sweep ``k``): ``p_k / p_k-1`` with ``p_k = T_k(rho / rho_w) / T_k(1 / rho_w)``
    (Golub and Van Loan 11.2.8), ``rho`` at the first sweep, tending to :func:`chebyshev_rate`.
    The error left over the last change is then ``r_k / (1 - r_k)`` exactly for that mode: in a
    (re)start's first sweeps the slowest mode has barely begun to fall, and the asymptotic rate
    would put its tail at a quarter of that (the candy's bounds' own weights at sweep 2).
    Computed as ``e^(a - b) (1 + e^-2ka)(1 + e^-2(k-1)b) / ((1 + e^-2(k-1)a)(1 + e^-2kb))`` with
    ``cosh a = rho / rho_w``, ``cosh b = 1 / rho_w`` (no overflow)."""
    asymptote = chebyshev_rate(rho, rho_weights)
    if rho_weights == 0.0:  # omega_k = 1: plain sweeps
        return np.full(count, rho)
    k = np.arange(1, count + 1, dtype=np.float64)
    e_b = (1.0 + np.sqrt(1.0 - rho_weights ** 2)) / rho_weights
    q_a, q_b = (asymptote * e_b) ** -2.0, e_b ** -2.0  # e^-2a, e^-2b (e^a = asymptote e^b)
    return asymptote * (1.0 + q_a ** k) * (1.0 + q_b ** (k - 1)) / ((1.0 + q_a ** (k - 1)) * (1.0 + q_b ** k))


def tail_error(sweeps: list[int], changes: list[float], floor: float, window: int | None = RATE_SWEEPS) -> float:
    """The distance [m/s] of the last checked sweep's iterate from the fixed point, estimated as
    the geometric tail ``r / (1 - r)`` times the largest change [m/s] of the last
    :data:`TAIL_CHECKS` checks, each carried down to the last sweep at ``r`` a sweep
    (``changes[j] r^(sweeps[-1] - sweeps[j])``): the sum of the changes still to come if each is
    ``r`` times the one before. One check's change alone can dip: on a contact step a restart
    leaves the contacts' transient in the iterate, and its change can fall 5-15x in two sweeps
    while the error does not (the bench cube's steps 20-55: a stop on the last change alone left
    up to 1.1e-4 m/s against a tolerance of 1e-5; from the last three checks, 0.8-1.3e-6).
    ``r`` is the larger of
    ``floor`` (the rate the spectrum's bounds promise) and the contraction observed over the last
    ``window`` sweeps (the largest change of sweeps ``(k - window, k]`` over that of
    ``(k - 2 window, k - window]``, to the power ``1 / window``; ``sweeps`` ascending, the
    sweep of each change): the promised rate holds for a linear iteration whose spectrum is
    within the bounds, and contacts changing their active set, or weights narrower than the
    bounds, make the iterates fall slower. inf where they do not fall. ``window`` None: ``floor``
    alone."""
    k = sweeps[-1]
    rate = max(floor, observed_rate(sweeps, changes, k, window)) if window is not None and k >= 2 * window else floor
    if rate >= 1.0:
        return np.inf
    lead = max(c * rate ** (k - s) for s, c in zip(sweeps[-TAIL_CHECKS:], changes[-TAIL_CHECKS:]))
    return lead * rate / (1.0 - rate)


def observed_rate(sweeps: list[int], changes: list[float], k: int, window: int) -> float:
    """The contraction per sweep of the largest changes ``changes`` [m/s] (of the sweeps
    ``sweeps``, ascending) at sweep ``k``: the largest of sweeps ``(k - window, k]`` over the
    largest of ``(k - 2 window, k - window]``, to the power ``1 / window`` (the largest of each
    window, as the Chebyshev iterates oscillate); 0 if the recent changes are 0, inf if only the
    earlier ones are."""
    recent, before = _largest(sweeps, changes, k - window, k), _largest(sweeps, changes, k - 2 * window, k - window)
    if recent <= 0.0:
        return 0.0
    return float((recent / before) ** (1.0 / window)) if before > 0.0 else np.inf


def _largest(sweeps: list[int], changes: list[float], after: int, upto: int) -> float:
    """The largest of ``changes`` of the sweeps ``j``, ``after < j <= upto`` (0 if none)."""
    return max(changes[bisect_right(sweeps, after):bisect_right(sweeps, upto)], default=0.0)


def fell_faster(sweeps: list[int], changes: list[float], rate: float) -> bool:
    """Whether the largest changes ``changes`` [m/s] (of the checked sweeps ``sweeps``, ascending)
    fell from the first to the last by more than ``rate`` a sweep on average:
    ``changes[-1] <= changes[0] rate^(sweeps[-1] - sweeps[0])``. :meth:`NodeSolve.solve` asks it
    of the narrower weights' sweeps when they slow, with the bounds' own rate: if they did not
    beat it even while the error inside their interval fell, the bounds' weights would have been
    the better start (the error sat at the bounds' ends from the first sweep)."""
    return changes[-1] <= changes[0] * rate ** (sweeps[-1] - sweeps[0])


def movable_contacts(model, state) -> int:
    """How many of this step's contacts can move a node (a free node of nonzero weight in the
    stencil, or a rigid side): the ones the PGS passes work on (:func:`_node_jacobi_kernels.contact_metric`)."""
    c = state.contacts
    n = min(int(c.count.numpy()[0]), c.capacity)
    nodes, weights = c.stencil_nodes.numpy()[:n], c.stencil_weights.numpy()[:n]
    used = np.arange(nodes.shape[1]) < c.stencil_count.numpy()[:n, None]
    free = model.fixed.numpy()[np.maximum(nodes, 0)] == 0
    moves = (used & free & (weights != 0.0)).any(axis=1) | (c.rigid_node.numpy()[:n] >= 0).any(axis=1)
    return int(moves.sum())


def _contact_threads(device) -> int:
    """Threads of a launch that strides over a step's contacts (:data:`CONTACT_THREADS_CUDA`,
    :func:`softvr.device.stride_threads`)."""
    return stride_threads(device, CONTACT_THREADS_CUDA)


def _contacts_may_share(model, coarse_bodies: int) -> bool:
    """Whether two of a step's contacts can act on one node or coarse body (so the thread-per-
    contact passes must split masses): bodies that meet each other (a triangle's nodes), rigid
    bodies (their nodes take all their corners' contacts), coarse bodies, two collision points
    on one node (points embedded in one tet), or a point that can meet more than one static."""
    if coarse_bodies or getattr(model, "rigid", None) is not None or bool(model.pair_enabled.numpy().any()):
        return True
    if len(model.plane_normal) + len(model.sphere_radius) + len(model.static_mesh_friction) > 1:
        return True
    nodes, weights = model.point_nodes.numpy(), model.point_weights.numpy()
    used = nodes[(nodes >= 0) & (weights != 0.0)]
    return len(np.unique(used)) < len(used)


def _own_blocks(model) -> wp.array:
    """[n] 1 where node ``i`` has its diagonal block in ``A``'s rows (every FEM node, and a
    spring-held rigid body's: the residual form of :func:`_node_jacobi_kernels.jacobi`), 0 where
    its ``D_A`` is only in ``d_inv`` (a free rigid body's)."""
    rows, cols = model.block_row.numpy(), model.block_col.numpy()
    own = np.zeros(model.node_count, np.int32)
    own[rows[rows == cols]] = 1
    partner = model.couplings.partner.numpy()
    paired = partner >= 0
    if not own[paired].all():
        raise ValueError("a spring-held rigid body's node has no diagonal block in A: its 6x6 block of D_A "
                         "cannot be taken in residual form")
    return wp.array(own, dtype=wp.int32, device=model.device)


def _nothing() -> None:
    """A replay with nothing to do: the contact step of a Gauss-Seidel sweep (it runs inside the
    node update), the largest change on the CPU (the Chebyshev kernel takes it)."""


class _Changes:
    """The largest changes [m/s] of the checked sweeps since the Chebyshev sweeps (re)started,
    in sweep order (the stop's plateau and stall tests take the largest of a window of them)."""

    def __init__(self):
        self.sweeps: list[int] = []
        self.values: list[float] = []

    def add(self, sweep: int, change: float) -> None:
        self.sweeps.append(sweep)
        self.values.append(change)

    def largest(self, after: int, upto: int) -> float:
        """The largest change of the sweeps ``j``, ``after < j <= upto``."""
        return _largest(self.sweeps, self.values, after, upto)

    def rate(self, k: int, window: int) -> float:
        """The contraction per sweep observed at sweep ``k`` (:func:`observed_rate`)."""
        return observed_rate(self.sweeps, self.values, k, window)


class NodeSolve:
    """The recorded sweeps of one step size, and the loop that runs them.

    Parameters
    ----------
    model, state
        :class:`softvr.sim.NodeModel`, :class:`softvr.sim.NodeState`.
    dt : float [s]
    spectrum : tuple of float
        (lo, hi): bounds of the eigenvalues of the iteration's ``M^-1 A`` (lo > 0; M = D_A for
        Jacobi), for the Chebyshev weights.
    max_sweeps : int
    passes : int
        PGS passes over the contacts per sweep.
    colours : NodeColouring, optional
        Sweep with multicolour symmetric block Gauss-Seidel over these colours
        (:mod:`softvr.contact.node_gauss_seidel`) instead of Jacobi.
    omega : float
        With ``colours``: the damping of the contact nodes' Jacobi update, at most
        1 / lambda_max(D_A^-1 A).
    coarse : ndarray or Aggregates, optional
        [B, 2] node ranges of the bodies (or aggregates) whose rigid motions the Jacobi sweeps
        correct exactly (:mod:`softvr.contact.node_coarse`; ``spectrum`` is then that of the
        two-level ``M^-1 A``); with ``colours``, the aggregates each Gauss-Seidel sweep corrects
        after its node update (:mod:`softvr.contact.node_gs_coarse`; ``spectrum`` that iteration's).
    device_loop : bool
        Take the loop's decisions on the device (:meth:`launch`: the sweeps and their
        checks as one :class:`~softvr.device.LaunchBatch` a solve, on CUDA one graph launch and
        one read back instead of a launch or more a kernel and a read a check); False: on the
        host, sweep by sweep (:meth:`solve`'s own loop, the reference the device's is checked
        against, and what an odd ``max_sweeps`` takes, or a CUDA without conditional graph
        nodes). The same launches in the same order and the same decisions: the same results.
    parallel : bool, optional
        The Jacobi sweeps' contact step and the stop's reductions with a thread per contact and
        per node (:mod:`softvr.contact._node_parallel_kernels`: Jacobi over the contacts on split
        masses, atomic maxima) instead of one thread walking them; None: on any device but the
        CPU. The Gauss-Seidel sweeps take the same contact step in the middle of their node update.
    """

    def __init__(self, model, state, dt: float, spectrum: tuple[float, float], *, max_sweeps: int = 500,
                 passes: int = 2, colours: NodeColouring | None = None, omega: float = 1.0,
                 coarse: np.ndarray | Aggregates | None = None, device_loop: bool = True,
                 parallel: bool | None = None):
        lo, hi = spectrum
        self.gamma, self.rho = 2.0 / (lo + hi), (hi - lo) / (hi + lo)
        #: Asymptotic error reduction per Chebyshev sweep.
        self.rate = (1.0 - np.sqrt(1.0 - self.rho * self.rho)) / self.rho if self.rho > 0 else 0.0
        self.max_sweeps = int(max_sweeps)
        self._weights_count = self.max_sweeps
        d = model.device
        for kernel in (_k.jacobi, _k.jacobi_walk, _k.transpose_blocks, _k.contact_metric, _k.warm_impulses,
                       _k.screen, _k.contacts, _k.contact_step, _k.list_movers, _k.chebyshev, _k.residual,
                       _k.rigid_contact_exact, _k.largest_change, _pk.contact_step_unshared,
                       _pk.residual_parallel):
            load_kernels(kernel, d)
        # The Jacobi sweeps start on narrower weights (CHEBYSHEV_RHO_FACTOR) and switch to the
        # bounds' own (solve); the Gauss-Seidel sweeps keep the bounds' own.
        rho_first = self.rho * (CHEBYSHEV_RHO_FACTOR if colours is None else 1.0)
        self._first_weights: wp.array = wp.array(chebyshev_weights(rho_first, self.max_sweeps), dtype=wp.float64,
                                                 device=d)
        self._bounds_weights: wp.array = wp.array(chebyshev_weights(self.rho, self.max_sweeps), dtype=wp.float64,
                                                  device=d)
        self._narrow = rho_first < self.rho
        #: Whether the next solve starts on the narrower weights (else on the bounds' own): what
        #: the last solves observed (:meth:`solve`). The weights differ by scene and by phase:
        #: the candy pile's steps carry most of their error inside the narrower interval and
        #: cycle on the bounds' weights (68 against 97 sweeps a step), a cube resting on a plane
        #: carries it at the bounds' ends (26 against 32 once it has settled).
        self.start_narrow = self._narrow
        # NARROW_RETRY: solves on the bounds' weights before the narrower ones are tried again,
        # how many of them are left, and whether the next start on the narrower ones is a retry.
        self._retry, self._until_retry, self._retrying = NARROW_RETRY[0], 0, False
        #: The omega_k the Chebyshev kernel reads (a copy of the first or the bounds' weights).
        self.weights: wp.array = wp.clone(self._first_weights)
        # The Jacobi stop's floors, sweep by sweep from a (re)start (chebyshev_rates); the
        # Gauss-Seidel sweeps keep the asymptotic rate (main's stop, measured on the shoulder).
        count = self.max_sweeps
        floors = (chebyshev_rates(self.rho, rho_first, count), chebyshev_rates(self.rho, self.rho, count)) \
            if colours is None else (np.full(count, self.rate),) * 2
        # Python floats, the same values: the stop's arithmetic on NumPy scalars cost ~2 us a check.
        self._floors = tuple(f.tolist() for f in floors)
        # The Gauss-Seidel sweeps (the shoulder's) keep the stop on the bounds' rate alone and their
        # plain windows whole: the observed rate was measured on the Jacobi scenes only.
        self._observed = colours is None
        #: Sweeps per decade of error of the Chebyshev iteration (inf if it does not contract).
        self.sweeps_per_decade = np.log(10.0) / -np.log(self.rate) if 0 < self.rate < 1 else (
            0.0 if self.rate == 0 else np.inf)
        # :meth:`_window`; capped at max_sweeps, past which no window test looks (inf: no contraction)
        self._window_sweeps = 2 * int(np.ceil(max(10.0, min(self.sweeps_per_decade, self.max_sweeps))))
        self.colours = colours
        #: The sweep's node residual ``b - A v`` [n] [kg m/s] (the Jacobi kernel's, for the coarse correction).
        self.residual_nodes = wp.zeros(model.node_count, dtype=wp.vec3d, device=d)
        #: Whether the sweeps' contact step takes the thread-per-contact form (``parallel``).
        self.parallel = (not wp.get_device(d).is_cpu if parallel is None else bool(parallel))
        self.coarse = CoarseSpace(model, state, np.zeros((0, 2), np.int64) if coarse is None or colours is not None
                                  else coarse, self.residual_nodes, parallel=self.parallel)
        co = self.coarse.arrays
        self._gauss_seidel = None if colours is None else GaussSeidelSweep(
            model, state, colours, omega, dt, None if coarse is None else aggregates_of(coarse), self.parallel)
        #: Sweeps of the last solve made plain (omega = 1) after the Chebyshev ones stalled.
        self.plain_sweeps = 0
        #: Whether the last solve stopped on a plateau under the tolerance (:meth:`_plateau`).
        self.plateaued = False
        #: Checks of the last solve that found a sleeping contact woken (Gauss-Seidel sweeps:
        #: :meth:`GaussSeidelSweep.wake`), each a restart of the Chebyshev weights.
        self.wakes = 0
        self.sweep = wp.zeros(1, dtype=wp.int32, device=d)
        #: [0] the last checked sweep's largest change [m/s] (on the CPU the last sweep's: the
        #: Chebyshev kernel takes it every sweep), [1] the largest normal-velocity
        #: error [m/s], [2] the contacts' largest natural residual [m/s] (:meth:`solve`,
        #: :func:`_node_jacobi_kernels.residual`): all the loop reads back, one view per check.
        self.stats = wp.zeros(3, dtype=wp.float64, device=d)
        self.change = wp.zeros(model.node_count, dtype=wp.float64, device=d)
        self._stats_view = self.stats.numpy() if wp.get_device(d).is_cpu else None
        # A rigid body's nodes take their sweep's update unextrapolated: their D_A is all of
        # their A, so the update is exact for the sweep's impulses, and the Chebyshev step only
        # made them overshoot their contacts (a box resting on a block: 2.4x the sweeps, a plate
        # 3.4x). A rigid body held by coupling springs has blocks of A off its nodes' diagonal,
        # so its update is a Jacobi one like an FEM node's and takes the extrapolation (its
        # nodes are then in the spectrum's bounds too) until a contact presses it: then its
        # update is the contacts' as a free body's is, and extrapolating it overshot them (the
        # shoulder's finger: its spin, held by nothing but the contacts' friction, cycled at the
        # 100-sweep cap and diverged at step 39; unextrapolated its last change stays under 1
        # rad/s a sweep, mostly 1e-3 to 1e-1, and the palpation ends with 0.09 mm overlap).
        # A body held only by springs to driven nodes (a haptic tool on its handle) is as exact:
        # its 6x6 block of D_A is all of its A (extrapolated, the arthroscopy's probe took its
        # steps to the 100-sweep cap, its change decaying at the Chebyshev rate from ~0.2 m/s).
        # The Gauss-Seidel sweeps solve larger rigid islands whole (the shoulder's two fingers).
        exact = isolated_rigid_nodes(model) | (False if self._gauss_seidel is None else self._gauss_seidel.island_nodes)
        exact = exact.astype(np.int32)
        self.exact: wp.array = wp.array(exact, dtype=wp.int32, device=d)
        self._exact_base: wp.array = wp.array(exact, dtype=wp.int32, device=d)
        c = state.contacts
        buf = state.sweep_buffers
        jacobi, cheb, plain = [], [], []
        # Plain sweeps (omega = 1, the same gamma: damped Jacobi / Richardson on M^-1 A, which
        # contracts on [lo, hi]) for a step whose Chebyshev sweeps stall (_stalled).
        self._ones: wp.array = wp.array(np.ones(1), dtype=wp.float64, device=d)
        self._plain_sweep = wp.ones(1, dtype=wp.int32, device=d)
        gs = self._gauss_seidel
        d_inv = state.d_inv if gs is None else gs.metric
        cross = model.couplings.cross if gs is None else gs.cross_metric
        metric = wp.zeros(c.capacity, dtype=wp.mat33d, device=d)
        #: Which contacts the sweeps' PGS passes visit [c] (:func:`_node_jacobi_kernels.screen`).
        self.live = wp.zeros(c.capacity, dtype=wp.int32, device=d)
        movable = wp.zeros(c.capacity, dtype=wp.int32, device=d)
        # Each contact's block of J M^-1 J^T, fixed over the step's sweeps (after the Gauss-Seidel
        # metric and the coarse inverses are set); on the CPU over the cores (~0.2 ms a step on
        # the candy's ~3 000 contacts).
        threads = _contact_threads(d)
        metric_threads = 2 * cpu_workers() if threads == 1 else threads
        self._metric = chunked_replayer(_k.contact_metric, metric_threads,
                                        [c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights, c.frame,
                                         c.rigid_node, c.rigid_lever, d_inv, model.couplings.partner, cross,
                                         model.fixed, co, metric, movable, metric_threads], d, min_chunk=1)
        contacts = self._record_contacts(model, state, dt, passes, d_inv, cross, metric, movable)
        own_block = _own_blocks(model) if gs is None else None
        # One thread on the CPU, which also takes the largest change (no second pass over the nodes).
        node_threads = 1 if wp.get_device(d).is_cpu and not self.parallel else model.node_count
        # On the CPU the Jacobi update walks its nodes in C++ (_node_jacobi_kernels.jacobi_walk),
        # in two parts a core, from A's blocks transposed once a step (and a padding block).
        walk = gs is None and node_threads == 1
        self._transpose = _nothing
        if walk:
            blocks_t = wp.zeros(model.block_col.shape[0] + 1, dtype=wp.mat33d, device=d)
            self._transpose = chunked_replayer(_k.transpose_blocks, model.block_col.shape[0],
                                               [state.blocks, blocks_t], d)
            parts = 2 * cpu_workers()
        for r in range(3):
            v, v_prev, v_next = buf[r], buf[(r + 2) % 3], buf[(r + 1) % 3]
            if gs is None:
                row_inputs = [model.row_start, model.block_col, blocks_t if walk else state.blocks, state.d_inv,
                              model.couplings.partner, model.couplings.cross, state.b, model.fixed,
                              state.fixed_velocity, own_block, v, state.v_hat, self.residual_nodes]
                jacobi.append(chunked_replayer(_k.jacobi_walk, parts, [*row_inputs, model.node_count, parts], d,
                                               min_chunk=2) if walk else
                              chunked_replayer(_k.jacobi, model.node_count, row_inputs, d))
                if self.coarse.residual is not None:  # the coarse velocities from the sweep's residual
                    jacobi[-1] = in_order(jacobi[-1], self.coarse.residual)
            else:  # the contact PGS runs inside the Gauss-Seidel sweep
                jacobi.append(gs.record(v, contacts))
            cheb.append(wp.launch(_k.chebyshev, dim=node_threads, device=d, record_cmd=True,
                                  inputs=[state.v_hat, v, v_prev, self.weights, float(self.gamma), self.sweep,
                                          model.fixed, self.exact, state.q, co, v_next, self.change,
                                          model.node_count, node_threads, int(self.parallel), self.stats]))
            plain.append(replayer(wp.launch(_k.chebyshev, dim=node_threads, device=d, record_cmd=True,
                                            inputs=[state.v_hat, v, v_prev, self._ones, float(self.gamma),
                                                    self._plain_sweep, model.fixed, self.exact, state.q, co,
                                                    v_next, self.change, model.node_count, node_threads,
                                                    int(self.parallel), self.stats])))
        self._launches = (jacobi, contacts, cheb)
        self._sweeps = [(jacobi[r], contacts if gs is None else _nothing, replayer(cheb[r])) for r in range(3)]
        self._plain = plain
        self._reset_exact = record_copy(self.exact, self._exact_base)
        # A spring-held rigid body's nodes in some contact this step are marked exact too.
        self._rigid_contacts = replayer(wp.launch(_k.rigid_contact_exact, dim=threads, device=d, record_cmd=True,
                                                  inputs=[c.count, c.rigid_node, model.couplings.partner, self.exact,
                                                          threads]))
        residual_inputs = [[c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights, c.frame, c.gap, c.rigid_node,
                            c.rigid_lever, float(dt), buf[r], c.impulse, c.friction, c.stiffness, c.slip, metric,
                            movable, c.gap_after, self.stats] for r in range(3)]
        self._residual_launches = [replayer(wp.launch(_pk.residual_parallel, dim=threads, device=d, record_cmd=True,
                                                      inputs=[*inputs, threads]) if self.parallel else
                                            wp.launch(_k.residual, dim=1, device=d, record_cmd=True, inputs=inputs))
                                   for inputs in residual_inputs]
        self._largest = _nothing if node_threads == 1 or self.parallel else replayer(
            wp.launch(_k.largest_change, dim=1, device=d, record_cmd=True,
                      inputs=[self.change, model.node_count, self.stats]))
        self._buffers = buf
        self.buffer_flags: list[wp.array] = []  # (:meth:`_record_loop`)
        conditional = wp.get_device(d).is_cpu or wp.is_conditional_graph_supported()
        self._loop: LaunchBatch | None = self._record_loop(model, plain) if device_loop and conditional else None

    def _record_loop(self, model, plain: list) -> LaunchBatch:
        """:meth:`solve`'s loop as one batch of launches whose every decision is taken on the
        device (:mod:`softvr.contact._node_loop_kernels`): :meth:`prepare`, ``begin``, then
        while ``ctl[GO]`` (``wp.capture_while``) three times two sweeps (from buffers 0, 2 and
        1: the rotation's period), each followed by its check and each after the first only
        while ``ctl[GO]`` (``wp.capture_if``); a check is ``check_change``, the contacts' residual where it is
        wanted, ``check_stop``; the Gauss-Seidel sweeps first ask whether a sleeping contact woke
        and, if so, mark every contact's nodes (:meth:`GaussSeidelSweep.wake`'s launches). On the
        CPU the conditions are read through their pointers, on CUDA they are graph nodes."""
        d = model.device
        load_kernels(_lk.check_change, d)
        gs = self._gauss_seidel
        #: The loop's integers (slots of :mod:`softvr.contact._node_loop_kernels`).
        self.ctl = wp.zeros(_lk.CTL_SLOTS, dtype=wp.int32, device=d)
        self._ctl_view = self.ctl.numpy() if wp.get_device(d).is_cpu else None
        # Whether the next start's state (start_narrow and its retry counters) is the host's: the
        # device's loop takes it over at its launch, the host's loop back from its outcome.
        self._start_on_host = True
        #: [1] the stop's tolerance [m/s] (:meth:`solve`'s, written when it changes).
        self._tolerance = wp.full(1, np.nan, dtype=wp.float64, device=d)
        self._tolerance_value = math.nan
        #: [1] the most sweeps (``max_sweeps``, written when it changes).
        self._cap = wp.full(1, self.max_sweeps, dtype=wp.int32, device=d)
        self._cap_value = self.max_sweeps
        checks = self.max_sweeps // 2 + 1
        changes = [wp.zeros(checks, dtype=wp.int32, device=d), wp.zeros(checks, dtype=wp.float64, device=d)]
        history = [wp.zeros(checks, dtype=wp.int32, device=d), wp.zeros(checks, dtype=wp.float64, device=d)]
        floors: wp.array = wp.array(np.stack([np.asarray(f, np.float64) for f in self._floors]), dtype=wp.float64,
                                    device=d)
        observed = RATE_SWEEPS if self._observed else 0
        woken = wp.zeros(1, dtype=wp.int32, device=d) if gs is None else gs.flag
        begin = replayer(wp.launch(_lk.begin, dim=1, device=d, record_cmd=True,
                                   inputs=[self.ctl, self._cap, self._first_weights, self._bounds_weights,
                                           self.weights]))
        check_change = replayer(wp.launch(
            _lk.check_change, dim=1, device=d, record_cmd=True,
            inputs=[self.ctl, woken, self.stats, self._tolerance, floors, float(self.rho), observed, TAIL_CHECKS,
                    self._window_sweeps, self._cap, *changes, *history]))
        check_stop = replayer(wp.launch(
            _lk.check_stop, dim=1, device=d, record_cmd=True,
            inputs=[self.ctl, self.stats, self._tolerance, float(self.rate), observed, SWITCH_SWEEPS, SWITCH_AFTER,
                    self._window_sweeps, NARROW_RETRY[0], NARROW_RETRY[1], self._cap, int(self._narrow),
                    *changes, *history, self._bounds_weights, self.weights, self.sweep]))

        def condition(slot: int) -> wp.array:
            return self.ctl[slot:slot + 1]

        go, is_plain, want = condition(_lk.GO), condition(_lk.PLAIN), condition(_lk.WANT)
        #: [3] int32 arrays of one element: 1 in the one for the buffer (sweeps modulo 3) that
        #: holds the last device-decided solve's velocities, set on the device when its loop ends
        #: (``wp.capture_if`` conditions for the launches after it: :meth:`launch`); empty
        #: without the device's loop.
        self.buffer_flags = [condition(_lk.BUFFER + r) for r in range(3)]
        wake = in_order(gs.wake_launches, *([gs.coarse.prepare] if gs.coarse is not None else [])) if gs else None

        def two_sweeps(r: int, plain_sweeps: bool) -> Callable[[], None]:
            return in_order(*[step for j in (r, (r + 1) % 3) for step in
                              (*self._sweeps[j][:2], plain[j] if plain_sweeps else self._sweeps[j][2])])

        def unit(r: int) -> Callable[[], None]:
            chebyshev, plain_pair = two_sweeps(r, False), two_sweeps(r, True)
            residual = self._residual_launches[(r + 2) % 3]

            def run() -> None:
                wp.capture_if(is_plain, on_true=plain_pair, on_false=chebyshev)
                if gs is not None:
                    gs.woken_launches()
                    wp.capture_if(woken, on_true=wake)
                self._largest()
                check_change()
                wp.capture_if(want, on_true=residual)
                check_stop()
            return run

        first, second, third = unit(0), unit(2), unit(1)

        def body() -> None:
            first()
            wp.capture_if(go, on_true=second)
            wp.capture_if(go, on_true=third)

        return LaunchBatch([self.prepare, begin, lambda: wp.capture_while(go, body)], d)

    def _record_contacts(self, model, state, dt: float, passes: int, d_inv: wp.array, cross: wp.array,
                         metric: wp.array, movable: wp.array) -> Callable[[], None]:
        """The contact step of a sweep: the last impulses applied to ``v^``, the contacts
        screened (:func:`_node_jacobi_kernels.screen`), then the PGS passes over the live ones
        (:func:`_node_jacobi_kernels.contacts`); with one thread a launch (the CPU) and Jacobi
        sweeps, the three in one launch over the step's movable contacts
        (:func:`_node_jacobi_kernels.contact_step`, listed by :attr:`_list_movers` once a step)."""
        c, d, co = state.contacts, model.device, self.coarse.arrays
        self._order = wp.zeros(c.capacity, dtype=wp.int32, device=d)
        threads = _contact_threads(d)
        self._list_movers = _nothing
        if self.parallel:
            return self._record_parallel_contacts(model, state, dt, passes, d_inv, cross, metric, movable)
        if threads == 1 and self._gauss_seidel is None:
            movers, mover_count = wp.zeros(c.capacity, dtype=wp.int32, device=d), wp.zeros(1, dtype=wp.int32, device=d)
            self._list_movers = replayer(wp.launch(_k.list_movers, dim=1, device=d, record_cmd=True,
                                                   inputs=[c.count, movable, self.live, movers, mover_count]))
            return replayer(wp.launch(_k.contact_step, dim=1, device=d, record_cmd=True,
                                      inputs=[movers, mover_count, c.stencil_count, c.stencil_nodes, c.stencil_weights,
                                              c.frame, c.gap, c.friction, c.rigid_node, c.rigid_lever, d_inv,
                                              model.couplings.partner, cross, model.fixed, float(dt), int(passes),
                                              c.impulse, state.v_hat, self.sweep, c.stiffness, c.slip, co, metric,
                                              self.live, self._order]))
        stencil = [c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights, c.frame]
        warm = wp.launch(_k.warm_impulses, dim=1, device=d, record_cmd=True,
                         inputs=[*stencil, c.rigid_node, c.rigid_lever, d_inv, model.couplings.partner, cross,
                                 model.fixed, c.impulse, state.v_hat, co, movable])
        screen = wp.launch(_k.screen, dim=threads, device=d, record_cmd=True,
                           inputs=[*stencil, c.gap, c.rigid_node, c.rigid_lever, float(dt), c.impulse, c.stiffness,
                                   state.v_hat, co, movable, threads, self.live])
        passes_launch = wp.launch(_k.contacts, dim=1, device=d, record_cmd=True,
                                  inputs=[*stencil, c.gap, c.friction, c.rigid_node, c.rigid_lever, d_inv,
                                          model.couplings.partner, cross, model.fixed, float(dt), int(passes),
                                          c.impulse, state.v_hat, self.sweep, c.stiffness, c.slip, co, metric,
                                          self.live, self._order])
        replays = [replayer(warm), replayer(screen), replayer(passes_launch)]
        gs = self._gauss_seidel
        if gs is not None and gs.tool_passes:  # the exact rigid bodies' contacts again
            replays += [gs.mark_tools(self.live, threads), replayer(wp.launch(
                _k.contacts, dim=1, device=d, record_cmd=True,
                inputs=[*stencil, c.gap, c.friction, c.rigid_node, c.rigid_lever, d_inv, model.couplings.partner,
                        cross, model.fixed, float(dt), int(gs.tool_passes), c.impulse, state.v_hat, gs.tool_sweep,
                        c.stiffness, c.slip, co, metric, gs.tool_live, self._order]))]
        return in_order(*replays)

    def _record_parallel_contacts(self, model, state, dt: float, passes: int, d_inv: wp.array, cross: wp.array,
                                  metric: wp.array, movable: wp.array) -> Callable[[], None]:
        """The contact step of a sweep (a Jacobi one, or in the middle of a Gauss-Seidel one's node
        update) with a thread per contact: the last impulses applied to ``v^``, the contacts
        screened, then passes over the live ones, in one launch. Where contacts can share a node
        or coarse body (:func:`_contacts_may_share`), one thread block with its barrier between
        the stages (:mod:`softvr.contact._node_block_kernels`: ``passes`` passes, x
        :data:`PARALLEL_PASS_FACTOR` where two lanes share a node or coarse body, Gauss-Seidel
        within a lane, Jacobi on split masses across lanes; the Gauss-Seidel sweeps' extra passes
        over the exact rigid bodies' contacts in a second launch); where none can, a thread per
        contact over the whole device, no stage waiting for another contact's
        (:func:`_node_parallel_kernels.contact_step_unshared`: ``passes`` passes on the true
        masses, exact for such contacts)."""
        c, d, co = state.contacts, model.device, self.coarse.arrays
        stencil = [c.stencil_count, c.stencil_nodes, c.stencil_weights]
        if not _contacts_may_share(model, self.coarse.count):
            threads = _contact_threads(d)
            change = wp.zeros(c.capacity, dtype=wp.vec3d, device=d)  # a pass's impulse changes [N s]
            return replayer(wp.launch(
                _pk.contact_step_unshared, dim=threads, device=d, record_cmd=True,
                inputs=[c.count, movable, *stencil, c.frame, c.gap, c.friction, c.rigid_node, c.rigid_lever, d_inv,
                        model.couplings.partner, cross, model.fixed, float(dt), c.impulse, state.v_hat, c.stiffness,
                        c.slip, co, metric, LOCAL_UPDATES, change, self.live, self.sweep, self.stats,
                        int(passes), threads]))
        n, bodies = model.node_count, max(self.coarse.count, 1)
        gs = self._gauss_seidel
        tool_node = gs.tool_node if gs is not None else wp.zeros(1, dtype=wp.int32, device=d)
        # The block's scratch (its kernel's docstring): shares, lane marks, deferred pushes, lists.
        scratch = [wp.zeros(n, dtype=wp.int32, device=d), wp.zeros(bodies, dtype=wp.int32, device=d)]
        int32, vec3d, lanes_max = wp.int32, wp.vec3d, CONTACT_BLOCK_THREADS
        lanes = [wp.zeros(n, dtype=int32, device=d), wp.zeros(n, dtype=int32, device=d),
                 wp.zeros(bodies, dtype=int32, device=d), wp.zeros(bodies, dtype=int32, device=d),
                 wp.zeros(n, dtype=vec3d, device=d), wp.zeros(bodies, dtype=vec3d, device=d),
                 wp.zeros(bodies, dtype=vec3d, device=d), wp.zeros(lanes_max + 1, dtype=int32, device=d),
                 wp.zeros(lanes_max, dtype=int32, device=d), wp.zeros(c.capacity, dtype=int32, device=d),
                 wp.zeros(1, dtype=int32, device=d)]

        def block(start: int, visit: wp.array, count: int) -> Callable[[], None]:
            return replayer(wp.launch_tiled(
                _bk.contact_step_block, dim=[1], block_dim=CONTACT_BLOCK_THREADS, device=d, record_cmd=True,
                inputs=[c.count, movable, *stencil, c.frame, c.gap, c.friction, c.rigid_node, c.rigid_lever, d_inv,
                        model.couplings.partner, cross, model.fixed, float(dt), c.impulse, state.v_hat, c.stiffness,
                        c.slip, co, *scratch, LOCAL_UPDATES, self.live, self.sweep, self.stats, tool_node, visit,
                        start, int(visit is not self.live), count, PARALLEL_PASS_FACTOR, *lanes]))

        steps = [block(1, self.live, int(passes))]
        if gs is not None and gs.tool_passes:  # the exact rigid bodies' contacts again, their shares their own
            steps.append(block(0, gs.tool_live, gs.tool_passes))
        return in_order(*steps)

    def _read_stats(self) -> np.ndarray:
        """``stats`` on the host: a view on the CPU, a copy of its three numbers on CUDA."""
        return self._stats_view if self._stats_view is not None else self.stats.numpy()

    def prepare(self) -> None:
        """What the sweeps read that is fixed over a step's sweeps, from this step's ``A``,
        ``b`` and contacts (:meth:`solve` starts with it): the sweep count reset, the
        Gauss-Seidel metric, ``A``'s blocks transposed for the CPU's Jacobi walk, the exact
        nodes, the coarse spaces, the contacts' metric and the movable ones' list."""
        self.sweep.zero_()
        if self._gauss_seidel is not None:
            self._gauss_seidel.prepare()
        self._transpose()
        self._reset_exact()
        self._rigid_contacts()
        self.coarse.prepare()
        self._metric()
        self._list_movers()

    def solve(self, tolerance: float, check_every: int = 2, then: Callable[[], None] | None = None,
              batch: Callable[[], None] | None = None) -> tuple[int, wp.array]:
        """Sweeps from the velocity in ``state.sweep_buffers[0]`` (and [2], the one before it)
        until the velocities are within ``tolerance`` [m/s] of the fixed point, or
        ``max_sweeps``. The error left is estimated as the geometric tail of the largest change
        of the last :data:`TAIL_CHECKS` checks, carried down to the last (:func:`tail_error`:
        a rigid body's nodes, exact, count none) at the
        larger of the contraction observed over the last :data:`RATE_SWEEPS` sweeps (Jacobi
        only) and the rate the weights in use promise over the bounds at that sweep since they
        (re)started (Jacobi: :func:`chebyshev_rates`, the slowest mode's ratio, ``rho`` at the
        first sweep, as it has barely begun to fall; Gauss-Seidel: :attr:`rate`; plain sweeps:
        ``rho``), checked every ``check_every`` sweeps; the sweeps stop when it is under
        ``tolerance`` and every contact meets eq. 5.5 within ``tolerance``
        (:meth:`_contacts_met`: contacts between bodies couple them, and the node change alone
        understates their error; a rigid body's error is all its contacts').

        The Jacobi sweeps start on the narrower weights of :data:`CHEBYSHEV_RHO_FACTOR` or on
        the bounds' own, as :attr:`start_narrow` says. When the narrower ones contract slower
        than :attr:`rate` (over :data:`SWITCH_SWEEPS`, after :data:`SWITCH_AFTER`: the error
        left is in the modes at the bounds' ends), or any Chebyshev sweeps stall
        (:meth:`_stalled`), a window of plain sweeps follows (counted in ``plain_sweeps``),
        which lets the contacts' active set settle; with Jacobi it ends early once it contracts
        slower than :attr:`rate` (what is left is smooth, which Chebyshev takes faster), and
        Chebyshev restarts on the bounds' own weights. The next solve starts on the bounds' own
        weights when the narrower ones slowed without having beaten :attr:`rate` from their
        first sweep (:func:`fell_faster`), on the narrower ones when Chebyshev sweeps stalled
        or after :data:`NARROW_RETRY` solves on the bounds' weights; otherwise as this one did
        (:meth:`_next_start`). The stop's floor is the slowest mode's ratio under the
        weights in use, whichever they are, so the choice moves the sweeps' count, never what
        the stop claims. Returns the sweeps made and the buffer
        holding the solved velocities; ``stats[1]`` then holds the largest normal-velocity error
        [m/s]. With ``device_loop`` the same decisions are taken on the device
        (:meth:`decides_on_device`: :meth:`launch`, ``then``, :meth:`outcome`); ``then``, only
        there, launches what follows the solve before its outcome is read (choosing its sweep
        buffer by :attr:`buffer_flags`), so that the read waits for all of it at once; ``batch``,
        only there too, runs in place of :attr:`loop`: a larger batch holding its replays (a whole
        step's, with the launches before and after them)."""
        self._check_cap()
        if self.decides_on_device(check_every):
            self.launch(tolerance, batch)
            if then is not None:
                then()
            return self.outcome()
        if then is not None or batch is not None:
            raise ValueError("NodeSolve.solve: 'then' and 'batch' need a solve that decides on the device "
                             "(decides_on_device())")
        self._start_on_host = True
        self.prepare()
        narrow = started_narrow = self.start_narrow
        retrying, self._retrying = self._retrying, False
        wp.copy(self.weights, self._first_weights if narrow else self._bounds_weights)
        changes = _Changes()  # every checked sweep's change, for the observed rate
        history = _Changes()  # change by sweeps since Chebyshev (re)started
        restart, plain_from, plain_until = 0, 0, 0
        self.plain_sweeps = self.wakes = 0
        self.plateaued = stopped = False
        k = 0
        while k < self.max_sweeps:
            if k == plain_until and k > 0 and restart < k:  # back to Chebyshev, from omega_1
                self.sweep.zero_()
                restart, history = k, _Changes()
            plain = k < plain_until
            jacobi, contacts, cheb = self._sweeps[k % 3]
            jacobi()
            contacts()
            (self._plain[k % 3] if plain else cheb)()
            k += 1
            self.plain_sweeps += plain
            if k % check_every == 0:
                if self._gauss_seidel is not None and self._gauss_seidel.wake():
                    plain_until = k  # a new iteration: Chebyshev from omega_1
                    self.wakes += 1
                    continue
                self._largest()
                change = float(self._read_stats()[0])
                if not math.isfinite(change):  # NaN: the integration reports it (np.isfinite: ~4 us a check)
                    break
                changes.add(k, change)
                floor = self.rho if plain else self._floors[0 if narrow else 1][k - restart - 1]
                window = RATE_SWEEPS if self._observed else None
                if tail_error(changes.sweeps, changes.values, floor, window) <= tolerance and \
                        self._contacts_met(k, tolerance):
                    stopped = True
                    break
                if plain:
                    if self._observed and k - plain_from >= 2 * RATE_SWEEPS and \
                            changes.rate(k, RATE_SWEEPS) > self.rate:
                        plain_until = k
                    continue
                history.add(k - restart, change)
                if self._plateau(history, k - restart, tolerance) and self._contacts_met(k, tolerance):
                    self.plateaued = stopped = True
                    break
                slowed = narrow and k - restart >= max(SWITCH_AFTER, 2 * SWITCH_SWEEPS) and \
                    changes.rate(k, SWITCH_SWEEPS) > self.rate
                if slowed or self._stalled(history, k - restart, tolerance):
                    if self._narrow:
                        self._next_start(slowed, changes, retrying)
                    plain_from, plain_until = k, k + self._window()
                    if narrow:  # the Chebyshev sweeps after the window take the bounds' weights
                        wp.copy(self.weights, self._bounds_weights)
                        narrow = False
        if not stopped:
            self._contacts_met(k, tolerance)
        if self._narrow and not started_narrow and not self.start_narrow:
            self._until_retry -= 1
            self.start_narrow = self._retrying = self._until_retry <= 0
        return k, self._buffers[k % 3]

    def _check_cap(self) -> None:
        if self.max_sweeps > self._weights_count:
            raise ValueError(f"NodeSolve.solve: expected max_sweeps <= {self._weights_count} (the sweeps' weights "
                             f"and floors were built for that many), found {self.max_sweeps}")

    def decides_on_device(self, check_every: int = 2) -> bool:
        """Whether :meth:`solve` takes its loop's decisions on the device (``device_loop``, an
        even ``max_sweeps``, checks every two sweeps): then it takes ``then``, and
        :attr:`buffer_flags` say on the device where the solution is."""
        return self._loop is not None and check_every == 2 and self.max_sweeps % 2 == 0

    def launch(self, tolerance: float, batch: Callable[[], None] | None = None) -> None:
        """The first half of :meth:`solve` on the device: :meth:`prepare` and the loop launched
        (one batch, on CUDA one graph: :attr:`loop`; or ``batch``, one holding its replays),
        every check's decision taken on the device by :mod:`softvr.contact._node_loop_kernels`
        (the host's formulas on the same float64 numbers, so the same sweeps), nothing read
        back; :meth:`outcome` reads it. Launches after it choose their sweep buffer on the
        device (:attr:`buffer_flags`). Before the launches, the host writes the start state
        carried from a solve it decided, ``tolerance`` [m/s] and ``max_sweeps`` where they
        changed (copies to the device, ordered before them)."""
        if self._loop is None or not self.decides_on_device():
            raise ValueError("NodeSolve.launch: expected a solve that decides on the device (device_loop, an even "
                             f"max_sweeps), found device_loop={self._loop is not None}, max_sweeps={self.max_sweeps}")
        self._check_cap()
        if self._start_on_host:  # (the other slots: begin's; ctl's copy back is outcome's)
            carried = np.zeros(_lk.CTL_SLOTS, np.int32)
            carried[[_lk.START_NARROW, _lk.RETRYING, _lk.RETRY, _lk.UNTIL_RETRY]] = \
                self.start_narrow, self._retrying, self._retry, self._until_retry
            self.ctl.assign(carried)
            self._start_on_host = False
        if self._tolerance_value != tolerance:
            self._tolerance.fill_(tolerance)
            self._tolerance_value = tolerance
        if self._cap_value != self.max_sweeps:
            self._cap.fill_(self.max_sweeps)
            self._cap_value = self.max_sweeps
        (self._loop if batch is None else batch)()

    @property
    def loop(self) -> LaunchBatch:
        """The solve's launches on the device (:meth:`_record_loop`), for :meth:`launch`; their
        ``replays`` can sit inside a larger batch (a whole step's: :meth:`solve`'s ``batch``)."""
        if self._loop is None:
            raise ValueError("NodeSolve.loop: expected a solve that decides on the device (device_loop), "
                             "found device_loop=False or no conditional graphs on this device")
        return self._loop

    def outcome(self) -> tuple[int, wp.array]:
        """The second half: the launched solve's outcome read back once (sweeps, plain sweeps,
        plateau, wakes, the next solve's start): the sweeps and the buffer with the velocities."""
        ctl = self._ctl_view if self._ctl_view is not None else self.ctl.numpy()
        k = int(ctl[_lk.K])
        self.plain_sweeps, self.plateaued = int(ctl[_lk.PLAIN_SWEEPS]), bool(ctl[_lk.PLATEAUED])
        self.wakes = int(ctl[_lk.WAKES])
        self.start_narrow, self._retrying = bool(ctl[_lk.START_NARROW]), bool(ctl[_lk.RETRYING])
        self._retry, self._until_retry = int(ctl[_lk.RETRY]), int(ctl[_lk.UNTIL_RETRY])
        return k, self._buffers[k % 3]

    def _next_start(self, slowed: bool, changes: _Changes, retrying: bool) -> None:
        """:attr:`start_narrow` from a solve's Chebyshev sweeps that ``slowed`` (the narrower
        weights, from the solve's start) or stalled, ``changes`` its checked sweeps' largest
        changes [m/s]: the bounds' own weights if the narrower ones slowed without having
        beaten :attr:`rate` from their first sweep (:func:`fell_faster`), for
        :data:`NARROW_RETRY` solves (twice as many as last time where this start was a
        ``retrying`` one); the narrower ones after a stall (the contacts' active set changing:
        less momentum)."""
        self.start_narrow = not slowed or fell_faster(changes.sweeps, changes.values, self.rate)
        if not self.start_narrow:
            self._retry = min(2 * self._retry, NARROW_RETRY[1]) if retrying else NARROW_RETRY[0]
            self._until_retry = self._retry

    def _contacts_met(self, k: int, tolerance: float) -> bool:
        """Whether, in the velocities and impulses of sweep ``k``, every contact meets eq. 5.5
        within ``tolerance`` [m/s]: no normal velocity more than that off its target
        (``stats[1]``), and no contact whose next projection would change its velocity by more
        (``stats[2]``, the natural residual: friction's stick or slip, adhesion's bounds). This
        is the whole test of the rigid bodies' nodes, whose change the stop leaves out
        (:func:`_node_jacobi_kernels.chebyshev`)."""
        self._residual_launches[k % 3]()
        stats = self._read_stats()
        return bool(stats[1] <= tolerance and stats[2] <= tolerance)

    def _window(self) -> int:
        """Two decades' worth of Chebyshev sweeps (100x on a linear system), at least 20."""
        return self._window_sweeps

    def _plateau(self, history: _Changes, k: int, tolerance: float) -> bool:
        """Whether the Chebyshev sweeps, ``k`` sweeps after they (re)started, hover under
        ``tolerance`` [m/s] without converging: every largest change of the last :meth:`_window`
        sweeps is under ``tolerance``, and their largest is over half that of the window before
        (a contracting iteration would have fallen 100x). The geometric tail of :meth:`solve`'s
        stop then does not hold (the change no longer falls at ``rate`` a sweep): it is soft-on-soft
        contacts whose PGS does not settle (the candy pile: ~3e-6 m/s changes from about sweep 150
        to the cap of 500 against a stop of 1.3e-6), and the change itself is the size of what
        more sweeps would still move."""
        window = self._window()
        if k < 2 * window:
            return False
        recent, before = history.largest(k - window, k), history.largest(k - 2 * window, k - window)
        return recent <= tolerance and recent > 0.5 * before

    def _stalled(self, history: _Changes, k: int, tolerance: float) -> bool:
        """Whether the Chebyshev sweeps stall, cycle or grow, ``k`` sweeps after they
        (re)started (``history``: their changes since): the largest change of the last decade's
        worth of sweeps (half :meth:`_window`, at least 10) is not half that of the decade
        before, and the change is still over ``tolerance`` [m/s]. Contacts that keep changing
        their active set break the polynomial's assumption of a fixed linear iteration, and its
        momentum then cycles; :meth:`solve` then sweeps plain (no momentum) for a window, which
        lets the active set settle, and restarts Chebyshev. A plateau under the tolerance
        (soft-on-soft contacts whose PGS does not settle) is left to :meth:`_plateau`.
        Measured on the candy pile (`softvr bench adhesion`'s scene, 100 steps): its contact
        steps' Chebyshev sweeps cycle at 2e-3 to 5e-3 m/s from about sweep 20 while plain sweeps
        then fall ~10 sweeps a decade; judged over one decade instead of two, 120 -> 89 sweeps a
        step; stalls counted down to the tolerance instead of 100x the stop (1.4e-4 m/s), which
        left Chebyshev growing slowly between the two up to the 500-sweep cap, 89 -> 81."""
        window = max(10, self._window() // 2)
        if k < 2 * window or history.values[-1] <= tolerance:
            return False
        recent, before = history.largest(k - window, k), history.largest(k - 2 * window, k - window)
        return recent > 0.5 * before
