"""The share of last step's velocity change that the node sweeps' first guess carries on
(``_node_kernels.carried_share`` and ``start_guess``; :func:`softvr.dynamics.node_arrays.record_start`).

The guess for step t + 1 is ``v + a (v - v_before)``; ``a`` is the mass-weighted least-squares
coefficient of the change each solve made, ``r_s = v_s+1 - v_s``, on the change carried into it,
``c_s = v_s - v_s-1``, over the recent steps s with weights ``memory^(t - s)``:
``a = argmin sum_s memory^(t - s) sum_i m_i |r_s,i - a c_s,i|^2``, clipped to [0, 1]. Checked
against NumPy's least squares (``numpy.linalg.lstsq`` on the rows scaled by the square roots of
the weights) and two closed forms: a uniformly accelerated body (free fall: every step changes
its velocity by the same ``g dt``, so the change carried on is exact and ``a`` = 1) and a mode
that reverses every step (``a`` clipped to 0). The sums are of a few hundred products of O(1)
terms: the kernel and NumPy agree to ~1e-15 relative; 1e-12 leaves room and no fault through.
Each check runs on every device, with the CPU's one thread walking all the nodes and with
several threads each summing a stride of them, then ``share_total`` adding their sums (CUDA's
path; 7 threads: strides of unequal length, and more threads than nodes in the smaller cases).
"""

import numpy as np
import pytest
import warp as wp

from softvr.dynamics import _node_kernels as _k

MEMORY = 0.9


@pytest.fixture(params=[1, 7], ids=["one-thread", "strided"])
def threads(request):
    """Threads of ``carried_share`` (1: the CPU's path; several: CUDA's, with ``share_total``)."""
    return request.param


def _launch_share(arrays, mass, fitted, memory, carried, share, device, threads):
    """One ``carried_share`` (and with several ``threads`` its ``share_total``) on ``device``."""
    partial = wp.zeros(threads, dtype=wp.vec2d, device=device)
    wp.launch(_k.carried_share, dim=threads, device=device,
              inputs=[*(wp.array(x, dtype=wp.vec3d, device=device) for x in arrays),
                      wp.array(mass, dtype=wp.float64, device=device),
                      wp.array(fitted.astype(np.int32), dtype=wp.int32, device=device), memory, carried, threads,
                      partial, share])
    if threads > 1:
        wp.launch(_k.share_total, dim=1, device=device, inputs=[partial, memory, carried, share])


def _share(steps, mass, fitted, device, threads, memory=MEMORY, share=(0.0, 0.0, 1.0)):
    """Runs ``carried_share`` over ``steps`` [(v, v_before, change), ...] in turn; the share after each."""
    s = wp.array(np.asarray(share, float), dtype=wp.float64, device=device)
    out = []
    for step in steps:
        _launch_share(step, mass, fitted, memory, 1, s, device, threads)
        out.append(float(s.numpy()[2]))
    return out


def test_the_share_is_numpys_weighted_least_squares_over_the_recent_steps(device, threads):
    rng = np.random.default_rng(3)
    n, steps = 40, 4
    mass = rng.uniform(1e-4, 3e-3, n)
    fitted = rng.random(n) > 0.2
    data = []
    for _ in range(steps):
        change = rng.standard_normal((n, 3)) * 1e-2
        v_before = rng.standard_normal((n, 3))
        v = v_before + 0.6 * change + rng.standard_normal((n, 3)) * 3e-3  # a true share near 0.6, noisy
        data.append((v, v_before, change))
    shares = _share(data, mass, fitted, device, threads)
    for t in range(steps):
        rows, rhs = [], []
        for s in range(t + 1):
            v, v_before, change = data[s]
            w = np.sqrt(mass[fitted] * MEMORY ** (t - s))[:, None]
            rows.append((w * change[fitted]).ravel())
            rhs.append((w * (v - v_before)[fitted]).ravel())
        a = np.linalg.lstsq(np.concatenate(rows)[:, None], np.concatenate(rhs), rcond=None)[0][0]
        assert 0.0 < a < 1.0  # the fit, not the clip, decides
        assert abs(shares[t] - a) <= 1e-12 * abs(a), (t, shares[t], a)


def test_a_uniformly_accelerated_body_carries_all_of_its_change(device, threads):
    # Free fall: v_s = v_0 + s g dt, so each solve's change equals the one carried into it.
    # Velocities on a 2^-10 m/s grid (g dt = -168/1024, ~9.8/60) make every v_s and change exact
    # in float64, so both sums add the same terms on any device, in any order: 1 exactly.
    n = 12
    mass = np.full(n, 1e-3)
    step = np.tile([0.0, 0.0, -168.0 / 1024.0], (n, 1))
    v0 = np.random.default_rng(1).integers(-2048, 2048, (n, 3)) / 1024.0
    data = [(v0 + (s + 1) * step, v0 + s * step, step) for s in range(3)]
    assert _share(data, mass, np.ones(n, bool), device, threads) == [1.0, 1.0, 1.0]


def test_a_mode_reversing_every_step_carries_none_and_the_explicit_step_starts_again(device, threads):
    n = 6
    mass = np.full(n, 1e-3)
    change = np.random.default_rng(2).standard_normal((n, 3))
    v_before = np.zeros((n, 3))
    assert _share([(v_before - change, v_before, change)], mass, np.ones(n, bool), device, threads) == [0.0]
    # After an explicit step (carried 0) the sums start again: all of the change, until a fit exists.
    s = wp.array([5.0, 2.0, 0.3], dtype=wp.float64, device=device)
    z = np.zeros((n, 3))
    _launch_share((z, z, z), mass, np.ones(n, bool), MEMORY, 0, s, device, threads)
    assert s.numpy().tolist() == [0.0, 0.0, 1.0]


def test_the_guess_carries_the_share_and_keeps_the_change(device):
    rng = np.random.default_rng(4)
    n = 8
    v, v_before = rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
    fixed = np.zeros(n, np.int32)
    fixed[2] = 1
    fixed_velocity = rng.standard_normal((n, 3))
    arrays = {name: wp.array(x, dtype=wp.vec3d, device=device) for name, x in
              (("v", v), ("before", v_before), ("fv", fixed_velocity), ("ext", np.zeros((n, 3))))}
    change, guess, prev = (wp.zeros(n, dtype=wp.vec3d, device=device) for _ in range(3))
    share = wp.array([0.0, 0.0, 0.35], dtype=wp.float64, device=device)
    wp.launch(_k.start_guess, dim=n, device=device,
              inputs=[arrays["v"], arrays["ext"], wp.full(n, 1e-3, dtype=wp.float64, device=device),
                      wp.vec3d(0.0, 0.0, -9.81), 1.0 / 60.0, 1, wp.array(fixed, dtype=wp.int32, device=device),
                      arrays["fv"], arrays["before"], share, change, guess, prev])
    expected = v + 0.35 * (v - v_before)
    expected[2] = fixed_velocity[2]
    np.testing.assert_allclose(guess.numpy(), expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(prev.numpy(), guess.numpy())
    np.testing.assert_allclose(change.numpy(), v - v_before, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(arrays["before"].numpy(), v)
