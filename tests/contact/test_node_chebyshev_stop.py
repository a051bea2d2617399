"""The Chebyshev weights the node sweeps start on and the stop's error estimate
(softvr.contact.node_jacobi: chebyshev_weights for CHEBYSHEV_RHO_FACTOR times the bounds'
spectral radius, chebyshev_rate, chebyshev_rates, tail_error), held to an independent truth on a small SPD
system of known spectrum: numpy.linalg.solve for the fixed point, numpy's Chebyshev
polynomials for the rate. NodeSolve's choice of the weights a solve starts on (start_narrow,
fell_faster) is held on a clamped FEM cube to SciPy's direct solve of eq. 5.2 and SciPy's
eigenvectors of D_A^-1 A. The stop on a contact step (a settling FEM cube on a plane) is held to
the same start swept on to 1e-9 m/s.

The iteration is the sweeps' (docs/physics-core.md, eq. 5.6 with M = I, no contacts):
v^ = v_k + (b - A v_k), v_k+1 = omega_k (gamma (v^ - v_k) + v_k - v_k-1) + v_k-1, its largest
change read every second sweep, as NodeSolve.solve reads it.
"""

import numpy as np
import pytest
import scipy.linalg as sl
from numpy.polynomial import chebyshev as C

from softvr.bench._cube_scene import CubeScene
from softvr.bench.contact import softvr_scene
from softvr.contact.node_jacobi import (CHEBYSHEV_RHO_FACTOR, NARROW_RETRY, NodeSolve, chebyshev_rate, chebyshev_rates,
                                        chebyshev_weights, tail_error)

from tests.contact.test_node_gauss_seidel import _prepared, _start
from tests.sim.test_node_arrays import _cube, _solve_step

# The candy's bounds of the spectrum of M^-1 A (the bench's scene, two-level Jacobi, with margins).
LO, HI = 0.01686, 2.488
RHO, GAMMA = (HI - LO) / (HI + LO), 2.0 / (LO + HI)
TOLERANCE = 1e-5  # [m/s], the sweeps' (SWEEP_TOLERANCE)


def _system(n=60, seed=3):
    """A = Q diag(lambda) Q^T with eigenvalues at both ends of [LO, HI] (the modes the bounds
    allow at their worst: mu = 1 - gamma lambda = +-rho), one in the middle (mu = 0) and the rest
    spread between; b; the fixed point by numpy.linalg.solve; Q."""
    rng = np.random.default_rng(seed)
    lam = np.concatenate([[LO, HI, (LO + HI) / 2], rng.uniform(LO, HI, n - 3)])
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    a = q @ np.diag(lam) @ q.T
    b = rng.standard_normal(n)
    return a, b, np.linalg.solve(a, b), q


def _sweep_until_stop(a, b, x0, floor, window, max_sweeps=3000, rho_w=RHO * CHEBYSHEV_RHO_FACTOR):
    """Chebyshev sweeps on the weights of rho_w (the first ones by default) from x0 until
    tail_error(.., floor, window) is under TOLERANCE; floor a number or one per sweep (index
    k - 1 for sweep k); returns (sweeps, iterate, estimate)."""
    omega = chebyshev_weights(rho_w, max_sweeps)
    floors = np.broadcast_to(np.asarray(floor, float), (max_sweeps,))
    x, prev = x0.copy(), x0.copy()
    sweeps, changes = [], []
    for k in range(1, max_sweeps + 1):
        v_hat = x + (b - a @ x)
        x, prev = omega[k - 1] * (GAMMA * (v_hat - x) + x - prev) + prev, x
        if k % 2 == 0:
            sweeps.append(k)
            changes.append(float(np.abs(x - prev).max()))
            estimate = tail_error(sweeps, changes, float(floors[k - 1]), window)
            if estimate <= TOLERANCE:
                return k, x, estimate
    raise AssertionError(f"no stop within {max_sweeps} sweeps")


def _starts(q, n, seed=4):
    """Start errors [m/s], 1 cm/s at most: random, the modes at LO and at HI (the slowest on the
    first weights), the one in the middle (the fastest), and a slowest one hidden under the
    middle one (1 % and 0.1 % of it)."""
    rng = np.random.default_rng(seed)
    starts = {"random": rng.standard_normal(n), "at LO": q[:, 0], "at HI": q[:, 1], "middle": q[:, 2],
              "LO under middle": 0.01 * q[:, 0] + q[:, 2], "LO under middle 0.1 %": 1e-3 * q[:, 0] + q[:, 2],
              "HI under middle": 0.01 * q[:, 1] + q[:, 2]}
    return {name: 1e-2 * e / np.abs(e).max() for name, e in starts.items()}


def test_chebyshev_rate_is_the_ratio_of_chebyshev_polynomials_outside_their_interval():
    """The error of the mode mu after k sweeps on weights built for rho_w is
    T_k(mu / rho_w) / T_k(1 / rho_w) times its start (Golub and Van Loan 11.2.8); its ratio from
    k = 399 to 400, by numpy's Chebyshev series, is the rate chebyshev_rate claims, to 1e-4
    (the ratio's approach to its limit goes as (rate_w / rate)^(2k), under 1e-6 here)."""
    for rho_w in (RHO, RHO * CHEBYSHEV_RHO_FACTOR, 0.9 * RHO):
        t = [C.chebval(np.array([RHO / rho_w, 1.0 / rho_w]), [0] * k + [1]) for k in (399, 400)]
        ratio = (t[1][0] / t[1][1]) / (t[0][0] / t[0][1])
        assert chebyshev_rate(RHO, rho_w) == pytest.approx(ratio, abs=1e-4)
    assert chebyshev_rate(RHO, RHO) == pytest.approx(RHO / (1 + np.sqrt(1 - RHO**2)), rel=1e-12)
    with pytest.raises(ValueError, match="rho_weights"):
        chebyshev_rate(RHO, 1.01 * RHO)


def test_the_stop_on_the_first_weights_fires_only_within_the_error_it_claims():
    """From every start, the first weights (CHEBYSHEV_RHO_FACTOR) reach numpy.linalg.solve's x*,
    and when the stop fires (tail_error at the floor chebyshev_rate(rho, rho_w), the contraction
    observed over 4 sweeps) |x - x*| is within TOLERANCE, the bound it claims; fewer sweeps
    than the floor promises for the slowest modes (ln(TOLERANCE / |e0|) / ln floor) where the
    start has none of them."""
    a, b, x_star, q = _system()
    floor = chebyshev_rate(RHO, RHO * CHEBYSHEV_RHO_FACTOR)
    worst = np.log(TOLERANCE / 1e-2) / np.log(floor)
    for name, e0 in _starts(q, len(b)).items():
        sweeps, x, estimate = _sweep_until_stop(a, b, x_star + e0, floor, 4)
        error = np.abs(x - x_star).max()
        assert error <= TOLERANCE, (name, sweeps, error, estimate)
        if name == "middle":
            assert sweeps < worst, (name, sweeps, worst)


def test_the_narrow_weights_own_rate_would_stop_before_the_slowest_mode_is_solved():
    """Why the floor is the rate over the whole of the bounds: with the first weights' own
    optimal rate (their interval's, rho_w / (1 + sqrt(1 - rho_w^2))) and no observed rate, the
    stop fires on the slowest mode with |x - x*| several times the TOLERANCE it claims."""
    a, b, x_star, q = _system()
    rho_w = RHO * CHEBYSHEV_RHO_FACTOR
    own = chebyshev_rate(rho_w, rho_w)
    sweeps, x, _ = _sweep_until_stop(a, b, x_star + _starts(q, len(b))["at LO"], own, 10**9)
    assert np.abs(x - x_star).max() > 3 * TOLERANCE


def test_chebyshev_rates_are_the_slowest_modes_ratio_from_the_first_sweep():
    """chebyshev_rates(rho, rho_w)[k - 1] is the ratio of the slowest mode's error after k and
    k - 1 sweeps from a (re)start, T_k(rho / rho_w) T_k-1(1 / rho_w) / (T_k-1(rho / rho_w)
    T_k(1 / rho_w)) by numpy's Chebyshev series (Golub and Van Loan 11.2.8), to 1e-12: rho at the
    first sweep, then down to chebyshev_rate."""
    for rho_w in (RHO, RHO * CHEBYSHEV_RHO_FACTOR, 0.5 * RHO):
        t = np.array([C.chebval(np.array([RHO / rho_w, 1.0 / rho_w]), [0] * k + [1]) for k in range(41)])
        p = t[:, 0] / t[:, 1]
        np.testing.assert_allclose(chebyshev_rates(RHO, rho_w, 40), p[1:] / p[:-1], rtol=1e-12)
        assert chebyshev_rates(RHO, rho_w, 2000)[-1] == pytest.approx(chebyshev_rate(RHO, rho_w), rel=1e-12)
    np.testing.assert_allclose(chebyshev_rates(RHO, 0.0, 3), RHO)


@pytest.mark.parametrize("weights", ["first", "bounds"])
def test_a_warm_start_at_the_slowest_modes_does_not_stop_the_first_sweeps(weights):
    """A (re)start whose error is a mode at an end of the bounds (mu = +-rho) of 1.2 to 4 times
    TOLERANCE, with 5 % of it spread over the other modes (faster): in the first sweeps the
    slowest mode falls by rho = 0.987 a sweep only (its change is 1.3 % of its error), so the
    stop at the asymptotic rate (chebyshev_rate: 0.848 on the bounds' own weights) would fire
    at sweep 2 with |x - x*| 1.1 and 1.9 times the TOLERANCE it claims. With the floor
    chebyshev_rates gives sweep by sweep (the slowest mode's own ratio) it fires only within
    TOLERANCE of numpy.linalg.solve's x*. (A larger fast mode hides nothing here: under the
    Chebyshev weights the modes inside the interval oscillate at its envelope, and their change
    keeps the stop off until the slowest mode's own shows.)"""
    a, b, x_star, q = _system()
    rho_w = RHO * (CHEBYSHEV_RHO_FACTOR if weights == "first" else 1.0)
    rest = np.random.default_rng(5).standard_normal(len(b))
    rest /= np.abs(rest).max()
    for end in (0, 1):  # LO (mu = rho), HI (mu = -rho)
        mode = q[:, end] / np.abs(q[:, end]).max()
        for amplitude in (1.2, 2.0, 4.0):
            x0 = x_star + amplitude * TOLERANCE * (mode + 0.05 * rest)
            sweeps, x, estimate = _sweep_until_stop(a, b, x0, chebyshev_rates(RHO, rho_w, 3000), 4, rho_w=rho_w)
            error = np.abs(x - x_star).max()
            assert error <= TOLERANCE, (weights, end, amplitude, sweeps, error, estimate)


def _clamped_cube():
    """A Jacobi NodeSolve (no contacts) on a 4-cell, 0.4 m cube clamped at its bottom face, the
    bench cube's material at its step (dt 1/60 s), with the exact ends of the spectrum of D_A^-1 A
    as its bounds (scipy.linalg.eigh(A, D_A) over the free velocities, D_A the 3x3 node blocks: its
    extreme eigenvectors are then the modes mu = +-rho, the slowest the weights allow); A, b of
    eq. 5.2 as the per-object path assembles them and SciPy's direct solve of A v = b. Returns
    (solve, stepper, v* [n, 3], free dofs [3 n], eigenvectors [free, free], ascending)."""
    body = _cube(lift=0.5, fixed=lambda nodes: nodes[:, 2] < nodes[:, 2].min() + 1e-9)
    dt = 1.0 / 60.0
    scene, stepper = _prepared(body, dt)
    system, expected = _solve_step(body, scene, dt)
    free = ~system.prescribed
    a = system.matrix.toarray()[np.ix_(free, free)]
    node = np.arange(len(a)) // 3
    lam, modes = sl.eigh(a, np.where(node[:, None] == node[None, :], a, 0.0))
    return NodeSolve(stepper.model, stepper.state, dt, (lam[0], lam[-1])), stepper, expected, free, modes


def _solve_from(solve, stepper, expected, free, error):
    """One solve from v* + ``error`` [m/s] on the free velocities (no momentum: v^k-1 = v^k);
    (whether it started on the narrower weights, sweeps, max |v - v*| [m/s])."""
    v0 = expected.copy()
    v0.reshape(-1)[free] += error
    _start(stepper, v0)
    narrow = solve.start_narrow
    sweeps, solved = solve.solve(TOLERANCE)
    assert sweeps < solve.max_sweeps
    return narrow, sweeps, float(np.abs(solved.numpy() - expected).max())


def test_a_solve_whose_error_sits_at_the_bounds_ends_sends_the_next_onto_the_bounds_weights():
    """NodeSolve.solve picks the weights the next solve starts on from what this one observed:
    from v* + 1 cm/s along the slowest mode (mu = rho, the low end of D_A^-1 A's spectrum) the
    narrower weights fall at chebyshev_rate(rho, 0.96 rho) only, slower than the bounds' own
    rate from their first sweep (fell_faster false), so the next solve starts on the bounds'
    weights, and from the same start takes fewer sweeps. Those solves stop on the floor of the
    weights in use from their first sweep (chebyshev_rates(rho, rho)): from warm starts of 1.2 to 4
    times the TOLERANCE along either end's mode (+5 % spread over the rest), where the
    asymptotic rate would stop in the first sweeps, |v - v*| against SciPy's direct solve of
    eq. 5.2 stays within the TOLERANCE the stop claims. After NARROW_RETRY[0] starts on the
    bounds' weights the narrower ones are tried again: from an error inside their interval (the
    middle mode, 1 % of the slowest under it) they win and are kept, and stop within the
    TOLERANCE."""
    solve, stepper, expected, free, modes = _clamped_cube()
    unit = modes / np.abs(modes).max(axis=0)
    rest = np.random.default_rng(5).standard_normal(len(modes))
    rest /= np.abs(rest).max()
    results = [_solve_from(solve, stepper, expected, free, 1e-2 * unit[:, 0]) for _ in range(2)]
    assert [narrow for narrow, _, _ in results] == [True, False], results
    assert results[1][1] < results[0][1], results
    warm = [amplitude * TOLERANCE * (unit[:, end] + 0.05 * rest) for amplitude in (1.2, 2.0, 4.0) for end in (0, -1)]
    while not solve.start_narrow:
        results.append(_solve_from(solve, stepper, expected, free, warm[(len(results) - 2) % len(warm)]))
        assert len(results) - 1 <= NARROW_RETRY[0], results
    assert len(results) - 1 == NARROW_RETRY[0] and not any(narrow for narrow, _, _ in results[1:]), results
    middle = unit[:, len(modes) // 2] + 0.01 * unit[:, 0]
    results += [_solve_from(solve, stepper, expected, free, 1e-2 * middle / np.abs(middle).max()) for _ in range(2)]
    assert all(narrow for narrow, _, _ in results[-2:]), results
    assert all(error <= TOLERANCE for _, _, error in results), results


# The bench contact cube (`softvr bench contact`: 0.8 m, friction 0.5, dt 1/60 s) at 4 cells a side,
# 0.1 m above the plane and 2.5x softer (E 1e5 Pa): at rest on the plane by step 20, its contacts restart
# every step, and its solves stop in 10-20 sweeps.
SETTLING = CubeScene(cells=4, drop=0.1, young=1e5)


def _step_and_truth(at, monkeypatch):
    """The cube's velocities [n, 3] m/s after step ``at``, and those of a twin played in lockstep
    (same steps, so the same start guess and first weights) whose step ``at`` sweeps on to
    1e-9 m/s; the sweeps of both."""
    (sim, body), (twin, twin_body) = softvr_scene(SETTLING), softvr_scene(SETTLING)
    for _ in range(at):
        sim.step(SETTLING.dt)
        twin.step(SETTLING.dt)
    sim.step(SETTLING.dt)
    monkeypatch.setattr("softvr.sim._node_step.SWEEP_TOLERANCE", 1e-9)
    twin.step(SETTLING.dt)
    return body.v.copy(), twin_body.v.copy(), sim.last_solution.iterations, twin.last_solution.iterations


@pytest.mark.parametrize("at", [27, 30])
def test_a_contact_steps_stop_is_within_the_tolerance_it_claims(at, monkeypatch):
    """The sweeps of a contact step (eq. 5.6, the contacts' eq. 5.5) stop when tail_error says
    the velocities are within TOLERANCE of the fixed point; the same start swept on to 1e-9 m/s
    is that fixed point to 1e-9 (its own stop's claim, four decades under TOLERANCE), so
    max |v - v*| <= TOLERANCE. On these resting steps the Chebyshev sweeps restart with the
    contacts' transient in the iterate, and one check's change falls 5-15x in two sweeps while
    the error does not: a tail from the last change alone stopped at sweep 12 with 1.6e-5 (step
    27) and 1.1e-5 m/s (step 30); from the larger of the last two checks' changes carried
    down at the rate, step 30 still 1.1e-5; from the largest of three (TAIL_CHECKS), 3.1e-6 and
    2.1e-6 at sweep 14."""
    v, v_star, sweeps, sweeps_star = _step_and_truth(at, monkeypatch)
    assert sweeps_star > sweeps  # the twin's sweeps went on past the stop under test
    error = float(np.abs(v - v_star).max())
    assert error <= TOLERANCE, (at, sweeps, error)
