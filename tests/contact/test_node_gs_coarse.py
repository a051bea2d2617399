"""The Gauss-Seidel sweeps' coarse correction (softvr.contact.node_gs_coarse: after each symmetric
block Gauss-Seidel sweep of thesis eq. 5.6's outer iteration, each aggregate's rigid motion solved
from its Galerkin system over the residual, contact nodes held), held to NumPy's dense error
operator, to the correction written out in NumPy, and to SciPy's direct solve of eq. 5.2.

Tolerances: the spectrum to ARPACK's (1e-4 relative) with a 2x allowance as in
tests/contact/test_node_aggregates.py (2e-3 relative on hi, 2e-4 hi absolute on lo); velocities
to 3x the sweeps' stopping tolerance (tests/sim/test_node_arrays.py).
"""

import numpy as np
import pytest
import warp as wp

from softvr.contact.node_coarse import coarse_aggregates
from softvr.contact.node_colouring import colour_nodes
from softvr.contact.node_factored import free_matrix
from softvr.contact.node_gauss_seidel import GaussSeidelSweep
from softvr.contact.node_gs_coarse import gauss_seidel_coarse_spectrum
from softvr.contact.node_jacobi import NodeSolve
from softvr.sim._node_step import SPECTRUM_MARGIN, SWEEP_TOLERANCE, spectrum
from softvr.sim._node_sweeps import sweeps_per_decade

from tests.contact.test_node_aggregates import DT, _beam, _moving_beam
from tests.contact.test_node_gauss_seidel import _gauss_seidel, _prepared, _start
from tests.sim.test_node_arrays import VELOCITY_TOL


def _groups(aggregates):
    return [aggregates.nodes[s:e] for s, e in zip(aggregates.start[:-1], aggregates.start[1:])]


def _rigid_motions(nodes, q, index, size):
    """[size, 6] translations and rotations about their mean of ``nodes`` (dof ``3 index + k``):
    the span of the code's rigid motions about the mass centre, so the same Galerkin correction."""
    p = np.zeros((size, 6))
    arm = q[nodes] - q[nodes].mean(axis=0)
    for k in range(3):
        p[3 * index[nodes] + k, k] = 1.0
        p[(3 * index[nodes][:, None] + np.arange(3)).ravel(), 3 + k] = np.cross(np.eye(3)[k], arm).ravel()
    return p


def test_a_gauss_seidel_sweep_and_the_coarse_correction_give_the_dense_spectrum():
    """lo, hi of I - E, E = (I - Q A)(I - M^-1 A) built densely here: M = (D + L) D^-1 (D + U)
    over the colour order, Q = sum_g P_g (P_g^T A P_g)^-1 P_g^T."""
    body = _beam()
    _, stepper = _prepared(body, DT)
    m, st = stepper.model, stepper.state
    a, free = free_matrix(m, st)
    aggregates = coarse_aggregates(m, st.q.numpy())
    colours = colour_nodes(m.row_start.numpy(), m.block_col.numpy())
    index = np.cumsum(free) - 1
    order = index[colours.order[free[colours.order]]]
    lo, hi = gauss_seidel_coarse_spectrum(a, order, aggregates, free, st.q.numpy(), m.mass.numpy())

    dense = a.toarray()
    size = len(dense)
    dofs = (3 * order[:, None] + np.arange(3)).ravel()
    position = np.empty(size, int)
    position[dofs] = np.arange(size)
    node = position // 3  # each dof's node position in the colour order
    diagonal = np.where(node[:, None] == node[None, :], dense, 0.0)
    lower = np.where(node[:, None] > node[None, :], dense, 0.0)
    m_inv_a = np.linalg.solve((diagonal + lower.T), diagonal @ np.linalg.solve(diagonal + lower, dense))
    q_op = sum(p @ np.linalg.solve(p.T @ dense @ p, p.T)
               for p in (_rigid_motions(g, body.q, index, size) for g in _groups(aggregates)))
    error = (np.eye(size) - q_op @ dense) @ (np.eye(size) - m_inv_a)
    eig = np.sort(np.linalg.eigvals(np.eye(size) - error).real)
    assert lo == pytest.approx(eig[0], abs=2e-4 * eig[-1]) and hi == pytest.approx(eig[-1], rel=2e-3)
    plain = np.sort(np.linalg.eigvals(m_inv_a).real)
    assert sweeps_per_decade((eig[0], eig[-1])) < 0.6 * sweeps_per_decade((plain[0], plain[-1]))


def test_one_sweep_with_the_coarse_correction_is_numpy_block_gauss_seidel_then_galerkin():
    """One sweep (colours forward, the contact nodes' damped Jacobi update, colours backward:
    written out in NumPy as tests/contact/test_node_gauss_seidel.py does) and then, per aggregate,
    its nodes that are not contact nodes moved by P_g (P_g^T A_gg P_g)^-1 P_g^T (b - A v^)_g.
    Tolerance: 1e-9 of the largest velocity, over 1e2 times eps times the largest condition
    number of the 6x6 Galerkin matrices (asserted under 1e5) for the sweep's sums."""
    body = _beam()
    rng = np.random.default_rng(5)
    body.v = 0.05 * rng.standard_normal(body.q.shape)
    body.v[body.fixed] = 0.0
    omega = 0.7
    scene, stepper = _prepared(body, DT)
    m, st, n = stepper.model, stepper.state, len(body.q)
    aggregates = coarse_aggregates(m, st.q.numpy())
    colours = colour_nodes(m.row_start.numpy(), m.block_col.numpy())
    sweep = GaussSeidelSweep(m, st, colours, omega, coarse=aggregates)
    contact = rng.random(n) < 0.15
    contact[body.fixed] = False
    sweep.prepare()
    sweep.set_contact_nodes(contact)
    sweep.coarse.prepare()  # over the hand-marked contact nodes
    v = wp.array(body.v, dtype=wp.vec3d, device=m.device)
    sweep.record(v, lambda: None)()

    system = body.step_system(DT, scene.gravity)
    a = system.matrix.toarray()
    b = system.rhs
    fixed = system.prescribed.reshape(n, 3).all(axis=1)
    x = body.v.copy()
    blocks = a.reshape(n, 3, n, 3).transpose(0, 2, 1, 3)

    def update(i):
        others = np.arange(n) != i
        return np.linalg.solve(blocks[i, i], b.reshape(n, 3)[i] - np.einsum("jab,jb->a", blocks[i, others], x[others]))

    for order in (colours.order, None, colours.order[::-1]):
        if order is None:
            x[contact] = [(1.0 - omega) * body.v[i] + omega * update(i) for i in np.flatnonzero(contact)]
            continue
        for i in order:
            if not contact[i]:
                x[i] = system.value.reshape(n, 3)[i] if fixed[i] else update(i)
    residual = b - a @ x.ravel()
    corrected, conditions = x.copy(), []
    for group in _groups(aggregates):
        held = group[~contact[group]]
        if len(held) < 4:
            continue
        p = _rigid_motions(held, body.q, np.arange(n), 3 * n)
        galerkin = p.T @ a @ p
        conditions.append(np.linalg.cond(galerkin))
        corrected += (p @ np.linalg.solve(galerkin, p.T @ residual)).reshape(n, 3)
    assert contact.sum() > 5 and max(conditions) < 1e5
    assert np.abs(corrected - x).max() > 1e-3 * np.abs(x).max()  # the correction moves something
    np.testing.assert_allclose(st.v_hat.numpy(), corrected, atol=1e-9 * np.abs(corrected).max(), rtol=0)


def test_coarse_gauss_seidel_sweeps_land_on_scipy_direct_solve_of_eq_5_2_in_fewer_sweeps():
    body, stepper, expected, a, free, aggregates = _moving_beam()
    m, st = stepper.model, stepper.state
    gauss_seidel, colours, _ = _gauss_seidel(stepper, DT, max_sweeps=2000)
    index = np.cumsum(free) - 1
    lo, hi = gauss_seidel_coarse_spectrum(a, index[colours.order[free[colours.order]]], aggregates, free,
                                          st.q.numpy(), m.mass.numpy())
    solve = NodeSolve(m, st, DT, (lo * SPECTRUM_MARGIN[0], hi * SPECTRUM_MARGIN[1]), max_sweeps=2000,
                      colours=colours, omega=1.0 / spectrum(m, st)[1], coarse=aggregates)
    _start(stepper, body.v)
    sweeps, solved = solve.solve(SWEEP_TOLERANCE)
    np.testing.assert_allclose(solved.numpy(), expected, atol=VELOCITY_TOL, rtol=0)
    _start(stepper, body.v)
    plain = gauss_seidel.solve(SWEEP_TOLERANCE)[0]
    print(f"sweeps: Gauss-Seidel with the coarse correction {sweeps}, without {plain}")
    assert sweeps < 0.6 * plain
