"""``softvr bench cave``: what the render cluster's synchronization costs (thesis 6.3, 6.5).

A master and 2 ... 16 render nodes run as processes on loopback, the nodes following the state
without drawing (so only synchronization is measured), the master paced at 60 frames per
second. Two loads: *events only* (poses, events, a static scene) and a *streamed* 10 K-vertex
deformable body (:class:`~softvr.cave.app.WavingSheet`). Reported per node count:

* sync overhead per frame: from the master publishing frame n until every node reported
  n rendered (p50 / p99) — the software barrier's round trip, what a frame costs beyond the
  slowest node's render;
* barrier wait at the nodes: from reporting ``ready`` to receiving ``go`` (p50 / p99 of the
  slowest node);
* bytes per frame on the wire (mean / max).

Master and nodes run as shipped: CURVE on (keys made on first use in the default key folder,
:mod:`softvr.cave.keys`), every packet validated, heartbeats both ways; ``--no-curve`` runs
them without CURVE (loopback), to tell its cost from the other checks'.

Peers, on the same machine in the same run: *ZeroMQ alone* — the same PUB fan-out and ROUTER
reply with an 8-byte message and nothing decoded (the transport's floor), and the thesis'
way of shipping state — the whole vertex array pickled every frame (cPickle over
multicast; here its size, since sending it to nodes that unpickle is what the cluster must
not do). Thesis anchors: 4 nodes, 16 us round trip, 12 kB peak packets. Targets: 16 nodes
with sync overhead p99 < 1 ms; streamed deformable state < 100 kB per frame.
"""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from softvr.bench._report import bench_parser, print_and_write, save_figure
from softvr.bench.contact import _git_commit
from softvr.bench.volume import _loadavg, _machine_info
from softvr.cave import Screen, save_display, tile
from softvr.cave.app import WavingSheet, plane_item, user_pose_facing
from softvr.cave.cluster import ClusterConfig, Master
from softvr.cave.command import node_command
from softvr.cave.display import Display

__all__ = ["TARGET_BYTES_PER_FRAME", "TARGET_SYNC_P99_MS", "format_table", "main", "run_cave_bench", "write_plot"]

TARGET_SYNC_P99_MS = 1.0
TARGET_BYTES_PER_FRAME = 100_000
THESIS = {"nodes": 4, "round_trip_us": 16.0, "peak_packet_bytes": 12_000}


class _StaticScene:
    """Events only: a ground plane and nothing that moves."""

    fps = 60.0

    def __init__(self):
        self.items = [plane_item(size=3.0)]

    def advance(self) -> dict:
        return {}


def _navigation(n: int, t: float):
    return (user_pose_facing((0.0, 0.0, 0.4), 0.3 * np.sin(0.5 * t)), [0.1 * np.sin(t), 0.0, 1.7, 1.0, 0.0, 0.0, 0.0],
            [("toggle", ("grid",))] if n % 60 == 0 else [])


def _display_file(nodes: int, folder: Path) -> Path:
    wall = Screen("wall", (-2.0, 2.0, 0.5), (2.0, 2.0, 0.5), (-2.0, 2.0, 2.75), (nodes * 64, 64), "wall")
    return save_display(Display(tile(wall, nodes, 1), name=f"{nodes} tiles"), folder / f"wall{nodes}.toml")


def _cluster_run(nodes: int, load: str, frames: int, folder: Path, curve: bool = True) -> dict:
    """One master (here) and ``nodes`` node processes (no rendering), ``frames`` frames at 60 fps."""
    display = _display_file(nodes, folder)
    names = [f"wall_{i}0" for i in range(nodes)]
    source = WavingSheet(10_000) if load == "streamed" else _StaticScene()
    out = folder / f"{load}{nodes}"
    config = ClusterConfig(publish="tcp://127.0.0.1:0", control="tcp://127.0.0.1:0", curve=curve)
    extra = ["--no-render", "--max-seconds", "600"] + ([] if curve else ["--no-curve"])
    with Master(source, names, config, navigation=_navigation) as master:
        procs = [subprocess.Popen(node_command(str(display), name, master.config.publish, master.config.control,
                                               out=out, extra=extra))
                 for name in names]
        try:
            master.wait_for_nodes(120)
            summary = master.run(frames, fps=60.0)
        finally:
            _reap(procs, 60)
    waits = [json.loads((out / f"{name}.json").read_text())["barrier_wait_ms"] for name in names]
    worst = max(waits, key=lambda w: w.get("p99", 0.0))
    return {"nodes": nodes, "load": load, "frames": frames, "sync_ms": summary["sync_ms"],
            "barrier_wait_ms": worst, "frame_bytes": summary["frame_bytes"], "mismatches": summary["mismatches"],
            "evictions": summary["evictions"], "sync_trace_ms": [1e3 * v for v in master.sync.values]}


def _reap(processes, seconds: float) -> None:
    """Wait for node processes to finish after the master's bye; kill what outlives ``seconds``."""
    for p in processes:
        try:
            p.wait(timeout=seconds)
        except subprocess.TimeoutExpired:
            p.kill()


def echo_node(publish: str, control: str, name: str) -> None:
    """The ZeroMQ-alone peer's node: answer every published message at once, decode nothing."""
    import zmq

    ctx: zmq.Context = zmq.Context.instance()
    sub, dealer = ctx.socket(zmq.SUB), ctx.socket(zmq.DEALER)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    dealer.setsockopt(zmq.ROUTING_ID, name.encode())
    sub.connect(publish)
    dealer.connect(control)
    dealer.send(b"hello")
    while True:
        message = sub.recv()
        if message == b"bye":
            break
        dealer.send(message)
    sub.close(0)
    dealer.close(0)


def _zmq_floor(nodes: int, frames: int) -> dict:
    """PUB an 8-byte frame number to ``nodes`` echo processes, wait for every reply; 60 fps."""
    import zmq

    ctx: zmq.Context = zmq.Context.instance()
    pub, router = ctx.socket(zmq.PUB), ctx.socket(zmq.ROUTER)
    pub.bind("tcp://127.0.0.1:0")
    router.bind("tcp://127.0.0.1:0")
    endpoints = [s.getsockopt_string(zmq.LAST_ENDPOINT) for s in (pub, router)]
    procs = [subprocess.Popen([sys.executable, "-m", "softvr.bench.cave", "--echo-node", *endpoints, f"echo{i}"])
             for i in range(nodes)]
    try:
        for _ in range(nodes):
            router.recv_multipart()
        time.sleep(0.3)  # every SUB connected before the first frame
        times = []
        for n in range(frames):
            t0 = time.perf_counter()
            pub.send(n.to_bytes(8, "little"))
            for _ in range(nodes):
                router.recv_multipart()
            times.append(time.perf_counter() - t0)
            time.sleep(max(0.0, 1 / 60 - (time.perf_counter() - t0)))
        pub.send(b"bye")
    finally:
        _reap(procs, 10)
        pub.close(0)
        router.close(0)
    a = 1e3 * np.asarray(times)
    return {"nodes": nodes, "frames": frames, "p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
            "max": float(a.max())}


def _pickled_bytes() -> int:
    """The thesis' way: the whole vertex state of the 10 K-vertex sheet pickled (float32)."""
    sheet = WavingSheet(10_000)
    vertices = sheet.advance()
    return len(pickle.dumps({h: v.astype(np.float32) for h, v in vertices.items()}, protocol=pickle.HIGHEST_PROTOCOL))


def run_cave_bench(*, quick: bool = False, progress: bool = True, node_counts=(2, 4, 8, 16), curve: bool = True) -> dict:
    """Every node count with both loads, and the peers; ``quick``: 2 and 4 nodes, 60 frames;
    ``curve``: CURVE on (as shipped)."""
    from tqdm import tqdm

    t0 = time.perf_counter()
    load_start = _loadavg()
    frames = 60 if quick else 600
    counts = (2, 4) if quick else tuple(node_counts)
    runs, floor = [], []
    jobs = [(n, load) for n in counts for load in ("events", "streamed")]
    with tempfile.TemporaryDirectory(prefix="softvr-bench-cave-") as tmp:
        for n, load in tqdm(jobs, desc="bench cave", unit="run", disable=not progress):
            runs.append(_cluster_run(n, load, frames, Path(tmp), curve))
        for n in counts:
            floor.append(_zmq_floor(n, frames))
    machine = _machine_info("cpu")
    machine["softvr_commit"] = _git_commit()
    largest = max(counts)
    sync16 = max(r["sync_ms"]["p99"] for r in runs if r["nodes"] == largest)
    streamed = max(r["frame_bytes"]["mean"] for r in runs if r["load"] == "streamed")
    return {
        "schema": "softvr-bench-cave/1",
        "machine": machine,
        "config": {"quick": quick, "frames": frames, "fps": 60.0, "node_counts": list(counts),
                   "streamed_vertices": 10_000, "curve": curve},
        "runs": runs,
        "peers": {"zmq_alone": floor, "pickled_state_bytes": _pickled_bytes()},
        "thesis": THESIS,
        "targets": {"sync_p99_ms": TARGET_SYNC_P99_MS, "at_nodes": largest, "sync_p99_measured_ms": sync16,
                    "sync_p99_met": sync16 < TARGET_SYNC_P99_MS, "bytes_per_frame": TARGET_BYTES_PER_FRAME,
                    "bytes_per_frame_measured": streamed, "bytes_per_frame_met": streamed < TARGET_BYTES_PER_FRAME},
        "loadavg_start": load_start,
        "loadavg_end": _loadavg(),
        "wall_s": time.perf_counter() - t0,
    }


def format_table(result: dict) -> str:
    floor = {f["nodes"]: f for f in result["peers"]["zmq_alone"]}
    lines = [f"Render cluster on loopback: master + N node processes (no drawing), {result['config']['frames']} frames "
             f"at 60 fps, CURVE {'on' if result['config'].get('curve', True) else 'off'}"]
    head = (f"{'nodes':>5} {'load':<9} {'sync p50/p99 ms':>16} {'zmq alone p50/p99':>18} {'p99 ratio':>9} "
            f"{'barrier wait p50/p99':>21} {'bytes/frame mean/max':>21} {'bad':>4}")
    lines += [head, "-" * len(head)]
    for r in result["runs"]:
        s, w, b, z = r["sync_ms"], r["barrier_wait_ms"], r["frame_bytes"], floor[r["nodes"]]
        lines.append(f"{r['nodes']:>5} {r['load']:<9} {s['p50']:>7.3f} / {s['p99']:<6.3f} "
                     f"{z['p50']:>8.3f} / {z['p99']:<7.3f} {s['p99'] / z['p99']:>8.1f}x "
                     f"{w.get('p50', float('nan')):>9.3f} / {w.get('p99', float('nan')):<9.3f} "
                     f"{b['mean']:>10.0f} / {b['max']:<8.0f} {r['mismatches']:>4}")
    t, th = result["targets"], result["thesis"]
    pickled = result["peers"]["pickled_state_bytes"]
    streamed = t["bytes_per_frame_measured"]
    lines += ["", f"thesis: {th['nodes']} nodes, {th['round_trip_us']:g} us round trip, "
                  f"{th['peak_packet_bytes']} B peak packets; its state shipping (pickle of the whole 10 K-vertex "
                  f"float32 state): {pickled} B per frame, "
                  f"{pickled / streamed:.1f}x the streamed frame",
              f"targets: {t['at_nodes']} nodes sync p99 < {t['sync_p99_ms']:g} ms: {t['sync_p99_measured_ms']:.3f} -> "
              f"{'MET' if t['sync_p99_met'] else 'NOT met'}; streamed state < {t['bytes_per_frame'] // 1000} kB/frame: "
              f"{streamed / 1000:.1f} kB -> {'MET' if t['bytes_per_frame_met'] else 'NOT met'}"]
    return "\n".join(lines)


def write_plot(result: dict, path) -> None:
    """PNG: sync overhead p50/p99 against node count (both loads and ZeroMQ alone), bytes per frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    for load, color in (("events", "tab:blue"), ("streamed", "tab:red")):
        rs = [r for r in result["runs"] if r["load"] == load]
        n = [r["nodes"] for r in rs]
        axes[0].plot(n, [r["sync_ms"]["p50"] for r in rs], "o-", color=color, label=f"{load} p50")
        axes[0].plot(n, [r["sync_ms"]["p99"] for r in rs], "s--", color=color, label=f"{load} p99")
        axes[1].plot(n, [r["frame_bytes"]["mean"] / 1e3 for r in rs], "o-", color=color, label=load)
    floor = result["peers"]["zmq_alone"]
    axes[0].plot([f["nodes"] for f in floor], [f["p99"] for f in floor], "k:", label="ZeroMQ alone p99")
    axes[0].axhline(TARGET_SYNC_P99_MS, color="k", lw=1, label="target p99")
    axes[0].set(xlabel="render nodes", ylabel="ms per frame", title="sync overhead (publish -> all ready)",
                xscale="log", yscale="log")
    axes[1].axhline(TARGET_BYTES_PER_FRAME / 1e3, color="k", lw=1, label="target")
    axes[1].axhline(result["peers"]["pickled_state_bytes"] / 1e3, color="tab:gray", ls=":", label="pickled state")
    axes[1].set(xlabel="render nodes", ylabel="kB per frame", title="bytes per frame", xscale="log")
    from matplotlib.ticker import NullLocator

    for ax in axes:
        ax.xaxis.set_minor_locator(NullLocator())
        ax.set_xticks(result["config"]["node_counts"], [str(n) for n in result["config"]["node_counts"]])
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    m = result["machine"]
    fig.suptitle(f"render cluster on loopback - {m['cpu_model']}, {m['cores']} cores, {m['date'][:10]}", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    """``softvr bench cave [--quick] [--nodes N ...] [--json PATH] [--plot PATH]``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--echo-node"]:
        echo_node(*argv[1:4])
        return 0
    p = bench_parser("cave", "Render cluster synchronization on loopback.", quick="2 and 4 nodes, 60 frames (CI)",
                     plot="write a PNG: sync overhead and bytes per frame")
    p.add_argument("--nodes", type=int, nargs="+", default=[2, 4, 8, 16], help="node counts (default 2 4 8 16)")
    p.add_argument("--no-curve", action="store_true", help="master and nodes without CURVE (its cost)")
    a = p.parse_args(argv)
    result = run_cave_bench(quick=a.quick, progress=not a.no_progress, node_counts=a.nodes, curve=not a.no_curve)
    print_and_write(result, format_table(result), a.json, a.plot, write_plot)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
