"""``softvr bench scene``: the scene-file layer, from the file to the frames (issue 7).

Every bundled scene (:data:`softvr.scene.BUNDLED`, ``src/softvr/scenes/*.toml``; ``--quick``:
soft-cube, box-stack and cloth-sphere), one after the other in this process, in the table's order:

* **read** [ms]: :func:`softvr.scene.read_any` (TOML parse and validation of every field),
* **build** [ms]: :class:`softvr.scene.SceneExample` (bodies, tet meshes, collision surfaces,
  model parts, the CT volume's FEM body; tools start their haptic loop),
* **check** [ms]: :meth:`~softvr.scene.SceneExample.start_problems` (crossing surface triangles
  between bodies, bodies below a plane: the collision-free start of ``softvr check``),

read and build each the median of ``repeat`` runs (5, ``--quick`` 3; the first pays the
imports), then ``frames`` frames (30, ``--quick`` 3) rendered offscreen at 640 x 480: the
**first frame** alone (step + render: Warp's kernel loads, the renderer's window and first
upload), then medians over the others of **step** (``step_ms``: the frame's ``steps_per_frame``
physics steps), **render** (``render_ms``) and **frame** (the wall time of ``step()`` and
``render()`` together, with what runs between: energies, the CT volume rasterized through the
deformed tets). **x real** = simulated ms per frame / step ms = ``dt * steps_per_frame * 1000 /
step_ms``. **step by stage**: the medians of the frame's physics split by
:data:`softvr.sim.STAGES` (``stage_ms``; per frame in ``stage_trace``): dynamics (eq. 5.2),
collision, contact (eqs. 5.5-5.6 and adhesion), integrate. One-off costs (imports, module loads,
VTK's first window) fall on the first scene that needs them. A scene that cannot be built here (the CT scenes without the Debian package
``invesalius-examples``) gets a row saying why.

**glTF vs TOML.** soft-cube.toml's scene written twice into a temporary folder: as a GLB whose
box mesh node carries ``softvr_*`` extras (what Blender's exporter writes for custom
properties) and as a TOML scene holding the same box mesh (an OBJ beside it); both build the
mesh path (cubes of edge / cells metres around the mesh), so they give the same body. Read and
build [ms] of each (medians of ``repeat``), with the nodes and tets built.

**Peer.** box-stack.toml (five rigid boxes resting on the ground) written as MJCF
(:func:`box_stack_mjcf`: same sizes, density, friction, gravity, dt) and run in MuJoCo when it is
installed (``pip install softvr[peers]``; else a row saying so): load = ``MjModel.from_xml_string``
(parse + compile) [ms], median of ``repeat``; ms per frame = ``steps_per_frame`` ``mj_step``
calls, first frame alone, median of the rest. Ratios softvr / MuJoCo of load (read + build), of
ms per frame (step: the frame's ``steps_per_frame`` ``Scene.step`` calls with the Player's
hooks and the deepest penetration after every step, read off the rigid arrays by one recorded
launch, ~5 us; the energies and contact counts come after the frame's steps, outside it) and of
the frame's physics alone (``physics_ms``: the sum of ``Scene.step``'s stage times, what
``mj_step`` compares to).

Examples
--------
``softvr bench scene --quick`` (seconds), ``softvr bench scene --scenes candy.toml``, or the
full run ``softvr bench scene --json bench-results/scene.json --plot docs/img/bench_scene.png``.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from softvr.bench._contact_peers import NOT_INSTALLED
from softvr.bench._report import bench_parser, print_and_write, save_figure
from softvr.bench.contact import _git_commit
from softvr.bench.volume import _loadavg, _machine_info
from softvr.device import resolve_device
from softvr.errors import SoftvrError
from softvr.scene import BUNDLED, FORMAT, SceneExample, bundled, read_any, read_scene
from softvr.sim import STAGES as STEP_STAGES

__all__ = ["IMAGE", "QUICK_SCENES", "box_stack_mjcf", "format_table", "main", "run_mujoco", "run_scene",
           "run_scene_bench", "soft_cube_twins", "time_load", "write_plot"]

#: Scenes of ``--quick``.
QUICK_SCENES = ("soft-cube.toml", "box-stack.toml", "cloth-sphere.toml")
#: Offscreen image size [pixels] of every scene's frames.
IMAGE = (640, 480)
#: The peer's scene.
PEER_SCENE = "box-stack.toml"
#: Table / plot stages: JSON key -> label.
STAGES = {"read_ms": "read", "build_ms": "build", "check_ms": "check", "first_frame_ms": "1st frame",
          "step_ms": "step", "render_ms": "render"}


def _ms(since: float) -> float:
    """Milliseconds from ``since`` (a :func:`time.perf_counter` value) to now."""
    return 1e3 * (time.perf_counter() - since)


def time_load(path, repeat: int) -> tuple[list[float], list[float], SceneExample]:
    """Read ``path`` and build its :class:`~softvr.scene.SceneExample` ``repeat`` times.

    Returns
    -------
    read_ms, build_ms : list of float
        Each run's time [ms].
    example : SceneExample
        The last one built (open: the caller closes it); the others are closed.
    """
    read: list[float] = []
    build: list[float] = []
    example: SceneExample | None = None
    for _ in range(repeat):
        if example is not None:
            example.close()
        t = time.perf_counter()
        scene = read_any(path)
        read.append(_ms(t))
        t = time.perf_counter()
        example = SceneExample(scene, width=IMAGE[0], height=IMAGE[1])
        build.append(_ms(t))
    assert example is not None  # repeat >= 1
    return read, build, example


def _size(example) -> dict:
    """Bodies, deformable nodes and tets of a built scene."""
    bodies = example.scene.bodies
    return {"bodies": len(bodies), "nodes": sum(len(b.q) for b in bodies if hasattr(b, "q")),
            "tets": sum(len(b.tets) for b in bodies if hasattr(b, "tets"))}


def run_scene(path, *, frames: int, repeat: int) -> dict:
    """One scene file's row (module docstring): times [ms], per-frame traces, sizes; ``status``
    "ok", or "failed: <why>" when it cannot be built here."""
    try:
        read, build, example = time_load(path, repeat)
    except SoftvrError as exc:
        return {"scene": Path(path).name, "status": f"failed: {exc}".splitlines()[0]}
    with example:
        t = time.perf_counter()
        problems = example.start_problems()
        check = _ms(t)
        trace: dict[str, list] = {"step_ms": [], "render_ms": [], "frame_ms": []}
        stages = []
        for _ in range(frames):
            t = time.perf_counter()
            example.step()
            example.render()
            trace["frame_ms"].append(_ms(t))
            trace["step_ms"].append(example.metrics[-1]["step_ms"])
            trace["render_ms"].append(example.metrics[-1]["render_ms"])
            stages.append(example.metrics[-1]["stage_ms"])
        size = _size(example)
        dt, steps = example.dt, example.steps_per_frame
    step = statistics.median(trace["step_ms"][1:])
    return {"scene": Path(path).name, "status": "ok", **size, "dt_s": dt, "steps_per_frame": steps,
            "frames": frames, "start_problems": len(problems),
            "read_ms": statistics.median(read), "build_ms": statistics.median(build), "check_ms": check,
            "first_frame_ms": trace["frame_ms"][0], "first_step_ms": trace["step_ms"][0],
            "first_render_ms": trace["render_ms"][0],
            "step_ms": step, "physics_ms": statistics.median(sum(f.values()) for f in stages[1:]),
            "render_ms": statistics.median(trace["render_ms"][1:]),
            "stage_ms": {k: statistics.median(f[k] for f in stages[1:]) for k in STEP_STAGES}, "stage_trace": stages,
            "frame_ms": statistics.median(trace["frame_ms"][1:]),
            "real_time_factor": dt * steps * 1e3 / step,
            "samples": {"read_ms": read, "build_ms": build}, "trace": trace}


def soft_cube_twins(folder) -> tuple[Path, Path]:
    """soft-cube.toml's scene written into ``folder`` as ``soft-cube.glb`` (a box mesh node with
    ``softvr_*`` extras, glTF y-up) and as ``soft-cube-mesh.toml`` (the same box as an OBJ
    mesh); returns (GLB, TOML)."""
    import json
    import struct

    import trimesh
    from scipy.spatial.transform import Rotation

    folder = Path(folder)
    source = read_scene(bundled("soft-cube.toml"))
    (body,), sim = source.bodies, source.simulation
    material = source.materials[body.material]
    edge = float(np.max(body.size) / np.max(body.cells))  # cube edge of the mesh path [m]
    rotation = Rotation.from_euler("xyz", body.rotation, degrees=True).as_matrix()  # the format's x, y, z angles
    # softvr's z-up (x, y, z) is glTF's y-up (x, z, -y).
    y_up = np.eye(4)
    y_up[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, body.position
    mesh = trimesh.creation.box(body.size)
    mesh.export(folder / "soft-cube.obj")
    gltf_mesh = mesh.copy()
    gltf_mesh.apply_transform(y_up)
    scene = trimesh.Scene()
    scene.add_geometry(gltf_mesh, node_name=body.name, geom_name="cube", transform=y_up @ pose @ y_up.T)
    data = scene.export(file_type="glb")
    length = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + length])
    doc["nodes"][0]["extras"] = {"softvr_type": body.type, "softvr_cells": edge,
                                 **{f"softvr_{k}": v for k, v in material.items()}}
    doc["scenes"][doc.get("scene", 0)]["extras"] = {f"softvr_{k}": sim[k] for k in
                                                    ("dt", "steps_per_frame", "frames", "friction")}
    chunk = json.dumps(doc).encode()
    chunk += b" " * (-len(chunk) % 4)
    chunks = struct.pack("<I4s", len(chunk), b"JSON") + chunk + data[20 + length:]
    glb = folder / "soft-cube.glb"
    glb.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)
    toml = folder / "soft-cube-mesh.toml"
    toml.write_text("\n".join([
        f'format = "{FORMAT}"', "[simulation]", *(f"{k} = {sim[k]!r}" for k in ("dt", "steps_per_frame", "frames",
                                                                               "friction")),
        f"[material.{body.material}]", *(f"{k} = {v!r}" for k, v in material.items()),
        "[[plane]]", f"friction = {source.planes[0]['friction']!r}",
        "[[body]]", f'name = "{body.name}"', f'type = "{body.type}"', 'mesh = "soft-cube.obj"', f"cells = {edge!r}",
        f'material = "{body.material}"', f"position = {list(body.position)!r}",
        f"rotation = {list(body.rotation)!r}", ""]))
    return glb, toml


def _gltf_vs_toml(repeat: int) -> dict:
    """Read and build [ms] of soft-cube as GLB and as TOML (:func:`soft_cube_twins`)."""
    out = {}
    with tempfile.TemporaryDirectory() as folder:
        for kind, path in zip(("gltf", "toml"), soft_cube_twins(folder)):
            read, build, example = time_load(path, repeat)
            with example:
                out[kind] = {"file": path.name, **_size(example),
                             "read_ms": statistics.median(read), "build_ms": statistics.median(build),
                             "samples": {"read_ms": read, "build_ms": build}}
    return out


def box_stack_mjcf(scene) -> str:
    """MJCF of a scene of resting, unrotated rigid boxes on the ground plane (box-stack.toml):
    same sizes, densities, friction, gravity and dt; MuJoCo's defaults otherwise (Newton solver,
    soft contacts)."""
    sim = scene.simulation
    (plane,) = scene.planes
    if tuple(plane["normal"]) != (0.0, 0.0, 1.0) or any(plane["point"]):
        raise ValueError(f"{scene.path}: MJCF here needs the ground plane z = 0")
    bodies = []
    for b in scene.bodies:
        if (b.type, b.shape) != ("rigid", "box") or any(b.rotation) or any(b.velocity) or any(b.angular_velocity):
            raise ValueError(f"{scene.path}: body {b.name!r} is not a resting, unrotated rigid box")
        bodies.append(f'<body pos="{" ".join(map(repr, b.position))}"><freejoint/><geom type="box" '
                      f'size="{" ".join(repr(s / 2) for s in b.size)}" '
                      f'density="{scene.materials[b.material]["density"]!r}" friction="{sim["friction"]!r}"/></body>')
    return (f'<mujoco><option timestep="{sim["dt"]!r}" gravity="{" ".join(map(repr, sim["gravity"]))}"/>'
            f'<worldbody><geom type="plane" size="5 5 .1" friction="{plane["friction"]!r}"/>'
            + "".join(bodies) + "</worldbody></mujoco>")


def run_mujoco(scene, *, frames: int, repeat: int) -> dict:
    """MuJoCo on :func:`box_stack_mjcf` of ``scene``: load [ms] (median of ``repeat``), the
    first frame and the median ms per frame of the rest; or a record saying it is not
    installed."""
    try:
        import mujoco
    except ImportError:
        return {"status": NOT_INSTALLED}
    xml = box_stack_mjcf(scene)
    load = []
    for _ in range(repeat):
        t = time.perf_counter()
        model = mujoco.MjModel.from_xml_string(xml)
        load.append(_ms(t))
    data = mujoco.MjData(model)
    steps = scene.simulation["steps_per_frame"]
    trace = []
    for _ in range(frames):
        t = time.perf_counter()
        for _ in range(steps):
            mujoco.mj_step(model, data)
        trace.append(_ms(t))
    frame = statistics.median(trace[1:])
    return {"status": "ok", "version": mujoco.__version__, "bodies": int(model.nbody) - 1,
            "mass_kg": float(model.body_mass.sum()), "load_ms": statistics.median(load),
            "first_frame_ms": trace[0], "frame_ms": frame,
            "real_time_factor": model.opt.timestep * steps * 1e3 / frame,
            "samples": {"load_ms": load}, "trace": {"frame_ms": trace}}


def run_scene_bench(*, quick: bool = False, scenes=None, progress: bool = True) -> dict:
    """Every scene's row, glTF vs TOML and the MuJoCo peer (module docstring); the JSON-ready
    result. ``scenes``: bundled scene file names (default: all; ``quick``: :data:`QUICK_SCENES`)."""
    from tqdm import tqdm

    t0 = time.perf_counter()
    load_start = _loadavg()
    frames, repeat = (3, 3) if quick else (30, 5)
    names = list(scenes or (QUICK_SCENES if quick else sorted(p.name for p in BUNDLED.glob("*.toml"))))
    rows = []
    with tqdm(names, desc="bench scene", unit="scene", disable=not progress) as bar:
        for name in bar:
            bar.set_postfix_str(name)
            rows.append(run_scene(bundled(name), frames=frames, repeat=repeat))
    gltf = _gltf_vs_toml(repeat)
    mujoco = run_mujoco(read_scene(bundled(PEER_SCENE)), frames=frames, repeat=repeat)
    softvr = next((r for r in rows if r["scene"] == PEER_SCENE and r["status"] == "ok"), None)
    ratios = None
    if softvr is not None and mujoco["status"] == "ok":
        ratios = {"load": (softvr["read_ms"] + softvr["build_ms"]) / mujoco["load_ms"],
                  "frame": softvr["step_ms"] / mujoco["frame_ms"],
                  "physics": softvr["physics_ms"] / mujoco["frame_ms"]}
    machine = _machine_info(resolve_device())
    machine["softvr_commit"] = _git_commit()
    return {
        "schema": "softvr-bench-scene/1",
        "machine": machine,
        "config": {"quick": quick, "frames": frames, "repeat": repeat, "image": list(IMAGE), "scenes": names},
        "scenes": rows,
        "gltf_vs_toml": gltf,
        "peer": {"scene": PEER_SCENE, "mujoco": mujoco, "softvr_over_mujoco": ratios},
        "loadavg_start": load_start,
        "loadavg_end": _loadavg(),
        "wall_s": time.perf_counter() - t0,
    }


def format_table(result: dict) -> str:
    c = result["config"]
    lines = [f"Scene files, {c['frames']} frames each at {c['image'][0]} x {c['image'][1]}; read and build: median "
             f"of {c['repeat']}; step, render, frame: median of frames 2..{c['frames']} [ms]; x real = dt * "
             "steps_per_frame / step"]
    head = (f"{'scene':<26} {'bodies':>6} {'tets':>6} {'read':>6} {'build':>7} {'check':>6} {'1st frame':>9} "
            f"{'step':>7} {'render':>7} {'frame':>7} {'x real':>7}  step by stage: dyn / coll / contact / integ")
    lines += [head, "-" * len(head)]
    for r in result["scenes"]:
        if r["status"] != "ok":
            lines.append(f"{r['scene']:<26} {r['status']}")
            continue
        lines.append(f"{r['scene']:<26} {r['bodies']:>6} {r['tets']:>6} {r['read_ms']:>6.1f} {r['build_ms']:>7.1f} "
                     f"{r['check_ms']:>6.1f} {r['first_frame_ms']:>9.0f} {r['step_ms']:>7.1f} {r['render_ms']:>7.1f} "
                     f"{r['frame_ms']:>7.1f} {r['real_time_factor']:>7.3f}  "
                     + " / ".join(f"{r['stage_ms'][k]:.1f}" for k in STEP_STAGES))
    g = result["gltf_vs_toml"]
    lines += ["", "soft-cube as glTF (box mesh node, softvr_* extras) vs TOML (the same box mesh as OBJ) [ms]:"]
    for kind in ("gltf", "toml"):
        r = g[kind]
        lines.append(f"  {r['file']:<20} read {r['read_ms']:>6.2f}  build {r['build_ms']:>6.1f}"
                     f"  ({r['nodes']} nodes, {r['tets']} tets)")
    lines.append(f"  glTF / TOML: read {g['gltf']['read_ms'] / g['toml']['read_ms']:.2f}x, build "
                 f"{g['gltf']['build_ms'] / g['toml']['build_ms']:.2f}x")
    peer = result["peer"]
    m = peer["mujoco"]
    lines += ["", f"Peer: {peer['scene']} in MuJoCo (MJCF of the same boxes) [ms]:"]
    if m["status"] != "ok":
        lines.append(f"  mujoco   {m['status']}")
    else:
        lines.append(f"  mujoco {m['version']}: load (from_xml_string) {m['load_ms']:.2f}, first frame "
                     f"{m['first_frame_ms']:.3f}, frame {m['frame_ms']:.3f}, x real {m['real_time_factor']:.0f}")
    ratios = peer["softvr_over_mujoco"]
    if ratios is not None:
        lines.append(f"  softvr / MuJoCo: load (read + build) {ratios['load']:.1f}x, ms per frame "
                     f"{ratios['frame']:.1f}x (the frame's steps alone, Scene.step as mj_step: "
                     f"{ratios['physics']:.1f}x; the rest: the hooks, the penetration after each step)")
    return "\n".join(lines)


def write_plot(result: dict, path) -> None:
    """PNG: ms per stage per scene (log), and the glTF / TOML and softvr / MuJoCo comparisons."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in result["scenes"] if r["status"] == "ok"]
    fig, axes = plt.subplots(1, 2, figsize=(17, 5), gridspec_kw={"width_ratios": [3, 1]})
    ax = axes[0]
    x = np.arange(len(ok))
    width = 0.8 / len(STAGES)
    for k, (key, label) in enumerate(STAGES.items()):
        ax.bar(x + (k - (len(STAGES) - 1) / 2) * width, [r[key] for r in ok], width, label=label)
    ax.set_xticks(x, [r["scene"].removesuffix(".toml") for r in ok], rotation=30, ha="right", fontsize=8)
    ax.set(yscale="log", ylabel="ms (log)", title="scene files: read, build, check, first frame; "
                                                   "step and render: median ms per frame")
    ax.set_ylim(top=30 * max((r[key] for r in ok for key in STAGES), default=1.0))  # room for the legend
    ax.legend(fontsize=8, ncol=len(STAGES), loc="upper left")
    ax = axes[1]
    g, m, softvr = result["gltf_vs_toml"], result["peer"]["mujoco"], \
        next((r for r in ok if r["scene"] == result["peer"]["scene"]), None)
    bars = {"soft-cube read\nTOML": g["toml"]["read_ms"], "soft-cube read\nglTF": g["gltf"]["read_ms"],
            "soft-cube build\nTOML": g["toml"]["build_ms"], "soft-cube build\nglTF": g["gltf"]["build_ms"]}
    if softvr is not None:
        bars |= {"box-stack load\nsoftvr": softvr["read_ms"] + softvr["build_ms"],
                 "box-stack frame\nsoftvr": softvr["step_ms"]}
    if m["status"] == "ok":
        bars |= {"box-stack load\nMuJoCo": m["load_ms"], "box-stack frame\nMuJoCo": m["frame_ms"]}
    y = np.arange(len(bars))
    ax.barh(y, list(bars.values()), color=["tab:orange" if "MuJoCo" in k else "tab:blue" for k in bars])
    ax.set_yticks(y, list(bars), fontsize=7)
    ax.invert_yaxis()
    for yi, v in zip(y, bars.values()):
        ax.text(v, yi, f" {v:.3g}", va="center", fontsize=7)
    ax.set(xscale="log", xlabel="ms (log)", title="glTF vs TOML; softvr vs MuJoCo")
    if m["status"] != "ok":
        ax.text(0.02, 0.02, f"mujoco: {m['status']}", transform=ax.transAxes, fontsize=6, color="0.4")
    for ax in axes:
        ax.grid(True, axis="y" if ax is axes[0] else "x", which="both", alpha=0.3)
    mi = result["machine"]
    fig.suptitle(f"softvr bench scene - {mi['cpu_model']}, {mi['cores']} cores, {mi['date'][:10]}, "
                 f"{result['config']['frames']} frames at {result['config']['image'][0]} x "
                 f"{result['config']['image'][1]}", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    """``softvr bench scene [--quick] [--scenes NAME ...] [--json PATH] [--plot PATH]``."""
    p = bench_parser("scene", "Scene files: read, build, collision-free start check and frames of every bundled "
                     "scene; glTF vs TOML; box-stack vs MuJoCo.",
                     quick=f"only {', '.join(QUICK_SCENES)}, 3 frames each (seconds; CI)",
                     plot="write a PNG: ms per stage per scene (log), glTF vs TOML, softvr vs MuJoCo")
    available = sorted(p.name for p in BUNDLED.glob("*.toml"))
    p.add_argument("--scenes", nargs="+", metavar="NAME",
                   help=f"bundled scenes to run (default: all; --quick: {' '.join(QUICK_SCENES)})")
    a = p.parse_args(argv)
    bad = sorted(set(a.scenes or ()) - set(available))
    if bad:
        p.error(f"--scenes: no bundled scene {', '.join(bad)}; choose from {', '.join(available)}")
    result = run_scene_bench(quick=a.quick, scenes=a.scenes, progress=not a.no_progress)
    print_and_write(result, format_table(result), a.json, a.plot, write_plot)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
