"""The end of every ``softvr bench`` run: the table, the run's wall time and load, the files."""

from __future__ import annotations

__all__ = ["print_and_write", "save_figure"]


def print_and_write(result: dict, table: str, json_path, plot_path, write_plot, *, after_table: str = "") -> None:
    """Print ``table`` and the wall time / load average line of ``result`` (keys ``wall_s``,
    ``loadavg_start``, ``loadavg_end``, ``machine.cores``), then ``after_table``; write the
    JSON to ``json_path`` and ``write_plot(result, plot_path)`` when those are given."""
    from softvr.bench.volume import write_json

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


def save_figure(fig, path) -> None:
    """Write a Matplotlib figure to ``path`` as PNG, atomically, then close it."""
    from pathlib import Path

    import matplotlib.pyplot as plt

    from softvr.bench.volume import _atomic_write

    try:
        _atomic_write(Path(path), lambda tmp: fig.savefig(tmp, format="png", dpi=110))
    finally:
        plt.close(fig)
