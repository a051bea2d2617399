"""Which sweeps a scene on the node arrays takes (thesis eq. 5.6): node-block Jacobi, Jacobi with
the rigid motions of the free bodies and of the held bodies' aggregates corrected
(:mod:`softvr.contact.node_coarse`), or
multicolour symmetric block Gauss-Seidel (:mod:`softvr.contact.node_gauss_seidel`), whichever
needs less work per decade of error, counting the contact PGS that every sweep of either kind
runs; none when all are slower than the per-object sparse LU.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softvr.contact.node_coarse import Aggregates, aggregates_of, coarse_spectrum
from softvr.contact.node_colouring import NodeColouring, colour_nodes
from softvr.contact.node_gauss_seidel import gauss_seidel_spectrum
from softvr.contact.node_gs_coarse import gauss_seidel_coarse_spectrum

__all__ = ["SweepChoice", "choose_sweeps", "sweep_costs", "sweeps_per_decade"]

#: Work per decade, in this scene's Jacobi sweeps, above which the Gauss-Seidel sweeps too are
#: left to the per-object path. Higher than Jacobi's limit: with Gauss-Seidel the steps of the
#: head CT need fewer decades than the estimate (the warm start carries the slow modes),
#: measured 1.0-2.4x faster than its LU at ~37 (docs: node-gs measurements); the draped cloth
#: of cloth-sphere.toml (47.6, its Gauss-Seidel sweep estimated 2.5x a Jacobi one, measured
#: ~1.6x) steps in ~30 ms against ~300 per object.
MAX_GAUSS_SEIDEL_WORK_PER_DECADE = 50.0
#: Cost of the parts of a sweep, in the time of one 3x3 block product of the Jacobi kernel
#: (~8 ns on the CPU, Warp 1.19; measured on the head CT: a Jacobi node update 160 us, a
#: Gauss-Seidel one 450 us over its 7 colours, 13 launches and the start copy, 2.7x): a
#: Gauss-Seidel block product (the nodes in colour order gather from farther apart), a launch
#: (a CPU replay's fixed cost, ~8 us), a node's Chebyshev update, and one contact's PGS pass
#: (stencil gathers and scatters, the friction disc).
GAUSS_SEIDEL_BLOCK = 1.15
LAUNCH = 1000.0
CHEBYSHEV_NODE = 1.0
CONTACT_PASS = 12.0
#: Jacobi's work per decade up to which the Gauss-Seidel spectrum is not estimated while a
#: Gauss-Seidel sweep costs at least :data:`GAUSS_SEIDEL_COST_FLOOR` Jacobi sweeps (node work,
#: not contact passes, dominating the sweep). Gauss-Seidel's Chebyshev sweeps per decade were
#: 2.2-2.7x fewer than Jacobi's on every matrix measured (soft cube, oranges, head CT), so there
#: it saves at most a quarter of under 15 sweeps per decade, while its estimate (a second
#: Lanczos through triangular solves) costs more than the first step itself: 89 of the soft
#: cube's 235 ms.
GAUSS_SEIDEL_FROM = 15.0
GAUSS_SEIDEL_COST_FLOOR = 2.0
#: Cost of the coarse correction per node of a coarse body and sweep, in block products: its
#: residual (a 3x3 product, a cross product) and its share of the Chebyshev update.
COARSE_NODE = 3.0
#: PGS passes over the contacts per sweep with the coarse correction. Every contact of a body
#: then moves the body's six coarse velocities, which couples them as a rigid body's contacts
#: are coupled, and two passes a sweep leave them unconverged: on the candy pile (steps 24-31)
#: 2 / 6 / 8 / 12 / 20 passes took 446 / 377 / 328 / 233 / 270 sweeps a step, the first four at
#: about the same time a step, and the largest contact velocity error fell from 6.1e-5 to
#: 1.1e-5 m/s. So the work per decade does not charge them (a scene restored in the middle of
#: the pile, 700 contacts, would otherwise be declined while the same scene stepped there from
#: its start is held).
COARSE_PASSES = 12
#: The coarse correction is taken over Gauss-Seidel, both over Jacobi's limit, only where it
#: needs at most this share of Gauss-Seidel's estimated work. One margin for every scene, held
#: tool or not, set between the measured outcomes of the bundled scenes whose two estimates are
#: both made (coarse / Gauss-Seidel work; main, session 11): the head CT of palpation.toml
#: (0.64: 38.3 against 60.0) steps faster on the coarse sweeps than per object; the arthroscopy
#: (0.86: 25.8 against 30.1, 0.77 in session 10: its light probe on a handle, which Gauss-Seidel
#: solves exactly) took the coarse sweeps at a share of 0.8 and ran all 70 measured steps to the
#: 100-sweep cap (0.22 mm deepest overlap; Gauss-Seidel: 14 sweeps a step before the probe
#: touches, 77 pressing); on shoulder.toml (1.01: 35.8 against 35.5) the coarse sweeps ended its
#: steps at the cap with changes of ~1e-2 m/s against Gauss-Seidel's ~3e-5 (its slowest mode is a
#: spring-held rigid finger's, which the aggregates do not take). 0.75 is the geometric middle of
#: 0.64 and 0.86 (0.74): each estimate may move ~15 % (the arthroscopy's moved 11 % since
#: session 10) before its scene changes sweeps. The held tools need no share of their own: the
#: scenes where the coarse sweeps cycled are above it.
COARSE_OVER_GAUSS_SEIDEL = 0.75
#: Cost of the Gauss-Seidel sweeps' coarse correction (:mod:`softvr.contact.node_gs_coarse`) per
#: block of its aggregates' rows (the residual ``b - A v^``, read from ``A``'s rows in node order),
#: in block products, and its two launches.
GAUSS_SEIDEL_COARSE_BLOCK = 1.0
#: The Gauss-Seidel sweeps take the coarse correction where its estimated work a decade is at most
#: this share of the plain sweeps'. Measured (session 12, process CPU a step, paired with main, load
#: 8-12): shoulder.toml at 0.75 (26.6 against 35.5) 9.05-9.30 -> 7.07-7.99 ms, 33.9 -> 18.8 sweeps a
#: step; the arthroscopy at 0.87 (26.1 against 30.1) 14.7 -> 9.7 sweeps but 4.13-4.96 -> 4.74-5.05 ms
#: (the correction's once-a-step Galerkin inverses, ~0.11 ms, and ~30 us a sweep eat the saving).
#: 0.8 is about their geometric middle (0.81).
GAUSS_SEIDEL_COARSE_SHARE = 0.8


@dataclass(frozen=True)
class SweepChoice:
    """The sweeps a scene takes.

    Attributes
    ----------
    kind : str or None
        "jacobi", "gauss-seidel", or None: both too slow (the scene steps per object).
    bounds : tuple of float
        (lo, hi) of the spectrum of the chosen iteration's ``M^-1 A`` (with margins).
    colours : NodeColouring or None
        The Gauss-Seidel colouring; None for Jacobi.
    omega : float
        The Gauss-Seidel sweeps' damping of the contact nodes: 1 / Jacobi's upper bound.
    work : dict
        Work per decade of each kind estimated, in this scene's Jacobi sweeps (contacts
        included); Jacobi's alone where nothing else was worth estimating.
    coarse : Aggregates or ndarray or None
        The aggregates (or [B, 2] node ranges of bodies) whose rigid motions the Jacobi sweeps
        correct (:mod:`softvr.contact.node_coarse`), or, with "gauss-seidel", each sweep after its
        node update (:mod:`softvr.contact.node_gs_coarse`); ``bounds`` are then the two-level
        iteration's.
    passes : int or None
        PGS passes over the contacts per sweep (:data:`COARSE_PASSES` with ``coarse``); None:
        the caller's.
    """

    kind: str | None
    bounds: tuple[float, float]
    colours: NodeColouring | None
    omega: float
    work: dict
    coarse: Aggregates | np.ndarray | None = None
    passes: int | None = None


def sweeps_per_decade(bounds: tuple[float, float]) -> float:
    """Chebyshev sweeps per decade of error on the spectrum ``bounds`` (lo, hi) (the
    asymptotic rate of :class:`softvr.contact.node_jacobi.NodeSolve`)."""
    lo, hi = bounds
    rho = (hi - lo) / (hi + lo)
    if rho <= 0:
        return 0.0
    rate = (1.0 - np.sqrt(1.0 - rho * rho)) / rho
    return float(np.log(10.0) / -np.log(rate))


def sweep_costs(row_start: np.ndarray, colours: NodeColouring, contacts: int, passes: int) -> tuple[float, float]:
    """Cost of one Jacobi and one Gauss-Seidel sweep (node update, contact PGS, Chebyshev) in
    block products, for the block pattern ``row_start`` [n + 1], ``contacts`` contacts and
    ``passes`` PGS passes a sweep."""
    n = len(row_start) - 1
    blocks = float(row_start[-1])
    last = colours.order[colours.start[-2]:] if colours.count else np.zeros(0, int)
    last_blocks = float((row_start[last + 1] - row_start[last]).sum())
    shared = CHEBYSHEV_NODE * n + LAUNCH * 2 + CONTACT_PASS * contacts * passes
    jacobi = blocks + LAUNCH + shared
    gauss_seidel = GAUSS_SEIDEL_BLOCK * (2 * blocks - last_blocks) + LAUNCH * 2 * colours.count + CHEBYSHEV_NODE * n \
        + shared  # the colours forward and back (the last once) and the start copy
    return jacobi, gauss_seidel


def _coarse_choice(a, free: np.ndarray, coarse: tuple, jacobi_cost: float, margin: tuple[float, float],
                   work: dict) -> SweepChoice:
    """The coarse-corrected Jacobi sweeps of least work per decade (recorded in ``work["coarse"]``)
    over the aggregates ``coarse[0]`` (:class:`softvr.contact.node_coarse.Aggregates`, or node
    ranges) and, where some are whole free bodies and some parts of held ones, over the whole
    bodies alone: the held bodies' aggregates widen the spectrum at its top, so they pay only
    where the held bodies hold the slowest modes (the candy: its Jell-O's aggregates took its
    free-fall steps from 50-60 sweeps to 64-74; the shoulder and the head CT have only held bodies)."""
    aggregates = aggregates_of(coarse[0])
    candidates = [aggregates]
    if 0 < aggregates.whole < len(aggregates):
        candidates.append(aggregates.head(aggregates.whole))
    choices = []
    for bodies in candidates:
        lo, hi = coarse_spectrum(a, free, bodies, *coarse[1:])
        bounds = (lo * margin[0], hi * margin[1])
        # Its extra PGS passes are not charged: they save as many sweeps as they cost (COARSE_PASSES).
        cost = sweeps_per_decade(bounds) * (1.0 + (COARSE_NODE * len(bodies.nodes) + LAUNCH) / jacobi_cost)
        choices.append((cost, SweepChoice("jacobi", bounds, None, 1.0, work, bodies, COARSE_PASSES)))
    work["coarse"], best = min(choices, key=lambda choice: choice[0])
    return best


def choose_sweeps(row_start: np.ndarray, block_col: np.ndarray, a, free: np.ndarray,
                  jacobi_bounds: tuple[float, float], jacobi_limit: float, contacts: int, passes: int,
                  margin: tuple[float, float], coarse: tuple | None = None) -> SweepChoice:
    """The sweeps of least work per decade, or none (kind None) when all are too slow (Jacobi, with
    or without the coarse correction, over ``jacobi_limit`` sweeps per decade, Gauss-Seidel over
    :data:`MAX_GAUSS_SEIDEL_WORK_PER_DECADE`). ``row_start``, ``block_col``: ``A``'s block
    pattern (host, [n + 1], [nb]); ``a`` [3 k, 3 k] ``A`` over the free nodes, ``free`` [n]
    which nodes those are; ``jacobi_bounds`` Jacobi's spectrum (with margins); ``contacts`` the
    contacts of this step, ``passes`` their PGS passes a sweep; ``margin`` the factors on the
    other kinds' bounds (as on Jacobi's); ``coarse`` (aggregates, q [n, 3] [m], mass [n] [kg])
    the aggregates the coarse correction may take (:func:`softvr.contact.node_coarse.coarse_aggregates`,
    or [B, 2] node ranges of :func:`~softvr.contact.node_coarse.coarse_bodies`).
    Jacobi is taken without estimating the others where they cannot pay
    (:data:`GAUSS_SEIDEL_FROM`); the coarse correction, where it brings Jacobi within its
    limit, without estimating Gauss-Seidel (its Lanczos costs more than a step: 1.7 s on the
    candy), and otherwise over Gauss-Seidel where it needs clearly less work
    (:data:`COARSE_OVER_GAUSS_SEIDEL`). Where Gauss-Seidel is taken and ``coarse`` holds only
    held bodies' aggregates, its sweeps take their coarse correction too
    (:mod:`softvr.contact.node_gs_coarse`) where that needs at most
    :data:`GAUSS_SEIDEL_COARSE_SHARE` of the plain sweeps' work."""
    colours = colour_nodes(row_start, block_col)
    jacobi_cost, gs_cost = sweep_costs(row_start, colours, contacts, passes)
    jacobi_work = sweeps_per_decade(jacobi_bounds)
    if jacobi_work <= min(GAUSS_SEIDEL_FROM, jacobi_limit) and gs_cost >= GAUSS_SEIDEL_COST_FLOOR * jacobi_cost:
        return SweepChoice("jacobi", jacobi_bounds, None, 1.0, {"jacobi": jacobi_work})
    work = {"jacobi": jacobi_work}
    if jacobi_work > jacobi_limit and coarse is not None and len(coarse[0]):
        coarse_choice = _coarse_choice(a, free, coarse, jacobi_cost, margin, work)
        if work["coarse"] <= jacobi_limit:
            return coarse_choice
    index = np.cumsum(free) - 1
    order = index[colours.order[free[colours.order]]]
    lo, hi = gauss_seidel_spectrum(a, order) if len(order) else (1.0, 1.0)
    gs_bounds = (lo * margin[0], hi * margin[1])
    work["gauss-seidel"] = sweeps_per_decade(gs_bounds) * gs_cost / jacobi_cost
    if "coarse" in work and work["coarse"] <= min(COARSE_OVER_GAUSS_SEIDEL * work["gauss-seidel"],
                                                  MAX_GAUSS_SEIDEL_WORK_PER_DECADE):
        return coarse_choice
    # Gauss-Seidel within its limit is taken over Jacobi's fewer work only where Jacobi may run:
    # else the choice is it or the per-object LU (the shoulder, its Jacobi over its limit and
    # both at ~39.5 sweeps of work a decade, went per object on 84 fewer contacts).
    if work["gauss-seidel"] <= MAX_GAUSS_SEIDEL_WORK_PER_DECADE and (
            work["gauss-seidel"] < jacobi_work or jacobi_work > jacobi_limit):
        # Only over held bodies' aggregates (all the shoulder's), the case measured.
        if coarse is not None and isinstance(coarse[0], Aggregates) and len(coarse[0]) and not coarse[0].whole:
            aggregates = coarse[0]
            lo, hi = gauss_seidel_coarse_spectrum(a, order, aggregates, free, *coarse[1:])
            bounds = (lo * margin[0], hi * margin[1])
            rows = aggregates.nodes
            extra = GAUSS_SEIDEL_COARSE_BLOCK * float((row_start[rows + 1] - row_start[rows]).sum()) \
                + COARSE_NODE * len(rows) + 2 * LAUNCH
            work["gauss-seidel-coarse"] = sweeps_per_decade(bounds) * (gs_cost + extra) / jacobi_cost
            if work["gauss-seidel-coarse"] <= GAUSS_SEIDEL_COARSE_SHARE * work["gauss-seidel"]:
                return SweepChoice("gauss-seidel", bounds, colours, 1.0 / jacobi_bounds[1], work, aggregates)
        return SweepChoice("gauss-seidel", gs_bounds, colours, 1.0 / jacobi_bounds[1], work)
    return SweepChoice("jacobi" if jacobi_work <= jacobi_limit else None, jacobi_bounds, None, 1.0, work)
