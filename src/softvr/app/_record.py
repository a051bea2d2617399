"""Frames to files: the one loop that plays a scene headless into an MP4, a contact sheet,
PNG frames, a metrics JSON and the scene's plots."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from softvr.render import contact_sheet, save_png, write_mp4
from softvr.render.figure import save_figure
from softvr.files import write_json

__all__ = ["output_name", "record", "sensor_plot"]


def output_name(name: str) -> str:
    """The stem of a run's files: the scene's name as the command line spells it (``soft-cube``,
    never ``soft_cube``), so every route to a scene writes the same file names."""
    return str(name).replace("_", "-")


def record(player, out, *, progress: bool = True, sheet_frames: int = 8, png_every: int = 0) -> dict:
    """Play every frame of ``player`` and write it to files; returns the metrics document.

    Files (``NAME`` = :func:`output_name` of ``player.name``): ``<out>/NAME.mp4``,
    ``NAME_sheet.png`` (``sheet_frames`` frames evenly over the run, labelled with their
    simulated time), ``NAME_metrics.json`` (``{"scene", **describe(), "summary", "frames"}``),
    the player's plots (``player.write_plots``) and, with ``png_every`` = k > 0, every k-th
    frame as ``NAME_frames/frame_NNNNN.png``, and with sensors (``player.sensors``) their plot
    ``NAME_sensors.png`` (:func:`sensor_plot`). All are written atomically; ``out`` is created if
    missing.

    Parameters
    ----------
    player : Player or an object with its frame interface
        ``name``, ``fps``, ``frames``, ``frame``, ``metrics``, ``step()``, ``render()``
        (RGB uint8 [h, w, 3]), ``describe()``, ``summary()``, ``status()``,
        ``write_plots(doc, out)`` and ``close()`` (:class:`~softvr.app.Player` has them all).
        It is closed afterwards.
    out : path
        Output folder.
    progress : bool
        Progress bar and the list of files written.
    sheet_frames : int
        Frames on the contact sheet.
    png_every : int
        Also every k-th frame as a PNG (0: none).

    Notes
    -----
    Frames are streamed to the video encoder: memory does not grow with the number of frames
    (only the contact sheet's few are kept).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    name = output_name(player.name)
    frames_dir = out / f"{name}_frames"
    if png_every > 0:
        frames_dir.mkdir(exist_ok=True)
    # Frames go to the encoder as they are rendered (one in memory, not all: 0.9 MB each at
    # 640 x 480); the contact sheet's few are kept as they pass.
    total = max(player.frames - player.frame, 1)
    pick = np.linspace(0, total - 1, min(sheet_frames, total)).round().astype(int)
    kept: dict = {}
    busy = [0.0]  # [s] spent stepping and rendering (not encoding)

    def rendered():
        try:
            with tqdm(total=total, desc=name, unit="frame", disable=not progress) as bar:
                i = 0
                while player.frame < player.frames:
                    t0 = time.perf_counter()
                    player.step()
                    image = player.render()
                    busy[0] += time.perf_counter() - t0
                    if i in pick:
                        kept[i] = image
                    if png_every > 0 and i % png_every == 0:
                        save_png(image, frames_dir / f"frame_{i:05d}.png")
                    bar.set_postfix_str(player.status(), refresh=False)
                    bar.update()
                    i += 1
                    yield image
        finally:
            player.close()

    frames = rendered()
    try:
        mp4 = write_mp4(frames, out / f"{name}.mp4", fps=player.fps)
    finally:
        frames.close()  # closes the player even when encoding failed
    metrics = player.metrics
    shown = [i for i in pick if i in kept]
    labels = [f"t = {metrics[i]['sim_time_s']:.2f} s" if "sim_time_s" in metrics[i] else f"frame {i}" for i in shown]
    sheet = save_png(contact_sheet([kept[i] for i in shown], columns=4, labels=labels), out / f"{name}_sheet.png")
    summary = {**player.summary(), "wall_s": busy[0]}
    doc = {"scene": name, **player.describe(), "summary": summary, "frames": metrics}
    path = write_json(doc, out / f"{name}_metrics.json")
    written = [mp4, sheet, path, *player.write_plots(doc, out)]
    if doc.get("sensors"):
        written.append(sensor_plot(doc, out / f"{name}_sensors.png"))
    if png_every > 0:
        written.append(frames_dir)
    if progress:
        print(f"{name}: {len(metrics)} frames in {busy[0]:.1f} s; last: {player.status()}")
        for file in written:
            print(f"wrote {file}")
    return doc


def sensor_plot(doc: dict, path) -> Path:
    """One panel per sensor of a metrics document (``doc["sensors"]``: name -> kind and unit;
    each frame's ``sensors``: name -> [x, y, z]) against simulated time [s], its x, y and z
    components, written atomically to ``path`` (PNG)."""
    import matplotlib  # noqa: PLC0415  (optional heavy dependency, only when there are sensors)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    sensors, frames = doc["sensors"], doc["frames"]
    t = [f["sim_time_s"] for f in frames]
    fig, axes = plt.subplots(len(sensors), 1, figsize=(6.4, 1.2 + 1.8 * len(sensors)), sharex=True, squeeze=False)
    for ax, (name, about) in zip(axes[:, 0], sensors.items()):
        values = np.array([f["sensors"][name] for f in frames])
        for k, axis in enumerate("xyz"):
            ax.plot(t, values[:, k], label=axis, lw=1.2)
        ax.set_ylabel(f"{name} [{about['unit']}]")
        ax.set_title(about["kind"], fontsize=8, loc="right")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=3, loc="best")
    axes[-1, 0].set_xlabel("simulated time [s]")
    fig.suptitle(doc.get("scene", ""))
    fig.tight_layout()
    return save_figure(fig, path, dpi=90)
