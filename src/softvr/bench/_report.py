"""The end of every ``softvr bench`` run: the table, the run's wall time and load, the files."""

from __future__ import annotations

import numpy as np

from softvr.files import write_json
from softvr.render.figure import save_figure

__all__ = ["bench_parser", "print_and_write", "save_figure", "steady", "step_times"]


def steady(per_step):
    """The steady state of a per-step sequence [n]: the steps after the first (which loads the
    scene), or the one step when there is only one."""
    return per_step[1:] if len(per_step) > 1 else per_step


def step_times(step_s) -> dict:
    """A played scene's per-step wall times, summarised as the steady state and the first step.

    The first step of a scene loads it into the solver (kernel modules, launch recording, the
    first factorizations): hundreds of ms that a player pays once, before the user touches
    anything. It is reported apart as a load time, and "ms a step" is the steady state.

    Parameters
    ----------
    step_s : array_like, shape (n,) [s]
        Wall time of each step, in order; ``n >= 1``.

    Returns
    -------
    dict
        ``ms_per_step`` / ``ms_per_step_median`` / ``ms_per_step_p95`` [ms]: mean, median and 95th
        percentile of the steps after the first (all steps when there is only one);
        ``first_step_ms`` [ms]: the first step; ``ms_per_step_with_first`` [ms]: the mean of all.
    """
    ms = 1e3 * np.asarray(step_s, dtype=float)
    if ms.ndim != 1 or not len(ms):
        raise ValueError(f"step times: expected a 1-D sequence of at least one step, found shape {ms.shape}")
    after = steady(ms)
    return {"ms_per_step": float(after.mean()), "ms_per_step_median": float(np.median(after)),
            "ms_per_step_p95": float(np.percentile(after, 95)), "first_step_ms": float(ms[0]),
            "ms_per_step_with_first": float(ms.mean())}


def bench_parser(area: str, description: str, *, quick: str, plot: str):
    """The command line every ``softvr bench AREA`` shares: ``--quick`` (help ``quick``),
    ``--json PATH``, ``--plot PATH`` (help ``plot``), ``--no-progress``; add the area's own."""
    import argparse  # noqa: PLC0415

    p = argparse.ArgumentParser(prog=f"softvr bench {area}", description=description)
    p.add_argument("--quick", action="store_true", help=quick)
    p.add_argument("--json", metavar="PATH", help="write all results as JSON")
    p.add_argument("--plot", metavar="PATH", help=plot)
    p.add_argument("--no-progress", action="store_true")
    return p


def print_and_write(result: dict, table: str, json_path, plot_path, write_plot, *, after_table: str = "") -> None:
    """Print ``table`` and the wall time / load average line of ``result`` (keys ``wall_s``,
    ``loadavg_start``, ``loadavg_end``, ``machine.cores``), then ``after_table``; write the
    JSON to ``json_path`` and ``write_plot(result, plot_path)`` when those are given."""
    print(table)
    print(f"\nwall time {result['wall_s']:.0f} s; load average at start {result['loadavg_start']}, "
          f"at end {result['loadavg_end']} ({result['machine']['cores']} cores)")
    if after_table:
        print()
        print(after_table)
    if json_path:
        write_json(result, json_path)
        print(f"wrote {json_path}")
    if plot_path:
        write_plot(result, plot_path)
        print(f"wrote {plot_path}")
