"""Where a CUDA node step's device time goes, for a session lent a GPU (after
``scripts/device_check.sh`` installed Warp there): ``python3 scripts/device_profile.py [OUT]``.

1. Per kernel, for the candy pile, the shoulder and 64 cubes on one plane: Warp's activity timing
   (``wp.timing_begin``) over a few steps with every launch replayed on its own (the CUDA graphs
   of ``softvr.device.LaunchBatch`` off, so that each kernel is timed): launches, total and
   mean device time by kernel, and the device time's share of the step's wall time (the rest is
   the host: launching, the checks' syncs, the solver's decisions).
2. The candy's wall time a step, graphs on, with ``PARALLEL_PASS_FACTOR`` (passes of the
   one-block contact step a Gauss-Seidel pass stands for on the GPU) 1, 2 and 4: fewer passes a
   sweep against more sweeps (on the CPU's fibers: 77.5 and 63.2 sweeps a step with 1 and 2).
3. Each scene's wall time a step, graphs on: the whole step one graph (the default), the sweeps'
   stop decided on the device in four graphs a step (one read a solve:
   ``NodeSolve(device_loop=True)``), and the stop decided on the host (a read, i.e. a sync, every
   two sweeps): what the one graph and the device's loop save.

Prints a table per part and writes ``OUT/profile.json`` (default ``device-out``). ``python3
scripts/device_profile.py OUT cpu`` runs the same code on the CPU, one step each, as a dry run
(no device times: Warp times CUDA activity only), so that a typo costs no device time.
"""

from __future__ import annotations

import collections
import functools
import json
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

import softvr.contact.node_jacobi as node_jacobi
import softvr.device as device_module
import softvr.sim._node_step as node_step
from softvr.bench.contact import FULL_SCENE, softvr_scene
from softvr.scene import bundled, load_scene

WARMUP, STEPS = 15, 10
DEVICE = "cuda"


def _scene(name: str):
    """(step function, Scene) of a bundled scene on :data:`DEVICE`, or of 64 cubes ("cubes64");
    on the CPU (the dry run) with a CUDA step's host copies and GPU forms."""
    if name == "cubes64":
        sim, _ = softvr_scene(FULL_SCENE, DEVICE, 64)
        step = lambda: sim.step(FULL_SCENE.dt)  # noqa: E731
    else:
        player = load_scene(bundled(f"{name}.toml"), frames=WARMUP + STEPS, width=64, height=48, haptics=False,
                            steps_per_frame=1, device=DEVICE)
        step, sim = player.step, player.scene
    if DEVICE == "cpu":
        sim._host_copies = sim._gpu_forms = True
    return step, sim


def _write(path: Path, report: dict) -> None:
    """``report`` as JSON at ``path``, atomically (a partial run leaves the last whole file)."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(report, indent=1))
    tmp.replace(path)


def _wall_ms(step, steps: int) -> float:
    """Median wall time [ms] of ``steps`` steps, each synchronized."""
    times = []
    for _ in range(steps):
        wp.synchronize()
        t = time.perf_counter()
        step()
        wp.synchronize()
        times.append(1e3 * (time.perf_counter() - t))
    return float(np.median(times))


def kernels(name: str) -> dict:
    """Part 1 for scene ``name``: device time by kernel over STEPS steps, graphs off."""
    plain = device_module.LaunchBatch.__init__

    def uncaptured(self, replays, dev):
        plain(self, replays, dev)
        self._try_capture = False

    device_module.LaunchBatch.__init__ = uncaptured
    try:
        step, _ = _scene(name)
        for _ in range(WARMUP):
            step()
        wall = _wall_ms(step, 3)
        wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
        for _ in range(STEPS):
            step()
        results = wp.timing_end()
    finally:
        device_module.LaunchBatch.__init__ = plain
    by = collections.defaultdict(lambda: [0, 0.0])
    for r in results:
        key = r.name.split(" ")[-1] if r.name else "?"
        by[key][0] += 1
        by[key][1] += r.elapsed
    rows = sorted(((ms / STEPS, n / STEPS, k) for k, (n, ms) in by.items()), reverse=True)
    device_ms = sum(ms for ms, _, _ in rows)
    wall = max(wall, 1e-9)
    print(f"\n{name}: {wall:.2f} ms a step uncaptured (median of 3), device {device_ms:.2f} ms "
          f"({100 * device_ms / wall:.0f} %), {sum(n for _, n, _ in rows):.0f} timed launches a step")
    for ms, n, k in rows[:25]:
        print(f"  {ms:8.3f} ms {n:7.1f} launches {1e3 * ms / max(n, 1e-9):8.1f} us each  {k}")
    return {"wall_ms_uncaptured": wall, "device_ms": device_ms,
            "kernels": [{"kernel": k, "ms_per_step": ms, "launches_per_step": n} for ms, n, k in rows]}


def pass_factors(name: str = "candy") -> dict:
    """Part 2: wall ms a step (graphs on) with each PARALLEL_PASS_FACTOR."""
    out, saved = {}, node_jacobi.PARALLEL_PASS_FACTOR
    try:
        for factor in (1, 2, 4):
            node_jacobi.PARALLEL_PASS_FACTOR = factor
            step, _ = _scene(name)
            for _ in range(WARMUP):
                step()
            out[factor] = _wall_ms(step, STEPS)
            print(f"{name}, PARALLEL_PASS_FACTOR {factor}: {out[factor]:.2f} ms a step (median of {STEPS})")
    finally:
        node_jacobi.PARALLEL_PASS_FACTOR = saved
    return out


def loops() -> dict:
    """Part 3: wall ms a step (graphs on), per scene: the whole step one graph (the default), the
    stop on the device in four graphs a step (``NodeStepper._whole_step`` off), and the stop on
    the host (a read every two sweeps)."""
    out: dict = {}
    solve, whole = node_step.NodeSolve, node_step.NodeStepper._whole_step
    variants = (("one graph a step", True, True), ("four graphs a step", True, False),
                ("stop on the host", False, False))
    try:
        for name in ("shoulder", "cubes64", "candy"):
            for label, on_device, one_graph in variants:
                node_step.NodeSolve = functools.partial(solve, device_loop=on_device)
                node_step.NodeStepper._whole_step = whole if one_graph else (lambda self: None)
                step, _ = _scene(name)
                for _ in range(WARMUP):
                    step()
                key = f"{name}, {label}"
                out[key] = _wall_ms(step, STEPS)
                print(f"{key}: {out[key]:.2f} ms a step (median of {STEPS})")
    finally:
        node_step.NodeSolve, node_step.NodeStepper._whole_step = solve, whole
    return out


def main(argv: list[str]) -> int:
    global DEVICE, WARMUP, STEPS
    out = Path(argv[0] if argv else "device-out")
    out.mkdir(parents=True, exist_ok=True)
    wp.init()
    if len(argv) > 1 and argv[1] == "cpu":
        DEVICE, WARMUP, STEPS = "cpu", 1, 1
    elif not wp.is_cuda_available():
        print("device_profile: no CUDA device here (it profiles the CUDA step; `OUT cpu` for a dry run)")
        return 2
    report = {"device": wp.get_device(DEVICE).name, "kernels": {}, "pass_factor_ms": {}, "loop_ms": {}}
    for name in ("shoulder", "cubes64", "candy"):
        report["kernels"][name] = kernels(name)
        _write(out / "profile.json", report)
    report["pass_factor_ms"] = pass_factors()
    _write(out / "profile.json", report)
    report["loop_ms"] = loops()
    _write(out / "profile.json", report)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
