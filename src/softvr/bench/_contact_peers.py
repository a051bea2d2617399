"""The soft-cube drop of ``softvr bench contact`` in MuJoCo, PyBullet and NVIDIA Newton.

Every peer gets the scene of :class:`softvr.bench.contact.CubeScene` (:mod:`softvr.bench._cube_scene`) (cube edge, cells,
drop height, density, E / nu or the equal Lamé mu / lambda, friction, dt, duration) and is set up
with the calls that worked in ``/work/shared/peers.md``, scaled to the scene:

* **MuJoCo** (``mujoco`` >= 3; 4.0 here): a ``flexcomp`` grid of ``(cells + 1)^3`` vertices,
  6 tets per cell, Saint Venant-Kirchhoff elasticity (``young``, ``poisson``, ``damping=1e-3``),
  CG solver, ``discrete`` integrator, vertex radius 5 mm, plane and flex friction 0.5.
* **PyBullet** (``pybullet`` 3.2): the *same* tet mesh as softvr (:func:`softvr.volume.grid_tet_mesh`,
  5 tets per cell, all positively oriented) written as a legacy VTK file, ``loadSoftBody`` with
  Neo-Hookean mu = lambda, damping 0.01, collision margin 6 mm, face contact, repulsion 800; the
  rigid plane is ``plane.urdf`` (lateral friction 1, so soft x rigid friction = 0.5 x 1).
* **Newton** (``newton`` 1.x, Warp on the CPU): ``add_soft_grid`` (5 tets per cell,
  Neo-Hookean k_mu = k_lambda, k_damp 10), VBD with 10 iterations, penalty ground contact
  ke = 1e4, kd = 10, mu = 0.5. Two deliberate changes from peers.md so that the scene is the
  same: particle radius 5 mm (the builder's default is 0.1 m, a whole cell, which keeps the
  cube floating 10 cm above the plane) and lumped node masses from the density
  (``add_soft_grid`` gives every particle density x cell volume: 729 kg instead of 512 kg).

Each peer runs in its own Python process (``python -m softvr.bench._contact_peers``) so that a
crash in a native library (PyBullet segfaults on a malformed mesh) cannot take the benchmark
down, and their threads and JIT caches do not disturb the others. Only the stepping calls are
timed; reading back node positions for the penetration / height traces is outside the timer.
Before timing, one untimed warm-up simulation of a few steps runs on a separate model (Newton
compiles or loads its Warp kernels there).
"""

from __future__ import annotations

import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from softvr.bench._cube_scene import CubeScene, cube_mesh

__all__ = ["PEERS", "installed", "peer_version", "run_peer", "run_peer_process"]

#: Peer name -> (import name, distribution name, material model, note for the table).
PEERS = {
    "mujoco": ("mujoco", "mujoco", "StVK",
               "MuJoCo flexcomp, 6 tets/cell, StVK, CG solver, vertex radius 5 mm"),
    "pybullet": ("pybullet", "pybullet", "Neo-Hookean",
                 "PyBullet deformable, same tets, Neo-Hookean, collision margin 6 mm"),
    "newton": ("newton", "newton", "Neo-Hookean",
               "Newton VBD 10 it, Neo-Hookean, penalty contact ke 1e4, radius 5 mm"),
}
WARMUP_STEPS = 3
NOT_INSTALLED = "skipped: not installed (pip install softvr[peers])"


def installed(name: str) -> bool:
    """Whether the peer's package can be imported (without importing it)."""
    try:
        return importlib.util.find_spec(PEERS[name][0]) is not None
    except (ImportError, ValueError):
        return False


def peer_version(name: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(PEERS[name][1])
    except metadata.PackageNotFoundError:
        return None


# ----------------------------------------------------------------------------- one simulation
class _Trace:
    """Per-step wall and process CPU time of the stepping call, and the node heights after it."""

    def __init__(self):
        self.step_s: list[float] = []
        self.cpu_s: list[float] = []
        self.min_z: list[float] = []
        self.mean_z: list[float] = []
        self.contacts: list[int | None] = []

    def add(self, seconds: float, cpu_seconds: float, z: np.ndarray, contacts) -> None:
        self.step_s.append(seconds)
        self.cpu_s.append(cpu_seconds)
        self.min_z.append(float(np.min(z)))
        self.mean_z.append(float(np.mean(z)))
        self.contacts.append(None if contacts is None else int(contacts))

    def as_dict(self) -> dict:
        return {"step_s": self.step_s, "cpu_s": self.cpu_s, "min_z": self.min_z, "mean_z": self.mean_z, "contacts": self.contacts}


def _mujoco(scene: dict, steps: int) -> tuple[_Trace, dict]:
    import mujoco

    h = scene["size"] / scene["cells"]
    n = scene["cells"] + 1
    mass = scene["density"] * scene["size"] ** 3
    xml = f"""<mujoco>
  <option timestep="{scene['dt']!r}" solver="CG" integrator="discrete" gravity="0 0 {-scene['gravity']!r}"/>
  <worldbody>
    <geom type="plane" size="5 5 .1" friction="{scene['friction']!r}"/>
    <flexcomp name="cube" type="grid" dim="3" count="{n} {n} {n}" spacing="{h!r} {h!r} {h!r}"
              pos="0 0 {scene['drop'] + scene['size'] / 2!r}" mass="{mass!r}" radius=".005" dof="full">
      <elasticity young="{scene['young']!r}" poisson="{scene['poisson']!r}" damping=".001"/>
      <contact condim="3" friction="{scene['friction']!r}" selfcollide="none"/>
      <edge equality="false"/>
    </flexcomp>
  </worldbody>
</mujoco>"""
    t = time.perf_counter()
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    setup = time.perf_counter() - t
    trace = _Trace()
    for _ in range(steps):
        t, c = time.perf_counter(), time.process_time()
        mujoco.mj_step(m, d)
        dt, dc = time.perf_counter() - t, time.process_time() - c
        ncon = d.ncon  # the contacts this step used
        # flexvert_xpos is computed before integration inside mj_step (one step behind): update it.
        mujoco.mj_fwdPosition(m, d)
        trace.add(dt, dc, d.flexvert_xpos[:, 2], ncon)
    info = {"setup_s": setup, "nodes": int(m.nflexvert), "tets": int(m.nflexelem),
            "mass_kg": float(mass), "version": mujoco.__version__}
    return trace, info


def write_vtk_tets(path, nodes: np.ndarray, tets: np.ndarray) -> None:
    """A legacy-VTK unstructured grid of tets, as PyBullet's loader reads it (``float`` points:
    its parser leaves every point at the origin with ``double``)."""
    with open(path, "w") as f:
        f.write("# vtk DataFile Version 2.0\nsoftvr cube\nASCII\nDATASET UNSTRUCTURED_GRID\n")
        f.write(f"POINTS {len(nodes)} float\n")
        f.writelines(f"{a:.7f} {b:.7f} {c:.7f}\n" for a, b, c in nodes)
        f.write(f"CELLS {len(tets)} {5 * len(tets)}\n")
        f.writelines(f"4 {a} {b} {c} {d}\n" for a, b, c, d in tets)
        f.write(f"CELL_TYPES {len(tets)}\n")
        f.writelines("10\n" for _ in range(len(tets)))


def _pybullet(scene: dict, steps: int) -> tuple[_Trace, dict]:
    import pybullet as p
    import pybullet_data


    cube = CubeScene(**scene)
    nodes, tets = cube_mesh(cube, drop=0.0)  # the base position lifts it
    lam, mu = cube.lame
    mass = cube.mass
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "cube.vtk")
        write_vtk_tets(path, nodes, tets)
        t = time.perf_counter()
        client = p.connect(p.DIRECT)
        try:
            p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD, physicsClientId=client)
            p.setGravity(0, 0, -cube.gravity, physicsClientId=client)
            p.setPhysicsEngineParameter(fixedTimeStep=cube.dt, physicsClientId=client)
            p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
            plane = p.loadURDF("plane.urdf", physicsClientId=client)
            p.changeDynamics(plane, -1, lateralFriction=1.0, physicsClientId=client)
            sb = p.loadSoftBody(path, simFileName=path, basePosition=[0, 0, cube.drop], mass=mass,
                                useNeoHookean=1, NeoHookeanMu=mu, NeoHookeanLambda=lam, NeoHookeanDamping=0.01,
                                collisionMargin=0.006, useSelfCollision=0, frictionCoeff=cube.friction,
                                useFaceContact=1, repulsionStiffness=800, physicsClientId=client)
            setup = time.perf_counter() - t
            trace = _Trace()
            for _ in range(steps):
                t, c = time.perf_counter(), time.process_time()
                p.stepSimulation(physicsClientId=client)
                dt, dc = time.perf_counter() - t, time.process_time() - c
                _, q = p.getMeshData(sb, -1, flags=p.MESH_DATA_SIMULATION_MESH, physicsClientId=client)
                trace.add(dt, dc, np.asarray(q)[:, 2], len(p.getContactPoints(sb, physicsClientId=client)))
        finally:
            p.disconnect(physicsClientId=client)
    info = {"setup_s": setup, "nodes": int(len(nodes)), "tets": int(len(tets)), "mass_kg": float(mass),
            "version": peer_version("pybullet")}
    return trace, info


def _newton(scene: dict, steps: int) -> tuple[_Trace, dict]:
    import newton
    import warp as wp

    wp.config.quiet = True  # type: ignore[attr-defined]  # a runtime setting Warp's stubs do not list
    h = scene["size"] / scene["cells"]
    lam = scene["young"] * scene["poisson"] / ((1 + scene["poisson"]) * (1 - 2 * scene["poisson"]))
    mu = scene["young"] / (2 * (1 + scene["poisson"]))
    with wp.ScopedDevice("cpu"):
        t = time.perf_counter()
        b = newton.ModelBuilder(gravity=(0.0, 0.0, -scene["gravity"]))
        b.default_shape_cfg.mu = scene["friction"]
        b.add_ground_plane()
        # (Newton annotates rot with warp's internal quatf class, not the public one it is.)
        b.add_soft_grid(pos=wp.vec3(-scene["size"] / 2, -scene["size"] / 2, scene["drop"]),
                        rot=wp.quat_identity(),  # type: ignore[arg-type, unused-ignore]  # only with newton installed
                        vel=wp.vec3(0.0, 0.0, 0.0), dim_x=scene["cells"], dim_y=scene["cells"], dim_z=scene["cells"],
                        cell_x=h, cell_y=h, cell_z=h, density=scene["density"], k_mu=mu, k_lambda=lam, k_damp=10.0,
                        particle_radius=0.005)
        b.color()  # VBD needs a graph colouring
        # Newton types the model's arrays Optional (each exists only for the features a model uses).
        model: Any = b.finalize()
        # Lumped masses from the density (a quarter of each incident tet), as softvr has them.
        q = model.particle_q.numpy()
        tt = model.tet_indices.numpy()
        x = q[tt]
        vol = np.abs(np.einsum("ij,ij->i", np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), x[:, 3] - x[:, 0])) / 6.0
        m = np.zeros(len(q))
        np.add.at(m, tt.ravel(), np.repeat(scene["density"] * vol / 4.0, 4))
        model.particle_mass.assign(m.astype(np.float32))
        model.particle_inv_mass.assign((1.0 / m).astype(np.float32))
        model.soft_contact_ke = 1e4
        model.soft_contact_kd = 10.0
        model.soft_contact_mu = scene["friction"]
        solver = newton.solvers.SolverVBD(model=model, iterations=10, particle_enable_self_contact=False,
                                          particle_enable_tile_solve=False)
        s0, s1 = model.state(), model.state()
        ctrl = model.control()
        pipe = newton.CollisionPipeline(model)
        contacts = pipe.contacts()
        setup = time.perf_counter() - t
        trace = _Trace()
        dt = scene["dt"]
        for _ in range(steps):
            t, c = time.perf_counter(), time.process_time()
            s0.clear_forces()
            pipe.collide(s0, contacts)
            solver.step(s0, s1, ctrl, contacts, dt)
            s0, s1 = s1, s0
            wp.synchronize()
            elapsed, cpu = time.perf_counter() - t, time.process_time() - c
            trace.add(elapsed, cpu, s0.particle_q.numpy()[:, 2], int(contacts.soft_contact_count.numpy()[0]))
    info = {"setup_s": setup, "nodes": int(model.particle_count), "tets": int(model.tet_count),
            "mass_kg": float(m.sum()), "version": newton.__version__, "warp": wp.config.version}
    return trace, info


_RUNNERS = {"mujoco": _mujoco, "pybullet": _pybullet, "newton": _newton}


def run_peer(name: str, scene: dict, repeat: int = 1) -> dict:
    """Warm up, then simulate ``scene`` ``repeat`` times with peer ``name`` (in this process).

    Returns ``steps_per_s`` (median over the repeats), ``steps_per_s_runs``, the trace of the
    first timed run, and model info (``nodes``, ``tets``, ``mass_kg``, ``setup_s``, ``version``).
    """
    steps = int(round(scene["duration"] / scene["dt"]))
    run = _RUNNERS[name]
    t = time.perf_counter()
    run(scene, WARMUP_STEPS)  # compiles / loads JIT kernels; warms caches
    warmup_s = time.perf_counter() - t
    rates: list[float] = []
    first: tuple[_Trace, dict] | None = None
    for _ in range(max(1, repeat)):
        trace, info = run(scene, steps)
        rates.append(steps / sum(trace.step_s))
        first = first or (trace, info)
    assert first is not None  # one round at least
    trace, info = first
    return {**info, "steps": steps, "warmup_s": warmup_s, "steps_per_s": statistics.median(rates),
            "steps_per_s_runs": rates, "trace": trace.as_dict()}


def run_peer_process(name: str, scene: dict, repeat: int = 1, timeout_s: float = 600.0) -> dict:
    """:func:`run_peer` in a child Python process; ``{"failed": reason, ...}`` if it dies or times out."""
    with tempfile.TemporaryDirectory() as tmp:
        scene_path, out_path = Path(tmp, "scene.json"), Path(tmp, "result.json")
        scene_path.write_text(json.dumps(scene))
        cmd = [sys.executable, "-m", "softvr.bench._contact_peers", name, str(scene_path), str(out_path), str(repeat)]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return {"failed": f"failed: no result within {timeout_s:.0f} s"}
        if proc.returncode != 0 or not out_path.exists():
            tail = (proc.stderr or proc.stdout or "").strip().splitlines()[-3:]
            return {"failed": f"failed: exit status {proc.returncode}" + (f" ({' | '.join(tail)})" if tail else "")}
        return json.loads(out_path.read_text())


def _main(argv: list[str]) -> int:
    name, scene_path, out_path, repeat = argv
    result = run_peer(name, json.loads(Path(scene_path).read_text()), int(repeat))
    Path(out_path).write_text(json.dumps(result))
    return 0


if __name__ == "__main__":  # pragma: no cover - the child process of run_peer_process
    raise SystemExit(_main(sys.argv[1:]))
