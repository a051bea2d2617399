"""The coarse correction for held bodies (softvr.contact.node_coarse.coarse_aggregates: a body
with fixed nodes split into spatial aggregates, each aggregate's six rigid motions in the
two-level M^-1 = D_A^-1 + sum_g P_g (P_g^T A P_g)^-1 P_g^T), held to NumPy's dense eigenvalues
of M^-1 A and to SciPy's direct solve of eq. 5.2 on a clamped beam.

Tolerances: velocities to 3x the sweeps' stopping tolerance (tests/sim/test_node_arrays.py);
the spectrum to ARPACK's tolerances with a 2x allowance: 1e-3 relative on hi, and lo = hi - mu
with mu (the largest eigenvalue of hi - M^-1 A, ~hi) to 1e-4 relative, so 2e-4 hi absolute.
"""

import numpy as np
import pytest

from softvr.contact.node_coarse import AGGREGATE_NODES, coarse_aggregates, coarse_spectrum
from softvr.contact.node_factored import free_matrix
from softvr.contact.node_jacobi import NodeSolve
from softvr.dynamics import FemBody, Material
from softvr.sim._node_step import SPECTRUM_MARGIN, SWEEP_TOLERANCE, spectrum
from softvr.sim._node_sweeps import sweeps_per_decade
from softvr.volume import Volume, grid_tet_mesh

from tests.contact.test_node_gauss_seidel import _gauss_seidel, _prepared, _start
from tests.sim.test_node_arrays import VELOCITY_TOL, _solve_step

DT = 0.01


def _beam():
    """A 0.6 m x 5 cm x 5 cm stiff cantilever (E = 2e7 Pa), clamped at x = 0, high above
    any plane: its bending modes are node-block Jacobi's slowest (the stiffness of a node's
    block grows as 1 / h^2, a bending mode's as 1 / L^4)."""
    spacing = np.array([0.6 / 24, 0.05 / 2, 0.05 / 2])
    nodes, tets = grid_tet_mesh(Volume(np.zeros((24, 2, 2), np.uint8), spacing=spacing, origin=spacing / 2), (24, 2, 2))
    nodes = nodes + [0.0, -0.025, 1.0]
    material = Material(2e7, 0.3, 1000.0, alpha=0.0, beta=1e-3)
    return FemBody(nodes, tets, material, fixed=nodes[:, 0] < 1e-9, name="beam")


def _dense_two_level(a, free, groups, q):
    """Eigenvalues of the dense M^-1 A, each group's P built here (translations and rotations
    about the origin: the span, and so each block of M^-1, is that of rotations about the mass
    centre), and of D_A^-1 A (node-block Jacobi)."""
    dense = a.toarray()
    node = np.arange(len(dense)) // 3
    d_inv = np.linalg.inv(np.where(node[:, None] == node[None, :], dense, 0.0))
    m_inv = d_inv.copy()
    index = np.cumsum(free) - 1
    for nodes in groups:
        p = np.zeros((len(dense), 6))
        for k in range(3):
            p[3 * index[nodes] + k, k] = 1.0
            p[(3 * index[nodes][:, None] + np.arange(3)).ravel(), 3 + k] = np.cross(np.eye(3)[k], q[nodes]).ravel()
        m_inv += p @ np.linalg.solve(p.T @ dense @ p, p.T)
    return np.sort(np.linalg.eigvals(m_inv @ dense).real), np.sort(np.linalg.eigvals(d_inv @ dense).real)


def test_aggregates_of_a_clamped_beam_give_the_dense_two_level_spectrum():
    body = _beam()
    _, stepper = _prepared(body, DT)
    m, st = stepper.model, stepper.state
    a, free = free_matrix(m, st)
    aggregates = coarse_aggregates(m, st.q.numpy())
    groups = [aggregates.nodes[s:e] for s, e in zip(aggregates.start[:-1], aggregates.start[1:])]
    # The free nodes partitioned into spatial groups, the clamped ones in none.
    assert sorted(aggregates.nodes) == list(np.flatnonzero(body.q[:, 0] > 1e-9))
    assert all(4 <= len(g) <= AGGREGATE_NODES for g in groups) and len(groups) >= 4
    lo, hi = coarse_spectrum(a, free, aggregates, st.q.numpy(), m.mass.numpy())
    eig, jacobi = _dense_two_level(a, free, groups, body.q)
    assert lo == pytest.approx(eig[0], abs=2e-4 * eig[-1]) and hi == pytest.approx(eig[-1], rel=2e-3)
    # The bending modes were node-block Jacobi's slowest; the aggregates' rigid motions take them.
    assert sweeps_per_decade((eig[0], eig[-1])) < 0.5 * sweeps_per_decade((jacobi[0], jacobi[-1]))


def _moving_beam():
    """The beam of :func:`_beam` moving at random velocities (seed 4): ``(body, stepper, expected,
    a, free, aggregates)`` with SciPy's direct solve of eq. 5.2 ``expected``, ``A`` over the free
    nodes and their aggregates."""
    body = _beam()
    rng = np.random.default_rng(4)
    body.v = 0.05 * rng.standard_normal(body.q.shape)
    body.v[body.fixed] = 0.0
    scene, stepper = _prepared(body, DT)
    _, expected = _solve_step(body, scene, DT)
    a, free = free_matrix(stepper.model, stepper.state)
    return body, stepper, expected, a, free, coarse_aggregates(stepper.model, stepper.state.q.numpy())


def test_aggregate_sweeps_without_contacts_land_on_scipy_direct_solve_of_eq_5_2_in_fewer_sweeps():
    body, stepper, expected, a, free, aggregates = _moving_beam()
    m, st = stepper.model, stepper.state
    lo, hi = coarse_spectrum(a, free, aggregates, st.q.numpy(), m.mass.numpy())
    solve = NodeSolve(m, st, DT, (lo * SPECTRUM_MARGIN[0], hi * SPECTRUM_MARGIN[1]), max_sweeps=2000,
                      coarse=aggregates)
    _start(stepper, body.v)
    sweeps, solved = solve.solve(SWEEP_TOLERANCE)
    np.testing.assert_allclose(solved.numpy(), expected, atol=VELOCITY_TOL, rtol=0)
    jacobi = NodeSolve(m, st, DT, spectrum(m, st), max_sweeps=2000)
    _start(stepper, body.v)
    jacobi_sweeps = jacobi.solve(SWEEP_TOLERANCE)[0]
    gauss_seidel = _gauss_seidel(stepper, DT, max_sweeps=2000)[0]
    _start(stepper, body.v)
    gauss_seidel_sweeps = gauss_seidel.solve(SWEEP_TOLERANCE)[0]
    print(f"sweeps: aggregates {sweeps}, Jacobi {jacobi_sweeps}, Gauss-Seidel {gauss_seidel_sweeps}")
    assert sweeps < 0.5 * jacobi_sweeps and sweeps < gauss_seidel_sweeps
