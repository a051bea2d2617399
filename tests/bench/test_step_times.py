"""The benches' "ms a step" is the steady state; the first step (loading the scene) stands apart.

Truth: arithmetic on a hand-made sequence of step times. A first step of 500 ms followed by steps
of 4, 5 and 6 ms is 5 ms a step in the steady state (mean and median), 128.75 ms if the first
step were averaged in, and its 95th percentile (NumPy's linear interpolation) 5.9 ms.
"""

import pytest

from softvr.bench._report import step_times


def test_the_first_step_is_reported_apart_from_the_steady_state():
    t = step_times([0.500, 0.004, 0.005, 0.006])
    assert t["ms_per_step"] == pytest.approx(5.0)
    assert t["ms_per_step_median"] == pytest.approx(5.0)
    assert t["ms_per_step_p95"] == pytest.approx(5.9)
    assert t["first_step_ms"] == pytest.approx(500.0)
    assert t["ms_per_step_with_first"] == pytest.approx(128.75)


def test_a_single_step_is_its_own_steady_state():
    t = step_times([0.002])
    assert t["ms_per_step"] == pytest.approx(2.0) and t["first_step_ms"] == pytest.approx(2.0)


def test_no_steps_is_a_clear_error():
    with pytest.raises(ValueError, match="at least one step"):
        step_times([])
