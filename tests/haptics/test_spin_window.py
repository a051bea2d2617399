"""The haptic loop's spin window (softvr.haptics.loop._SpinWindow) against known sleep overshoots.

The loop (thesis 5.4: forces at 1 kHz) sleeps until a window before each tick and spins the
rest; the window is the 99th percentile of its sleeps' overshoots plus a margin. Truth: the
quantiles of the overshoot distributions the tests draw from, and a synthetic clock whose only
time is the sleeps' and one microsecond a clock read (the spinning).
"""

import numpy as np

from softvr.haptics import MouseDevice
from softvr.haptics.loop import (SPIN_CAP, SPIN_FLOOR, SPIN_MARGIN, SPIN_SAMPLES, SPIN_UPDATE, HapticLoop,
                                 _run, _SpinWindow)

US = 1e-6


def test_the_window_is_the_overshoots_99th_percentile_plus_the_margin_within_its_bounds():
    rng = np.random.default_rng(3)
    # Uniform on [10, 60] us: p99 = 10 + 0.99 * 50 = 59.5 us; the order statistic of 1024 draws
    # has a standard deviation of 50 sqrt(0.99 * 0.01 / 1024) = 0.16 us: 1 us is 6 of them.
    for cases, expected in (((10 * US, 60 * US), 59.5 * US + SPIN_MARGIN), ((0.0, 5 * US), SPIN_FLOOR),
                            ((1e-3, 4e-3), SPIN_CAP)):
        window = _SpinWindow()
        assert window.seconds == SPIN_CAP  # until it has seen enough
        for overshoot in rng.uniform(*cases, SPIN_SAMPLES):
            window.record(overshoot)
        assert abs(window.seconds - expected) < 1 * US, (cases, window.seconds)
    # It follows a change: the last SPIN_SAMPLES overshoots only.
    for overshoot in rng.uniform(10 * US, 30 * US, SPIN_SAMPLES + SPIN_UPDATE):
        window.record(overshoot)
    assert abs(window.seconds - (29.8 * US + SPIN_MARGIN)) < 1 * US


class _Clock:
    """Synthetic time [s]: a sleep lasts what it was asked plus an overshoot drawn uniform on
    [10, 60] us, a clock read 1 us (a spin's cost). Counts the time slept after ``warm`` [s]."""

    def __init__(self, seed: int, warm: float):
        self.t, self.rng, self.warm, self.slept = 0.0, np.random.default_rng(seed), warm, 0.0

    def clock(self) -> float:
        self.t += US
        return self.t

    def sleep(self, seconds: float) -> None:
        took = seconds + self.rng.uniform(10 * US, 60 * US)
        if self.t >= self.warm:
            self.slept += took
        self.t += took


class _StopAfter:
    def __init__(self, ticks: int):
        self.left = ticks

    def is_set(self) -> bool:
        self.left -= 1
        return self.left < 0


def test_on_a_synthetic_clock_the_loop_ticks_on_time_and_spins_only_the_window_less_the_overshoot():
    loop = HapticLoop(MouseDevice())
    ticks, warm = 3000, 300  # the window is learnt from the 128th sleep on
    time = _Clock(seed=5, warm=warm * 1e-3)
    _run(loop._shared, loop.device, 1e-3, 10.0, _StopAfter(ticks), clock=time.clock, sleep=time.sleep)
    assert loop.ticks == ticks
    periods = loop._data[25:25 + ticks - 1]
    # Every overshoot (<= 60 us) falls inside the learnt window (79.5 us): each tick is taken within
    # the clock reads after its time (1 us each), so a period is 1 ms within 2 us.
    assert np.abs(periods[warm:] - 1e-3).max() <= 2 * US + 1e-12
    # What is not slept is spun (and the loop's few clock reads outside the spin, 1 us each): the
    # window less the mean overshoot, 79.5 - 35 = 44.5 us a tick, where the old fixed 0.2 ms window
    # spun 165 us. The mean of 2 700 overshoots has a standard deviation of 50 / sqrt(12 * 2700) = 0.28 us.
    awake = ((time.t - warm * 1e-3) - time.slept) / (ticks - warm)
    assert 44.5 * US - 2 * US < awake < 44.5 * US + 6 * US, awake
