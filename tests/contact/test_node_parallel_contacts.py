"""The node sweeps' contact step with a thread per contact (softvr.contact._node_parallel_kernels,
the form a GPU takes): one thread block's launch (softvr.contact._node_block_kernels),
Gauss-Seidel within a lane's contacts and Jacobi on split masses across lanes, with one lane or
several (on the CPU, Warp's cooperative fibers, ``wp.config.enable_cpu_blocks``: lanes that
really interleave at the barriers); and the one launch for contacts that share nothing.

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

from softvr.contact import _node_block_kernels as _bk
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


def _jacobian(frames, stencils=STENCILS, masses=MASSES):
    """The normal rows of J [c, 3 n]."""
    j = np.zeros((len(stencils), 3 * len(masses)))
    for c, (nodes, weights) in enumerate(stencils):
        for node, w in zip(nodes, weights):
            j[c, 3 * node:3 * node + 3] += w * frames[c, 0]
    return j


def _solve(device, form="block", lanes=_bk.CONTACT_BLOCK_THREADS, warm=None, stencils=STENCILS, gaps=GAPS,
           masses=MASSES, passes=PASSES):
    """Impulses [c, 3] [N s] after ``passes`` passes over the module's contact set,
    frictionless, from the velocities ``v0`` [n, 3] [m/s] and the impulses ``warm`` [c] (normal,
    [N s]; zero where None), and the set itself. ``form``: "block" (one launch of the block
    kernel with ``lanes`` lanes: shares counted, split masses; with ``warm``, its start stage
    applies them to ``v^`` and screens the contacts first) or "true masses" (the launch for
    contacts that share nothing, on the true masses' blocks of ``J M^-1 J^T``: with one
    thread, or with ``lanes`` threads striding over them)."""
    rng = np.random.default_rng(3)
    frames = _frames(rng, len(stencils))
    v0 = np.array([0.0, 0.0, -1.0]) + 0.2 * rng.standard_normal((len(masses), 3))  # falling [m/s]
    gap = gaps
    c_count, width = len(stencils), max(len(s[0]) for s in stencils)
    nodes = np.zeros((c_count, width), np.int32)
    weights = np.zeros((c_count, width))
    for c, (n, w) in enumerate(stencils):
        nodes[c, :len(n)], weights[c, :len(w)] = n, w

    def arr(x, dtype):
        return wp.array(x, dtype=dtype, device=device)

    count = arr([c_count], wp.int32)
    live = arr(np.ones(c_count, np.int32), wp.int32)
    stencil = [arr([len(s[0]) for s in stencils], wp.int32), arr(nodes, wp.int32), arr(weights, wp.float64)]
    rigid_node, rigid_lever = arr(np.full((c_count, 2), -1, np.int32), wp.int32), wp.zeros((c_count, 2),
                                                                                          dtype=wp.vec3d, device=device)
    d_inv = arr(np.array([np.eye(3) / m for m in masses]), wp.mat33d)
    partner, cross = arr(np.full(len(masses), -1, np.int32), wp.int32), wp.zeros(len(masses), dtype=wp.mat33d,
                                                                                  device=device)
    fixed = wp.zeros(len(masses), dtype=wp.int32, device=device)
    co = _coarse(len(masses), c_count, device)
    start = np.zeros((c_count, 3))
    if warm is not None:
        start[:, 0] = warm
    impulse = arr(start, wp.vec3d)
    v_hat = arr(v0, wp.vec3d)
    node_share = wp.full(len(masses), 7, dtype=wp.int32, device=device)  # stale counts: the kernel zeroes them
    body_share = wp.zeros(1, dtype=wp.int32, device=device)
    sweep, stats = wp.zeros(1, dtype=wp.int32, device=device), wp.full(3, 5.0, dtype=wp.float64, device=device)
    change = wp.zeros(c_count, dtype=wp.vec3d, device=device)
    zeros = wp.zeros(c_count, dtype=wp.float64, device=device)
    pass_inputs = [count, live, *stencil, arr(frames, wp.mat33d), arr(gap, wp.float64), zeros, rigid_node,
                   rigid_lever, d_inv, partner, cross, fixed, DT, impulse, v_hat, zeros,
                   wp.zeros(c_count, dtype=wp.vec3d, device=device), co, node_share, body_share,
                   wp.zeros(c_count, dtype=wp.mat33d, device=device)]
    if form == "true masses":  # (one thread: each pass updates every contact, then pushes them all)
        metric = np.array([f @ (sum(w * w / masses[k] for k, w in zip(*stencils[c])) * np.eye(3)) @ f.T
                           for c, f in enumerate(frames)])  # J M^-1 J^T's blocks in the contacts' frames
        pass_inputs[-1] = arr(metric, wp.mat33d)
        (_count, _live, *rest), movable = pass_inputs, arr(np.ones(c_count, np.int32), wp.int32)
        threads = 1 if lanes == _bk.CONTACT_BLOCK_THREADS else lanes
        wp.launch(_pk.contact_step_unshared, dim=threads, device=device,
                  inputs=[count, movable, *rest[:-3], rest[-1], 8, change, live, sweep, stats, passes, threads])
        return impulse.numpy(), v_hat.numpy(), frames, v0, gap
    (_count, _live, *rest), movable = pass_inputs, arr(np.ones(c_count, np.int32), wp.int32)
    live.fill_(0 if warm is not None else 1)  # the start stage's screen must set it
    no_tools = wp.zeros(1, dtype=wp.int32, device=device)
    n, lanes_max = len(masses), max(lanes, _bk.CONTACT_BLOCK_THREADS)
    scratch = [wp.zeros(n, dtype=wp.int32, device=device), wp.zeros(n, dtype=wp.int32, device=device),
               wp.zeros(1, dtype=wp.int32, device=device), wp.zeros(1, dtype=wp.int32, device=device),
               wp.zeros(n, dtype=wp.vec3d, device=device), wp.zeros(1, dtype=wp.vec3d, device=device),
               wp.zeros(1, dtype=wp.vec3d, device=device), wp.zeros(lanes_max + 1, dtype=wp.int32, device=device),
               wp.zeros(lanes_max, dtype=wp.int32, device=device), wp.zeros(c_count, dtype=wp.int32, device=device),
               wp.zeros(1, dtype=wp.int32, device=device)]
    wp.launch_tiled(_bk.contact_step_block, dim=[1], block_dim=lanes, device=device,
                    inputs=[count, movable, *rest[:-1], 8, live, sweep, stats, no_tools, live,
                            int(warm is not None), 0, passes, 1, *scratch])
    if warm is not None:
        assert sweep.numpy()[0] == 1 and not stats.numpy().any()  # the sweep started
    return impulse.numpy(), v_hat.numpy(), frames, v0, gap


def _pushed(v0, lam, frames, stencils=STENCILS, masses=MASSES):
    """``v0 + M^-1 J^T lambda`` [n, 3] [m/s] for the impulses ``lam`` [c, 3] [N s] in the frames."""
    world = np.einsum("ci,cij->cj", lam, frames)
    pushed = v0.copy()
    for c, (nodes, weights) in enumerate(stencils):
        for node, wt in zip(nodes, weights):
            pushed[node] += wt * world[c] / masses[node]
    return pushed


def _lcp(frames, v0, gap, stencils=STENCILS, masses=MASSES):
    """SciPy's solution of the frictionless LCP (module docstring) [c] [N s]."""
    j = _jacobian(frames, stencils, masses)
    m_inv = np.diag(np.repeat(1.0 / masses, 3))
    w = j @ m_inv @ j.T
    q = j @ v0.ravel() + gap / DT
    lower = scipy.linalg.cholesky(w, lower=True)
    lam, _ = scipy.optimize.nnls(lower.T, -scipy.linalg.solve_triangular(lower, q, lower=True))
    return lam, w, q


@pytest.fixture(params=["one lane", "lanes"])
def lanes(request, device, monkeypatch):
    """Lanes of the block: CONTACT_BLOCK_THREADS (one on the CPU), or 4 (fewer than the six
    contacts, so a lane takes several; on the CPU as cooperative fibers)."""
    if request.param == "one lane":
        return _bk.CONTACT_BLOCK_THREADS
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    return 4


@pytest.mark.parametrize("warm", [None, "guess"])
def test_jacobi_passes_on_split_masses_reach_the_lcp_solution(device, lanes, warm):
    """Shared nodes (each by 2-3 contacts), the block's passes (with 4 lanes, the shared nodes
    split across them: Jacobi on split masses), from zero impulses or from a guess that the start stage first applies to ``v^`` (and screens the
    contacts: all of them are pushed or press): the normal impulses reach SciPy's LCP
    solution, the tangents stay 0 (no friction), and the velocities in ``v^`` are ``v0 + M^-1
    J^T lambda`` (the atomic pushes lose nothing, the guess's push counted once). Tolerance: the
    iteration contracts the error geometrically (a convergent splitting of W: the block module's
    docstring); 400 passes take this 6-contact set to rounding, 1e-9 relative."""
    guess = None if warm is None else np.array([0.5, 0.1, 0.0, 0.3, 0.2, 0.0])  # [N s]
    lam, v, frames, v0, gap = _solve(device, lanes=lanes, warm=guess)
    expected, w, q = _lcp(frames, v0, gap)
    assert (expected > 0).sum() >= 2 and (expected == 0).sum() >= 1  # pushing and separating contacts both
    np.testing.assert_allclose(lam[:, 0], expected, rtol=1e-9, atol=1e-9 * expected.max())
    np.testing.assert_allclose(lam[:, 1:], 0.0, atol=1e-12)
    np.testing.assert_allclose(v, _pushed(v0, lam, frames), atol=1e-12)
    # Complementarity in the velocities themselves: w = W lambda + q >= 0, 0 where it pushes.
    w_after = w @ lam[:, 0] + q
    assert (w_after >= -1e-9).all()
    np.testing.assert_allclose(w_after[lam[:, 0] > 0], 0.0, atol=1e-9)


def test_jacobi_passes_on_the_true_masses_miss_the_lcp_solution(device):
    """The reason for the split masses: the same passes on the true masses (every share 1)
    overshoot the shared nodes and do not reach the solution."""
    lam, _, frames, v0, gap = _solve(device, form="true masses")
    expected, _, _ = _lcp(frames, v0, gap)
    assert not np.allclose(lam[:, 0], expected, rtol=1e-3, atol=1e-3 * expected.max())


#: Contacts that share no node (a two-node one and three one-node ones), one separating.
APART = [((0, 1), (0.5, 0.5)), ((2,), (1.0,)), ((3,), (1.0,)), ((4,), (1.0,))]
APART_GAPS = np.array([-0.001, 0.0, 0.002, 0.05])  # [m]
APART_MASSES = np.array([1.0, 2.0, 1.5, 0.5, 3.0])  # [kg]


def test_contacts_that_share_nothing_reach_the_lcp_solution_in_one_launch_without_barriers(device):
    """The launch for contacts that share no node (contact_step_unshared: each thread takes its
    contacts through the warm start, the screen and every pass, no thread waiting for another),
    3 threads striding over 4 contacts from a guess: SciPy's LCP solution and ``v^ = v0 + M^-1
    J^T lambda``. Tolerance: each contact alone is solved exactly by its first pass (its block
    is all of W's row), so to rounding, 1e-12."""
    guess = np.array([0.2, 0.0, 0.4, 0.1])  # [N s]
    lam, v, frames, v0, gap = _solve(device, form="true masses", lanes=3, warm=guess, stencils=APART,
                                     gaps=APART_GAPS, masses=APART_MASSES)
    expected, _, _ = _lcp(frames, v0, gap, APART, APART_MASSES)
    assert (expected > 0).sum() >= 2 and (expected == 0).sum() >= 1
    np.testing.assert_allclose(lam[:, 0], expected, rtol=1e-12, atol=1e-12 * expected.max())
    np.testing.assert_allclose(v, _pushed(v0, lam, frames, APART, APART_MASSES), atol=1e-12)


#: The candy pile's landing in small: one vertex (node 0, 0.05 kg) pressed into four triangles of
#: another body (nodes 1-4 and 5, the triangles' points' weights) with normals within ~17 degrees
#: of +z: four redundant contacts on one hub node, and a fifth contact on the triangles' side.
HUB = [((0, 1, 2), (1.0, -0.5, -0.5)), ((0, 2, 3), (1.0, -0.5, -0.5)), ((0, 3, 4), (1.0, -0.5, -0.5)),
       ((0, 4, 1), (1.0, -0.5, -0.5)), ((5, 1), (1.0, -0.3))]
HUB_GAPS = np.array([0.0, -0.0005, 0.0002, -0.0002, 0.0])  # [m]
HUB_MASSES = np.array([0.05, 1.0, 1.0, 1.0, 1.0, 0.5])  # [kg]
HUB_PASSES = 12


def test_a_hub_nodes_redundant_contacts_meet_the_lcp_in_a_dozen_passes_gauss_seidel_within_its_lane(device, lanes):
    """Four contacts on one light vertex (redundant: their rows of J nearly parallel), taken by
    one lane in turn (the vertex is private to it: Gauss-Seidel on its true mass), the triangles'
    shared nodes split across lanes: after HUB_PASSES passes from zero the impulses meet the
    LCP's conditions (eq. 5.5, frictionless normal rows): lambda >= 0, ``w = W lambda + q >=
    0``, ``lambda w = 0`` (the impulses are not unique, the velocities are), ``v^ = v0 + M^-1
    J^T lambda``. Tolerance: 1e-6 m/s against velocities of ~1 m/s. The four contacts in one lane
    on the vertex's true mass are Gauss-Seidel passes over them, which meet it in 12; Jacobi over
    them on the 4-fold split vertex does not (every node taken as shared: this test fails; the
    candy's landing stall, docs/benchmarks.md, session 19)."""
    lam, v, frames, v0, gap = _solve(device, lanes=lanes, stencils=HUB, gaps=HUB_GAPS, masses=HUB_MASSES,
                                     passes=HUB_PASSES)
    j = _jacobian(frames, HUB, HUB_MASSES)
    w = j @ np.diag(np.repeat(1.0 / HUB_MASSES, 3)) @ j.T
    q = j @ v0.ravel() + HUB_GAPS / DT
    normal = lam[:, 0]
    after = w @ normal + q
    assert (normal > 0).sum() >= 2
    assert (normal >= 0).all() and (after >= -1e-6).all()
    np.testing.assert_allclose(normal * after, 0.0, atol=1e-6 * normal.max())
    np.testing.assert_allclose(v, _pushed(v0, lam, frames, HUB, HUB_MASSES), atol=1e-12)
