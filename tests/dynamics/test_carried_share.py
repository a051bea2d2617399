"""The node sweeps' first guess from the second step on (:func:`softvr.dynamics.node_arrays.record_start`;
``_node_kernels.share_sums``, ``share_total`` and ``start_guess``).

On the free nodes of a held body (one a chain of ``A``'s blocks ties to a fixed node,
:func:`~softvr.dynamics.node_arrays.free_bodies`) that no free body touches
(:func:`~softvr.dynamics.node_arrays.shared_bodies`) the guess for step t + 1 is ``v + a c`` with
``c = v - v_before`` last step's change; ``a`` is the mass-weighted least-squares coefficient of
the change each solve made, ``r_s = v_s+1 - v_s``, on the change carried into it, ``c_s``, over
the recent steps s with weights ``memory^(t - s)``:
``a = argmin sum_s memory^(t - s) sum_i m_i |r_s,i - a c_s,i|^2``, clipped to [0, 1]. A free
body's nodes carry all of ``c``: ``2 v - v_before``.

Checked against NumPy's least squares (``numpy.linalg.lstsq`` on the rows scaled by the square
roots of the weights) and against closed forms: a held body whose velocities follow
``v_s = v_0 + lam^s phi`` (a mode decaying by ``lam`` a step) fits ``a = lam`` and is then
guessed exactly; a mode reversing every step fits 0; and a free body's guessed momentum is the
exact impulse of free fall (``P_s + M g dt``, Newton's second law over the step) while the held
body beside it carries a share strictly inside (0, 1). The sums are of a few hundred products
of O(1) terms: the kernels and NumPy agree to ~1e-15 relative; 1e-12 leaves room and no fault
through.
"""

from types import SimpleNamespace

import numpy as np
import warp as wp

from softvr.dynamics.node_arrays import SHARE_MEMORY, free_bodies, record_start, shared_bodies

G = np.array([0.0, 0.0, -9.81])  # [m/s^2]
DT = 1.0 / 50.0  # [s]


def _model(mass, body_node_start, device, fixed=None, links=(), touching=()):
    """A bare model of ``mass`` [n] [kg] over bodies ``body_node_start`` [B + 1] (nodes
    ``fixed`` [n] bool): the block pattern of ``A`` ties each body's nodes in a chain and the
    node pairs ``links`` (couplings); the body pairs ``touching`` may collide."""
    n = len(mass)
    fixed = np.zeros(n, np.int32) if fixed is None else fixed.astype(np.int32)
    pairs = [(i, i) for i in range(n)] + [(i, i + 1) for a, b in zip(body_node_start[:-1], body_node_start[1:])
                                          for i in range(a, b - 1)] + list(links)
    pattern = sorted({p for a, b in pairs for p in ((a, b), (b, a))})
    rows = np.array([p[0] for p in pattern])
    pair_enabled = np.zeros((len(body_node_start) - 1,) * 2, np.int32)
    for a, b in touching:
        pair_enabled[a, b] = 1
    return SimpleNamespace(device=device, node_count=n, rigid=None, body_node_start=np.asarray(body_node_start),
                           pair_enabled=wp.array(pair_enabled, dtype=wp.int32, device=device),
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


def test_the_share_is_numpys_weighted_least_squares_over_the_held_bodies(device):
    rng = np.random.default_rng(3)
    mass, start = _bodies(rng, [15, 1, 24])
    n, steps = len(mass), 6
    fixed = np.zeros(n, bool)
    fixed[[3, 20, 31, 33]] = True  # the first and third bodies are held, the second free
    fitted = ~fixed
    fitted[start[1]:start[2]] = False
    v = [rng.standard_normal((n, 3))]
    change = rng.standard_normal((n, 3)) * 1e-2
    for _ in range(steps - 1):  # each change ~0.6 of the last one, noisy
        change = 0.6 * change + rng.standard_normal((n, 3)) * 3e-3
        v.append(np.where(fixed[:, None], 0.0, v[-1] + change))
    guesses = _guesses(np.array(v), mass, start, device, fixed)
    for t in range(2, steps):  # the guess of step t: the fit over the solves of steps 1 .. t - 1
        rows, rhs = [], []
        for s in range(1, t):
            w = np.sqrt(mass[fitted] * SHARE_MEMORY ** (t - 1 - s))[:, None]
            rows.append((w * (v[s] - v[s - 1])[fitted]).ravel())
            rhs.append((w * (v[s + 1] - v[s])[fitted]).ravel())
        a = np.linalg.lstsq(np.concatenate(rows)[:, None], np.concatenate(rhs), rcond=None)[0][0]
        assert 0.0 < a < 1.0  # the fit, not the clip, decides
        expected = np.where(fitted[:, None], v[t] + a * (v[t] - v[t - 1]), 2 * v[t] - v[t - 1])
        expected[fixed] = 0.0
        np.testing.assert_allclose(guesses[t], expected, rtol=0, atol=1e-12 * np.abs(v[t]).max(), err_msg=str(t))


def test_a_held_mode_decaying_by_lam_a_step_is_guessed_exactly_from_the_third_step(device):
    # v_s = v_0 + lam^s phi on a held body: its change lam^(s-1) (lam - 1) phi shrinks by lam a
    # step, so the fit finds a = lam and v_s + lam c_s is v_s+1 itself; the free body beside it
    # (free fall with the same mode) carries all of its change.
    lam = 0.625
    rng = np.random.default_rng(5)
    mass, start = _bodies(rng, [10, 14])
    fixed = np.zeros(len(mass), bool)
    fixed[0] = True
    phi, v0 = rng.standard_normal((2, len(mass), 3))
    phi[0] = v0[0] = 0.0
    fall = np.where(np.arange(len(mass))[:, None] >= start[1], DT * G, 0.0)
    v = np.array([v0 + s * fall + lam**s * phi for s in range(7)])
    guesses = _guesses(v[:-1], mass, start, device, fixed)
    np.testing.assert_allclose(guesses[0][1:], v[0][1:] + DT * G, rtol=0, atol=1e-15)  # the explicit step
    np.testing.assert_allclose(guesses[1], 2 * v[1] - v[0], rtol=0, atol=1e-15)  # no fit yet: all of it
    held = slice(0, start[1])
    for s in range(2, 6):
        np.testing.assert_allclose(guesses[s][held], v[s + 1][held], rtol=0, atol=1e-14, err_msg=str(s))
        np.testing.assert_allclose(guesses[s][start[1]:], (2 * v[s] - v[s - 1])[start[1]:], rtol=0, atol=1e-15)


def test_a_free_bodys_guess_carries_the_exact_impulse_of_free_fall_beside_a_fitted_share(device):
    # Free fall with changes that turn, beside a held body whose changes shrink ~half a step:
    # the fitted share lies strictly inside (0, 1) (read from the held body's guess), yet the
    # free bodies' guessed momentum is P_s + M g dt, the impulse of gravity over the step.
    rng = np.random.default_rng(6)
    mass, start = _bodies(rng, [9, 30, 2])
    n = len(mass)
    fixed = np.zeros(n, bool)
    fixed[0] = True
    free = np.arange(n) >= start[1]
    v, turn = [np.where(fixed[:, None], 0.0, rng.standard_normal((n, 3)))], np.zeros((n, 3))
    for s in range(5):
        turn = np.where(fixed[:, None], 0.0, 0.5 * turn + 0.05 * rng.standard_normal((n, 3)))
        v.append(v[-1] + np.where(free[:, None], DT * G, 0.0) + turn)
    guesses = _guesses(np.array(v), mass, start, device, fixed)
    for s in range(1, len(v)):
        for b in (1, 2):
            nodes = slice(start[b], start[b + 1])
            m = mass[nodes]
            impulse = (m[:, None] * guesses[s][nodes]).sum(0) - (m[:, None] * v[s][nodes]).sum(0)
            expected = (m[:, None] * (v[s] - v[s - 1])[nodes]).sum(0)  # the body's own last impulse
            np.testing.assert_allclose(impulse, expected, rtol=0, atol=1e-15 * m.sum(), err_msg=f"{s} {b}")
        if s >= 2:  # the share the held body's guess carried: neither all of its change nor none
            c = (v[s] - v[s - 1])[1:start[1]]
            share = np.sum((guesses[s] - v[s])[1:start[1]] * c) / np.sum(c * c)
            assert 0.05 < share < 0.95, (s, share)


def test_a_held_mode_reversing_every_step_carries_none_and_the_explicit_step_starts_again(device):
    rng = np.random.default_rng(2)
    mass, start = _bodies(rng, [6])
    fixed = np.zeros(6, bool)
    fixed[5] = True
    phi = np.where(fixed[:, None], 0.0, rng.standard_normal((6, 3)))
    v = np.array([(-1.0) ** s * phi for s in range(4)])
    guesses = _guesses(v, mass, start, device, fixed)
    np.testing.assert_allclose(guesses[2:], v[2:], rtol=0, atol=1e-15)  # a = 0: v itself
    state, first, carried = _guesser(mass, start, device, fixed)
    for s in range(3):  # the share fitted 0 ...
        state.v.assign(wp.array(v[s], dtype=wp.vec3d, device=device))
        (carried if s else first)()
    first()  # ... a restore: the explicit step, then all of the change until a fit exists
    state.v.assign(wp.array(v[3], dtype=wp.vec3d, device=device))
    carried()
    np.testing.assert_allclose(state.sweep_buffers[0].numpy(), 2 * v[3] - v[2], rtol=0, atol=1e-15)


def test_held_bodies_share_unless_a_free_body_touches_them(device):
    # Bodies of 3 nodes: 0 -- 1 coupled, 1 has a fixed node: both held; 2 -- 3 coupled, free;
    # 4 alone with a fixed node: held; 5 alone: free; 6 held, touching 0 (held) only; 5's
    # surface meets 4's: 4 carries all of its change, as the free bodies do.
    start = np.arange(0, 22, 3)
    fixed = np.zeros(21, bool)
    fixed[[4, 12, 18]] = True
    model = _model(np.full(21, 1e-3), start, device, fixed, links=[(2, 3), (7, 9)], touching=[(5, 4), (0, 6)])
    assert free_bodies(model).tolist() == [False, False, True, True, False, True, False]
    assert shared_bodies(model).tolist() == [True, True, False, False, False, False, True]
