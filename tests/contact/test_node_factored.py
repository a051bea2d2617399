"""The factored contact solve (softvr.contact.node_factored: A_0 factored once, rotated to the
nodes' rotations, the contacts' Delassus operator solved by PGS, the outer iteration
Anderson-accelerated): the nodes' rotations held to a rigid turn and to SciPy's polar factor,
the kept columns of A_0^-1 to NumPy's dense inverse, the solve to SciPy's direct solve of eq.
5.2 on a bent clamped beam whose A differs from the factored one, and to the MLCP of eq. 5.5 (A v = b + J^T lambda over the free
nodes with SciPy's A and b, complementarity, the friction disc) where a clamped beam, too stiff
for the node sweeps, swings down onto a plane.

Tolerances: the solve stops when an outer iteration changes no velocity by more than
SWEEP_TOLERANCE (1e-5 m/s); velocities are held to 3x that (tests/sim/test_node_arrays.py).
"""

import numpy as np
import pytest
from scipy.linalg import polar
from scipy.sparse.linalg import spsolve
from scipy.spatial.transform import Rotation

from softvr.contact import node_factored
from softvr.contact.node_factored import KEPT_NODES, REFRESH_PERIOD, FactoredSolve, _Anderson, free_matrix
from softvr.sim._node_step import SWEEP_TOLERANCE

from tests.contact.test_node_aggregates import _beam
from tests.contact.test_node_gauss_seidel import _prepared, _start
from tests.sim.test_node_arrays import VELOCITY_TOL, _scene, _solve_step
from tests.sim.test_node_rigid import _check_mlcp, _system

DT = 0.01


def _random_start(stepper, body, scene, seed: int, rms: float = 0.05) -> np.ndarray:
    """Random velocities (``rms`` [m/s]) on the free nodes, this step's assembly replayed and the
    sweeps' start set from them; returns SciPy's direct solve of eq. 5.2 from there [m/s]."""
    rng = np.random.default_rng(seed)
    body.v[:] = rms * rng.standard_normal(body.q.shape)
    body.v[body.fixed] = 0.0
    for replay in stepper._recorded[1:4]:
        replay()
    _, expected = _solve_step(body, scene, DT)
    _start(stepper, body.v)
    return expected


@pytest.mark.cpu_arrays
def test_factored_solve_of_a_bent_beam_lands_on_scipy_direct_solve_of_eq_5_2():
    body = _beam()
    scene, stepper = _prepared(body, DT)
    solve = FactoredSolve(stepper.model, stepper.state, DT)  # A_0: the straight beam's
    # Bent up to 0.2 rad at the free end (each node turned about y by 0.2 x / L about the clamp):
    # the tets co-rotate, so this step's A is far from A_0 (eq. 5.2 with R_e K_e R_e^T).
    x = body.q[:, 0]
    turn = Rotation.from_rotvec(np.outer(0.2 * x / x.max(), [0.0, 1.0, 0.0]))
    body.q[:] = turn.apply(body.q - [0.0, 0.0, 1.0]) + [0.0, 0.0, 1.0]
    expected = _random_start(stepper, body, scene, seed=5)
    iterations, solved = solve.solve(SWEEP_TOLERANCE)
    print(f"outer iterations {iterations}")
    np.testing.assert_allclose(solved.numpy(), expected, atol=VELOCITY_TOL, rtol=0)
    assert solve.factorizations == 1  # the one factorization, reused on the bent beam
    np.testing.assert_allclose(solved.numpy(), expected, atol=VELOCITY_TOL, rtol=0)


@pytest.mark.cpu_arrays
def test_steps_with_last_steps_rotations_or_local_correction_still_land_on_scipy_direct_solve(monkeypatch):
    # P's two turned parts take turns (REFRESH_PERIOD 2): a step refreshes the nodes' rotations
    # R or the local correction D (Woodbury) and keeps the other as the last step left it. P
    # only steers the outer iteration; its fixed point is A v = b (eq. 5.2) whatever P is, so
    # every step must still be SciPy's direct solve at its own configuration. Four steps of a
    # beam bent further each step (0.02 rad more at the free end) with its top corner node
    # pressed down 4 mm more (its tets squeezed: a local correction S of a few nodes), from
    # random velocities (5 mm/s rms); refactoring is switched off so that the kept parts are
    # really used (this beam's A drifts from A_0 by rotations of 0.02-0.08 rad).
    monkeypatch.setattr(node_factored, "REFACTOR_AFTER", 1000)
    assert REFRESH_PERIOD == 2
    body = _beam()
    scene, stepper = _prepared(body, DT)
    solve = FactoredSolve(stepper.model, stepper.state, DT)
    rest = body.q.copy()
    x = rest[:, 0]
    corner = np.argmax(rest.sum(axis=1))
    kept = []
    for step in range(1, 5):
        turn = Rotation.from_rotvec(np.outer(0.02 * step * x / x.max(), [0.0, 1.0, 0.0]))
        body.q[:] = turn.apply(rest - [0.0, 0.0, 1.0]) + [0.0, 0.0, 1.0]
        body.q[corner, 2] -= 0.004 * step
        expected = _random_start(stepper, body, scene, seed=step, rms=0.005)
        rotations, local = solve._host["rotation"].copy(), solve._kept_local
        _, solved = solve.solve(SWEEP_TOLERANCE)
        np.testing.assert_allclose(solved.numpy(), expected, atol=VELOCITY_TOL, rtol=0)
        kept.append((np.array_equal(rotations, solve._host["rotation"]), local is solve._kept_local,
                     len(solve._kept_local[1])))
    assert solve.factorizations == 1
    # Step 1 refreshes both; then rotations (local kept), local (rotations kept), rotations.
    assert [k[:2] for k in kept] == [(False, False), (False, True), (True, False), (False, True)]
    assert kept[2][2] > 0 and kept[3][2] > 0  # a squeezed set S, computed at step 3 and kept at step 4


def test_a_stiff_clamped_beam_swinging_onto_a_plane_takes_the_factored_solve_and_meets_eq_5_5():
    # The node sweeps decline this beam (over their work limits); per object it would take a
    # sparse LU every step. Its clamped nodes' rows of eq. 5.2 carry the clamp's reaction, so
    # the momentum balance is held on the free rows (_check_mlcp).
    body = _beam()
    body.q[:] = body.q - [0.0, 0.0, 1.0 - 0.0005]  # its underside 0.5 mm above the plane z = 0
    body.v[:] = 0.0
    body.v[:, 2] = -0.3 * body.q[:, 0] / body.q[:, 0].max()  # swinging down about the clamp
    body.v[body.fixed] = 0.0
    scene = _scene(body)
    pushing = 0
    for _ in range(6):
        systems = [_system(b, DT, scene.gravity) for b in scene.bodies]
        solution = scene.step(DT)
        _check_mlcp(scene, systems, solution, DT, 0.5)
        pushing += sum(int((lam[:, 0] > 0).sum()) for lam in solution.impulses)
    assert type(scene._stepper._recorded[5]).__name__ == "FactoredSolve"
    assert scene._stepper._spectrum[DT].kind is None  # what the sweeps made of it
    assert pushing >= 10


@pytest.mark.cpu_arrays
def test_node_rotations_are_a_rigid_turn_and_scipys_polar_factor_of_the_stiffness_weighted_sums():
    # Each solved node's rotation (stiffness warping) is the polar factor of the sum of its
    # tets' co-rotations R_e weighted by the trace of K_e's diagonal blocks. Turned rigidly by Q,
    # every R_e is Q and so is every node's rotation; bent, the sums are near rotations (the
    # scaled sum is 1.2e-5 from the polar factor: neighbouring tets differ by ~0.2 rad / 24)
    # and the kernel's three Newton steps X <- (X + X^-T) / 2 converge quadratically from
    # there (~1e-10, ~1e-20, ...), so 1e-10 holds with room; with no Newton step it fails.
    body = _beam()
    scene, stepper = _prepared(body, DT)
    solve = FactoredSolve(stepper.model, stepper.state, DT)
    model = stepper.model
    tets, ke = model.tets.numpy(), model.ke.numpy()
    weight = np.einsum("eaii->e", ke.reshape(len(tets), 4, 4, 3, 3)[:, np.arange(4), np.arange(4)])
    solved = np.flatnonzero((model.fixed.numpy() == 0) & (np.diff(model.row_start.numpy()) > 0))
    rest = body.q.copy()
    q_turn = Rotation.from_rotvec([0.3, -0.5, 0.7])
    body.q[:] = q_turn.apply(rest - [0.0, 0.0, 1.0]) + [0.0, 0.0, 1.0]
    stepper._recorded[1]()  # the tets' co-rotations
    solve._rotations()
    np.testing.assert_allclose(solve._absolute.numpy(), np.broadcast_to(q_turn.as_matrix(), (len(solved), 3, 3)),
                               atol=1e-12, rtol=0)
    x = rest[:, 0]
    turn = Rotation.from_rotvec(np.outer(0.2 * x / x.max(), [0.0, 1.0, 0.0]))
    body.q[:] = turn.apply(rest - [0.0, 0.0, 1.0]) + [0.0, 0.0, 1.0]
    stepper._recorded[1]()
    solve._rotations()
    rotations = stepper.state.rotations.numpy()
    expected = []
    for i in solved:
        mine = np.flatnonzero((tets == i).any(axis=1))
        expected.append(polar(np.einsum("e,eij->ij", weight[mine], rotations[mine]))[0])
    np.testing.assert_allclose(solve._absolute.numpy(), expected, atol=1e-10, rtol=0)


@pytest.mark.cpu_arrays
def test_rotations_and_warp_change_recomputed_only_where_tets_turned_stay_scipys_and_numpys_everywhere():
    # The nodes' rotations (the polar factor of their tets' stiffness-weighted co-rotations) and
    # each solved row's warp change (max_j |R_i^T A_ij R_j - A0_ij|_F / |A0_ii|_F) are recomputed
    # only at the nodes one of whose tets' R_e changed since the last call (and, for the warp
    # change, at the rows reaching a node whose rotation was recomputed); the others keep what
    # they had. Here the beam is bent, then only its outer part (x > 0.45 m) bent further: the
    # tets inside keep their R_e bit for bit, and every node must still be SciPy's polar factor
    # of its sums (1e-10, as the test above) and every row NumPy's warp change of this A with
    # those rotations (round-off of 3 x 3 products: 1e-12 relative).
    body = _beam()
    scene, stepper = _prepared(body, DT)
    solve = FactoredSolve(stepper.model, stepper.state, DT)
    model, state = stepper.model, stepper.state
    tets, ke = model.tets.numpy(), model.ke.numpy()
    weight = np.einsum("eaii->e", ke.reshape(len(tets), 4, 4, 3, 3)[:, np.arange(4), np.arange(4)])
    solved = np.flatnonzero((model.fixed.numpy() == 0) & (np.diff(model.row_start.numpy()) > 0))
    n = model.node_count
    a0 = state.blocks.numpy().copy()
    rotation0 = solve._rotation0.numpy().copy()
    x = body.q[:, 0]
    body.q[:] = Rotation.from_rotvec(np.outer(0.2 * x / x.max(), [0.0, 1.0, 0.0])).apply(body.q - [0.0, 0.0, 1.0]) \
        + [0.0, 0.0, 1.0]
    calls = []
    for outer in (x >= 0.0, x > 0.45):
        pivot = body.q[np.argmin(np.abs(x - 0.45))].copy()
        body.q[outer] = Rotation.from_rotvec([0.0, 0.15, 0.0]).apply(body.q[outer] - pivot) + pivot
        for replay in stepper._recorded[1:3]:  # the tets' co-rotations, A
            replay()
        solve._rotations()
        calls.append(int(solve._moved[0].numpy()[solved].sum()))  # nodes whose rotation was recomputed
        solve._warp_change()
    # The first call after the factorization recomputes every node; the second only those of the
    # tets the outer turn reached (the inner tets' R_e are the same bits).
    assert calls[0] == len(solved) and 0 < calls[1] < len(solved) - 20
    assert not solve._turned.numpy().any()  # the warp change took them all
    r_e = state.rotations.numpy()
    expected = [polar(np.einsum("e,eij->ij", weight[mine], r_e[mine]))[0]
                for mine in (np.flatnonzero((tets == i).any(axis=1)) for i in solved)]
    np.testing.assert_allclose(solve._absolute.numpy(), expected, atol=1e-10, rtol=0)
    relative = np.tile(np.eye(3), (n, 1, 1))
    relative[solved] = np.matmul(expected, rotation0.transpose(0, 2, 1))
    blocks, rows, cols = state.blocks.numpy(), model.block_row.numpy(), model.block_col.numpy()
    is_solved = np.isin(np.arange(n), solved)
    change = np.zeros(n)
    for i in solved:
        mine = np.flatnonzero((rows == i) & is_solved[cols])
        d = relative[i].T @ blocks[mine] @ relative[cols[mine]] - a0[mine]
        own = a0[np.flatnonzero((rows == i) & (cols == i))[0]]
        change[i] = np.sqrt(np.max(np.sum(d * d, axis=(1, 2))) / np.sum(own * own))
    np.testing.assert_allclose(solve._change.numpy(), change, rtol=1e-12, atol=0)


@pytest.mark.cpu_arrays
def test_kept_columns_over_the_limit_drop_to_the_last_steps_and_stay_scipys_columns_of_the_inverse():
    # The columns of A_0^-1 a step multiplies are kept across steps; over KEPT_NODES nodes'
    # (a probe moved over the body) a step first drops those the last step did not use. The
    # ones kept must still be A_0^-1's columns at their nodes (NumPy's dense inverse of the
    # factored A over the solved rows; the solve is exact to ~1e-13 relative, as SuperLU's
    # backward error times A's condition, ~1e3 here), and the step still SciPy's direct solve.
    body = _beam()
    scene, stepper = _prepared(body, DT)
    solve = FactoredSolve(stepper.model, stepper.state, DT)
    a0, solved = free_matrix(stepper.model, stepper.state)
    inverse = np.linalg.inv(a0.toarray())
    nodes = np.flatnonzero(solved)
    assert len(nodes) > KEPT_NODES
    solve._slots_of(nodes[::-1])  # every solved node's columns, in an order unlike the nodes'
    solve._used = solve._slots_of(nodes[:10])  # the last step used these ten
    expected = _random_start(stepper, body, scene, seed=7)
    _, solved_v = solve.solve(SWEEP_TOLERANCE)
    np.testing.assert_allclose(solved_v.numpy(), expected, atol=VELOCITY_TOL, rtol=0)
    kept = np.flatnonzero(solve._slot >= 0)
    # The ten, and any this step's Woodbury set needed (the straight beam: none expected).
    assert set(nodes[:10]) <= set(kept) and len(kept) < len(nodes) // 2
    assert solve._kept == 3 * len(kept)
    rows = np.cumsum(solved) - 1
    for node in kept:
        dofs = 3 * rows[node] + np.arange(3)
        columns = 3 * solve._slot[node] + np.arange(3)
        np.testing.assert_allclose(solve._columns[:, columns], inverse[:, dofs], rtol=0,
                                   atol=1e-10 * np.abs(inverse).max())


def test_block_triangular_solves_are_scipys_direct_solve_of_the_factored_matrix():
    # The outer iteration's A_0^-1 r runs SuperLU's factors as 3 x 3 blocks in one Warp thread
    # (factor_solve), its permutations over the flat entries. It must be SciPy's direct solve
    # (spsolve, its own factorization) of the factored A over the solved rows, to the rounding
    # of either (backward error ~1e-16 times A's condition, ~1e3 on this beam: 1e-12 relative
    # to the largest entry holds with room), for a random right-hand side.
    body = _beam()
    scene, stepper = _prepared(body, DT)
    solve = FactoredSolve(stepper.model, stepper.state, DT)
    a0, _ = free_matrix(stepper.model, stepper.state)
    r = np.random.default_rng(3).standard_normal(a0.shape[0])
    solve._r.numpy()[:] = r.reshape(-1, 3)
    solve._solve_r()
    expected = spsolve(a0.tocsc(), r)
    np.testing.assert_allclose(solve._y.numpy().ravel(), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def _contraction(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A random linear map x -> M x + c on R^n with M's singular values 0.9 (a slow contraction)."""
    rng = np.random.default_rng(seed)
    q1, _ = np.linalg.qr(rng.standard_normal((n, n)))
    q2, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return 0.9 * q1 @ q2, rng.standard_normal(n)


def test_anderson_acceleration_is_its_least_squares_definition_and_exact_in_n_plus_1_steps_on_a_linear_map():
    # Type II Anderson (Walker and Ni 2011, eq. 2.2 and their Theorem 2.2): with the last m
    # differences dF = [f_j+1 - f_j], dG = [g_j+1 - g_j] of residuals f = G(x) - x and images
    # g = G(x), the next iterate is g - dG gamma with gamma = argmin |f - dF gamma|. Held to
    # NumPy's least squares of that definition (the ring of kept differences wraps: memory 3,
    # 12 calls); and on a linear map of R^4 with memory 5 it is GMRES on (I - M) x = c, exact
    # after 4 + 1 calls, where the plain iteration is still ~0.9^5 of its start away. The
    # code's guard (the Gram diagonal times 1 + 1e-10) moves gamma by ~1e-10 x the Gram
    # matrix's condition: <= 18 in the first case (1e-8 relative holds with room), 200 at the
    # last call of the second (1e-7).
    m_, c = _contraction(30, seed=1)
    anderson = _Anderson(3)
    x, fs, gs = np.zeros(30), [], []
    for _ in range(12):
        g = m_ @ x + c
        fs.append(g - x)
        gs.append(g)
        df = np.diff(np.array(fs[-4:]), axis=0).T
        dg = np.diff(np.array(gs[-4:]), axis=0).T
        expected = g - dg @ np.linalg.lstsq(df, fs[-1], rcond=None)[0] if len(fs) > 1 else g
        x = anderson.next(x, g)
        np.testing.assert_allclose(x, expected, rtol=0, atol=1e-8 * np.abs(expected).max())
    m_, c = _contraction(4, seed=2)
    exact = np.linalg.solve(np.eye(4) - m_, c)
    anderson, x = _Anderson(5), np.zeros(4)
    for _ in range(5):
        x = anderson.next(x, m_ @ x + c)
    np.testing.assert_allclose(x, exact, rtol=0, atol=1e-7 * np.abs(exact).max())
    # At a fixed point met exactly (G(x) = x: zero residuals and differences, a zero Gram
    # matrix) the iterate stays where it is.
    anderson = _Anderson(5)
    for _ in range(4):
        x = anderson.next(x, x.copy())
    np.testing.assert_allclose(x, exact, rtol=0, atol=1e-7 * np.abs(exact).max())
