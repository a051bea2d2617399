"""One tick of the haptic loop renders the published linearization (thesis 5.4, multi-rate):
F = F0 + K (x - x0), clipped to max_force along its direction. Truth: the formula evaluated here
with NumPy's matrix product on models with a non-symmetric K (a transposed K or a swapped
difference differs by O(1) of the force)."""

import numpy as np

from softvr.haptics import HandleModel, HapticLoop, MouseDevice


def test_a_tick_renders_f0_plus_k_times_the_handles_offset_clipped_to_max_force():
    rng = np.random.default_rng(11)
    for _ in range(20):
        x, x0 = rng.normal(scale=0.02, size=3), rng.normal(scale=0.02, size=3)  # [m]
        f0, k = rng.normal(size=3), rng.normal(scale=300.0, size=(3, 3))  # [N], [N/m]
        expected = f0 + k @ (x - x0)
        for max_force in (1e3, 0.5 * np.linalg.norm(expected)):
            loop = HapticLoop(MouseDevice(position=x), max_force=max_force)
            loop.publish(HandleModel(position=x0, force=f0, stiffness=k))
            force = loop.tick()
            clipped = expected * min(1.0, max_force / np.linalg.norm(expected))
            # Sums of three products of O(1) N: a few ulps of 10 N.
            np.testing.assert_allclose(force, clipped, rtol=0, atol=1e-12)
            np.testing.assert_array_equal(loop.last_force(), force)
            np.testing.assert_array_equal(loop.handle_position(), x)
