"""``softvr bench adhesion``: the candy scene (thesis Fig. 4.1) with and without adhesion.

Both runs use :func:`softvr.bench.contact.run_candy` on the same scene, one after the other in
this process: the bundled ``candy-adhesive.toml`` with its ``candies`` variant (the Jell-O block
and eight candies, every surface adhesive; the held candy and its hand left out), 8 ms steps,
0.8 s simulated (``--quick``: its ``quick`` variant too, 0.16 s), the plain run with its ``dry``
variant too (the same scene, every adhesion off). Reported per run: ms per step (mean over all steps and over the
steps with contacts), contacts (mean / max), contacts pulling (negative normal impulse:
adhesion at work), PGS sweeps (mean / max) and the largest normal-velocity residual. The cost
of adhesion at equal contact count is the ratio of the mean ms per contact-step of the steps
with contacts (adhesive / plain). The plot is the thesis' Fig. 4.4: contacts and ms per step
over time, with and without adhesion. Side by side, the pull-off case (:data:`PULL_OFF`): a
cube pulled off an adhesive plane in softvr and in MuJoCo (``adhesion`` actuator), force at
separation against the prediction and steps/s; and its lift-vs-pull curve in the plot.

Targets (issue): the whole candy scene in real time (<= 8 ms per 8 ms step; the thesis took
400 ms with adhesion, 250 ms without), and adhesion's cost at equal contact count <= 1.2x
plain contact; issue 16's step on this 2-core CPU: the plain candy <= 40 ms a step
(:data:`TARGET_CANDY_MS`).

Examples
--------
``softvr bench adhesion --quick`` (seconds), or the full run
``softvr bench adhesion --json bench-results/adhesion.json --plot docs/img/bench_adhesion.png``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from softvr import Scene
from softvr.app import Player
from softvr.bench.contact import _git_commit, run_candy
from softvr.bench._report import bench_parser, print_and_write, save_figure
from softvr.bench.volume import _loadavg, _machine_info
from softvr.collision import Plane
from softvr.contact import Adhesion
from softvr.device import resolve_device
from softvr.dynamics import RigidBody, RigidPoints
from softvr.model.shapes import box_surface

__all__ = ["PULL_OFF", "PullOffPlayer", "SCENE", "TARGET_CANDY_MS", "TARGET_COST_RATIO", "format_table", "main",
           "mujoco_pull_off", "run_adhesion_bench", "softvr_pull_off", "write_plot"]

#: The bundled scene both runs play (its ``candies`` variant), the plain one with its ``dry``
#: variant too (adhesion off).
SCENE = "candy-adhesive.toml"
#: Adhesion's cost at equal contact count, x plain contact.
TARGET_COST_RATIO = 1.2
TARGET_CANDY_MS = 40.0  # [ms] the plain candy's step on a 2-core CPU (issue 16)

#: The pull-off case: a 10 cm rigid cube (800 kg/m^3) on an adhesive plane, pulled up by a force
#: ramped at 40 N/s, dt 2 ms. softvr: C = 1e7 N/m^3, W = 1 J/m^2, eta = 1e-3 J s/m^2, the
#: cube's surface 4 x 4 quads per face (25 bottom contacts whose areas, the surface around each
#: projected on the plane, sum to the bottom face's (10 cm)^2), so debonding starts at
#: F* = m g + sum(A) sqrt(W C) (tests/contact/test_adhesion.py). MuJoCo: an
#: ``adhesion`` actuator on the cube with gain sum(A) sqrt(W C) [N] (its pull-off force limit).
PULL_OFF = dict(edge=0.1, quads=4, density=800.0, stiffness=1e7, max_energy=1.0, viscosity=1e-3, rate=40.0,
                dt=0.002, lift=0.004)
#: Thesis 4.4: seconds per 8 ms step with and without adhesion (1.8 GHz Core 2 Duo).
THESIS_S_PER_STEP = {"adhesion": 0.4, "plain": 0.25}


def _cost_per_contact(run: dict) -> float | None:
    """Mean of ms per contact over the steps with contacts."""
    ms = 1e3 * np.asarray(run["trace"]["step_s"])
    contacts = np.asarray(run["trace"]["contacts"])
    busy = contacts > 0
    return float(np.mean(ms[busy] / contacts[busy])) if busy.any() else None


def _pull_off_prediction(case: dict) -> tuple[float, float]:
    """(adhesive force limit sum(A) sqrt(W C) [N], predicted separation force m g + that [N])."""
    area = case["edge"] ** 2  # the bottom face: the contacts' projected areas sum to it
    limit = area * float(np.sqrt(case["stiffness"] * case["max_energy"]))
    return limit, case["density"] * case["edge"] ** 3 * 9.81 + limit


class PullOffPlayer(Player):
    """The pull-off case (:data:`PULL_OFF`) played headless by the one player, one step a frame
    (nothing drawn, no frame measures: :attr:`~softvr.app.Player.frame_measures`): its
    :meth:`drive` hook pulls the cube up with ``pull`` [N]."""

    name = "pull-off"
    frame_measures = False

    def __init__(self, case: dict = PULL_OFF):
        edge = case["edge"]
        verts, tris = box_surface((edge,) * 3, case["quads"])
        self.cube = RigidBody.box((edge,) * 3, case["density"], position=(0.0, 0.0, edge / 2), name="cube")
        adhesion = Adhesion(stiffness=case["stiffness"], max_energy=case["max_energy"], viscosity=case["viscosity"])
        scene = Scene(contact_margin=0.002)
        scene.add_body(self.cube, collision_points=RigidPoints(self.cube, verts - edge / 2), collision_triangles=tris,
                       adhesion=adhesion)
        scene.add_plane(Plane(friction=0.5), adhesion=adhesion)
        self.pull = 0.0
        super().__init__(scene, case["dt"], 1, 1, 64, 48)

    def drive(self) -> None:
        self.scene.external[0] = np.array([0.0, 0.0, self.pull, 0.0, 0.0, 0.0])


def softvr_pull_off(case: dict = PULL_OFF) -> dict:
    """softvr on the pull-off case, played by :class:`PullOffPlayer`: the force when the cube
    has lifted ``lift`` [m], the trace of force and lift, and steps/s of the ramp."""
    player = PullOffPlayer(case)
    for _ in range(20):
        player.step()
    return _ramp(lambda force: setattr(player, "pull", force), player.step,
                 lambda: float(player.cube.position[2]) - case["edge"] / 2, case)


def mujoco_pull_off(case: dict = PULL_OFF) -> dict:
    """MuJoCo on the pull-off case (adhesion actuator, default soft contacts), or a record
    saying it is not installed."""
    try:
        import mujoco
    except ImportError:
        return {"status": "skipped: not installed (pip install softvr[peers])"}
    limit, _ = _pull_off_prediction(case)
    h = case["edge"] / 2
    xml = f"""<mujoco><option timestep="{case['dt']}"/><worldbody>
      <geom type="plane" size="1 1 .1" friction="0.5"/>
      <body name="cube" pos="0 0 {h}"><freejoint/><geom type="box" size="{h} {h} {h}" density="{case['density']}"/>
      </body></worldbody>
      <actuator><adhesion body="cube" ctrlrange="0 1" gain="{limit}"/></actuator></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.ctrl[0] = 1.0
    cube = model.body("cube").id
    for _ in range(20):
        mujoco.mj_step(model, data)
    rest = float(data.xpos[cube][2])

    def push(force):
        data.xfrc_applied[cube, 2] = force

    out = _ramp(push, lambda: mujoco.mj_step(model, data), lambda: float(data.xpos[cube][2]) - rest, case)
    out["version"] = mujoco.__version__
    return out


def _ramp(push, step, lift, case: dict) -> dict:
    """Ramp the pull at ``rate`` until the lift exceeds ``case["lift"]``; force and lift trace."""
    forces, lifts = [], []
    elapsed = 0.0
    _, predicted = _pull_off_prediction(case)
    for n in range(1, int(3 * predicted / (case["rate"] * case["dt"]))):
        force = case["rate"] * n * case["dt"]
        push(force)
        t = time.perf_counter()
        step()
        elapsed += time.perf_counter() - t
        forces.append(force)
        lifts.append(lift())
        if lifts[-1] > case["lift"]:
            return {"status": "ok", "separation_force_n": force, "steps": n, "steps_per_s": n / elapsed,
                    "trace": {"force_n": forces, "lift_m": lifts}}
    return {"status": "failed: never separated", "trace": {"force_n": forces, "lift_m": lifts}}


def run_adhesion_bench(*, quick: bool = False, progress: bool = True) -> dict:
    """Run the candy scene without, then with adhesion; returns the JSON-ready result."""
    resolve_device("cpu")
    t0 = time.perf_counter()
    load_start = _loadavg()
    runs = {"plain": run_candy(quick=quick, progress=progress, scene=SCENE, variants=("candies", "dry")),
            "adhesion": run_candy(quick=quick, progress=progress, scene=SCENE, variants=("candies",))}
    for name, run in runs.items():
        run["ms_per_contact"] = _cost_per_contact(run)
        run["pulling_contacts_max"] = int(max(run["trace"]["pulling_contacts"]))
        run["thesis_s_per_step"] = THESIS_S_PER_STEP[name]
    limit, predicted = _pull_off_prediction(PULL_OFF)
    pull_off = {"case": PULL_OFF, "adhesive_limit_n": limit, "predicted_separation_n": predicted,
                "softvr": softvr_pull_off(), "mujoco": mujoco_pull_off()}
    plain, sticky = runs["plain"]["ms_per_contact"], runs["adhesion"]["ms_per_contact"]
    ratio = None if not plain or sticky is None else sticky / plain
    machine = _machine_info("cpu")
    machine["softvr_commit"] = _git_commit()
    return {
        "schema": "softvr-bench-adhesion/1",
        "machine": machine,
        "config": {"quick": quick, "scene": SCENE},
        "runs": runs,
        "pull_off": pull_off,
        "targets": {"real_time_ms": runs["adhesion"]["dt_s"] * 1e3,
                    "real_time_met": runs["adhesion"]["ms_per_step"] <= runs["adhesion"]["dt_s"] * 1e3,
                    "cost_ratio": ratio, "cost_ratio_target": TARGET_COST_RATIO,
                    "cost_ratio_met": None if ratio is None else ratio <= TARGET_COST_RATIO,
                    "candy_ms": TARGET_CANDY_MS, "candy_met": runs["plain"]["ms_per_step"] <= TARGET_CANDY_MS},
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
    head = (f"{'run':<9} {'ms/step':>8} {'in contact':>10} {'first':>6} {'contacts':>13} {'pulling':>7} {'PGS sweeps':>13} "
            f"{'residual':>9} {'ms/contact':>10} {'thesis ms':>9}")
    lines += [head, "-" * len(head)]
    for name, r in runs.items():
        lines.append(f"{name:<9} {r['ms_per_step']:>8.1f} {r['ms_per_step_in_contact'] or 0:>10.1f} {r['first_step_ms']:>6.0f} "
                     f"{r['contacts_mean']:>6.0f} / {r['contacts_max']:<4d} {r['pulling_contacts_max']:>7d} "
                     f"{r['pgs_iterations_mean']:>6.0f} / {r['pgs_iterations_max']:<4d} {r['residual_max_m_s']:>9.2g} "
                     f"{r['ms_per_contact'] or 0:>10.3f} {r['thesis_s_per_step'] * 1e3:>9.0f}")
    lines.append("ms/step, in contact: the steps after the first; first: the first step [ms], which loads the scene")
    pull = result["pull_off"]
    lines += ["", f"Pull-off: 10 cm cube on an adhesive plane, pull ramped at {pull['case']['rate']:g} N/s, dt "
                  f"{pull['case']['dt'] * 1e3:g} ms; predicted separation m g + sum(A) sqrt(W C) = "
                  f"{pull['predicted_separation_n']:.2f} N"]
    for engine in ("softvr", "mujoco"):
        r = pull[engine]
        if r["status"] != "ok":
            lines.append(f"  {engine:<7} {r['status']}")
            continue
        lines.append(f"  {engine:<7} separated at {r['separation_force_n']:.2f} N "
                     f"({r['separation_force_n'] / pull['predicted_separation_n'] - 1:+.1%}), "
                     f"{r['steps_per_s']:.0f} steps/s")
    t = result["targets"]
    ratio = "-" if t["cost_ratio"] is None else f"{t['cost_ratio']:.2f}x"
    lines += ["", f"targets: real time {runs['adhesion']['ms_per_step']:.0f} ms per {t['real_time_ms']:g} ms step -> "
                  f"{'MET' if t['real_time_met'] else 'NOT met'}; adhesion's cost at equal contact count {ratio} vs "
                  f"<= {TARGET_COST_RATIO:g}x -> {'MET' if t['cost_ratio_met'] else 'NOT met'}; plain candy "
                  f"{runs['plain']['ms_per_step']:.1f} ms per step vs <= {t['candy_ms']:g} -> "
                  f"{'MET' if t['candy_met'] else 'NOT met'}"]
    return "\n".join(lines)


def write_plot(result: dict, path) -> None:
    """PNG like thesis Fig. 4.4: contacts and ms per step over time, with and without adhesion."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 4.2))
    for name, color in (("plain", "tab:blue"), ("adhesion", "tab:red")):
        r = result["runs"][name]
        t = (np.arange(len(r["trace"]["contacts"])) + 1) * r["dt_s"]
        axes[0].plot(t, r["trace"]["contacts"], color=color, label=name)
        axes[1].plot(t, 1e3 * np.asarray(r["trace"]["step_s"]), color=color, label=name)
    axes[0].set(xlabel="time [s]", ylabel="contacts", title="contact constraints per step")
    axes[1].set(xlabel="time [s]", ylabel="ms per step", title="time per 8 ms step")
    pull = result["pull_off"]
    for engine, color in (("softvr", "tab:red"), ("mujoco", "tab:orange")):
        r = pull[engine]
        if "trace" in r:
            axes[2].plot(r["trace"]["force_n"], 1e3 * np.asarray(r["trace"]["lift_m"]), color=color, label=engine)
    axes[2].axvline(pull["predicted_separation_n"], color="k", ls=":", lw=1, label="predicted F*")
    axes[2].set(xlabel="pull [N]", ylabel="lift [mm]", title="pull-off of an adhesive cube")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    m = result["machine"]
    fig.suptitle(f"candy scene with and without adhesion - {m['cpu_model']}, {m['cores']} cores, {m['date'][:10]}",
                 fontsize=9)
    fig.tight_layout()

    save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    """``softvr bench adhesion [--quick] [--json PATH] [--plot PATH]``."""
    p = bench_parser("adhesion", "The candy scene (thesis Fig. 4.1) with and without adhesion.",
                     quick="the small candy scene, 0.16 s (seconds; CI)",
                     plot="write a PNG: contacts and ms per step (thesis Fig. 4.4)")
    a = p.parse_args(argv)
    result = run_adhesion_bench(quick=a.quick, progress=not a.no_progress)
    print_and_write(result, format_table(result), a.json, a.plot, write_plot)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
