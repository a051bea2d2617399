"""One sweep of eq. 5.6's outer iteration on the node arrays (softvr.contact._node_jacobi_kernels:
the Jacobi update in residual form, the coarse correction from its residual, the Chebyshev
step, the largest change) against the sweep written out in NumPy on A, b of eq. 5.2 as the
per-object path assembles them (SciPy), with the coarse spaces built here.
"""

import numpy as np

from softvr.contact.node_coarse import coarse_aggregates
from softvr.contact import node_jacobi
from softvr.contact.node_jacobi import NodeSolve

from tests.contact.test_node_aggregates import DT, _beam
from tests.contact.test_node_gauss_seidel import _prepared, _start

EPS = np.finfo(float).eps


def _rigid_motions(q: np.ndarray) -> np.ndarray:
    """[3 k, 6] translations and rotations about the origin of points ``q`` [k, 3]: the span of
    an aggregate's coarse basis (the code turns about the mass centre; the projection
    P (P^T A P)^-1 P^T is the same for any basis of the span)."""
    p = np.zeros((3 * len(q), 6))
    for k in range(3):
        p[k::3, k] = 1.0
        p[:, 3 + k] = np.cross(np.eye(3)[k], q).ravel()
    return p


def test_one_sweep_is_numpy_two_level_jacobi_with_the_chebyshev_step():
    """Sweep k = 4 from v^3 (random) and v^2 (random), no contacts, on a clamped beam whose free
    nodes are split into aggregates of at most 12:

        v^_i = A_ii^-1 (b_i - sum_{j != i} A_ij v_j)              (eq. 5.6, free nodes)
        v^  += sum_g P_g (P_g^T A P_g)^-1 P_g^T (b - A v)          (the coarse correction)
        v^4  = omega_4 (gamma (v^ - v^3) + v^3 - v^2) + v^2        (Chebyshev; fixed nodes: their value)

    omega by the recurrence 1, 2 / (2 - rho^2), 4 / (4 - rho^2 omega_{k-1}) (Golub and Van Loan
    11.2.8) for the first weights' rho, the bounds' times CHEBYSHEV_RHO_FACTOR; and the largest change max |v^4 - v^3| over the free nodes.

    Tolerance, per node (first-order rounding): the Jacobi update is a sum of at most 27 block
    products, 81 terms a component, so it carries ~81 eps times the sum of the magnitudes of its
    terms (Higham, gamma_n), scaled by |A_ii^-1|; the residual form v + A_ii^-1 r adds the same
    with the diagonal term and eps |v_i|. The coarse velocity carries the residual's rounding
    through |P| |G^-1| |P^T| (G = P^T A P) and the 6x6 solve's kappa(G) eps |P y|. The
    Chebyshev step multiplies v^'s error by omega gamma and adds a few eps of its terms. 4x
    all that."""
    body = _beam()
    rng = np.random.default_rng(5)
    n = len(body.q)
    v3, v2 = (0.05 * rng.standard_normal((n, 3)) for _ in range(2))
    v3[body.fixed] = v2[body.fixed] = 0.0
    scene, stepper = _prepared(body, DT)
    m = stepper.model
    aggregates = coarse_aggregates(m, stepper.state.q.numpy(), size=12)
    assert len(aggregates) >= 6
    lo, hi = 0.02, 1.9
    solve = NodeSolve(m, stepper.state, DT, (lo, hi), coarse=aggregates)
    _start(stepper, v2)
    stepper.state.sweep_buffers[0].numpy()[:] = v3
    solve.prepare()
    solve.sweep.numpy()[0] = 3  # the contact step counts this sweep: the fourth
    for replay in solve._sweeps[0]:
        replay()
    solve._largest()

    system = body.step_system(DT, scene.gravity)
    a = system.matrix.toarray()
    b = system.rhs
    fixed = system.prescribed.reshape(n, 3).all(axis=1)
    blocks = a.reshape(n, 3, n, 3).transpose(0, 2, 1, 3)
    x = v3.ravel()
    terms = np.einsum("ijab,jb->ija", blocks, v3)  # [i, j, 3] A_ij v_j
    off = b.reshape(n, 3) - terms.sum(axis=1) + terms[np.arange(n), np.arange(n)]
    d_inv = np.linalg.inv(blocks[np.arange(n), np.arange(n)])
    v_hat = np.einsum("iab,ib->ia", d_inv, off)
    magnitude = np.abs(b.reshape(n, 3)).max(axis=1) + np.abs(terms).sum(axis=1).max(axis=1)  # [n] N s
    r_round = 84 * EPS * magnitude  # the residual's rounding [n]
    jacobi_round = np.abs(d_inv).max(axis=(1, 2)) * 3 * r_round + EPS * np.abs(v3).max(axis=1)
    residual = b - a @ x
    coarse_round = np.zeros(n)
    for g in range(len(aggregates)):
        nodes = aggregates.nodes[aggregates.start[g]:aggregates.start[g + 1]]
        dofs = (3 * nodes[:, None] + np.arange(3)).ravel()
        p = _rigid_motions(body.q[nodes])
        galerkin = p.T @ a[np.ix_(dofs, dofs)] @ p
        y = np.linalg.solve(galerkin, p.T @ residual[dofs])
        v_hat[nodes] += (p @ y).reshape(-1, 3)
        spread = np.abs(p) @ (np.abs(np.linalg.inv(galerkin)) @ (np.abs(p.T) @ np.repeat(r_round[nodes], 3)))
        coarse_round[nodes] += spread.reshape(-1, 3).max(axis=1) + np.linalg.cond(galerkin) * EPS * np.abs(p @ y).max()
    rho = (hi - lo) / (hi + lo) * node_jacobi.CHEBYSHEV_RHO_FACTOR  # the weights a solve starts on
    gamma = 2.0 / (lo + hi)
    omega = 1.0
    for k in range(2, 5):
        omega = 2.0 / (2.0 - rho * rho) if k == 2 else 4.0 / (4.0 - rho * rho * omega)
    expected = omega * (gamma * (v_hat - v3) + v3 - v2) + v2
    expected[fixed] = system.value.reshape(n, 3)[fixed]
    got = stepper.state.sweep_buffers[1].numpy()
    assert not fixed.all() and fixed.any() and np.abs(expected - v3).max() > 1e-3

    scale = np.abs(v_hat).max(axis=1) + np.abs(v3).max(axis=1) + np.abs(v2).max(axis=1)
    tolerance = 4 * (omega * gamma * (jacobi_round + coarse_round) + 8 * EPS * omega * (1 + gamma) * scale)
    np.testing.assert_array_less(np.abs(got - expected).max(axis=1), tolerance + 1e-300)
    change = np.abs(expected - v3)[~fixed].max()
    assert abs(float(solve.stats.numpy()[0]) - change) <= tolerance.max()
