"""The coarse correction of the node sweeps (softvr.contact.node_coarse: each free FEM body's rigid
motions solved exactly every sweep, the two-level preconditioner M^-1 = D_A^-1 +
P (P^T A P)^-1 P^T), held to NumPy's dense eigenvalues of M^-1 A, to SciPy's direct solve of
eq. 5.2 and to the MLCP of eq. 5.5.

Tolerances: velocities to 3x the sweeps' stopping tolerance (tests/sim/test_node_arrays.py);
the spectrum to ARPACK's tolerances with a 2x allowance: 1e-3 relative on hi, and lo = hi - mu
with mu (the largest eigenvalue of hi - M^-1 A, ~hi) to 1e-4 relative, so 2e-4 hi absolute.
"""

import numpy as np
import pytest

from softvr.contact.node_coarse import coarse_bodies, coarse_spectrum
from softvr.contact.node_factored import free_matrix
from softvr.contact.node_jacobi import NodeSolve
from softvr.dynamics import Material
from softvr.sim import _node_step, _node_sweeps
from softvr.sim._node_step import MAX_SWEEPS_PER_DECADE, SPECTRUM_MARGIN, SWEEP_TOLERANCE, spectrum
from softvr.sim._node_sweeps import sweeps_per_decade

from tests.contact.test_node_gauss_seidel import _prepared, _start
from tests.sim.test_node_arrays import VELOCITY_TOL, _cube, _scene, _solve_step, check_mlcp_steps

DT = 0.008


def _candy(lift=0.5):
    """A 6 cm gummy-stiff block at the candy scene's step: dt^2 E / (rho h^2) ~ 300, so its
    rigid motions are node-block Jacobi's slowest modes."""
    return _cube(cells=3, size=0.06, lift=lift, material=Material(2e6, 0.35, 1000.0, alpha=0.0, beta=2e-3))


def _two_level(a, dofs_per_node, q):
    """Dense M^-1 A for one body, with P built here: translations and rotations about the
    origin (the code turns about the mass centre; the span, and so M^-1, is the same)."""
    dense = a.toarray()
    node = np.arange(len(dense)) // 3
    d = np.where(node[:, None] == node[None, :], dense, 0.0)
    p = np.zeros((len(dense), 6))
    for k in range(3):
        p[k::3, k] = 1.0
        p[:, 3 + k] = np.cross(np.eye(3)[k], q).ravel()
    m_inv = np.linalg.inv(d) + p @ np.linalg.solve(p.T @ dense @ p, p.T)
    return np.sort(np.linalg.eigvals(m_inv @ dense).real), np.sort(np.linalg.eigvals(np.linalg.solve(d, dense)).real)


def test_coarse_spectrum_is_the_dense_two_level_spectrum_and_narrower_than_jacobi():
    body = _candy()
    _, stepper = _prepared(body, DT)
    a, free = free_matrix(stepper.model, stepper.state)
    lo, hi = coarse_spectrum(a, free, coarse_bodies(stepper.model), stepper.state.q.numpy(),
                             stepper.model.mass.numpy())
    eig, jacobi = _two_level(a, 3, body.q)
    assert lo == pytest.approx(eig[0], abs=2e-4 * eig[-1]) and hi == pytest.approx(eig[-1], rel=2e-3)
    # The rigid motions were Jacobi's slowest modes: without them the spectrum is 10x narrower.
    assert sweeps_per_decade((jacobi[0], jacobi[-1])) > MAX_SWEEPS_PER_DECADE
    assert sweeps_per_decade((eig[0], eig[-1])) < 0.5 * sweeps_per_decade((jacobi[0], jacobi[-1]))


@pytest.mark.parametrize("parallel", [False, True], ids=["thread per body", "thread per node"])
def test_coarse_sweeps_without_contacts_land_on_scipy_direct_solve_of_eq_5_2(parallel):
    """Either form of the coarse sums (a thread walking a body's nodes, the CPU's; a thread per
    node with atomic sums, a GPU's: NodeSolve's ``parallel``) lands on SciPy's solve."""
    body = _candy()
    rng = np.random.default_rng(2)
    body.v = np.cross([1.0, -2.0, 3.0], body.q - body.q.mean(0)) + 0.05 * rng.standard_normal(body.q.shape)
    scene, stepper = _prepared(body, DT)
    _, expected = _solve_step(body, scene, DT)
    a, free = free_matrix(stepper.model, stepper.state)
    bodies = coarse_bodies(stepper.model)
    lo, hi = coarse_spectrum(a, free, bodies, stepper.state.q.numpy(), stepper.model.mass.numpy())
    solve = NodeSolve(stepper.model, stepper.state, DT, (lo * SPECTRUM_MARGIN[0], hi * SPECTRUM_MARGIN[1]),
                      coarse=bodies, parallel=parallel)
    _start(stepper, body.v)
    sweeps, solved = solve.solve(SWEEP_TOLERANCE)
    np.testing.assert_allclose(solved.numpy(), expected, atol=VELOCITY_TOL, rtol=0)
    plain = NodeSolve(stepper.model, stepper.state, DT, spectrum(stepper.model, stepper.state))
    _start(stepper, body.v)
    assert sweeps < 0.5 * plain.solve(SWEEP_TOLERANCE)[0]


@pytest.mark.parametrize("parallel", [False, True], ids=["thread per body", "thread per node"])
def test_the_coarse_inverse_and_velocity_are_numpys_dense_ones(parallel):
    """Both forms of the coarse sums against NumPy: the body's mass centre c, the blocks of
    (P^T A P)^-1 with P_i = [I, -[q_i - c]x] built densely from this step's A, and the coarse
    velocity y = (P^T A P)^-1 P^T r of a random residual r. Tolerance: one 6x6 inverse of a
    matrix with condition ~1e4 and sums over 64 nodes in another order, 1e-9 relative. (The
    sweeps' tests above cannot see a wrong coarse operator: it is a preconditioner, and a wrong
    one changes how fast the sweeps go, not where they land.)"""
    body = _candy()
    _, stepper = _prepared(body, DT)
    m, st = stepper.model, stepper.state
    a, free = free_matrix(m, st)
    assert free.all()  # one free body: A is all of it
    solve = NodeSolve(m, st, DT, (0.1, 1.0), coarse=coarse_bodies(m), parallel=parallel)
    solve.coarse.prepare()
    co = solve.coarse.arrays
    q, mass = st.q.numpy(), m.mass.numpy()
    centre = (mass[:, None] * q).sum(axis=0) / mass.sum()
    p = np.zeros((3 * len(q), 6))
    for i, rho in enumerate(q - centre):
        p[3 * i:3 * i + 3, :3] = np.eye(3)
        p[3 * i:3 * i + 3, 3:] = -np.cross(np.eye(3), rho)  # -[rho]x (np.cross(I, rho) is [rho]x)
    inverse = np.linalg.inv(p.T @ a.toarray() @ p)
    np.testing.assert_allclose(co.centre.numpy()[0], centre, rtol=1e-12, atol=1e-15)
    scale = np.abs(inverse).max()
    for name, block in (("ll", inverse[:3, :3]), ("la", inverse[:3, 3:]), ("aa", inverse[3:, 3:])):
        np.testing.assert_allclose(getattr(co, name).numpy()[0], block, rtol=1e-9, atol=1e-9 * scale, err_msg=name)
    r = np.random.default_rng(5).standard_normal(q.shape)
    solve.residual_nodes.assign(r)
    solve.coarse.residual()
    y = inverse @ (p.T @ r.ravel())
    np.testing.assert_allclose(np.concatenate([co.y_lin.numpy()[0], co.y_ang.numpy()[0]]), y, rtol=1e-9,
                               atol=1e-9 * np.abs(y).max())


@pytest.mark.parametrize("parallel", [False, True], ids=["one thread", "thread per contact"])
def test_a_stiff_block_landing_with_the_coarse_correction_solves_the_mlcp_of_eq_5_5(monkeypatch, parallel):
    """Node-block Jacobi alone is too slow for this block (the scene would step per object);
    the rule takes the coarse correction, and every contact step is held to eq. 5.5 (the contact
    impulses move the block's rigid motions through the same M^-1) by the checker of
    tests/sim/test_node_arrays.py; with the contact step walked by one thread or a thread per
    contact (its contacts share the coarse body: split masses, softvr.contact._node_parallel_kernels)."""
    chosen = []

    def record(*args, **kwargs):
        choice = _node_sweeps.choose_sweeps(*args, **kwargs)
        chosen.append(choice)
        return choice

    monkeypatch.setattr(_node_step, "choose_sweeps", record)
    body = _candy(lift=0.002)
    body.v[:] = [0.3, 0.0, -0.5]
    scene = _scene(body)
    scene._gpu_forms = parallel
    assert check_mlcp_steps(body, scene, DT, 30, friction=0.5) >= 10
    assert scene._stepper._recorded[5].parallel == scene._gpu_forms
    assert [c.coarse is not None for c in chosen] == [True]
    assert chosen[0].work["jacobi"] > MAX_SWEEPS_PER_DECADE >= chosen[0].work["coarse"]
    assert type(scene._stepper).__name__ == "NodeStepper"


def test_the_rule_takes_the_coarse_correction_however_many_contacts_the_first_step_has():
    # Its 12 PGS passes a sweep pay for themselves in sweeps (COARSE_PASSES), so the choice made
    # on a scene's first step must not turn on how many contacts that step has: the candy
    # restored in the middle of its pile (~700 contacts) was once declined while the same scene
    # stepped there from its start (none) was held.
    body = _candy()
    _, stepper = _prepared(body, DT)
    m, st = stepper.model, stepper.state
    a, free = free_matrix(m, st)
    coarse = (coarse_bodies(m), st.q.numpy(), m.mass.numpy())
    kinds = [_node_sweeps.choose_sweeps(m.row_start.numpy(), m.block_col.numpy(), a, free, spectrum(m, st),
                                        MAX_SWEEPS_PER_DECADE, contacts, 2, SPECTRUM_MARGIN, coarse)
             for contacts in (0, 10 * len(body.q))]
    assert [(c.kind, c.coarse is not None, c.passes) for c in kinds] == [("jacobi", True, 12)] * 2
