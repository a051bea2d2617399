"""Volume deformation demo: the real head CT pressed and twisted through its tet mesh.

The InVesalius head CT (Debian ``invesalius-examples``) is embedded in a regular mesh of
~10 K tetrahedra; a scripted deformation first presses a dent into the face, then twists
the head about its long axis. Every frame the CT is rasterized through the deformed mesh
(thesis ch. 3) and volume-rendered offscreen (softvr's Warp ray caster, or VTK's with
``--renderer vtk``); the frames go to an MP4 and a PNG
contact sheet. Run ``softvr demo``.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

import numpy as np

from softvr.app import DEFAULT_OUT, add_device_option, out_folder, record
from softvr.volume import Rasterizer, Volume, grid_tet_mesh, load

if TYPE_CHECKING:  # vtk loads with the first frame drawn
    from softvr.render import VolumeRenderer

__all__ = ["Example", "press_and_twist", "main"]


def press_and_twist(nodes: np.ndarray, bounds: np.ndarray, s: float, press_point=None) -> np.ndarray:
    """Scripted deformation of mesh nodes at animation time ``s`` in [0, 1].

    For s in [0, 0.5] a finger presses a dent in -y at ``press_point`` (Gaussian footprint
    in x-z, 12 % of the y extent deep, decaying behind the pressed surface); for s in
    [0.5, 1] the dented head twists about the z axis, up to 35 degrees at the top, linearly
    in z. Both stay far from inverting any tet.

    Parameters
    ----------
    nodes : ndarray, shape [node_count, 3] [volume units]
        Rest node positions.
    bounds : ndarray, shape [2, 3] [volume units]
        Lower and upper corner of the rest mesh.
    s : float
        Animation time, 0 = rest, 1 = fully pressed and twisted.
    press_point : array_like, shape [3] [volume units], optional
        Surface point the finger presses; default the centre of the +y face of ``bounds``.

    Returns
    -------
    ndarray, shape [node_count, 3]
        Deformed node positions.
    """
    lo, hi = bounds
    size = hi - lo
    centre = (lo + hi) / 2
    press = min(s / 0.5, 1.0)
    twist = max((s - 0.5) / 0.5, 0.0)
    x = nodes.copy()
    # Press: ease-in-out depth, Gaussian footprint in x-z, exponential decay away from +y.
    p = np.array([centre[0], hi[1], centre[2]]) if press_point is None else np.asarray(press_point, float)
    depth = 0.12 * size[1] * (0.5 - 0.5 * np.cos(np.pi * press))
    r2 = ((x[:, 0] - p[0]) / (0.16 * size[0])) ** 2 + ((x[:, 2] - p[2]) / (0.2 * size[2])) ** 2
    behind = np.maximum(p[1] - x[:, 1], 0.0)
    x[:, 1] -= depth * np.exp(-r2) * np.exp(-behind / (0.3 * size[1]))
    # Twist about the z axis through the centre, growing linearly with height.
    angle = np.radians(35.0) * (0.5 - 0.5 * np.cos(np.pi * twist)) * (x[:, 2] - lo[2]) / size[2]
    c, sn = np.cos(angle), np.sin(angle)
    dx, dy = x[:, 0] - centre[0], x[:, 1] - centre[1]
    x[:, 0] = centre[0] + c * dx - sn * dy
    x[:, 1] = centre[1] + sn * dx + c * dy
    return x


def _front_surface_point(volume: Volume) -> np.ndarray:
    """World position of the most anterior (+y) voxel above a quarter of the value range:
    the tip of the nose for the head CT."""
    lo, hi = float(volume.data.min()), float(volume.data.max())
    idx = np.argwhere(volume.data > lo + 0.25 * (hi - lo))
    if len(idx) == 0:
        idx = np.argwhere(np.ones(volume.shape, bool))
    return volume.index_to_world(idx[idx[:, 1].argmax()])


class Example:
    """Press-and-twist of a CT volume, deformed by tetrahedral rasterization each frame.

    Parameters
    ----------
    volume : Volume, optional
        Defaults to the real head CT (:func:`softvr.datasets.head_ct`).
    cells : int or (int, int, int)
        Mesh cubes per axis (5 tets each); default (16, 16, 8) = 10 240 tets.
    frames : int
        Frames in the animation.
    device : str, optional
        Warp device for the rasterizer (``None`` = CUDA when present).
    width, height : int
        Rendered image size [pixels].
    culling : bool or str
        Rasterization strategy, see :class:`~softvr.volume.Rasterizer`.
    renderer : {"warp", "vtk"}
        Volume renderer: softvr's :class:`~softvr.render.RayCaster` (label volumes always go
        to VTK's, which draws categorical colours) or VTK's CPU ray caster.
    """

    def __init__(self, volume: Volume | None = None, cells=(16, 16, 8), frames: int = 36, device=None,
                 width: int = 480, height: int = 360, culling=True, renderer: str = "warp"):
        if volume is None:
            from softvr.datasets import head_ct

            volume = head_ct()
        self.volume = volume
        self.nodes, self.tets = grid_tet_mesh(volume, cells)
        self.bounds = np.stack([self.nodes.min(axis=0), self.nodes.max(axis=0)])
        self.press_point = _front_surface_point(volume)
        self.rasterizer = Rasterizer(volume, self.nodes, self.tets, culling=culling, device=device)
        self.frames = max(int(frames), 2)
        self.frame = 0
        self.width, self.height = width, height
        if renderer not in ("warp", "vtk"):
            from softvr.errors import InputError

            raise InputError("renderer", "'warp' or 'vtk'", repr(renderer))
        self.renderer = renderer
        self.deformed: Volume | None = None
        #: One record per frame: ``frame``, ``s`` (animation time), ``deform_ms`` and the
        #: rasterizer's statistics (:attr:`softvr.volume.Rasterizer.stats`).
        self.metrics: list[dict] = []
        self._renderer: VolumeRenderer | None = None

    def step(self) -> Volume:
        """Deform the volume for the current frame, record its metrics and advance the frame counter."""
        s = self.frame / (self.frames - 1)
        moved = press_and_twist(self.nodes, self.bounds, s, self.press_point)
        self.deformed = self.rasterizer.deform(moved)
        assert self.rasterizer.stats is not None  # deform() measured itself
        stats = self.rasterizer.stats.as_dict()
        self.metrics.append({"frame": self.frame, "s": s, "deform_ms": stats["time_total_s"] * 1e3, **stats})
        self.frame += 1
        return self.deformed

    def render(self) -> np.ndarray:
        """Volume-render the last deformed volume; returns RGB uint8 [height, width, 3]."""
        if self._renderer is None:
            from softvr.render import Camera, VolumeRenderer

            preset = "labels" if self.volume.is_label else ("mri" if self.volume.dtype == np.uint8 else "ct")
            mapper = "warp" if self.renderer == "warp" and preset != "labels" else "cpu"
            self._renderer = VolumeRenderer(self.width, self.height, preset=preset, mapper=mapper,
                                            camera=Camera("front", azimuth=70, elevation=10, zoom=1.1))
        return self._renderer.render(self.deformed)

    # -- what softvr.app.record reads ---------------------------------------------------
    name = "volume"
    fps = 12.0

    def describe(self) -> dict:
        """Facts of the run for the metrics file."""
        return {"volume": repr(self.volume), "nodes": len(self.nodes), "tets": len(self.tets),
                "method": self.rasterizer.method, "device": self.rasterizer.device}

    def summary(self) -> dict:
        """Median and worst deformation time [ms] per frame."""
        ms = np.array([m["deform_ms"] for m in self.metrics])
        return {"frames": len(ms), "deform_ms_median": float(np.median(ms)), "deform_ms_max": float(ms.max())}

    def status(self) -> str:
        m = self.metrics[-1]
        return f"deform {m['deform_ms']:.1f} ms ({m['voxels_written'] / 1e6:.2f} M voxels)"

    def write_plots(self, doc: dict, out) -> list:
        return []

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def main(argv: list[str] | None = None) -> int:
    """``softvr demo [volume]``: run the example and write MP4, PNG contact sheet and metrics JSON."""
    p = argparse.ArgumentParser(prog="softvr demo volume", description=__doc__.splitlines()[0])
    p.add_argument("--input", help="volume file to deform instead of the bundled head CT")
    p.add_argument("--out", default=None, metavar="DIR", help=f"output folder (default ./{DEFAULT_OUT}/volume)")
    p.add_argument("--frames", type=int, default=36)
    p.add_argument("--cells", type=int, nargs=3, default=(16, 16, 8), metavar=("CX", "CY", "CZ"))
    p.add_argument("--size", type=int, nargs=2, default=(480, 360), metavar=("W", "H"))
    p.add_argument("--culling", default="spans", choices=["bbox", "cells", "spans"])
    add_device_option(p)
    p.add_argument("--renderer", choices=("warp", "vtk"), default="warp",
                   help="volume renderer: softvr's Warp ray caster (default) or VTK's CPU ray caster")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    if args.frames < 2:
        p.error(f"--frames: expected an integer >= 2, got {args.frames}")
    volume = load(args.input) if args.input else None
    if not args.quiet:
        print("softvr demo: preparing (the first run compiles the kernels, ~10-30 s)", flush=True)
    with Example(volume, tuple(args.cells), args.frames, args.device, args.size[0], args.size[1], args.culling,
                 args.renderer) as ex:
        if not args.quiet:
            print(f"softvr demo: {ex.volume!r}\n  mesh {len(ex.nodes)} nodes, {len(ex.tets)} tets; "
                  f"rasterizer '{ex.rasterizer.method}' on {ex.rasterizer.device}")
        record(ex, out_folder(args.out, ex.name), progress=not args.quiet)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
