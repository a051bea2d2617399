"""The compiled PGS sweeps against independent characterizations of the LCP solution.

Frictionless: ``0 <= lambda _|_ B lambda - d >= 0`` with B symmetric positive definite is the
optimality condition of ``min 1/2 lambda^T B lambda - d^T lambda, lambda >= 0``, solved here by
SciPy's bounded least squares on the Cholesky factor. With friction the solution is checked
against the conditions that define it (Signorini, and per tangent: inside the pyramid with zero
sliding velocity, or on its bound with the velocity opposing the impulse).
"""

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from softvr.contact._pgs_kernels import pgs_sweeps


def random_delassus(contacts, seed):
    rng = np.random.default_rng(seed)
    j = rng.standard_normal((3 * contacts, 2 * contacts))  # fewer velocities than rows: coupled
    return j @ j.T + 0.05 * np.eye(3 * contacts), rng


def test_frictionless_solution_is_the_bounded_quadratic_minimum():
    b, rng = random_delassus(12, 0)
    rows = np.arange(0, 36, 3)
    bn = b[np.ix_(rows, rows)]
    d = rng.standard_normal(12)
    target = np.zeros(36)
    target[rows] = d
    lam, rel = np.zeros(36), np.zeros(36)
    sweeps = pgs_sweeps(b, target, np.zeros(12), lam, rel, 20000, 1e-13)
    assert sweeps < 20000
    chol = np.linalg.cholesky(bn)  # B = L L^T: min |L^T x - L^-1 d|^2 / 2 has the same minimizer
    expected = lsq_linear(chol.T, np.linalg.solve(chol, d), bounds=(0, np.inf), tol=1e-14).x
    np.testing.assert_allclose(lam[rows], expected, atol=1e-7 * np.abs(expected).max())
    np.testing.assert_allclose(rel, b @ lam, atol=1e-12 * np.abs(rel).max())


@pytest.mark.parametrize("mu", [0.2, 1.0])
def test_frictional_solution_satisfies_signorini_and_the_pyramid(mu):
    b, rng = random_delassus(8, 3)
    target = np.zeros(24)
    target[0::3] = np.abs(rng.standard_normal(8))  # every contact pushed: normal impulses > 0
    free = rng.standard_normal(24)  # J v_free: tangential velocities to stop
    lam, rel = np.zeros(24), free.copy()
    pgs_sweeps(b, target, np.full(8, mu), lam, rel, 50000, 1e-14)
    np.testing.assert_allclose(rel, free + b @ lam, atol=1e-10)
    tol = 1e-7 * np.abs(rel).max()
    ln, wn = lam[0::3], rel[0::3] - target[0::3]
    assert (ln >= 0).all() and (wn >= -tol).all() and np.abs(ln * wn).max() < tol * np.abs(ln).max()
    for t in (1, 2):
        lt, wt = lam[t::3], rel[t::3]
        inside = np.abs(lt) < mu * ln - 1e-9
        np.testing.assert_allclose(wt[inside], 0.0, atol=tol)
        assert (lt[~inside] * wt[~inside] <= tol * np.abs(lt).max()).all()  # sliding opposes impulse
