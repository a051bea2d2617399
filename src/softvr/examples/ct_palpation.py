"""Volumetric palpation: a CT pressed by a probe, its FEM built from the voxels (thesis 3.3.2).

The real head CT is embedded in a regular tet mesh over the head (cubes holding tissue); each
tet's Young's modulus, Poisson ratio and density are integrated from the voxels' Hounsfield
units (:mod:`softvr.model.tissue`), and the nodes of bone-dense tets are clamped, so the skull
holds the soft tissue. A round probe presses into the cheek and withdraws; the co-rotational
FEM deforms under it through frictional contact. Every frame the CT is rasterized from the
deformed mesh — only the box around the tets that moved (:meth:`softvr.volume.Rasterizer.update`)
— and volume-rendered.

The demo is the bundled scene file ``palpation.toml`` (``softvr demo palpation``, ``softvr view
palpation``). This :class:`~softvr.app.Player` remains for what a scene file does not hold: a
segmentation deformed with the CT (``labels``, :meth:`CTPalpation.label_surface`), the choice of volume
renderer and its ray step, which ``softvr bench palpation`` measures; ``example_palpation.py``
plays the scene file.
"""

from __future__ import annotations

import time

import numpy as np

from softvr import Scene
from softvr.app import Player
from softvr.datasets import head_ct
from softvr.dynamics import EmbeddedPoints, KinematicBody, RigidPoints
from softvr.errors import InputError
from softvr.model import CT_TISSUE, collision_mesh, embed_surface, tissue_fem_body
from softvr.model.shapes import icosphere
from softvr.render import Camera, VolumeRenderer
from softvr.volume import DeformedVolume, Volume, grid_tet_mesh, iso_surface

__all__ = ["CTPalpation", "press_point"]

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


class CTPalpation(Player):
    """A CT palpated by a probe (module docstring), played as a :class:`~softvr.app.Player`:
    per step the FEM and the contacts, per frame the CT rasterized where the mesh moved
    (:meth:`update_volume`), its metrics (``fem_ms``, ``raster_ms``, ``raster_voxels``,
    ``indentation_m``, ``max_displacement_m`` besides the player's), and volume rendering.

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
        if volume is None:
            volume = head_ct()
        from scipy.ndimage import binary_dilation

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
        self.skin = EmbeddedPoints(self.body, self.tets[tet_index], weights)
        scene.add_body(self.body, collision_points=self.skin, collision_triangles=skin_triangles)
        self.target = press_point(volume) * _UNIT
        self.radius, self.depth = float(radius), float(depth)
        # (Player.__init__ sets them again; the probe's path reads them as it is made.)
        self.frames, self.dt, self.steps_per_frame = max(int(frames), 2), float(dt), int(steps_per_frame)
        self.probe = KinematicBody(self.pose, name="probe")
        unit_sphere, faces = icosphere(2)
        scene.add_body(self.probe, collision_points=RigidPoints(self.probe, unit_sphere * radius),
                       collision_triangles=faces)
        # Embedding tets in the air in front of the skin fold as the skin is pressed: skip them.
        # Node motion under 0.01 mm is drawn once it adds up.
        self.drawing = DeformedVolume(volume, self.nodes, self.tets, tolerance=0.01, incremental=incremental,
                                      device=device, inverted="skip")
        self.labels = labels
        if labels is not None:
            if labels.shape != volume.shape:
                raise InputError("labels", f"a label volume of the CT's shape {volume.shape}", f"shape {labels.shape}")
            self.label_drawing = DeformedVolume(labels, self.nodes, self.tets, tolerance=0.01,
                                                incremental=incremental, device=device, inverted="skip",
                                                interpolation="nearest", background=0)
        self.preset, self.azimuth = "ct-skin", -40.0
        if not (isinstance(render_step, int) and render_step >= 1):
            raise InputError("render_step", "an integer >= 1", repr(render_step))
        if renderer not in ("warp", "vtk"):
            raise InputError("renderer", "'warp' or 'vtk'", repr(renderer))
        self.render_step, self.renderer, self.sample_distance = render_step, renderer, float(sample_distance)
        self._changed: bool | tuple = True  # what the rasterizer rewrote since the last render: everything at first
        super().__init__(scene, self.dt, self.steps_per_frame, self.frames, width, height)
        #: The volume renderer (made with the first frame drawn; the player's surface renderer is not used).
        self.volume_renderer: VolumeRenderer | None = None
        # The video shows the 0.4 s press slowed down: 12 frames per second, not 1 / (dt * steps).
        self.fps = 12.0

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

    # -- the player's hooks -----------------------------------------------------------------
    def penetration(self) -> float:
        """Deepest skin point inside the probe sphere [m]."""
        inside = self.radius - np.linalg.norm(self.skin.positions() - self.probe.position, axis=1)
        return max(0.0, float(inside.max()))

    def update_volume(self) -> dict:
        """Rasterize the CT (and the labels) where the mesh moved; the frame's raster metrics."""
        t0 = time.perf_counter()
        drawn = self.drawing.update(self.body.q / _UNIT)
        self._note_changed(drawn["box"])
        if self.labels is not None:
            self.label_drawing.update(self.body.q / _UNIT)
        return {"raster_ms": 1e3 * (time.perf_counter() - t0), "raster_voxels": drawn["raster_voxels"]}

    def frame_metrics(self) -> dict:
        return {"indentation_m": self.indentation(),
                "max_displacement_m": float(np.linalg.norm(self.body.q - self.body.rest, axis=1).max())}

    def step(self) -> dict:
        """One frame (:meth:`softvr.app.Player.step`); ``fem_ms`` is its physics (``step_ms``)."""
        record = super().step()
        record["fem_ms"] = record["step_ms"]
        return record

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
        k, d = self.render_step, self.deformed
        if k == 1:
            return d
        return Volume(np.ascontiguousarray(d.data[::k, ::k, ::k]), d.spacing * k, d.origin.copy(), d.direction.copy())

    def render(self) -> np.ndarray:
        """Volume-render the deformed CT; returns RGB uint8 [height, width, 3]."""
        t0 = time.perf_counter()
        if self.volume_renderer is None:
            self.volume_renderer = VolumeRenderer(self.width, self.height, preset=self.preset,
                                            camera=Camera("front", azimuth=self.azimuth, elevation=5, zoom=1.3),
                                            mapper="warp" if self.renderer == "warp" else "cpu",
                                            sample_distance=self.sample_distance)
            self._probe_actor = _probe_actor(self.radius / _UNIT)
            self.volume_renderer.vtk_renderer.AddActor(self._probe_actor)
        # The probe as a surface in the same frame: in front of the skin it hides it, pressed
        # in it is hidden by the skin around it.
        self._probe_actor.SetPosition(*(np.asarray(self.probe.position) / _UNIT))
        if self.renderer == "warp":
            # The rewritten box is in full-resolution voxels: a subsampled volume is redone whole.
            changed = self._changed if self.render_step == 1 else True
            image = self.volume_renderer.render(self.shown_volume(), changed=changed)
        else:
            image = self.volume_renderer.render(self.shown_volume())
        self._changed = False
        if self.metrics:
            self.metrics[-1]["render_ms"] = 1e3 * (time.perf_counter() - t0)
            self.metrics[-1]["wall_ms"] = self.metrics[-1]["step_ms"] + self.metrics[-1]["render_ms"]
        return image

    def label_surface(self, label: int) -> tuple[np.ndarray, np.ndarray]:
        """The surface [mm] of segmentation ``label`` as deformed now: vertices [n, 3] and
        triangles [t, 3] of the iso-surface of its mask."""
        if self.labels is None:
            raise InputError("labels", "a label volume given to CTPalpation(labels=...)", "none")
        d = self.labels_deformed
        mask = Volume((d.data == label).astype(np.float32), d.spacing.copy(), d.origin.copy(), d.direction.copy())
        return iso_surface(mask, 0.5)

    def describe(self) -> dict:
        return {**super().describe(), "volume": repr(self.volume), "tets": len(self.tets), "nodes": len(self.nodes),
                "clamped_nodes": int(self.body.fixed.sum()), "press_point_m": self.target.tolist(),
                "young_pa_min_median_max": [float(np.min(self.tissue.young)), float(np.median(self.tissue.young)),
                                            float(np.max(self.tissue.young))],
                "mass_kg": float(self.body.mass.sum()), "dt_s": self.dt, "incremental": self.incremental,
                "render_step": self.render_step, "renderer": self.renderer, "sample_distance": self.sample_distance}

    # -- what softvr.app.record reads ---------------------------------------------------
    name = "palpation"

    def summary(self) -> dict:
        """The player's summary, and median ms per frame of the FEM step, the rasterization and
        the rendering; the deepest indentation [m]."""
        med = {f"{k}_median": float(np.median([m.get(k, 0.0) for m in self.metrics]))
               for k in ("fem_ms", "raster_ms", "render_ms")}
        return {**super().summary(), **med, "max_indentation_m": max(m["indentation_m"] for m in self.metrics)}

    def status(self) -> str:
        m = self.metrics[-1]
        return f"indentation {m['indentation_m'] * 1e3:.2f} mm, raster {m['raster_ms']:.0f} ms"

    def close(self) -> None:
        if self.volume_renderer is not None:
            self.volume_renderer.close()
            self.volume_renderer = None
        super().close()


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

