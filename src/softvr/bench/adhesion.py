"""``softvr bench adhesion``: the candy scene (thesis Fig. 4.1) with and without adhesion.

Both runs use :func:`softvr.bench.contact.run_candy` on the same scene, one after the other in
this process: the Jell-O block and eight candies, 8 ms steps, 0.8 s simulated (``--quick``:
the small scale, 0.16 s). Reported per run: ms per step (mean over all steps and over the
steps with contacts), contacts (mean / max), contacts pulling (negative normal impulse:
adhesion at work), PGS sweeps (mean / max) and the largest normal-velocity residual. The cost
of adhesion at equal contact count is the ratio of the mean ms per contact-step of the steps
with contacts (adhesive / plain). The plot is the thesis' Fig. 4.4: contacts and ms per step
over time, with and without adhesion.

Targets (issue): the whole candy scene in real time (<= 8 ms per 8 ms step; the thesis took
400 ms with adhesion, 250 ms without), and adhesion's cost at equal contact count <= 1.2x
plain contact.

Examples
--------
``softvr bench adhesion --quick`` (seconds), or the full run
``softvr bench adhesion --json bench-results/adhesion.json --plot docs/img/bench_adhesion.png``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from softvr.bench.contact import _git_commit, run_candy
from softvr.bench._report import print_and_write
from softvr.bench.volume import _atomic_write, _loadavg, _machine_info

__all__ = ["TARGET_COST_RATIO", "format_table", "main", "run_adhesion_bench", "write_plot"]

#: Adhesion's cost at equal contact count, x plain contact.
TARGET_COST_RATIO = 1.2
#: Thesis 4.4: seconds per 8 ms step with and without adhesion (1.8 GHz Core 2 Duo).
THESIS_S_PER_STEP = {"adhesion": 0.4, "plain": 0.25}


def _cost_per_contact(run: dict) -> float | None:
    """Mean of ms per contact over the steps with contacts."""
    ms = 1e3 * np.asarray(run["trace"]["step_s"])
    contacts = np.asarray(run["trace"]["contacts"])
    busy = contacts > 0
    return float(np.mean(ms[busy] / contacts[busy])) if busy.any() else None


def run_adhesion_bench(*, quick: bool = False, progress: bool = True) -> dict:
    """Run the candy scene without, then with adhesion; returns the JSON-ready result."""
    from softvr.device import resolve_device

    resolve_device("cpu")
    t0 = time.perf_counter()
    load_start = _loadavg()
    runs = {"plain": run_candy(quick=quick, progress=progress, adhesion=False),
            "adhesion": run_candy(quick=quick, progress=progress, adhesion=True)}
    for name, run in runs.items():
        run["ms_per_contact"] = _cost_per_contact(run)
        run["pulling_contacts_max"] = int(max(run["trace"]["pulling_contacts"]))
        run["thesis_s_per_step"] = THESIS_S_PER_STEP[name]
    plain, sticky = runs["plain"]["ms_per_contact"], runs["adhesion"]["ms_per_contact"]
    ratio = None if not plain or sticky is None else sticky / plain
    machine = _machine_info("cpu")
    machine["softvr_commit"] = _git_commit()
    return {
        "schema": "softvr-bench-adhesion/1",
        "machine": machine,
        "config": {"quick": quick, "scene": "softvr.examples.example_candy"},
        "runs": runs,
        "targets": {"real_time_ms": runs["adhesion"]["dt_s"] * 1e3,
                    "real_time_met": runs["adhesion"]["ms_per_step"] <= runs["adhesion"]["dt_s"] * 1e3,
                    "cost_ratio": ratio, "cost_ratio_target": TARGET_COST_RATIO,
                    "cost_ratio_met": None if ratio is None else ratio <= TARGET_COST_RATIO},
        "loadavg_start": load_start,
        "loadavg_end": _loadavg(),
        "wall_s": time.perf_counter() - t0,
    }


def format_table(result: dict) -> str:
    runs = result["runs"]
    any_run = runs["plain"]
    lines = [f"Candy scene (thesis Fig. 4.1): {any_run['tets']} tets, {any_run['collision_triangles']} collision "
             f"triangles, {any_run['bodies']} bodies, dt {any_run['dt_s'] * 1e3:g} ms, {any_run['steps']} steps"
             + (" (quick scale)" if result["config"]["quick"] else "")]
    head = (f"{'run':<9} {'ms/step':>8} {'in contact':>10} {'contacts':>13} {'pulling':>7} {'PGS sweeps':>13} "
            f"{'residual':>9} {'ms/contact':>10} {'thesis ms':>9}")
    lines += [head, "-" * len(head)]
    for name, r in runs.items():
        lines.append(f"{name:<9} {r['ms_per_step']:>8.0f} {r['ms_per_step_in_contact'] or 0:>10.0f} "
                     f"{r['contacts_mean']:>6.0f} / {r['contacts_max']:<4d} {r['pulling_contacts_max']:>7d} "
                     f"{r['pgs_iterations_mean']:>6.0f} / {r['pgs_iterations_max']:<4d} {r['residual_max_m_s']:>9.2g} "
                     f"{r['ms_per_contact'] or 0:>10.3f} {r['thesis_s_per_step'] * 1e3:>9.0f}")
    t = result["targets"]
    ratio = "-" if t["cost_ratio"] is None else f"{t['cost_ratio']:.2f}x"
    lines += ["", f"targets: real time {runs['adhesion']['ms_per_step']:.0f} ms per {t['real_time_ms']:g} ms step -> "
                  f"{'MET' if t['real_time_met'] else 'NOT met'}; adhesion's cost at equal contact count {ratio} vs "
                  f"<= {TARGET_COST_RATIO:g}x -> {'MET' if t['cost_ratio_met'] else 'NOT met'}"]
    return "\n".join(lines)


def write_plot(result: dict, path) -> None:
    """PNG like thesis Fig. 4.4: contacts and ms per step over time, with and without adhesion."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for name, color in (("plain", "tab:blue"), ("adhesion", "tab:red")):
        r = result["runs"][name]
        t = (np.arange(len(r["trace"]["contacts"])) + 1) * r["dt_s"]
        axes[0].plot(t, r["trace"]["contacts"], color=color, label=name)
        axes[1].plot(t, 1e3 * np.asarray(r["trace"]["step_s"]), color=color, label=name)
    axes[0].set(xlabel="time [s]", ylabel="contacts", title="contact constraints per step")
    axes[1].set(xlabel="time [s]", ylabel="ms per step", title="time per 8 ms step")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    m = result["machine"]
    fig.suptitle(f"candy scene with and without adhesion - {m['cpu_model']}, {m['cores']} cores, {m['date'][:10]}",
                 fontsize=9)
    fig.tight_layout()

    def save(tmp):
        fig.savefig(tmp, format="png", dpi=110)

    try:
        _atomic_write(Path(path), save)
    finally:
        plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """``softvr bench adhesion [--quick] [--json PATH] [--plot PATH]``."""
    p = argparse.ArgumentParser(prog="softvr bench adhesion",
                                description="The candy scene (thesis Fig. 4.1) with and without adhesion.")
    p.add_argument("--quick", action="store_true", help="the small candy scene, 0.16 s (seconds; CI)")
    p.add_argument("--json", metavar="PATH", help="write all results as JSON")
    p.add_argument("--plot", metavar="PATH", help="write a PNG: contacts and ms per step (thesis Fig. 4.4)")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    result = run_adhesion_bench(quick=a.quick, progress=not a.no_progress)
    print_and_write(result, format_table(result), a.json, a.plot, write_plot)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
