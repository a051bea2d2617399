"""The node sweeps' contact step with a thread per contact (softvr.contact._node_parallel_kernels,
the form a GPU takes): Jacobi passes over the contacts on split masses.

Truth: the frictionless contact LCP (thesis eq. 5.5's normal rows) solved by SciPy: with ``W =
J M^-1 J^T`` and ``q`` the normal velocities before the impulses less their targets ``-gap /
dt``, ``lambda = argmin 1/2 lambda^T W lambda + q^T lambda`` over ``lambda >= 0`` (the LCP's
KKT conditions), which is ``nnls(L^T, -L^-1 q)`` for ``W = L L^T``. Contacts that share nodes
(the case the split masses are for) must reach it; a Jacobi pass on the true masses overshoots
a shared node once per contact and does not.
"""

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
import warp as wp

from softvr.contact import _node_parallel_kernels as _pk
from softvr.contact._node_coarse_kernels import SIDES, Coarse

DT = 0.01  # [s]
#: Stencils (nodes, weights) of the contacts: node 1 is pressed by four of them, nodes 0 and 2
#: by three, one contact is a one-node one (the local solve's path), weights of either sign (a
#: triangle's). The last one separates (its gap is open).
STENCILS = [((0, 1), (0.5, 0.5)), ((1, 2), (0.3, 0.7)), ((1, 0), (0.6, 0.4)), ((1,), (1.0,)), ((0, 2), (1.2, -0.2)),
            ((2, 0), (0.5, 0.5))]
GAPS = np.array([0.0, -0.002, 0.001, 0.0, -0.001, 0.05])  # [m]
MASSES = np.array([1.0, 2.0, 1.5])  # [kg]
PASSES = 400


def _frames(rng, count):
    """Orthonormal contact frames [c, 3, 3] (rows: normal, tangents), normals within ~17 degrees
    of +z: the contacts press their shared nodes the same way, as on a resting face."""
    out = []
    for _ in range(count):
        normal = np.array([0.0, 0.0, 1.0]) + 0.3 * rng.uniform(-1.0, 1.0, 3) * [1, 1, 0]
        q, _ = np.linalg.qr(np.column_stack([normal, rng.standard_normal((3, 2))]))
        out.append(q.T * np.sign(q[2, 0]))
    return np.array(out)


def _coarse(nodes, contacts, device):
    """No coarse bodies: every node's body -1, every contact's coarse sides -1."""
    co = Coarse()
    co.node_body = wp.full(nodes, -1, dtype=wp.int32, device=device)
    for name in ("centre", "y_lin", "y_ang"):
        setattr(co, name, wp.zeros(1, dtype=wp.vec3d, device=device))
    for name in ("ll", "la", "aa"):
        setattr(co, name, wp.zeros(1, dtype=wp.mat33d, device=device))
    co.side = wp.full((contacts, SIDES), -1, dtype=wp.int32, device=device)
    co.weight = wp.zeros((contacts, SIDES), dtype=wp.float64, device=device)
    co.lever = wp.zeros((contacts, SIDES), dtype=wp.vec3d, device=device)
    return co


def _jacobian(frames):
    """The normal rows of J [c, 3 n]."""
    j = np.zeros((len(STENCILS), 3 * len(MASSES)))
    for c, (nodes, weights) in enumerate(STENCILS):
        for node, w in zip(nodes, weights):
            j[c, 3 * node:3 * node + 3] += w * frames[c, 0]
    return j


def _solve(device, split=True):
    """Impulses [c, 3] [N s] after PASSES Jacobi passes of the thread-per-contact kernels from
    zero, frictionless, with the velocities ``v0`` [n, 3] [m/s] and gaps [c] [m] of the
    module's contact set; and the set itself."""
    rng = np.random.default_rng(3)
    frames = _frames(rng, len(STENCILS))
    v0 = np.array([0.0, 0.0, -1.0]) + 0.2 * rng.standard_normal((len(MASSES), 3))  # falling [m/s]
    gap = GAPS
    c_count, width = len(STENCILS), max(len(s[0]) for s in STENCILS)
    nodes = np.zeros((c_count, width), np.int32)
    weights = np.zeros((c_count, width))
    for c, (n, w) in enumerate(STENCILS):
        nodes[c, :len(n)], weights[c, :len(w)] = n, w

    def arr(x, dtype):
        return wp.array(x, dtype=dtype, device=device)

    count = arr([c_count], wp.int32)
    live = arr(np.ones(c_count, np.int32), wp.int32)
    stencil = [arr([len(s[0]) for s in STENCILS], wp.int32), arr(nodes, wp.int32), arr(weights, wp.float64)]
    rigid_node, rigid_lever = arr(np.full((c_count, 2), -1, np.int32), wp.int32), wp.zeros((c_count, 2),
                                                                                          dtype=wp.vec3d, device=device)
    d_inv = arr(np.array([np.eye(3) / m for m in MASSES]), wp.mat33d)
    partner, cross = arr(np.full(len(MASSES), -1, np.int32), wp.int32), wp.zeros(len(MASSES), dtype=wp.mat33d,
                                                                                  device=device)
    fixed = wp.zeros(len(MASSES), dtype=wp.int32, device=device)
    co = _coarse(len(MASSES), c_count, device)
    impulse = wp.zeros(c_count, dtype=wp.vec3d, device=device)
    v_hat = arr(v0, wp.vec3d)
    node_share = wp.zeros(len(MASSES), dtype=wp.int32, device=device)
    body_share = wp.zeros(1, dtype=wp.int32, device=device)
    sweep, stats = wp.zeros(1, dtype=wp.int32, device=device), wp.zeros(3, dtype=wp.float64, device=device)
    change = wp.zeros(c_count, dtype=wp.vec3d, device=device)
    threads = 2  # striding threads: fewer than the contacts, so a thread takes several
    if split:
        wp.launch(_pk.count_shares, dim=threads, device=device,
                  inputs=[count, live, *stencil, rigid_node, fixed, co, node_share, body_share, sweep, stats, 1,
                          threads])
    zeros = wp.zeros(c_count, dtype=wp.float64, device=device)
    for _ in range(PASSES):
        wp.launch(_pk.jacobi_contacts, dim=threads, device=device,
                  inputs=[count, live, *stencil, arr(frames, wp.mat33d), arr(gap, wp.float64), zeros, rigid_node,
                          rigid_lever, d_inv, partner, cross, fixed, DT, impulse, v_hat, zeros,
                          wp.zeros(c_count, dtype=wp.vec3d, device=device), co, node_share, body_share,
                          wp.zeros(c_count, dtype=wp.mat33d, device=device), 1, 8, change, threads])
        wp.launch(_pk.apply_contacts, dim=threads, device=device,
                  inputs=[count, live, *stencil, rigid_node, rigid_lever, d_inv, partner, cross, fixed, change,
                          v_hat, co, threads])
    return impulse.numpy(), v_hat.numpy(), frames, v0, gap


def _lcp(frames, v0, gap):
    """SciPy's solution of the frictionless LCP (module docstring) [c] [N s]."""
    j = _jacobian(frames)
    m_inv = np.diag(np.repeat(1.0 / MASSES, 3))
    w = j @ m_inv @ j.T
    q = j @ v0.ravel() + gap / DT
    lower = scipy.linalg.cholesky(w, lower=True)
    lam, _ = scipy.optimize.nnls(lower.T, -scipy.linalg.solve_triangular(lower, q, lower=True))
    return lam, w, q


def test_jacobi_passes_on_split_masses_reach_the_lcp_solution(device):
    """Shared nodes (each by 2-3 contacts), Jacobi passes on split masses from zero impulses:
    the normal impulses reach SciPy's LCP solution, the tangents stay 0 (no friction), and the
    velocities in ``v^`` are ``v0 + M^-1 J^T lambda`` (the atomic pushes lose nothing).
    Tolerance: the split Jacobi iteration contracts the error geometrically (its rate is at most
    1 - lambda_min(D^-1 W) < 1); 400 passes take this 4-contact set to rounding, 1e-9 relative."""
    lam, v, frames, v0, gap = _solve(device)
    expected, w, q = _lcp(frames, v0, gap)
    assert (expected > 0).sum() >= 2 and (expected == 0).sum() >= 1  # pushing and separating contacts both
    np.testing.assert_allclose(lam[:, 0], expected, rtol=1e-9, atol=1e-9 * expected.max())
    np.testing.assert_allclose(lam[:, 1:], 0.0, atol=1e-12)
    world = np.einsum("ci,cij->cj", lam, frames)
    pushed = v0.copy()
    for c, (nodes, weights) in enumerate(STENCILS):
        for node, wt in zip(nodes, weights):
            pushed[node] += wt * world[c] / MASSES[node]
    np.testing.assert_allclose(v, pushed, atol=1e-12)
    # Complementarity in the velocities themselves: w = W lambda + q >= 0, 0 where it pushes.
    w_after = w @ lam[:, 0] + q
    assert (w_after >= -1e-9).all()
    np.testing.assert_allclose(w_after[lam[:, 0] > 0], 0.0, atol=1e-9)


def test_jacobi_passes_on_the_true_masses_miss_the_lcp_solution(device):
    """The reason for the split masses: the same passes on the true masses (every share 1)
    overshoot the shared nodes and do not reach the solution."""
    lam, _, frames, v0, gap = _solve(device, split=False)
    expected, _, _ = _lcp(frames, v0, gap)
    assert not np.allclose(lam[:, 0], expected, rtol=1e-3, atol=1e-3 * expected.max())
