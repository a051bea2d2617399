"""``softvr bench contact``: a soft cube dropped on a plane, softvr against MuJoCo, PyBullet, Newton.

The scene (``/work/shared/peers.md``): a 0.8 m cube of 8 x 8 x 8 cells (729 nodes; 2 560 tets at
5 per cell), density 1000 kg/m^3, E = 2.5e5 Pa, nu = 0.25 (Lamé mu = lambda = 1e5 Pa), its
bottom face 0.5 m above a plane z = 0 with Coulomb friction 0.5, dt = 1/60 s, 1 s simulated.
``--quick`` uses a 0.2 m cube of 3 x 3 x 3 cells dropped from 5 cm for 0.25 s (15 steps).

softvr runs in this process: :class:`softvr.dynamics.FemBody` (linear co-rotational FEM, backward
Euler + CG, Rayleigh beta = 1e-3 s like MuJoCo's ``damping``) in a :class:`softvr.Scene` with
every node a collision point (:class:`~softvr.dynamics.EmbeddedPoints`) against a
:class:`~softvr.collision.Plane`; contacts are solved as an LCP by PGS (thesis eqs. 5.5-5.6).
Each installed peer runs in its own process (:mod:`softvr.bench._contact_peers`); a peer that is
not installed gets a row saying so.

Reported per engine: steps/s (steps / summed wall time of the stepping calls, median over
``--repeat`` rounds; every round runs each engine once, after an untimed warm-up, so that load
from other jobs on a shared machine spreads over all engines), x real time (= steps/s x dt), the
ratio to the fastest peer, the maximum penetration over the run (the deepest node centre below
the plane; MuJoCo's vertices carry a 5 mm radius, so its nodes rest ~4 mm *above* the plane when the
vertex spheres touch it), the height of the lowest node and of the node centroid at the end, the
contact count of the last step (softvr: contacts handed to the solver, speculative ones within
the 5 mm margin included; JSON: also those carrying an impulse), softvr's PGS sweeps, and the
cores used (process CPU time / wall time of the stepping calls: the peers run on one thread,
softvr's compiled element and collision kernels split over the cores, BLAS stays on one thread).
``--profile`` adds a cProfile of one softvr step with the cube resting on the plane.
``--device cuda`` steps softvr's physics (the cube, the candy) on the GPU (:attr:`softvr.Scene.device`;
the peers stay on the CPU); ``--cubes N`` also steps N of the cubes in one scene (the GPU
target: 64 cubes at >= 1 000 steps/s each).

Examples
--------
``softvr bench contact --quick`` (seconds), or the full run
``softvr bench contact --json bench-results/contact.json --plot docs/img/bench_contact.png``.
"""

from __future__ import annotations

import statistics
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

import softvr
from softvr import Scene
from softvr.app import Player
from softvr.bench import _contact_peers as P
from softvr.bench._cube_scene import FULL_SCENE, QUICK_SCENE, CubeScene, cube_mesh
from softvr.bench._report import bench_parser, print_and_write, save_figure, steady, step_times
from softvr.bench.volume import _loadavg, _machine_info
from softvr.collision import Plane
from softvr.device import resolve_device
from softvr.dynamics import EmbeddedPoints, FemBody, Material
from softvr.errors import SoftvrError
from softvr.scene import BUNDLED, load_scene

__all__ = ["CubePlayer", "CubeScene", "FULL_SCENE", "QUICK_SCENE", "cube_mesh", "format_table", "main", "run_contact_bench",
           "run_softvr", "softvr_scene", "write_plot"]

#: The issue's targets on this cube.
TARGET_SPEEDUP = 1.5  # x the fastest peer's steps/s
TARGET_PENETRATION_M = 1e-3
#: Stiffness-proportional Rayleigh damping of softvr's cube [s] (MuJoCo's ``damping`` is the same).
SOFTVR_BETA = 1e-3
ENGINES = ("softvr",) + tuple(P.PEERS)


def softvr_scene(scene: CubeScene, device: str = "cpu", count: int = 1):
    """(Scene, FemBody) of the cube above its plane, every node a collision point, stepped on
    ``device``; with ``count`` > 1 that many cubes in the one scene (one set of node arrays), on
    a square grid 1.25 edges apart (they meet only the plane), and the first cube returned."""
    nodes, tets = cube_mesh(scene)
    sim = Scene(gravity=(0.0, 0.0, -scene.gravity), device=device)
    side, pitch = int(np.ceil(np.sqrt(count))), 1.25 * scene.size
    for k in range(count):
        offset = pitch * np.array([k % side - (side - 1) / 2, k // side - (side - 1) / 2, 0.0])
        body = FemBody(nodes + offset, tets,
                       Material(scene.young, scene.poisson, scene.density, alpha=0.0, beta=SOFTVR_BETA),
                       name="cube" if count == 1 else f"cube {k}")
        sim.add_body(body, collision_points=EmbeddedPoints(body, np.arange(len(nodes))[:, None],
                                                           np.ones((len(nodes), 1))))
    sim.add_plane(Plane(friction=scene.friction))
    return sim, sim.bodies[0]


def run_cubes(count: int, scene: CubeScene, device: str = "cpu", progress: bool = True) -> dict:
    """``count`` copies of ``scene``'s cube in one scene (:func:`softvr_scene`), dropped together
    and stepped on ``device`` for the scene's duration: ms a step of the whole scene (the
    steady state, :func:`step_times`) and steps/s, which each cube makes too (the issue's GPU
    target: 64 cubes at >= 1 000 steps/s each), the deepest penetration of any cube over the run
    and each cube's lowest node at the end [m]."""
    from tqdm import tqdm

    sim, _ = softvr_scene(scene, resolve_device(device), count)
    step_s: list[float] = []
    penetration = 0.0
    for _ in tqdm(range(scene.steps), desc=f"{count} cubes", unit="step", disable=not progress, leave=False):
        t = time.perf_counter()
        sim.step(scene.dt)
        step_s.append(time.perf_counter() - t)
        penetration = max(penetration, -min(float(b.q[:, 2].min()) for b in sim.bodies))
    times = step_times(step_s)
    return {"cubes": count, "device": sim.device, "path": sim.path,
            "tets": int(sum(len(b.tets) for b in sim.bodies)), "steps": scene.steps, **times,
            "steps_per_s": 1e3 / times["ms_per_step"], "max_penetration_m": penetration,
            "bottom_end_m": [float(b.q[:, 2].min()) for b in sim.bodies]}


class CubePlayer(Player):
    """The bench's cube played headless by the one player, one physics step a frame: nothing
    drawn, the measures read by the bench itself (:attr:`~softvr.app.Player.frame_measures`).

    Parameters
    ----------
    scene : CubeScene
    steps : int
        Frames (= steps) to play.
    device : str
        Where the physics steps (:attr:`softvr.Scene.device`).
    """

    name = "contact-cube"
    frame_measures = False

    def __init__(self, scene: CubeScene, steps: int, device: str = "cpu"):
        sim, self.body = softvr_scene(scene, device)
        super().__init__(sim, scene.dt, 1, steps, 64, 48)


def _softvr_once(scene: CubeScene, steps: int, device: str = "cpu") -> tuple[dict, dict]:
    t = time.perf_counter()
    player = CubePlayer(scene, steps, device)
    body = player.body
    setup = time.perf_counter() - t
    trace: dict[str, list] = {k: [] for k in ("step_s", "cpu_s", "min_z", "mean_z", "contacts", "active_contacts",
                                              "pgs_iterations", "residual", "cg_iterations")}
    for _ in range(steps):
        t, c = time.perf_counter(), time.process_time()
        player.step()
        trace["step_s"].append(time.perf_counter() - t)
        trace["cpu_s"].append(time.process_time() - c)
        sol = player.scene.last_solution
        z = body.q[:, 2]
        trace["min_z"].append(float(z.min()))
        trace["mean_z"].append(float(z.mean()))
        trace["contacts"].append(int(sum(len(i) for i in sol.impulses)))
        trace["active_contacts"].append(int(sum(int((i[:, 0] > 0).sum()) for i in sol.impulses)))
        trace["pgs_iterations"].append(int(sol.iterations))
        trace["residual"].append(float(sol.residual))
        trace["cg_iterations"].append(int(body.last_cg_iterations))
    info = {"setup_s": setup, "nodes": int(len(body.q)), "tets": int(len(body.tets)),
            "mass_kg": float(body.mass.sum())}
    return trace, info


def run_softvr(scene: CubeScene, repeat: int = 1, device: str = "cpu") -> dict:
    """softvr on ``scene`` stepped on ``device``: warm-up, then ``repeat`` simulations (record as
    :func:`_contact_peers.run_peer`)."""
    t = time.perf_counter()
    _softvr_once(replace(scene, drop=0.0), P.WARMUP_STEPS, device)  # imports, first sparse LU and PGS call
    warmup_s = time.perf_counter() - t
    rates: list[float] = []
    first: tuple[dict, dict] | None = None
    for _ in range(max(1, repeat)):
        trace, info = _softvr_once(scene, scene.steps, device)
        rates.append(scene.steps / sum(trace["step_s"]))
        first = first or (trace, info)
    assert first is not None  # one round at least
    trace, info = first
    return {**info, "steps": scene.steps, "warmup_s": warmup_s, "steps_per_s": statistics.median(rates),
            "steps_per_s_runs": rates, "version": softvr.__version__, "trace": trace}


#: The candy scene's simulated time in the full / quick bench [s].
CANDY_DURATION_S = 0.8
CANDY_QUICK_DURATION_S = 0.16
#: Thesis 4.4: 0.4 s per 8 ms step with adhesion, 13 min for 25 s (0.25 s per step) without.
THESIS_CANDY_S_PER_STEP = 0.25


def run_candy(*, quick: bool = False, progress: bool = True, scene: str = "candy.toml", variants=(),
              device: str = "cpu") -> dict:
    """softvr on the thesis' candy scene, the bundled scene file ``scene`` (``candy.toml``;
    ``candy-adhesive.toml`` with adhesion) with ``variants`` (its ``[variant.NAME]`` tables,
    ``"quick"`` added for the small scale): candies fall on a Jell-O block, 8 ms steps. Full: ~10 K
    tets, ~25 K collision triangles, 0.8 s simulated (the candies land and start to pile);
    quick: the small scale, 0.16 s.

    Returns ms per step (the steady state: the steps after the first, overall and over those with
    contacts between bodies; the first step, which loads the scene, apart: ``first_step_ms``),
    contacts (mean / max), PGS sweeps (mean / max), the largest normal-velocity residual,
    whether adhesion was on and the sizes; peers do not run this scene. The physics steps on
    ``device``.
    """
    from tqdm import tqdm

    variants = (*variants, "quick") if quick else tuple(variants)
    # Played headless by the one player, one step a frame: nothing drawn, the measures read here.
    player = load_scene(BUNDLED / scene, variants, frames=1, width=64, height=48, steps_per_frame=1, device=device)
    player.frame_measures = False
    adhesion = bool(player.adhesions)
    steps = int(round((CANDY_QUICK_DURATION_S if quick else CANDY_DURATION_S) / player.dt))
    trace: dict[str, list] = {k: [] for k in ("step_s", "contacts", "pulling_contacts", "pgs_iterations", "residual")}
    label = "candy + adhesion" if adhesion else "candy"
    for _ in tqdm(range(steps), desc=label, unit="step", disable=not progress, leave=False):
        t = time.perf_counter()
        player.step()
        trace["step_s"].append(time.perf_counter() - t)
        sol = player.scene.last_solution
        trace["contacts"].append(int(sum(len(i) for i in sol.impulses)))
        trace["pulling_contacts"].append(int(sum(int((i[:, 0] < 0).sum()) for i in sol.impulses)))
        trace["pgs_iterations"].append(int(sol.iterations))
        trace["residual"].append(float(sol.residual))
    times = step_times(trace["step_s"])
    ms = 1e3 * np.asarray(steady(trace["step_s"]))
    busy = np.asarray(steady(trace["contacts"])) > 0
    tets = sum(len(b.tets) for b in player.scene.bodies if isinstance(b, FemBody))
    triangles = sum(len(s.triangles) for s in player.scene.collision_surfaces)
    return {"scene": scene, "variants": list(variants), "tets": tets, "collision_triangles": triangles,
            "bodies": len(player.scene.bodies), "dt_s": player.dt, "steps": steps, **times,
            "ms_per_step_in_contact": float(ms[busy].mean()) if busy.any() else None,
            "ms_per_step_max": float(ms.max()), "contacts_mean": float(np.mean(trace["contacts"])),
            "contacts_max": int(max(trace["contacts"])), "pgs_iterations_mean": float(np.mean(trace["pgs_iterations"])),
            "pgs_iterations_max": int(max(trace["pgs_iterations"])), "residual_max_m_s": float(max(trace["residual"])),
            "real_time_factor": player.dt * 1e3 / times["ms_per_step"], "thesis_s_per_step": THESIS_CANDY_S_PER_STEP,
            "quick": quick, "adhesion": adhesion, "trace": trace}


# ----------------------------------------------------------------------------- the run
def _git_commit() -> str | None:
    """The checkout's commit (``+dirty`` with local changes), or None outside a git checkout."""
    import subprocess

    root = Path(__file__).resolve().parents[3]
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10)
        return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def _cores_used(trace: dict) -> float:
    """Process CPU time / wall time of the stepping calls (1.0 = one busy core)."""
    return sum(trace["cpu_s"]) / max(sum(trace["step_s"]), 1e-12)


def _summarize(rec: dict, scene: CubeScene) -> dict:
    tr = rec["trace"]
    rec["real_time_factor"] = rec["steps_per_s"] * scene.dt
    rec["max_penetration_m"] = max(0.0, -min(tr["min_z"]))
    rec["bottom_end_m"] = tr["min_z"][-1]
    rec["centre_end_m"] = tr["mean_z"][-1]
    rec["centre_speed_end_m_s"] = (tr["mean_z"][-1] - tr["mean_z"][-2]) / scene.dt if len(tr["mean_z"]) > 1 else None
    rec["contacts_end"] = tr["contacts"][-1]
    rec["cores_used"] = statistics.median(rec["cores_used_runs"])
    if "pgs_iterations" in tr:
        rec["active_contacts_end"] = tr["active_contacts"][-1]
        rec["pgs_iterations_end"] = tr["pgs_iterations"][-1]
        rec["pgs_iterations_max"] = max(tr["pgs_iterations"])
        in_contact = [it for it, c in zip(tr["pgs_iterations"], tr["contacts"]) if c]
        rec["pgs_iterations_mean_in_contact"] = statistics.fmean(in_contact) if in_contact else 0.0
    return rec


def run_contact_bench(*, quick: bool = False, repeat: int | None = None, engines=ENGINES, progress: bool = True,
                      scene: CubeScene | None = None, peer_timeout_s: float = 600.0, candy: bool = True,
                      device: str = "cpu", cubes: int = 0) -> dict:
    """Run softvr (its physics on ``device``) and every installed peer (CPU) on the cube, and
    with ``cubes`` > 0 softvr on that many cubes in one scene (:func:`run_cubes`); returns the
    JSON-ready result.

    Keys: ``schema``, ``machine``, ``config`` (the scene and settings), ``engines`` (one record
    per engine, in ``engines`` order: ``status`` "ok" / "skipped" / "failed", ``reason``, the
    measures of the module docstring and the per-step ``trace``), ``candy`` (:func:`run_candy`,
    None when ``candy`` is False), ``targets``, ``wall_s``.
    """
    from tqdm import tqdm

    device = resolve_device(device)  # also initializes Warp quietly (the machine info asks it for the device name)
    scene = scene or (QUICK_SCENE if quick else FULL_SCENE)
    rep = repeat or (1 if quick else 3)
    t_start = time.perf_counter()
    load_start = _loadavg()
    # Round robin: every engine runs once per round, so that a burst of load from other jobs
    # on this shared machine spreads over all engines instead of hitting one.
    records = {}
    for name in engines:
        if name == "softvr":
            records[name] = {"engine": name, "status": "ok", "reason": None, "material": "linear co-rotational",
                             "note": f"co-rotational FEM, backward Euler; eq. 5.6 sweeps on arrays (node-block Jacobi + "
                                     f"PGS, Chebyshev), margin 5 mm, "
                                     f"beta {SOFTVR_BETA:g} s"}
        else:
            _, _, material, note = P.PEERS[name]
            records[name] = {"engine": name, "material": material, "note": note, "status": "ok", "reason": None}
            if not P.installed(name):
                records[name] |= {"status": "skipped", "reason": P.NOT_INSTALLED}
    bar = tqdm(total=len(engines) * rep, desc="bench contact", unit="run", disable=not progress, leave=False)
    for _ in range(rep):
        for name, rec in records.items():
            bar.set_postfix_str(name)
            if rec["status"] == "ok":
                if name == "softvr":
                    out = run_softvr(scene, 1, device)
                else:
                    out = P.run_peer_process(name, asdict(scene), 1, timeout_s=peer_timeout_s)
                if "failed" in out:
                    if "steps_per_s" in rec:  # an earlier round ran: keep it, say so
                        rec.setdefault("failed_rounds", []).append(out["failed"])
                    else:
                        rec |= {"status": "failed", "reason": out["failed"]}
                elif "steps_per_s" not in rec:
                    rec |= out
                    rec["cores_used_runs"] = [_cores_used(out["trace"])]
                else:
                    rec["steps_per_s_runs"] += out["steps_per_s_runs"]
                    rec["cores_used_runs"].append(_cores_used(out["trace"]))
                    rec["steps_per_s"] = statistics.median(rec["steps_per_s_runs"])
            bar.update()
    bar.close()
    engine_records = list(records.values())
    for rec in engine_records:
        if rec["status"] == "ok":
            _summarize(rec, scene)
    peers_ok = [r for r in engine_records if r["status"] == "ok" and r["engine"] != "softvr"]
    fastest = max(peers_ok, key=lambda r: r["steps_per_s"], default=None)
    for r in engine_records:
        if r["status"] == "ok":
            r["vs_fastest_peer"] = r["steps_per_s"] / fastest["steps_per_s"] if fastest else None
    machine = _machine_info(device)
    machine["versions"] |= {name: P.peer_version(name) for name in P.PEERS}
    machine["softvr_commit"] = _git_commit()
    result: dict[str, Any] = {
        "schema": "softvr-bench-contact/1",
        "machine": machine,
        "config": {"quick": quick, "repeat": rep, "device": device, "scene": asdict(scene), "steps": scene.steps,
                   "mass_kg": scene.mass, "lame_lambda_mu": list(scene.lame), "softvr_beta_s": SOFTVR_BETA,
                   "engines": list(engines), "fastest_peer": fastest["engine"] if fastest else None,
                   "steps_per_s": "steps / summed wall time of the stepping calls; median over repeat rounds, "
                                  "engines run round robin (one simulation each per round)",
                   "penetration": "max over steps of the deepest node centre below z = 0"},
        "engines": engine_records,
        "candy": run_candy(quick=quick, progress=progress, device=device) if candy else None,
        "cubes": run_cubes(cubes, scene, device, progress) if cubes > 0 else None,
        "wall_s": None,
        "loadavg_start": load_start,
        "loadavg_end": _loadavg(),
    }
    result["targets"] = _targets(result)
    result["wall_s"] = time.perf_counter() - t_start
    return result


def _targets(result: dict) -> dict:
    sv = next((r for r in result["engines"] if r["engine"] == "softvr" and r["status"] == "ok"), None)
    out = {"speedup_target": TARGET_SPEEDUP, "penetration_target_m": TARGET_PENETRATION_M,
           "fastest_peer": result["config"]["fastest_peer"]}
    candy = result.get("candy")
    if candy is not None:
        out["candy_ms_per_step"] = candy["ms_per_step"]
        out["candy_real_time_met"] = candy["ms_per_step"] <= candy["dt_s"] * 1e3
    if sv is None:
        return out
    out["softvr_penetration_m"] = sv["max_penetration_m"]
    out["penetration_met"] = sv["max_penetration_m"] < TARGET_PENETRATION_M
    out["softvr_vs_fastest_peer"] = sv.get("vs_fastest_peer")
    out["speedup_met"] = None if sv.get("vs_fastest_peer") is None else sv["vs_fastest_peer"] >= TARGET_SPEEDUP
    return out


# ----------------------------------------------------------------------------- output
def format_table(result: dict) -> str:
    sc = CubeScene(**result["config"]["scene"])
    lines = [f"Soft cube on a plane: {sc.describe()}; softvr's physics on {result['config'].get('device', 'cpu')}",
             f"steps/s = steps / wall time of the stepping calls (median of {result['config']['repeat']} round-robin runs); "
             "pen = deepest node below the plane over the run;",
             "bottom / centre = lowest node / node centroid at the end; contacts = last step; "
             "cores = process CPU time / wall time of the stepping calls"]
    head = (f"{'engine':<9} {'tets':>5} {'steps/s':>8} {'x real':>7} {'vs fastest peer':>15} {'max pen mm':>10} "
            f"{'bottom mm':>9} {'centre mm':>9} {'contacts':>8} {'PGS it':>12} {'cores':>5}  notes")
    lines += [head, "-" * len(head)]
    for r in result["engines"]:
        if r["status"] != "ok":
            lines.append(f"{r['engine']:<9} {r['reason']}")
            continue
        ratio = "-" if r.get("vs_fastest_peer") is None else f"{r['vs_fastest_peer']:.3f}"
        contacts = "-" if r["contacts_end"] is None else str(r["contacts_end"])
        pgs = f"{r['pgs_iterations_end']} (max {r['pgs_iterations_max']})" if "pgs_iterations_end" in r else "-"
        lines.append(f"{r['engine']:<9} {r['tets']:>5} {r['steps_per_s']:>8.1f} {r['real_time_factor']:>7.2f} "
                     f"{ratio:>15} {_mm(r['max_penetration_m'], 2):>10} {_mm(r['bottom_end_m'], 2):>9} "
                     f"{_mm(r['centre_end_m'], 1):>9} {contacts:>8} {pgs:>12} {r['cores_used']:>5.2f}  "
                     f"{r['material']}: {r['note']}")
    candy = result.get("candy")
    if candy is not None:
        lines += ["", f"Candy scene (thesis Fig. 4.1 without adhesion, softvr only): {candy['tets']} tets, "
                      f"{candy['collision_triangles']} collision triangles, {candy['bodies']} bodies, dt "
                      f"{candy['dt_s'] * 1e3:g} ms, {candy['steps']} steps",
                  f"  {candy['ms_per_step']:.0f} ms per step (in contact {candy['ms_per_step_in_contact'] or 0:.0f}, "
                  f"max {candy['ms_per_step_max']:.0f}; after a first step of {candy['first_step_ms']:.0f} ms that loads the scene), "
                  f"{candy['real_time_factor']:.3f}x real time; contacts mean "
                  f"{candy['contacts_mean']:.0f} / max {candy['contacts_max']}; PGS sweeps mean "
                  f"{candy['pgs_iterations_mean']:.0f} / max {candy['pgs_iterations_max']}; residual max "
                  f"{candy['residual_max_m_s']:.2g} m/s; thesis: {candy['thesis_s_per_step'] * 1e3:.0f} ms per step "
                  f"(1.8 GHz Core 2 Duo, 97 contacts mean)"]
    cubes = result.get("cubes")
    if cubes is not None:
        lines += ["", f"{cubes['cubes']} cubes in one scene ({cubes['tets']} tets, {cubes['path']}): "
                      f"{cubes['ms_per_step']:.2f} ms per step = {cubes['steps_per_s']:.0f} "
                      f"steps/s each (after a first step of {cubes['first_step_ms']:.0f} ms), max penetration "
                      f"{_mm(cubes['max_penetration_m'], 2)} mm; GPU target: 64 cubes at >= 1000 steps/s each"]
    lines.append("")
    lines.append(_targets_text(result))
    return "\n".join(lines)


def _mm(metres: float, digits: int) -> str:
    """Millimetres, without a "-0.00" for a node a few nm below the plane."""
    return f"{round(metres * 1e3, digits) + 0.0:.{digits}f}"


def _targets_text(result: dict) -> str:
    t = result["targets"]
    if "softvr_penetration_m" not in t:
        return "targets: softvr did not run"
    pen = (f"penetration {t['softvr_penetration_m'] * 1e3:.3f} mm vs < {TARGET_PENETRATION_M * 1e3:g} mm -> "
           f"{'MET' if t['penetration_met'] else 'NOT met'}")
    if t["softvr_vs_fastest_peer"] is None:
        speed = f"speed vs the fastest peer: no peer ran (target >= {TARGET_SPEEDUP:g}x)"
    else:
        speed = (f"speed {t['softvr_vs_fastest_peer']:.3f}x the fastest peer ({t['fastest_peer']}) vs >= "
                 f"{TARGET_SPEEDUP:g}x -> {'MET' if t['speedup_met'] else 'NOT met'}")
    candy = result.get("candy")
    if candy is None:
        real_time = "candy scale real time: not measured (--no-candy)"
    else:
        real_time = (f"candy scale real time: {candy['ms_per_step']:.0f} ms per {candy['dt_s'] * 1e3:g} ms step -> "
                     f"{'MET' if t['candy_real_time_met'] else 'NOT met'}"
                     + (" (quick scale)" if candy["quick"] else ""))
    return f"targets: {speed}; {pen}; {real_time}"


ENGINE_STYLE = {"softvr": "tab:blue", "mujoco": "tab:orange", "pybullet": "tab:green", "newton": "tab:red"}


def write_plot(result: dict, path) -> None:
    """PNG: penetration and heights over time per engine, and a steps/s bar chart."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sc = CubeScene(**result["config"]["scene"])
    ok = [r for r in result["engines"] if r["status"] == "ok"]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    for r in ok:
        t = (np.arange(len(r["trace"]["min_z"])) + 1) * sc.dt
        col = ENGINE_STYLE.get(r["engine"], "tab:purple")
        zmin = np.asarray(r["trace"]["min_z"])
        axes[0].plot(t, np.maximum(0.0, -zmin) * 1e3, color=col, label=r["engine"])
        axes[1].plot(t, zmin * 1e3, color=col, label=f"{r['engine']} bottom")
        axes[1].plot(t, np.asarray(r["trace"]["mean_z"]) * 1e3, color=col, ls="--", label=f"{r['engine']} centre")
    axes[0].axhline(TARGET_PENETRATION_M * 1e3, color="k", ls=":", lw=1)
    axes[0].text(0, TARGET_PENETRATION_M * 1e3, " 1 mm target", fontsize=7, va="bottom")
    axes[0].set(xlabel="time [s]", ylabel="penetration [mm]", title="deepest node below the plane")
    axes[1].axhline(0.0, color="k", lw=0.8)
    axes[1].set(xlabel="time [s]", ylabel="height [mm]", title="lowest node (solid) and node centroid (dashed)")
    for ax in axes[:2]:
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    ax = axes[2]
    names = [r["engine"] for r in ok]
    rates = [r["steps_per_s"] for r in ok]
    if rates:
        y = np.arange(len(rates))
        ax.barh(y, rates, color=[ENGINE_STYLE.get(n, "tab:purple") for n in names])
        ax.set_yticks(y, [f"{n}\n{r['material']}" for n, r in zip(names, ok)], fontsize=8)
        ax.invert_yaxis()
        for yi, v in zip(y, rates):
            ax.text(v, yi, f" {v:.1f}", va="center", fontsize=8)
        ax.axvline(1.0 / sc.dt, color="k", ls=":", lw=1)
        ax.text(1.0 / sc.dt, len(rates) - 0.5, " real time", fontsize=7, va="bottom")
        fastest = result["config"]["fastest_peer"]
        if fastest:
            goal = TARGET_SPEEDUP * next(r["steps_per_s"] for r in ok if r["engine"] == fastest)
            ax.axvline(goal, color="tab:blue", ls="--", lw=1)
            ax.text(goal, -0.5, f" target {TARGET_SPEEDUP:g}x {fastest}", fontsize=7, va="top", color="tab:blue")
        ax.set(xscale="log", xlabel="steps / s (log)", title="speed")
        ax.grid(True, axis="x", which="both", alpha=0.3)
    skipped = [f"{r['engine']}: {r['reason']}" for r in result["engines"] if r["status"] != "ok"]
    if skipped:
        ax.text(0.02, 0.02, "\n".join(skipped), transform=ax.transAxes, fontsize=6, color="0.4", va="bottom")
    m = result["machine"]
    fig.suptitle(f"soft cube on a plane: {sc.size:g} m, {sc.cells}^3 cells, dt 1/{1 / sc.dt:.0f} s, {sc.duration:g} s "
                 f"- {m['cpu_model']}, {m['cores']} cores, {m['date'][:10]}", fontsize=9)
    fig.tight_layout()

    save_figure(fig, path)


def profile_softvr_step(scene: CubeScene, top: int = 25) -> str:
    """cProfile of one softvr step with the cube resting on the plane (after ``scene.duration``)."""
    import cProfile
    import io
    import pstats

    sim, body = softvr_scene(scene)
    for _ in range(scene.steps):
        sim.step(scene.dt)
    prof = cProfile.Profile()
    prof.enable()
    sol = sim.step(scene.dt)
    prof.disable()
    s = io.StringIO()
    s.write(f"one softvr step at t = {sim.time:.3f} s: {sum(len(i) for i in sol.impulses)} contacts, "
            f"{sol.iterations} sweeps (eq. 5.6 on arrays: eq. 5.2 and the contacts together; per-object "
            f"path: PGS sweeps), {body.last_cg_iterations} CG iterations\n")
    pstats.Stats(prof, stream=s).sort_stats("cumulative").print_stats(top)
    return s.getvalue()


def main(argv: list[str] | None = None) -> int:
    """``softvr bench contact [--quick] [--repeat N] [--engines LIST] [--device D] [--json PATH] [--plot PATH]
    [--profile]``."""
    p = bench_parser("contact", "Soft cube dropped on a plane: softvr vs MuJoCo, PyBullet and Newton (when "
                     "installed); then the thesis' candy scene at full scale (softvr).",
                     quick="0.2 m cube of 3^3 cells, 0.25 s (seconds; CI)",
                     plot="write a PNG: penetration, heights, steps/s")
    p.add_argument("--repeat", type=int, default=None, metavar="N", help="rounds; each runs every engine once, round robin (default 3, quick 1)")
    p.add_argument("--engines", default=",".join(ENGINES), help=f"comma list of {', '.join(ENGINES)}")
    p.add_argument("--profile", action="store_true", help="also print a cProfile of one softvr step in contact")
    p.add_argument("--no-candy", action="store_true", help="skip the candy-scale scene")
    p.add_argument("--device", default="cpu", help="where softvr's physics steps: cpu (default) or cuda")
    p.add_argument("--cubes", type=int, default=0, metavar="N",
                   help="also step N cubes in one scene (softvr only; the GPU target: 64 at >= 1000 steps/s)")
    a = p.parse_args(argv)
    if a.cubes < 0:
        p.error("--cubes must be >= 0")
    if a.repeat is not None and a.repeat < 1:
        p.error("--repeat must be >= 1")
    engines = tuple(e.strip() for e in a.engines.split(",") if e.strip())
    bad = set(engines) - set(ENGINES)
    if bad or not engines:
        p.error(f"unknown engines {sorted(bad)}; choose from {', '.join(ENGINES)}")
    try:
        result = run_contact_bench(quick=a.quick, repeat=a.repeat, engines=engines, progress=not a.no_progress,
                                   candy=not a.no_candy, device=a.device, cubes=a.cubes)
    except SoftvrError as exc:
        print(f"softvr bench contact: {exc}", file=sys.stderr)
        return 2
    profile = profile_softvr_step(QUICK_SCENE if a.quick else FULL_SCENE) if a.profile else ""
    print_and_write(result, format_table(result), a.json, a.plot, write_plot, after_table=profile)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
