"""Volumetric palpation: a CT pressed by a probe, its FEM built from the voxels (thesis 3.3.2).

The real head CT is embedded in a regular tet mesh over the head (cubes holding tissue); each
tet's Young's modulus, Poisson ratio and density are integrated from the voxels' Hounsfield
units (:mod:`softvr.model.tissue`), and the nodes of bone-dense tets are clamped, so the skull
holds the soft tissue. A round probe presses into the cheek and withdraws; the co-rotational
FEM deforms under it through frictional contact. Every frame the CT is rasterized from the
deformed mesh — only the box around the tets that moved (:meth:`softvr.volume.Rasterizer.update`)
— and volume-rendered. Run ``softvr demo palpation`` (``--input FILE`` for another CT);
``softvr view palpation`` plays the same scene as a scene file (``palpation.toml``) in a window.
"""

from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING

import numpy as np

from softvr.app import DEFAULT_OUT, add_device_option, out_folder, record
from softvr.volume import load

if TYPE_CHECKING:  # vtk loads with the first frame drawn
    from softvr.render import VolumeRenderer

__all__ = ["Example", "main", "press_point"]

_UNIT = 1e-3  # metres per millimetre: CT geometry is in mm, the FEM in m
_SKIN_HU = -300.0  # between air (-1000) and fat (-100)


def press_point(volume, *, threshold: float = -300.0, lateral: float = 0.15) -> np.ndarray:
    """The skin point [mm] the probe presses: the most anterior (+y) tissue voxel (above
    ``threshold`` HU) in the column ``lateral`` of the head's width beside its midline, at
    the height of the most anterior voxel of all (the nose tip): the cheek."""
    tissue = volume.data > threshold
    idx = np.argwhere(tissue)
    nose = idx[idx[:, 1].argmax()]
    lo, hi = idx.min(axis=0), idx.max(axis=0)
    x = int(round(nose[0] + lateral * (hi[0] - lo[0])))
    column = np.flatnonzero(tissue[x, :, nose[2]])
    y = column.max() if len(column) else nose[1]
    return volume.index_to_world(np.array([x, y, nose[2]]))


class Example:
    """A CT palpated by a probe (module docstring).

    Parameters
    ----------
    volume : Volume, optional
        CT in Hounsfield units; default the head CT (:func:`softvr.datasets.head_ct`).
    cells : (int, int, int)
        Mesh cubes per axis over the volume (5 tets each); cubes without tissue are dropped.
    frames : int
    width, height : int [pixels]
    radius : float [m]
        Probe radius.
    depth : float [m]
        How far the probe goes past the skin.
    dt : float [s]
    steps_per_frame : int
    incremental : bool
        Rasterize only around the tets that moved (else the whole volume every frame).
    skin_triangles_budget : int
        Triangles of the skin's collision surface (simplified iso-surface).
    render_step : int
        Volume-render every ``render_step``-th voxel per axis (1: full resolution).
    renderer : {"warp", "vtk"}
        ``"warp"``: softvr's ray caster (:class:`softvr.render.RayCaster`), which re-derives its
        empty-space grid only where the rasterizer wrote and draws at full resolution.
        ``"vtk"``: VTK's CPU ray caster, which re-derives gradients of the whole volume every
        frame (use ``render_step=2`` with it for speed).
    sample_distance : float [voxels]
        Ray step in units of the rendered volume's smallest voxel spacing (1: the world step
        of VTK's default 0.5 on the former half-resolution rendering; jittered starts keep
        the skin free of banding at this step).
    labels : Volume, optional
        A segmentation on the CT's grid: deformed by the same mesh every frame
        (:attr:`labels_deformed`), its labels shown as surfaces by :meth:`label_surface`.
    device : str, optional
        Warp device of the rasterizer.
    """

    def __init__(self, volume=None, cells=(16, 16, 8), frames: int = 40, width: int = 512, height: int = 512, *,
                 radius: float = 0.012, depth: float = 0.005, dt: float = 0.01, steps_per_frame: int = 1,
                 incremental: bool = True, skin_triangles_budget: int = 4000, labels=None,
                 render_step: int = 1, renderer: str = "warp", sample_distance: float = 1.0,
                 device: str | None = None):
        from softvr import Scene
        from softvr.dynamics import EmbeddedPoints, KinematicBody, RigidPoints
        from softvr.model.shapes import icosphere
        from softvr.model import CT_TISSUE, tissue_fem_body
        from softvr.volume import DeformedVolume, grid_tet_mesh

        if volume is None:
            from softvr.datasets import head_ct

            volume = head_ct()
        from scipy.ndimage import binary_dilation

        from softvr.model import collision_mesh, embed_surface
        from softvr.volume import iso_surface

        self.volume = volume
        # Cubes holding tissue, grown by two voxels so that the skin surface lies inside them.
        tissue = binary_dilation(volume.data > _SKIN_HU, iterations=2)
        self.nodes, self.tets = grid_tet_mesh(volume, cells, mask=tissue)
        self.body, self.tissue = tissue_fem_body(volume, self.nodes, self.tets, CT_TISSUE, unit=_UNIT, alpha=2.0,
                                                 beta=0.01, fix_denser_than=1150.0, name="head")
        scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.4, contact_margin=0.001)
        # The probe touches the skin (the CT's iso-surface, embedded in the tets), not the
        # hull of the mesh's cubes, whose outer parts are air.
        skin, skin_triangles = iso_surface(volume, _SKIN_HU, step=2)
        skin, skin_triangles = collision_mesh(skin * _UNIT, skin_triangles, skin_triangles_budget)
        tet_index, weights = embed_surface(self.nodes * _UNIT, self.tets, skin)
        self.skin_triangles = skin_triangles
        scene.add_body(self.body, collision_points=EmbeddedPoints(self.body, self.tets[tet_index], weights),
                       collision_triangles=skin_triangles)
        self.target = press_point(volume) * _UNIT
        self.radius, self.depth = float(radius), float(depth)
        self.frames, self.dt, self.steps_per_frame = max(int(frames), 2), float(dt), int(steps_per_frame)
        self.probe = KinematicBody(self.pose, name="probe")
        unit_sphere, faces = icosphere(2)
        scene.add_body(self.probe, collision_points=RigidPoints(self.probe, unit_sphere * radius),
                       collision_triangles=faces)
        self.scene = scene
        # Embedding tets in the air in front of the skin fold as the skin is pressed: skip them.
        # Node motion under 0.01 mm is drawn once it adds up.
        self.drawing = DeformedVolume(volume, self.nodes, self.tets, tolerance=0.01, incremental=incremental,
                                      device=device, inverted="skip")
        self.labels = labels
        if labels is not None:
            if labels.shape != volume.shape:
                from softvr.errors import InputError

                raise InputError("labels", f"a label volume of the CT's shape {volume.shape}", f"shape {labels.shape}")
            self.label_drawing = DeformedVolume(labels, self.nodes, self.tets, tolerance=0.01,
                                                incremental=incremental, device=device, inverted="skip",
                                                interpolation="nearest", background=0)
        self.width, self.height = width, height
        self.preset, self.azimuth = "ct-skin", -40.0
        if not (isinstance(render_step, int) and render_step >= 1):
            from softvr.errors import InputError

            raise InputError("render_step", "an integer >= 1", repr(render_step))
        if renderer not in ("warp", "vtk"):
            from softvr.errors import InputError

            raise InputError("renderer", "'warp' or 'vtk'", repr(renderer))
        self.render_step, self.renderer, self.sample_distance = render_step, renderer, float(sample_distance)
        self._changed = True  # what the rasterizer rewrote since the last render: everything at first
        self.frame = 0
        self.metrics: list[dict] = []
        self._renderer: VolumeRenderer | None = None

    def pose(self, t: float):
        """Probe centre [m] and orientation at time ``t`` [s]: from 2 mm off the skin along -y
        to ``depth`` past it over the first half of the run, back over the second."""
        total = self.frames * self.steps_per_frame * self.dt
        s = min(max(t / total, 0.0), 1.0)
        travel = (self.depth + 0.002) * np.sin(np.pi * s) ** 2
        centre = self.target + np.array([0.0, self.radius + 0.002 - travel, 0.0])
        return centre, np.array([1.0, 0.0, 0.0, 0.0])

    def indentation(self) -> float:
        """How far [m] the probe's front is past the rest skin point (negative: not touching)."""
        return float(self.target[1] - (self.probe.position[1] - self.radius))

    def step(self):
        """One frame: the FEM steps, then the volume is rasterized where the mesh moved."""
        t0 = time.perf_counter()
        for _ in range(self.steps_per_frame):
            self.scene.step(self.dt)
        t1 = time.perf_counter()
        drawn = self.drawing.update(self.body.q / _UNIT)
        self._note_changed(drawn["box"])
        if self.labels is not None:
            self.label_drawing.update(self.body.q / _UNIT)
        t2 = time.perf_counter()
        self.metrics.append({"frame": self.frame, "fem_ms": 1e3 * (t1 - t0), "raster_ms": 1e3 * (t2 - t1),
                             "raster_voxels": drawn["raster_voxels"], "indentation_m": self.indentation(),
                             "max_displacement_m": float(np.linalg.norm(self.body.q - self.body.rest, axis=1).max())})
        self.frame += 1
        return self.deformed

    def _note_changed(self, box) -> None:
        """Grow the region the renderer must re-derive by ``box`` (None: nothing new)."""
        if box is None or self._changed is True:
            return
        if self._changed is False:
            self._changed = box
        else:
            self._changed = (np.minimum(self._changed[0], box[0]), np.maximum(self._changed[1], box[1]))

    @property
    def incremental(self) -> bool:
        return self.drawing.incremental

    @property
    def deformed(self):
        """The CT as drawn now (its own grid, mm)."""
        return self.drawing.deformed

    @property
    def labels_deformed(self):
        """The segmentation as drawn now (None without ``labels``)."""
        return self.label_drawing.deformed if self.labels is not None else None

    def shown_volume(self):
        """The deformed CT as rendered: every ``render_step``-th voxel per axis."""
        from softvr.volume import Volume

        k, d = self.render_step, self.deformed
        if k == 1:
            return d
        return Volume(np.ascontiguousarray(d.data[::k, ::k, ::k]), d.spacing * k, d.origin.copy(), d.direction.copy())

    def render(self) -> np.ndarray:
        """Volume-render the deformed CT; returns RGB uint8 [height, width, 3]."""
        from softvr.render import Camera, VolumeRenderer

        t0 = time.perf_counter()
        if self._renderer is None:
            self._renderer = VolumeRenderer(self.width, self.height, preset=self.preset,
                                            camera=Camera("front", azimuth=self.azimuth, elevation=5, zoom=1.3),
                                            mapper="warp" if self.renderer == "warp" else "cpu",
                                            sample_distance=self.sample_distance)
            self._probe_actor = _probe_actor(self.radius / _UNIT)
            self._renderer.vtk_renderer.AddActor(self._probe_actor)
        # The probe as a surface in the same frame: in front of the skin it hides it, pressed
        # in it is hidden by the skin around it.
        self._probe_actor.SetPosition(*(np.asarray(self.probe.position) / _UNIT))
        if self.renderer == "warp":
            # The rewritten box is in full-resolution voxels: a subsampled volume is redone whole.
            changed = self._changed if self.render_step == 1 else True
            image = self._renderer.render(self.shown_volume(), changed=changed)
        else:
            image = self._renderer.render(self.shown_volume())
        self._changed = False
        if self.metrics:
            self.metrics[-1]["render_ms"] = 1e3 * (time.perf_counter() - t0)
        return image

    def label_surface(self, label: int) -> tuple[np.ndarray, np.ndarray]:
        """The surface [mm] of segmentation ``label`` as deformed now: vertices [n, 3] and
        triangles [t, 3] of the iso-surface of its mask."""
        from softvr.volume import Volume, iso_surface

        if self.labels is None:
            from softvr.errors import InputError

            raise InputError("labels", "a label volume given to Example(labels=...)", "none")
        d = self.labels_deformed
        mask = Volume((d.data == label).astype(np.float32), d.spacing.copy(), d.origin.copy(), d.direction.copy())
        return iso_surface(mask, 0.5)

    def describe(self) -> dict:
        return {"volume": repr(self.volume), "tets": len(self.tets), "nodes": len(self.nodes),
                "clamped_nodes": int(self.body.fixed.sum()), "press_point_m": self.target.tolist(),
                "young_pa_min_median_max": [float(np.min(self.tissue.young)), float(np.median(self.tissue.young)),
                                            float(np.max(self.tissue.young))],
                "mass_kg": float(self.body.mass.sum()), "dt_s": self.dt, "incremental": self.incremental,
                "render_step": self.render_step, "renderer": self.renderer, "sample_distance": self.sample_distance}

    # -- what softvr.app.record reads ---------------------------------------------------
    name = "palpation"
    fps = 12.0

    def summary(self) -> dict:
        """Median ms per frame of the FEM step, the rasterization and the rendering; the deepest indentation [m]."""
        med = {f"{k}_median": float(np.median([m.get(k, 0.0) for m in self.metrics]))
               for k in ("fem_ms", "raster_ms", "render_ms")}
        return {"frames": len(self.metrics), **med,
                "max_indentation_m": max(m["indentation_m"] for m in self.metrics)}

    def status(self) -> str:
        m = self.metrics[-1]
        return f"indentation {m['indentation_m'] * 1e3:.2f} mm, raster {m['raster_ms']:.0f} ms"

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


def _probe_actor(radius_mm: float):
    """A VTK sphere actor of the probe [mm], centred at the origin (moved by SetPosition)."""
    from vtkmodules.vtkFiltersSources import vtkSphereSource
    from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper

    source = vtkSphereSource()
    source.SetRadius(radius_mm)
    source.SetThetaResolution(48)
    source.SetPhiResolution(24)
    mapper = vtkPolyDataMapper()
    mapper.SetInputConnection(source.GetOutputPort())
    actor = vtkActor()
    actor.SetMapper(mapper)
    actor.GetProperty().SetColor(0.55, 0.65, 0.8)
    actor.GetProperty().SetSpecular(0.4)
    return actor


def main(argv: list[str] | None = None) -> int:
    """``softvr demo palpation``: MP4, PNG contact sheet and JSON metrics of a palpated CT."""
    p = argparse.ArgumentParser(prog="softvr demo palpation", description=__doc__.splitlines()[0])
    p.add_argument("--input", help="CT volume file (Hounsfield units) instead of the bundled head CT")
    p.add_argument("--out", default=None, metavar="DIR", help=f"output folder (default ./{DEFAULT_OUT}/palpation)")
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--cells", type=int, nargs=3, default=(16, 16, 8), metavar=("CX", "CY", "CZ"))
    p.add_argument("--size", type=int, nargs=2, default=(512, 512), metavar=("W", "H"))
    p.add_argument("--full", action="store_true", help="rasterize the whole volume every frame")
    p.add_argument("--render-step", type=int, default=1, help="render every k-th voxel per axis (default 1)")
    p.add_argument("--renderer", choices=("warp", "vtk"), default="warp",
                   help="volume renderer: softvr's Warp ray caster (default) or VTK's CPU ray caster")
    add_device_option(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    if args.frames < 2:
        p.error(f"--frames: expected an integer >= 2, got {args.frames}")
    volume = load(args.input) if args.input else None
    with Example(volume, tuple(args.cells), args.frames, *args.size, incremental=not args.full,
                 render_step=args.render_step, renderer=args.renderer, device=args.device) as ex:
        if not args.quiet:
            print(f"softvr demo palpation: {ex.volume!r}; {len(ex.tets)} tets, {int(ex.body.fixed.sum())} clamped "
                  f"nodes (bone), mass {ex.body.mass.sum():.2f} kg", flush=True)
        record(ex, out_folder(args.out, ex.name), progress=not args.quiet)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
