"""``softvr bench palpation``: where the time of a palpation frame goes (thesis 3.3.2).

The palpation demo's scene file (``palpation.toml``, its ``[variant.quick]`` with ``--quick``)
played through the one :class:`~softvr.app.Player`, on the real head CT (256 x 256 x 108
voxels, ~6 K tets over the head, tissue from the voxels, bone clamped): per frame the FEM step
with the probe's contact, the CT rasterized from the deformed mesh — in full (the thesis' way:
every voxel, every frame) and incrementally (only the box around the tets that moved), both on
the same node positions — and the volume rendering at 512 x 512, full resolution, by the
scene's renderer (softvr's Warp ray caster over the probe's surface, its empty-space grid
re-derived only where the rasterizer wrote, only the rays that can see a change cast again).
VTK's CPU ray caster renders the same volume with the same transfer function, camera and
sample distance on a few frames of the same run, for the ratio. A full frame is step +
incremental rasterization + render.

A second pass plays the same frames with :attr:`softvr.app.Player.overlap` on: each frame's
render overlapped with the next frame's FEM step on a worker thread. It reports the frame
period (wall time per frame of that loop), the latency (from a frame's input read to its
image: the period plus one render, which now ends a frame later) and the process CPU time per
frame, beside the sequential pass's; each of its images must equal the sequential pass's.

Thesis anchor: the torso (4.99 M voxels, 700 tets) rasterized in 14.86 ms on a GTX 680.
Target on this 2-core CPU: a full frame (step + incremental raster + render, as a player draws
it by default, one stage after the other) <= 33 ms on the head CT; on an H100 when lent, <= 5 ms.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from softvr.bench._report import bench_parser, print_and_write, save_figure
from softvr.bench.contact import _git_commit
from softvr.bench.volume import _loadavg, _machine_info
from softvr.errors import InputError
from softvr.render import VolumeRenderer
from softvr.scene import BUNDLED, SceneExample, read_scene
from softvr.volume import Volume, iso_surface

__all__ = ["SCENE", "TARGET_FRAME_MS", "TARGET_RENDER_RATIO", "format_table", "main", "run_palpation_bench",
           "write_plot"]

#: The benchmarked scene: the palpation demo's one definition.
SCENE = BUNDLED / "palpation.toml"
TARGET_FRAME_MS = 33.0
TARGET_RENDER_RATIO = 5.0
THESIS = {"voxels": 4.99e6, "tets": 700, "raster_ms": 14.86, "gpu": "GTX 680"}
#: ``--renderer`` -> the scene's ``[volume] mapper``.
_MAPPERS = {"warp": "warp", "vtk": "cpu"}


def _indentation(probe, radius: float, skin) -> float:
    """How far [m] the probe sphere (``radius`` [m]) reaches past the rest ``skin`` vertices
    [n, 3] [m]: the depth of the deepest one inside it (negative: its gap to the nearest)."""
    return float(radius - np.linalg.norm(skin - np.asarray(probe.position), axis=1).min())


def run_palpation_bench(*, quick: bool = False, progress: bool = True, size: int | None = None,
                        device: str | None = None, renderer: str | None = None, render_step: int | None = None,
                        sample_distance: float | None = None) -> dict:
    """The palpation scene's frames, each stage timed; ``quick``: its ``quick`` variant (6
    frames at 128 x 128). ``size`` [pixels] (square), ``renderer`` (``"warp"``, ``"vtk"``),
    ``render_step`` and ``sample_distance`` [voxels] replace the file's (``None``: the file's)."""
    from tqdm import tqdm

    t0 = time.perf_counter()
    load_start = _loadavg()
    scene_file = read_scene(SCENE, ("quick",) if quick else ())
    if render_step is not None and not (isinstance(render_step, int) and render_step >= 1):
        raise InputError("render_step", "an integer >= 1", repr(render_step))
    if renderer is not None and renderer not in _MAPPERS:
        raise InputError("renderer", "'warp' or 'vtk'", repr(renderer))
    probe_spec = scene_file.body("probe")
    assert scene_file.volume is not None and probe_spec is not None  # palpation.toml has its [volume] and probe
    options = {"mapper": _MAPPERS.get(renderer or ""), "render_step": render_step, "sample_distance": sample_distance}
    scene_file.volume.update({k: v for k, v in options.items() if v is not None})
    probe_radius = float(probe_spec.size)  # [m] a sphere's
    trace: dict[str, list] = {k: [] for k in ("fem_ms", "raster_incremental_ms", "raster_full_ms", "render_ms",
                                              "render_cpu_ms", "raster_voxels", "indentation_m")}
    trace.update({k: [] for k in ("render_paired_ms", "render_vtk_ms", "render_vtk_cpu_ms", "rays_cast",
                                  "frame_wall_ms", "frame_cpu_ms")})
    images = []
    with SceneExample(scene_file, width=size, height=size, device=device) as player:
        player.frame_measures = False  # the bench reads its own measures
        player.overlap = False  # this pass: each stage alone
        frames, size = player.frames, player.width
        vol, probe = player.volume, player.bodies["probe"]
        assert vol is not None
        skin = iso_surface(vol.rest, vol.spec["threshold"], step=2)[0] * vol.unit  # the rest skin [m]
        full = Volume(np.empty(vol.rest.shape, vol.rest.dtype), vol.rest.spacing.copy(), vol.rest.origin.copy(),
                      vol.rest.direction.copy())
        player.render()  # the renderer's set-up (window, first upload) is not a frame's cost
        assert player.renderer is not None and player.volume_handle is not None
        caster = player.renderer.ray_caster(player.volume_handle)
        step = caster.sample_distance if caster is not None else vol.spec["sample_distance"] or 1.0
        # VTK's CPU ray caster on the same volume, transfer function, camera and step, timed right
        # after softvr's on every 8th frame (paired: both see the same machine load).
        vtk = VolumeRenderer(size, size, vol.spec["preset"], player.camera, mapper="cpu", sample_distance=step)
        vtk.render(vol.shown())  # its set-up
        for i in tqdm(range(frames), desc="bench palpation", unit="frame", disable=not progress):
            start, start_cpu = time.perf_counter(), time.process_time()
            record = player.step()
            frame_wall, frame_cpu = time.perf_counter() - start, time.process_time() - start_cpu
            s = time.perf_counter()
            vol.drawing.rasterizer.deform(vol.body.q / vol.unit, out=full)
            trace["raster_full_ms"].append(1e3 * (time.perf_counter() - s))
            s, cpu = time.perf_counter(), time.process_time()
            image = player.render()
            trace["render_cpu_ms"].append(1e3 * (time.process_time() - cpu))
            trace["frame_wall_ms"].append(1e3 * (frame_wall + time.perf_counter() - s))
            trace["frame_cpu_ms"].append(1e3 * (frame_cpu + time.process_time() - cpu))
            images.append(image)
            trace["rays_cast"].append(caster.cast_pixels if caster is not None else size * size)
            if i % 8 == 4 or (quick and i % 3 == 1):
                s, cpu = time.perf_counter(), time.process_time()
                vtk.render(vol.shown())
                trace["render_vtk_ms"].append(1e3 * (time.perf_counter() - s))
                trace["render_vtk_cpu_ms"].append(1e3 * (time.process_time() - cpu))
                trace["render_paired_ms"].append(record["render_ms"])
            trace["fem_ms"].append(record["step_ms"])
            trace["raster_incremental_ms"].append(record["raster_ms"])
            trace["render_ms"].append(record["render_ms"])
            trace["raster_voxels"].append(record["raster_voxels"])
            trace["indentation_m"].append(_indentation(probe, probe_radius, skin))
        # The incremental volume must equal the full one at the end (the benchmark's own check),
        # and the last incrementally cast frame a cast from scratch.
        agree = float(np.mean(vol.deformed.data == full.data))
        if caster is not None:
            caster.reset()
        same_image = float(np.mean(np.all(image == player.renderer.render(), axis=2)))
        vtk.close()
        facts = player.describe()
        volume_facts = facts.pop("volume")
        scene = {**facts, **volume_facts, "volume": volume_facts["source"],
                 "renderer": "warp" if caster is not None else "vtk", "sample_distance": step}
        rasterizer_device = vol.drawing.rasterizer.device
        physics_device = player.scene.device
    trace.update(_overlapped(scene_file, size, device, images, progress))
    med = {k: float(np.median(v)) for k, v in trace.items()}
    frame_ms = med["fem_ms"] + med["raster_incremental_ms"] + med["render_ms"]
    period_ms = med["period_ms"]
    # Per paired frame: VTK's wall time over softvr's, then the median.
    render_ratio = float(np.median(np.divide(trace["render_vtk_ms"], trace["render_paired_ms"])))
    render_cpu_ratio = med["render_vtk_cpu_ms"] / med["render_cpu_ms"]
    machine = _machine_info(rasterizer_device)
    machine["softvr_commit"] = _git_commit()
    return {
        "schema": "softvr-bench-palpation/1",
        "machine": machine,
        "config": {"quick": quick, "frames": frames, "image": [size, size], "device": rasterizer_device,
                   "physics_device": physics_device},
        "scene": scene,
        "median": med,
        "frame_ms": frame_ms,
        "period_ms": period_ms,
        "overlap_equals_sequential": float(np.mean(trace["overlap_same_image"])),
        "incremental_equals_full": agree,
        "render_equals_fresh_cast": same_image,
        "trace": trace,
        "thesis": THESIS,
        "render_vs_vtk": render_ratio,
        "render_vs_vtk_cpu_time": render_cpu_ratio,
        "targets": {"frame_ms": TARGET_FRAME_MS, "frame_met": frame_ms <= TARGET_FRAME_MS,
                    "render_ratio": TARGET_RENDER_RATIO, "render_ratio_met": render_ratio >= TARGET_RENDER_RATIO},
        "loadavg_start": load_start,
        "loadavg_end": _loadavg(),
        "wall_s": time.perf_counter() - t0,
    }


def _overlapped(scene_file, size: int, device: str | None, images: list, progress: bool) -> dict:
    """The same frames played overlapped (each render beside the next frame's FEM step on the
    player's worker thread), in a player of its own: per frame the period [ms] (wall time from
    one image to the next), the process CPU time of that period [ms] (all threads), the latency
    [ms] (first input read to image), the step's wall time [ms] (beside the render) and whether
    the image equals the sequential pass's (``images``, one per frame)."""
    from tqdm import tqdm

    trace: dict[str, list] = {k: [] for k in ("period_ms", "period_cpu_ms", "latency_ms", "fem_overlapped_ms",
                                              "overlap_same_image")}
    with SceneExample(scene_file, width=size, height=size, device=device) as player:
        player.frame_measures = False
        player.overlap = True
        player.render()  # the renderer's set-up, as in the sequential pass
        last, last_cpu = time.perf_counter(), time.process_time()
        for i in tqdm(range(player.frames), desc="bench palpation, overlapped", unit="frame", disable=not progress):
            record = player.step()
            image = player.render()
            now, cpu = time.perf_counter(), time.process_time()
            trace["period_ms"].append(1e3 * (now - last))
            trace["period_cpu_ms"].append(1e3 * (cpu - last_cpu))
            last, last_cpu = now, cpu
            trace["latency_ms"].append(record["latency_ms"])
            trace["fem_overlapped_ms"].append(record["step_ms"])
            trace["overlap_same_image"].append(bool(np.array_equal(image, images[i])))
    return trace


def format_table(result: dict) -> str:
    m, s, c = result["median"], result["scene"], result["config"]
    voxels = int(np.prod([int(x) for x in s["volume"].split("shape=(")[1].split(")")[0].split(",")]))
    lines = [f"Palpation of the head CT ({voxels / 1e6:.2f} M voxels, {s['tets']} tets, {s['clamped_nodes']} clamped "
             f"nodes), {c['frames']} frames, {c['image'][0]} x {c['image'][1]} render ({s['renderer']}, render step "
             f"{s['render_step']}, sample distance {s['sample_distance']} voxel), rasterizer on {c['device']}, "
             f"physics on {c.get('physics_device', 'cpu')}",
             f"{'stage':<28} {'median ms':>10} {'vs full raster':>15}", "-" * 55]
    full = m["raster_full_ms"]
    for name, key in (("FEM step (contact, factored)", "fem_ms"), ("rasterize: full (thesis)", "raster_full_ms"),
                      ("rasterize: incremental", "raster_incremental_ms"), ("volume render", "render_ms"),
                      ("VTK ray caster, same view", "render_vtk_ms")):
        ratio = f"{full / m[key]:.1f}x faster" if key == "raster_incremental_ms" else ""
        lines.append(f"{name:<28} {m[key]:>10.1f} {ratio:>15}")
    lines.append(f"{'frame (step+incr.+render)':<28} {result['frame_ms']:>10.1f}")
    lines += ["", f"{'one frame, median':<34} {'wall ms':>8} {'CPU ms':>8} {'latency ms':>11}", "-" * 64,
              f"{'sequential (step, raster, render)':<34} {m['frame_wall_ms']:>8.1f} {m['frame_cpu_ms']:>8.1f} "
              f"{m['frame_wall_ms']:>11.1f}",
              f"{'overlapped (render || next step)':<34} {m['period_ms']:>8.1f} {m['period_cpu_ms']:>8.1f} "
              f"{m['latency_ms']:>11.1f}",
              f"overlapped: the wall is the frame period; the latency (input read -> image) is the period plus "
              f"one render (a frame is drawn while the next one steps; that step: {m['fem_overlapped_ms']:.1f} ms "
              f"wall); its images == the sequential pass's: {100 * result['overlap_equals_sequential']:.0f} % of "
              f"frames"]
    th, t = result["thesis"], result["targets"]
    lines += ["", f"incremental voxels per frame (median): {m['raster_voxels'] / 1e6:.2f} M of {voxels / 1e6:.2f} M; "
                  f"incremental == full at the end: {100 * result['incremental_equals_full']:.3f} % of voxels",
              f"rays cast per frame (median): {m['rays_cast'] / 1e3:.1f} K of "
              f"{c['image'][0] * c['image'][1] / 1e3:.1f} K "
              f"pixels (the rest keep last frame's colour); last frame == a cast from scratch: "
              f"{100 * result['render_equals_fresh_cast']:.3f} % of pixels",
              f"thesis: torso {th['voxels'] / 1e6:.2f} M voxels, {th['tets']} tets rasterized in {th['raster_ms']} ms "
              f"({th['gpu']})",
              f"target: full frame <= {t['frame_ms']:g} ms: {result['frame_ms']:.1f} -> "
              f"{'MET' if t['frame_met'] else 'NOT met'} (overlapped: a period of {result['period_ms']:.1f} ms "
              f"at a latency of {m['latency_ms']:.1f} ms)",
              f"target: render >= {t['render_ratio']:g}x faster than VTK's ray caster (same volume, camera, step; "
              f"median of {len(result['trace']['render_vtk_ms'])} paired frames): {result['render_vs_vtk']:.1f}x -> "
              f"{'MET' if t['render_ratio_met'] else 'NOT met'} (CPU time of all threads: "
              f"{m['render_cpu_ms']:.0f} vs {m['render_vtk_cpu_ms']:.0f} ms, {result['render_vs_vtk_cpu_time']:.1f}x)"]
    return "\n".join(lines)


def write_plot(result: dict, path) -> None:
    """PNG: each stage's ms per frame over the press, and the indentation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = result["trace"]
    f = np.arange(len(tr["fem_ms"]))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    for key, label in (("fem_ms", "FEM step"), ("raster_full_ms", "rasterize full"),
                       ("raster_incremental_ms", "rasterize incremental"), ("render_ms", "render"),
                       ("period_ms", "frame period, overlapped")):
        axes[0].plot(f, tr[key], label=label)
    axes[0].axhline(TARGET_FRAME_MS, color="k", lw=1, label="frame target")
    axes[0].set(xlabel="frame", ylabel="ms", title="time per stage", yscale="log")
    axes[1].plot(f, 1e3 * np.asarray(tr["indentation_m"]), color="tab:red")
    axes[1].set(xlabel="frame", ylabel="mm", title="probe indentation")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    m = result["machine"]
    fig.suptitle(f"palpation of the head CT - {m['cpu_model']}, {m['cores']} cores, {m['date'][:10]}", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    """``softvr bench palpation [--quick] [--device D] [--json PATH] [--plot PATH]``."""
    p = bench_parser("palpation", __doc__.splitlines()[0], quick="6 frames at 128 x 128 (CI)",
                     plot="write a PNG of the stages over the press")
    p.add_argument("--device", default=None,
                   help="rasterizer and renderer device: cpu or cuda (default cuda when present); where given, "
                        "the physics' too (default: the CPU)")
    p.add_argument("--renderer", choices=tuple(_MAPPERS), default=None,
                   help="volume renderer: softvr's Warp ray caster or VTK's (default: the scene file's)")
    p.add_argument("--render-step", type=int, default=None,
                   help="render every k-th voxel per axis (default: the scene file's)")
    p.add_argument("--sample-distance", type=float, default=None, help="ray step [voxels] (default: the scene file's)")
    a = p.parse_args(argv)
    result = run_palpation_bench(quick=a.quick, progress=not a.no_progress, device=a.device, renderer=a.renderer,
                                 render_step=a.render_step, sample_distance=a.sample_distance)
    print_and_write(result, format_table(result), a.json, a.plot, write_plot)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
