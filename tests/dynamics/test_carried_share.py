"""The node sweeps' first guess from the second step on (:func:`softvr.dynamics.node_arrays.record_start`;
``_node_kernels.body_changes``, ``share_total`` and ``start_guess``).

Last step's change ``c = v - v_before`` is split per free body (one no block of ``A`` ties to a
fixed node) into its mass-weighted mean ``c_b`` and the deviations ``d = c - c_b`` (a held
body's ``c_b`` is 0); the guess is ``v + c_b + a d``. ``a`` is the mass-weighted least-squares coefficient of the
deviation each solve made, ``r_s - r_s,b`` (``r_s = v_s+1 - v_s``), on the deviation carried
into it, ``d_s``, over the recent steps s with weights ``memory^(t - s)``:
``a = argmin sum_s memory^(t - s) sum_i m_i |r_s,i - r_s,b - a d_s,i|^2``, clipped to [0, 1].

Checked against NumPy's least squares (``numpy.linalg.lstsq`` on the rows scaled by the square
roots of the weights, the deviations formed in NumPy) and against closed forms: a velocity
sequence ``v_s = v_0 + s g dt + lam^s phi`` (free fall plus a mode of zero momentum decaying by
``lam`` a step) fits ``a = lam`` and is then guessed exactly; a mode reversing every step fits 0;
and the guess's momentum, body by body, is the exact impulse of free fall (``P_s + M g dt``,
Newton's second law over the step) whatever share is fitted. The sums are of a few hundred
products of O(1) terms: the kernels and NumPy agree to ~1e-15 relative; 1e-12 leaves room and
no fault through.
"""

from types import SimpleNamespace

import numpy as np
import warp as wp

from softvr.dynamics import _node_kernels as _k
from softvr.dynamics.node_arrays import SHARE_MEMORY, free_bodies, record_start

G = np.array([0.0, 0.0, -9.81])  # [m/s^2]
DT = 1.0 / 50.0  # [s]


def _model(mass, body_node_start, device, fixed=None, links=()):
    """A bare model of ``mass`` [n] [kg] over bodies ``body_node_start`` [B + 1] (nodes
    ``fixed`` [n] bool): the block pattern of ``A`` ties each body's nodes in a chain and the
    node pairs ``links`` (couplings)."""
    n = len(mass)
    fixed = np.zeros(n, np.int32) if fixed is None else fixed.astype(np.int32)
    pairs = [(i, i) for i in range(n)] + [(i, i + 1) for a, b in zip(body_node_start[:-1], body_node_start[1:])
                                          for i in range(a, b - 1)] + list(links)
    pattern = sorted({p for a, b in pairs for p in ((a, b), (b, a))})
    rows = np.array([p[0] for p in pattern])
    return SimpleNamespace(device=device, node_count=n, rigid=None, body_node_start=np.asarray(body_node_start),
                           mass=wp.array(mass, dtype=wp.float64, device=device),
                           fixed=wp.array(fixed, dtype=wp.int32, device=device),
                           row_start=wp.array(np.searchsorted(rows, np.arange(n + 1)), dtype=wp.int32, device=device),
                           block_col=wp.array([p[1] for p in pattern], dtype=wp.int32, device=device))


def _guesser(mass, body_node_start, device, fixed=None):
    """``record_start`` on a bare model (:func:`_model`) and state: (state, first replay,
    carried replay)."""
    n = len(mass)
    model = _model(mass, body_node_start, device, fixed)
    state = SimpleNamespace(v=wp.zeros(n, dtype=wp.vec3d, device=device),
                            external=wp.zeros(n, dtype=wp.vec3d, device=device),
                            fixed_velocity=wp.zeros(n, dtype=wp.vec3d, device=device),
                            sweep_buffers=[wp.zeros(n, dtype=wp.vec3d, device=device) for _ in range(3)])
    first, carried = record_start(model, state, DT, G, wp.zeros(n, dtype=wp.vec3d, device=device))
    return state, first, carried


def _guesses(velocities, mass, body_node_start, device, fixed=None):
    """The first guesses [steps, n, 3] [m/s] of the steps whose start velocities are
    ``velocities`` [steps, n, 3] (the first step's explicit, the others carried)."""
    state, first, carried = _guesser(mass, body_node_start, device, fixed)
    out = []
    for s, v in enumerate(velocities):
        state.v.assign(wp.array(v, dtype=wp.vec3d, device=device))
        (carried if s else first)()
        out.append(state.sweep_buffers[0].numpy().copy())
    return np.array(out)


def _bodies(rng, sizes):
    """Node masses [n] [kg] and ``body_node_start`` [B + 1] for bodies of ``sizes`` nodes."""
    return rng.uniform(1e-4, 3e-3, sum(sizes)), np.concatenate([[0], np.cumsum(sizes)])


def _deviation(x, mass, start, fitted):
    """``x`` [n, 3] less each free body's mass-weighted mean over its ``fitted`` nodes (a body
    with an unfitted, i.e. fixed, node is held: none taken); 0 where not fitted."""
    out = np.where(fitted[:, None], x, 0.0)
    for b in range(len(start) - 1):
        nodes = np.arange(start[b], start[b + 1])
        if fitted[nodes].all():
            out[nodes] = x[nodes] - np.average(x[nodes], axis=0, weights=mass[nodes])
    return out


def test_the_share_is_numpys_weighted_least_squares_of_the_deviations(device):
    rng = np.random.default_rng(3)
    mass, start = _bodies(rng, [15, 1, 24])
    n, steps = len(mass), 6
    fixed = np.zeros(n, bool)
    fixed[[20, 31, 33]] = True  # the third body is held: the share on its whole change
    fitted = ~fixed
    v = [rng.standard_normal((n, 3))]
    change = rng.standard_normal((n, 3)) * 1e-2
    for _ in range(steps - 1):  # each change ~0.6 of the last one's deviation, noisy, plus a mean per body
        mean = np.repeat(rng.standard_normal((len(start) - 1, 3)), np.diff(start), axis=0)
        mean[start[2]:] = 0.0  # the held body's change follows its last one as a whole
        change = mean + 0.6 * _deviation(change, mass, start, fitted) + rng.standard_normal((n, 3)) * 3e-3
        v.append(v[-1] + change)
    guesses = _guesses(np.array(v), mass, start, device, fixed)
    for t in range(2, steps):  # the guess of step t: the fit over the solves of steps 1 .. t - 1
        rows, rhs = [], []
        for s in range(1, t):
            carried = _deviation(v[s] - v[s - 1], mass, start, fitted)
            made = _deviation(v[s + 1] - v[s], mass, start, fitted)
            w = np.sqrt(mass[fitted] * SHARE_MEMORY ** (t - 1 - s))[:, None]
            rows.append((w * carried[fitted]).ravel())
            rhs.append((w * made[fitted]).ravel())
        a = np.linalg.lstsq(np.concatenate(rows)[:, None], np.concatenate(rhs), rcond=None)[0][0]
        assert 0.0 < a < 1.0  # the fit, not the clip, decides
        c = v[t] - v[t - 1]
        d = _deviation(c, mass, start, fitted)
        expected = np.where(fixed[:, None], 0.0, v[t] + (c - d) + a * d)
        np.testing.assert_allclose(guesses[t], expected, rtol=0, atol=1e-12 * np.abs(v[t]).max(), err_msg=str(t))


def test_free_fall_with_a_decaying_mode_is_guessed_exactly_from_the_third_step(device):
    # v_s = v_0 + s g dt + lam^s phi, phi of zero momentum in each body: the change's body mean
    # is g dt every step and its deviation lam^(s-1) (lam - 1) phi shrinks by lam a step, so
    # the fit finds a = lam and v_s + g dt + lam d_s is v_s+1 itself.
    lam = 0.625  # exact in binary, as are the sequence's terms up to the rounding of lam^s
    rng = np.random.default_rng(5)
    mass, start = _bodies(rng, [10, 14])
    fitted = np.ones(len(mass), bool)
    phi = _deviation(rng.standard_normal((len(mass), 3)), mass, start, fitted)
    v0 = rng.standard_normal((len(mass), 3))
    v = np.array([v0 + s * DT * G + lam**s * phi for s in range(7)])
    guesses = _guesses(v[:-1], mass, start, device)
    np.testing.assert_allclose(guesses[0], v[0] + DT * G, rtol=0, atol=1e-15)  # the explicit step
    np.testing.assert_allclose(guesses[1], 2 * v[1] - v[0], rtol=0, atol=1e-15)  # no fit yet: all of it
    for s in range(2, 6):
        np.testing.assert_allclose(guesses[s], v[s + 1], rtol=0, atol=1e-14, err_msg=str(s))


def test_every_bodys_guess_carries_the_exact_impulse_of_free_fall_whatever_the_share(device):
    # Free fall with deviations: the fitted share lies strictly inside (0, 1) (checked),
    # yet each body's guessed momentum is P_s + M g dt, the impulse of gravity over the step.
    rng = np.random.default_rng(6)
    mass, start = _bodies(rng, [9, 30, 2])
    n = len(mass)
    v, d = [rng.standard_normal((n, 3))], np.zeros((n, 3))
    for s in range(5):  # deviations of zero momentum, each ~half the last one, noisy
        d = 0.5 * d + 0.05 * _deviation(rng.standard_normal((n, 3)), mass, start, np.ones(n, bool))
        v.append(v[-1] + DT * G + d)
    guesses = _guesses(np.array(v), mass, start, device)
    for s in range(1, len(v)):
        for b in range(len(start) - 1):
            nodes = slice(start[b], start[b + 1])
            m = mass[nodes]
            impulse = (m[:, None] * guesses[s][nodes]).sum(0) - (m[:, None] * v[s][nodes]).sum(0)
            np.testing.assert_allclose(impulse, m.sum() * DT * G, rtol=0, atol=1e-15 * m.sum(), err_msg=f"{s} {b}")
        if s >= 2:  # the share the guess carried: neither all of the deviations nor none
            d = v[s] - v[s - 1] - DT * G
            share = np.sum((guesses[s] - v[s] - DT * G) * d) / np.sum(d * d)
            assert 0.05 < share < 0.95, (s, share)


def test_a_mode_reversing_every_step_carries_none_and_the_explicit_step_starts_again(device):
    rng = np.random.default_rng(2)
    mass, start = _bodies(rng, [6])
    phi = _deviation(rng.standard_normal((6, 3)), mass, start, np.ones(6, bool))
    v = np.array([(-1.0) ** s * phi for s in range(4)])
    guesses = _guesses(v, mass, start, device)
    np.testing.assert_allclose(guesses[2:], v[2:], rtol=0, atol=1e-15)  # a = 0: v itself
    share = wp.array([5.0, 2.0, 0.3], dtype=wp.float64, device=device)
    wp.launch(_k.share_total, dim=1, device=device,
              inputs=[wp.zeros(1, dtype=wp.vec2d, device=device), SHARE_MEMORY, 0, share])
    assert share.numpy().tolist() == [0.0, 0.0, 1.0]


def test_a_body_is_held_where_a_chain_of_blocks_reaches_a_fixed_node(device):
    # Bodies of 3 nodes: 0 -- 1 coupled, 1 has a fixed node: both held; 2 -- 3 coupled, free;
    # 4 alone with a fixed node: held; 5 alone: free.
    start = np.arange(0, 19, 3)
    fixed = np.zeros(18, bool)
    fixed[[4, 12]] = True
    model = _model(np.full(18, 1e-3), start, device, fixed, links=[(2, 3), (7, 9)])
    assert free_bodies(model).tolist() == [False, False, True, True, False, True]
