"""From a validated scene file to a running simulation: :class:`SceneExample`.

Each ``[[body]]`` becomes a contact object with its collision geometry and a drawn surface:

=========  =====================================================================================
rigid      box or sphere (an exact box / sphere collider for planes and its own kind, and its
           surface for everything else) or mesh (its vertices and triangles collide; mass,
           centre and inertia of the closed mesh): of the material's density
fem        box: a grid of ``cells``^3 cubes, 5 tets each; sphere (an icosphere) or mesh: the model
           pipeline's dynamics mesh (cubes of ``cells`` metres touching the surface) with the
           surface embedded in it; tets: a tet mesh file, its boundary the surface; co-rotational
           FEM of the material. ``drive`` moves the held nodes (driven boundary, ``fixed_velocity``)
cloth      a ``cloth = [w, h]`` sheet of ``quads`` in the body's x-y plane (or a glTF mesh),
           mass-spring cloth
fixed      box (box collider of a fixed body) or mesh (a static triangle mesh obstacle)
kinematic  box, sphere or mesh moved through ``motion`` keyframes (linear in between, held after)
tool       a rigid box, sphere or mesh on a virtual coupling to a haptic handle that follows ``motion``
           (:class:`softvr.haptics.HapticTool`; ``haptics = true``: the 1 kHz loop in its own process)
=========  =====================================================================================

A ``[[model]]`` adds the parts of a parts file (built by :func:`softvr.model.build_model` as
the scene loads) or of a built model: bodies named as the parts, its couplings as springs.

The built scene is a :class:`softvr.app.Player`: ``softvr run SCENE.toml`` records it
(:func:`softvr.app.record`), ``softvr view SCENE.toml`` plays it in a window
(:func:`softvr.app.play_window`).
"""

from __future__ import annotations

import numpy as np

from pathlib import Path
from typing import Any

import softvr.datasets
from softvr import Scene
from softvr.app import Drawable, Player, Sensor, plane_drawable, pose_matrix, sphere_drawable
from softvr.collision import Plane, Sphere, TriangleMesh
from softvr.contact import Adhesion
from softvr.device import resolve_device
from softvr.dynamics import (ClothBody, ContactObject, Coupling, EmbeddedPoints, FemBody, FixedBody, KinematicBody,
                             Material, RigidBody, RigidPoints, embed_in_tets)
from softvr.errors import InputError
from softvr.files import native_read
from softvr.haptics import HapticLoop, HapticTool, ScriptedDevice
from softvr.model import (CT_TISSUE, build_model, collision_mesh, dynamics_mesh, embed_surface, load_mesh, load_model,
                          nodes_near_surface, rigid_properties, tissue_fem_body)
from softvr.model.shapes import BOX_TRIANGLES, box_corners, box_surface, icosphere
from softvr.render import Camera, merge_changed
from softvr.scene.gltf import read_gltf_scene, read_gltf_scene_with_problems
from softvr.scene._description import SENSOR_KINDS, STATIC
from softvr.scene.schema import DATASETS, BodySpec, SceneFile, read_scene, read_scene_with_problems
from softvr.scene.start import collision_free_start, start_pairs, start_problems
from softvr.volume import DeformedVolume, Volume, boundary_faces, grid_tet_mesh, iso_surface, load_tet_mesh
from softvr.volume import load as load_volume

__all__ = ["SceneExample", "load_scene", "read_any", "read_any_with_problems", "scene_path"]


def _rotation(degrees) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrix [3, 3] and quaternion (w, x, y, z) of x-then-y-then-z angles [deg]."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_euler("xyz", degrees, degrees=True)
    x, y, z, w = r.as_quat()
    return r.as_matrix(), np.array([w, x, y, z])


def _linear(times, values, t: float) -> np.ndarray:
    """Keyframes ``values`` [k, ...] at ``times`` [k] [s], linear in between, held outside."""
    # min/max on a Python int: np.clip on a scalar costs ~8 us, and this runs every haptic tick
    j = min(max(int(np.searchsorted(times, t, side="right")), 1), len(times) - 1)
    if len(times) == 1 or t <= times[0]:
        return np.asarray(values[0], float)
    if t >= times[-1]:
        return np.asarray(values[-1], float)
    w = (t - times[j - 1]) / (times[j] - times[j - 1])
    return (1.0 - w) * values[j - 1] + w * values[j]


def _drive(drive: dict):
    """Offset [3] [m] of a body's held nodes at time t [s] (its ``[body.drive]`` keyframes)."""
    times, offsets = np.asarray(drive["times"], float), np.asarray(drive["offsets"], float)
    return lambda t: _linear(times, offsets, t)


def _node_animation(path, nodes) -> tuple[np.ndarray, np.ndarray]:
    """``times`` [k] [s] and ``nodes`` [k, node_count, 3] [m] of a node animation (.npz), checked
    against the mesh's nodes [node_count, 3] [m]: same count, the first key at them."""

    try:
        with np.load(path) as f:
            times, cache = np.asarray(f["times"], float), np.asarray(f["nodes"], float)
    except (OSError, ValueError, KeyError) as exc:
        raise InputError("animation", "an .npz with arrays times [k] [s] and nodes [k, node_count, 3] [m]",
                         f"{type(exc).__name__}: {exc}", source=str(path)) from None
    if times.ndim != 1 or len(times) == 0 or np.any(np.diff(times) <= 0):
        raise InputError("times", "increasing times [s], at least one", f"shape {times.shape}", source=str(path))
    if cache.shape != (len(times), *nodes.shape):
        raise InputError("nodes", f"[{len(times)}, {len(nodes)}, 3]: one position per mesh node per time",
                         f"shape {cache.shape}", source=str(path))
    off = float(np.abs(cache[0] - nodes).max())
    if off > 1e-6:
        raise InputError("nodes[0]", "the mesh's rest nodes (within 1 um)", f"{off:.3g} m off", source=str(path))
    return times, cache


def _attached(body, points) -> object:
    """Point entity on ``body`` at world ``points`` [n, 3] [m] as it is now: barycentric in
    its tets (a fem body), its nearest nodes (cloth), or fixed in its frame (rigid)."""
    if hasattr(body, "tets"):
        ti, w = embed_in_tets(body.q, body.tets, points, tolerance=np.inf)
        return EmbeddedPoints(body, body.tets[ti], w)
    if hasattr(body, "q"):
        nearest = np.linalg.norm(body.q[None, :, :] - points[:, None, :], axis=2).argmin(axis=1)
        return EmbeddedPoints(body, nearest[:, None], np.ones((len(points), 1)))
    return RigidPoints.from_world(body, points)


def _contact_force(index: int, other: int | str | None, dt: float):
    """Sensor read: the contact force [3] [N] on scene body ``index`` over the last step, its
    contact impulses / ``dt`` (thesis eq. 5.5; + on side a, - on side b), from every contact
    (``other`` None), from body ``other``'s only, or from the static geometry's (:data:`STATIC`)."""
    if other is None:
        return lambda solution: solution.force_on(index, dt)

    def read(solution) -> np.ndarray:
        total = np.zeros(3)
        for (a, b), impulses, frames in zip(solution.set_bodies(), solution.impulses, solution.frames):
            b = STATIC if b is None else b
            world = np.einsum("ci,cij->j", impulses, frames)
            if (a, b) == (index, other):
                total += world
            elif (a, b) == (other, index):
                total -= world
        return total / float(dt)

    return read


def _coupling_force(scene, body):
    """Sensor read: the force [3] [N] of the couplings on ``body`` (thesis eq. 5.4: spring and
    damper of every coupling with a side on it)."""

    def read(_solution) -> np.ndarray:
        total = np.zeros(3)
        for c in scene.couplings:
            sign = (c.a.body is body) - (c.b.body is body)
            if sign:
                total += sign * c.forces().sum(axis=0)
        return total

    return read


def _centre(body):
    """Sensor read: ``body``'s centre [3] [m]: a node body's mass-weighted mean node, else its
    position (a rigid body's centre of mass)."""
    if hasattr(body, "q"):
        mass = np.broadcast_to(np.asarray(body.mass, float), (len(body.q),))
        return lambda _solution: mass @ np.asarray(body.q) / mass.sum()
    return lambda _solution: np.array(body.position, float)


def _hand_force(tool):
    """Sensor read: the force [3] [N] a tool's haptic device renders on the hand now
    (:meth:`softvr.haptics.HapticTool.force`: its virtual coupling's spring, thesis 5.4)."""
    return lambda _solution: tool.force()


#: Model parts' colours by kind.
_PART_COLORS = {"fixed": (0.92, 0.9, 0.82), "kinematic": (0.92, 0.9, 0.82), "rigid": (0.95, 0.95, 0.9),
                "soft": (0.72, 0.3, 0.3)}


#: A tool's haptic handle (where the hand is; the tool follows it on its virtual coupling) is
#: drawn as a translucent ball of this radius [m], a fingertip's, so that the lag shows.
_HANDLE_RADIUS = 0.008
_HANDLE_COLOR = (0.95, 0.8, 0.2)

#: Folder of the bundled scene files (:data:`softvr.scene.BUNDLED`).
_BUNDLED = Path(__file__).resolve().parent.parent / "scenes"


class _Drawn:
    """A body's drawn surface: ``name`` (the body's), ``vertices()`` [n, 3] [m] now, ``triangles``
    [t, 3]; ``rigid``: (body, points [n, 3] [m] in its frame) where the vertices are
    ``position + R points`` (given, or a :class:`~softvr.dynamics.RigidPoints`' ``positions``),
    else None."""

    def __init__(self, name: str, vertices, triangles, color, opacity: float = 1.0, visible: bool = True,
                 rigid=None):
        self.name, self.vertices, self.triangles, self.color = name, vertices, np.asarray(triangles, np.int32), color
        self.opacity, self.visible = opacity, visible
        points = getattr(vertices, "__self__", None)
        if rigid is None and type(points) is RigidPoints and vertices.__func__ is RigidPoints.positions:
            rigid = (points.body, points.local)
        self.rigid = rigid


def _read_volume(source, scene_path: str):
    """The ``[volume] file``: a dataset of :mod:`softvr.datasets` by name, or a volume file."""
    if isinstance(source, str) and source in DATASETS:
        return getattr(softvr.datasets, DATASETS[source])()
    return load_volume(source)


class _DeformedVolume:
    """The scene's volume: a :class:`~softvr.volume.DeformedVolume` following its FEM body
    (nodes in metres, the volume in its own units), and the ``labels`` segmentation deformed
    with it (nearest voxel); :meth:`shown` the rendered one in metres."""

    def __init__(self, volume, body, tissue, nodes, tets, spec: dict, device: str | None = None):
        self.unit, self.body, self.spec = spec["unit"], body, spec
        #: The volume at rest (its own units) and its tets' :class:`~softvr.model.TetTissue`.
        self.rest, self.tissue = volume, tissue
        # Tets in the air in front of a pressed skin fold: skipped, not drawn inverted; node
        # motion under 10 um is drawn once it adds up.
        options = dict(tolerance=1e-5 / self.unit, incremental=spec["incremental"], inverted="skip", device=device)
        self.drawing = DeformedVolume(volume, nodes, tets, **options)
        self.labels: DeformedVolume | None = None
        if spec["labels"] is not None:
            labels = load_volume(spec["labels"], is_label=True)
            if labels.shape != volume.shape:
                raise InputError("volume.labels", f"a label volume of the volume's shape {volume.shape}",
                                 f"shape {labels.shape}", source=str(spec["labels"]))
            self.labels = DeformedVolume(labels, nodes, tets, interpolation="nearest", background=0, **options)
        #: What the rasterizer rewrote since the last :meth:`take_changed` (everything at first).
        self._changed: bool | tuple = True

    @property
    def deformed(self):
        """The volume as drawn now, in its own units."""
        return self.drawing.deformed

    def update(self) -> dict:
        """Draw the volume (and the labels) for the body's current nodes; returns frame metrics
        (``raster_ms``, ``raster_voxels`` of the volume)."""
        drawn = self.drawing.update(self.body.q / self.unit)
        self._changed = merge_changed(self._changed, drawn.pop("box"))
        if self.labels is not None:
            self.labels.update(self.body.q / self.unit)
        return drawn

    def take_changed(self):
        """What the volume as :meth:`shown` changed since the last call (:func:`softvr.render.merge_changed`):
        the rewritten voxel box, or everything when only every ``render_step``-th voxel is shown."""
        changed, self._changed = self._changed, False
        return changed if self.spec["render_step"] == 1 or changed is False else True

    def shown(self):
        """The deformed volume as rendered [m]: every ``render_step``-th voxel per axis."""
        k, d = self.spec["render_step"], self.deformed
        data = d.data if k == 1 else np.ascontiguousarray(d.data[::k, ::k, ::k])
        return Volume(data, d.spacing * k * self.unit, d.origin * self.unit, d.direction.copy())

    def label_surface(self, label: int) -> tuple[np.ndarray, np.ndarray]:
        """The surface of segmentation ``label`` as deformed now: vertices [n, 3] [m] in the
        world and triangles [t, 3], the iso-surface of its mask."""
        if self.labels is None:
            raise InputError("volume.labels", "a label volume ([volume] labels = FILE)", "none")
        d = self.labels.deformed
        mask = Volume((d.data == label).astype(np.float32), d.spacing.copy(), d.origin.copy(), d.direction.copy())
        vertices, triangles = iso_surface(mask, 0.5)
        return vertices * self.unit, triangles


class SceneExample(Player):
    """A scene file played as a demo (module docstring).

    Parameters
    ----------
    scene_file : SceneFile
        From :func:`~softvr.scene.read_scene`.
    frames : int, optional
        Override the file's ``simulation.frames``.
    width, height : int, optional
        Override the file's ``render.size``.
    steps_per_frame : int, optional
        Override the file's ``simulation.steps_per_frame`` (a bench times every step: 1).
    device : {"cpu", "cuda", None}
        Warp device of the volume's rasterizer (None: CUDA when present) and, where given, of
        the physics' node arrays (:attr:`softvr.Scene.device`; None: the CPU, whose step the
        tests hold to physics on every machine).
    haptics : bool, optional
        False: no tool runs its 1 kHz haptic process, whatever its ``haptics`` says (each
        reads its handle once per step instead); None or True: as the file says.
    """

    def __init__(self, scene_file: SceneFile, frames: int | None = None, width: int | None = None,
                 height: int | None = None, device: str | None = None, haptics: bool | None = None,
                 steps_per_frame: int | None = None):
        self.file = scene_file
        self.name = scene_file.path.stem
        self.device = device
        self._haptics = haptics
        sim, ren = scene_file.simulation, scene_file.render
        # simulation.adhesion false: the same scene dry (every adhesion name finds none).
        self.adhesions = {k: Adhesion(**v) for k, v in scene_file.adhesions.items()} if sim["adhesion"] else {}
        scene = Scene(gravity=sim["gravity"], friction=sim["friction"], pgs_iterations=sim["pgs_iterations"],
                      pgs_tolerance=sim["pgs_tolerance"], contact_margin=sim["contact_margin"],
                      rotation_lag=sim["rotation_lag"],
                      edge_contacts=sim["edge_contacts"], device="cpu" if device is None else resolve_device(device))
        self.scene = scene  # (again in Player.__init__) the collision-free start needs it
        self.planes = []
        for p in scene_file.planes:
            plane = Plane(point=p["point"], normal=p["normal"], friction=p["friction"])
            scene.add_plane(plane, adhesion=self.adhesions.get(p["adhesion"]))
            self.planes.append((plane, p["size"]))
        self.spheres = []
        for s in scene_file.spheres:
            sphere = Sphere(center=s["center"], radius=s["radius"], friction=s["friction"])
            scene.add_sphere(sphere, adhesion=self.adhesions.get(s["adhesion"]))
            self.spheres.append(sphere)
        self.bodies: dict[str, Any] = {}
        self.drawn: list[_Drawn] = []
        self.index: dict[str, int] = {}
        self._drawn_by_name: dict[str, _Drawn] = {}
        # name -> the collision surface of a fixed mesh (a static obstacle, not a body)
        self._obstacles: dict[str, _Drawn] = {}
        self.tools: list[HapticTool] = []
        self._driven: list[tuple] = []  # (body, drive)
        self.volume: _DeformedVolume | None = None
        #: The volume's handle in the renderer (:meth:`softvr.render.SurfaceRenderer.ray_caster`), once drawn.
        self.volume_handle: int | None = None
        if scene_file.volume is not None:
            self._add_volume(scene, scene_file.volume)
        for model in scene_file.models:
            self._add_model(scene, model)
        for spec in scene_file.bodies:
            self._add(scene, spec)
        # The haptic handles' ball (unit vertices, triangles), made once: an icosphere costs ~4 ms,
        # too much for every frame's drawables().
        self._handle_ball = icosphere(2) if self.tools else (np.zeros((0, 3)), np.zeros((0, 3), np.int32))
        for a, b in scene_file.filters:
            scene.disable_collision(self.index[a], self.index[b])
        for spec in scene_file.bodies:
            if spec.collides_with is not None:
                for other, j in self.index.items():
                    if other != spec.name and other not in spec.collides_with:
                        scene.disable_collision(self.index[spec.name], j)
        # Cloth is an open sheet: it has no inside to start in.
        apart = {frozenset((c["a"], c["b"])) for c in scene_file.couplings if not c["collide"]}
        names = [n for n in self._drawn_by_name if getattr(scene_file.body(n), "type", None) != "cloth"]
        self._pairs = start_pairs(names, list(self._obstacles),
                                  lambda a, b: scene.collision_enabled(self.index[a], self.index[b]), apart)
        #: (moved body, obstacle, its largest node displacement [m]) of the collision-free start.
        self.separation = (collision_free_start(self.bodies, self._surfaces(), self._pairs)
                           if sim.get("collision_free_start") else [])
        for c in scene_file.couplings:
            self._couple(scene, c)
        w, h = ren["size"]
        camera = Camera(ren["camera"], azimuth=ren["azimuth"], elevation=ren["elevation"], zoom=ren["zoom"])
        super().__init__(scene, sim["dt"], steps_per_frame or sim["steps_per_frame"], frames or sim["frames"],
                         width or w, height or h, bounds=ren["bounds"], camera=camera)
        if ren["fps"] is not None:
            self.fps = ren["fps"]
        self.sensors = [self._sensor(s) for s in scene_file.sensors]

    # -- building ----------------------------------------------------------------------
    def _add_volume(self, scene, spec: dict) -> None:
        """The ``[volume]``: a FEM body over the volume's tissue with per-tet materials from its
        voxels, the skin (iso-surface) as its collision surface, and a rasterizer that draws
        the volume through the deformed tets every frame (:class:`_DeformedVolume`)."""
        from scipy.ndimage import binary_dilation

        volume = _read_volume(spec["file"], str(self.file.path))
        unit = spec["unit"]
        # Cubes holding tissue, grown by two voxels so that the skin lies inside them.
        tissue = binary_dilation(volume.data > spec["threshold"], iterations=2) if spec["mask"] else None
        nodes, tets = grid_tet_mesh(volume, spec["cells"], mask=tissue)
        body, tissue = tissue_fem_body(volume, nodes, tets, CT_TISSUE, unit=unit, alpha=spec["alpha"], beta=spec["beta"],
                                  fix_denser_than=spec["fix_denser_than"], name=spec["name"])
        skin, triangles = iso_surface(volume, spec["threshold"], step=2)
        skin, triangles = collision_mesh(skin * unit, triangles, spec["skin_triangles"])
        tet_index, weights = embed_surface(nodes * unit, tets, skin)
        points = EmbeddedPoints(body, tets[tet_index], weights)
        self.index[spec["name"]] = scene.add_body(body, collision_points=points, collision_triangles=triangles)
        self.bodies[spec["name"]] = body
        # The skin is drawn by the volume itself.
        self._drawn_by_name[spec["name"]] = _Drawn(spec["name"], points.positions, triangles, (0.9, 0.7, 0.6),
                                                    visible=False)
        self.drawn.append(self._drawn_by_name[spec["name"]])
        self.volume = _DeformedVolume(volume, body, tissue, nodes, tets, spec, self.device)
        if spec["animation"] is not None:
            times, cache = _node_animation(spec["animation"], body.q)
            body.fixed[:] = True
            self._driven.append((body, lambda t: _linear(times, cache, t)))

    def _add_model(self, scene, model: dict) -> None:
        """The parts of a parts file (built now) or of a built model, with their couplings."""
        path = model["file"]
        built = load_model(path) if path.suffix.lower() == ".npz" else build_model(path, progress=False)
        first = len(scene.bodies)
        _, bodies, render_points = built.build_scene(scene)
        for k, (name, body) in enumerate(bodies.items()):
            part = built.part(name)
            color = model["colors"].get(name, _PART_COLORS.get(part.spec.kind, _PART_COLORS["soft"]))
            self.bodies[name], self.index[name] = body, first + k
            self.drawn.append(_Drawn(name, render_points[name].positions, part.render_triangles, color,
                                     model["opacity"].get(name, 1.0)))
            self._drawn_by_name[name] = self.drawn[-1]

    def _add(self, scene, spec: BodySpec) -> None:
        rotation, quaternion = _rotation(spec.rotation)
        centre = np.asarray(spec.position, float)
        adhesion = self.adhesions.get(spec.adhesion)
        material: Any = self.file.materials.get(spec.material)  # None only for types that take none (validated)
        body: ContactObject
        if spec.type in ("rigid", "kinematic", "tool") and spec.shape == "mesh":
            v, t = self._surface(spec, rotation, centre)
            if spec.type == "kinematic":
                # Its frame: the world axes at the body's position, moved through the keyframes.
                body = KinematicBody(self._keyframes(spec, centre, np.array([1.0, 0.0, 0.0, 0.0])), name=spec.name)
                origin = centre
            else:
                mass, origin, inertia = rigid_properties(v, t, material["density"], f"body {spec.name!r}")
                body = RigidBody(mass, inertia, position=origin, velocity=spec.velocity,
                                 angular_velocity=spec.angular_velocity, name=spec.name)
            local = v - origin
            cv, ct = self._collision_surface(spec, v, t)
            index = scene.add_body(body, collision_points=RigidPoints(body, cv - origin), collision_triangles=ct,
                                   adhesion=adhesion)
            self.drawn.append(_Drawn(spec.name, lambda b=body, p=local: b.position + p @ b.rotation.T, t, spec.color,
                                     rigid=(body, local)))
            if spec.type == "tool":  # the handle holds the body's position, not its centre of mass
                self.tools.append(self._tool(scene, spec, body, tip=centre - origin))
        elif spec.type in ("rigid", "fixed", "kinematic", "tool") and spec.shape in ("box", "sphere"):
            if spec.type in ("rigid", "tool"):
                make = RigidBody.box if spec.shape == "box" else RigidBody.sphere
                body = make(spec.size, material["density"], position=centre, orientation=quaternion,
                            velocity=spec.velocity, angular_velocity=spec.angular_velocity, name=spec.name)
            elif spec.type == "fixed":
                body = FixedBody(centre, quaternion, name=spec.name)
            else:
                body = KinematicBody(self._keyframes(spec, centre, quaternion), name=spec.name)
            if spec.shape == "box":
                half = np.asarray(spec.size) / 2
                collider = {"collision_box": half}
                if spec.surface_quads > 1:
                    local, triangles = box_surface(spec.size, spec.surface_quads)
                    local = local - half
                else:
                    local, triangles = box_corners(half), BOX_TRIANGLES
            else:
                collider = {"collision_sphere": spec.size}
                unit, triangles = icosphere(spec.subdivisions)
                local = unit * spec.size
            # The primitive meets planes and its kind exactly, the surface everything else.
            index = scene.add_body(body, adhesion=adhesion, collision_points=RigidPoints(body, local),
                                   collision_triangles=triangles, **collider)
            if spec.type == "tool":
                self.tools.append(self._tool(scene, spec, body))
            self.drawn.append(_Drawn(spec.name, lambda b=body, p=local: b.position + p @ b.rotation.T, triangles,
                                     spec.color, rigid=(body, local)))
        elif spec.type == "fixed":  # a mesh: a static obstacle, not a body
            v, t = self._surface(spec, rotation, centre)
            scene.add_mesh(TriangleMesh(v, t), adhesion=adhesion)
            self._obstacles[spec.name] = _Drawn(spec.name, lambda v=v: v, t, spec.color)
            if spec.render_mesh is not None:
                v, t = self._surface(spec, rotation, centre, spec.render_mesh)
            self.drawn.append(_Drawn(spec.name, lambda v=v: v, t, spec.color))
            return
        elif spec.type == "fem":
            m = Material(material["young"], material["poisson"], material["density"], alpha=material["alpha"],
                         beta=material["beta"])
            nodes, tets, surface, embedding = self._tet_mesh(spec, rotation, centre)
            if spec.shape in ("sphere", "mesh"):
                # The embedding cubes reach past the surface: the object weighs rho times the
                # volume its surface encloses, spread over them.
                inside = rigid_properties(*self._surface(spec, rotation, centre), 1.0, f"body {spec.name!r}")[0]
                tet_volume = np.abs(np.linalg.det(nodes[tets[:, 1:]] - nodes[tets[:, :1]])).sum() / 6.0
                m = Material(m.young, m.poisson, m.density * inside / tet_volume, alpha=m.alpha, beta=m.beta)
            body = FemBody(nodes, tets, m, fixed=self._clamped(spec, nodes), name=spec.name)
            self._set_velocity(body, spec, centre)
            if spec.drive:
                self._driven.append((body, _drive(spec.drive)))
            tet_nodes, weights = embedding
            points = EmbeddedPoints(body, tet_nodes, weights)
            index = scene.add_body(body, collision_points=points, collision_triangles=surface, adhesion=adhesion)
            self.drawn.append(_Drawn(spec.name, points.positions, surface, spec.color))
        else:  # cloth
            c = spec.cloth
            springs = dict(density=c["area_density"], stretch=c["stretch"], shear=c["shear"], bend=c["bend"],
                           damping=c["damping"], alpha=c["alpha"], name=spec.name)
            if spec.mesh_data is not None:
                cloth = ClothBody(*self._surface(spec, rotation, centre), **springs)
            else:
                w, h = spec.size
                origin = centre - rotation @ np.array([w / 2, h / 2, 0.0])
                cloth = ClothBody.grid(w, h, *c["quads"], origin=origin, u_axis=rotation[:, 0],
                                       v_axis=rotation[:, 1], **springs)
            body = cloth
            cloth.fixed[:] = self._clamped(spec, cloth.q)
            self._set_velocity(cloth, spec, centre)
            if spec.drive:
                self._driven.append((cloth, _drive(spec.drive)))
            n = len(cloth.q)
            points = EmbeddedPoints(cloth, np.arange(n)[:, None], np.ones((n, 1)))
            # The triangles give the contacts their areas (adhesion works on tractions) and
            # meet other bodies' surfaces.
            index = scene.add_body(cloth, collision_points=points, collision_triangles=cloth.triangles,
                                   adhesion=adhesion)
            self.drawn.append(_Drawn(spec.name, lambda b=cloth: b.q, cloth.triangles, spec.color))
        if spec.render_mesh is not None or (spec.type == "fem" and spec.collision_triangles is not None):
            # Drawn: the render mesh, or the full shape when only the collision surface is simplified.
            self.drawn[-1] = self._render_surface(spec, body, rotation, centre, spec.render_mesh)
        self.bodies[spec.name] = body
        self.index[spec.name] = index
        self._drawn_by_name[spec.name] = self.drawn[-1]

    @staticmethod
    def _collision_surface(spec: BodySpec, vertices, triangles):
        """The shape's surface, simplified to ``collision_triangles`` when given."""
        if spec.collision_triangles is None:
            return vertices, triangles
        return collision_mesh(vertices, triangles, spec.collision_triangles)

    def _render_surface(self, spec: BodySpec, body, rotation, centre, file=None) -> "_Drawn":
        """A drawn surface (``file``, else the shape's own) placed as the shape and carried by
        the body: barycentric in its tets (extrapolated from the nearest tet where it pokes
        out), or fixed in its frame."""
        v, t = self._surface(spec, rotation, centre, file)
        points: EmbeddedPoints | RigidPoints
        if hasattr(body, "tets"):
            ti, w = embed_in_tets(body.q, body.tets, v, tolerance=np.inf)
            points = EmbeddedPoints(body, body.tets[ti], w)
        else:
            points = RigidPoints.from_world(body, v)
        return _Drawn(spec.name, points.positions, t, spec.color)

    def _couple(self, scene, c: dict) -> None:
        """Springs from the nodes of body ``a`` within ``radius`` of body ``b``'s surface, or at
        the world ``points`` (tied to both bodies where they are at the start)."""
        a, b = self.bodies[c["a"]], self.bodies[c["b"]]
        if c["points"] is not None:
            springs = np.asarray(c["points"], float)
            side_a = _attached(a, springs)
        else:
            surface = self._drawn_by_name[c["b"]]
            near = np.flatnonzero(nodes_near_surface(a.q, surface.vertices(), surface.triangles, c["radius"]))
            if len(near) == 0:
                raise InputError(f"coupling {c['a']} - {c['b']}", f"nodes of {c['a']!r} within {c['radius']} m of "
                                 f"{c['b']!r}", "none", source=str(self.file.path))
            springs = a.q[near]
            side_a = EmbeddedPoints(a, near[:, None], np.ones((len(near), 1)))
        scene.add_coupling(Coupling(side_a, _attached(b, springs), c["stiffness"], damping=c["damping"],
                                    name=f"{c['a']} - {c['b']}"), collide=c["collide"])

    def _sensor(self, s: dict) -> Sensor:
        """A ``[[sensor]]`` (validated: its bodies exist) read off the scene's bodies."""
        body, kind = self.bodies[s["body"]], s["kind"]
        if kind == "contact_force":
            other = s["other"] if s["other"] in (None, STATIC) else self.index[s["other"]]
            read = _contact_force(self.index[s["body"]], other, self.dt)
        elif kind == "coupling_force":
            read = _coupling_force(self.scene, body)
        elif kind == "hand_force":
            read = _hand_force(next(t for t in self.tools if t.tool is body))
        else:
            read = _centre(body)
        return Sensor(s["name"], kind, SENSOR_KINDS[kind], read)

    def _tool(self, scene, spec: BodySpec, body, tip=(0.0, 0.0, 0.0)):
        """A :class:`~softvr.haptics.HapticTool`: ``body`` on a virtual coupling, at ``tip`` [3]
        [m] in its frame, to a handle that follows the motion keyframes in simulated time."""
        path = self._keyframes(spec, np.asarray(spec.position, float), None)
        # The loop reads the hand once as it is made, before its clock exists: at the scene's
        # start time, not at the wall seconds since that reading (which moved the handle's
        # start, and so every step, by ~1e-9 m from run to run).
        start = float(scene.time)
        device = ScriptedDevice(lambda t: path(t)[0], clock=lambda: start)
        process = bool(spec.tool["haptics"]) and self._haptics is not False
        loop = HapticLoop(device, max_force=spec.tool["max_force"], process=process)
        device.clock = loop.simulation_clock
        tool = HapticTool(scene, body, loop, stiffness=spec.tool["stiffness"], damping=spec.tool["damping"], tip=tip,
                          angular_stiffness=spec.tool["angular_stiffness"])
        tool.haptics = process
        return tool

    def _surfaces(self) -> dict:
        """Name -> the surface a body or a fixed mesh obstacle starts crossing others with."""
        return {**self._obstacles, **self._drawn_by_name}

    def start_problems(self) -> list:
        """(what, expected, found) for bodies that start intersecting each other or a fixed
        mesh (crossing surface triangles; pairs that may not collide are left out) or below a
        plane (:func:`softvr.scene.start.start_problems`). Needs no start: no haptic process
        runs, no renderer is made."""
        return start_problems(self._drawn_by_name, self._surfaces(), [p for p, _ in self.planes], self._pairs)

    @staticmethod
    def _tet_mesh(spec: BodySpec, rotation, centre):
        """Nodes [n, 3] [m], tets, the collision / drawn surface over the embedded points and
        the embedding (tet node indices [k, 4] or [k, 1], weights)."""
        if spec.shape in ("box", "tets"):
            if spec.shape == "box":
                size = np.asarray(spec.size, float)
                cells = np.broadcast_to(np.asarray(spec.cells, int), (3,))
                spacing = size / cells
                grid = Volume(np.zeros(tuple(cells), np.uint8), spacing=spacing, origin=spacing / 2 - size / 2)
                nodes, tets = grid_tet_mesh(grid, tuple(cells))
            else:
                # meshio exits the process on some unreadable files: native_read turns that into an error.
                assert spec.mesh is not None  # a tets body names its file (validated)
                nodes, tets = native_read(load_tet_mesh, spec.mesh, f"body {spec.name!r}.tets",
                                          "a tet mesh file meshio can read")
                nodes = nodes * np.asarray(spec.scale)
            nodes = nodes @ rotation.T + centre
            if spec.shape == "box" and spec.surface_quads > 1:
                v, t = box_surface(size, spec.surface_quads)
                v = (v - size / 2) @ rotation.T + centre
                tet_index, weights = embed_surface(nodes, tets, v)
                return nodes, tets, t, (tets[tet_index], weights)
            faces = boundary_faces(tets)
            on_surface, local = np.unique(faces, return_inverse=True)
            return nodes, tets, local.reshape(-1, 3).astype(np.int32), (on_surface[:, None],
                                                                        np.ones((len(on_surface), 1)))

        v, t = SceneExample._surface(spec, rotation, centre)
        cv, ct = SceneExample._collision_surface(spec, v, t)
        # The cubes touching the shape or its simplified collision surface (which may reach a
        # little further out), as the model pipeline makes them.
        try:
            nodes, tets = dynamics_mesh(np.vstack([v, cv]), np.vstack([t, ct + len(v)]), float(spec.cells)) \
                if cv is not v else dynamics_mesh(v, t, float(spec.cells))
        except InputError as exc:  # a cube size too fine for the body's size: named as the body's field
            raise InputError(f"body {spec.name!r}.cells", exc.expected, exc.found) from None
        tet_index, weights = embed_surface(nodes, tets, cv)
        return nodes, tets, ct, (tets[tet_index], weights)

    @staticmethod
    def _clamped(spec: BodySpec, nodes) -> np.ndarray:
        """Nodes [n] bool held by ``fixed_below`` / ``fixed_above``."""
        held = np.zeros(len(nodes), bool)
        if spec.fixed_below is not None:
            held |= nodes[:, 2] < spec.fixed_below
        if spec.fixed_above is not None:
            held |= nodes[:, 2] > spec.fixed_above
        return held

    @staticmethod
    def _set_velocity(body, spec: BodySpec, centre) -> None:
        """Node velocities v + w x (x - c) [m/s] of a deformable body (c: ``spin_centre``, else
        the body's position); held nodes stay still."""
        c = np.asarray(spec.spin_centre if spec.spin_centre is not None else centre, float)
        body.v[:] = np.asarray(spec.velocity) + np.cross(np.asarray(spec.angular_velocity), body.q - c)
        body.v[body.fixed] = 0.0

    @staticmethod
    def _surface(spec: BodySpec, rotation, centre, file=None) -> tuple[np.ndarray, np.ndarray]:
        """The body's mesh (from its file, or given in memory; or ``file``) placed in the world [m]."""
        if isinstance(file, tuple):  # given in memory (a glTF object's mesh)
            v, t = file
        elif file is not None:
            v, t = load_mesh(file)
        elif spec.mesh_data is not None:
            v, t = spec.mesh_data
        elif spec.shape == "sphere":
            v, t = icosphere(spec.subdivisions)
            v = v * spec.size
        else:
            v, t = load_mesh(spec.mesh)
        v = np.asarray(v, float) * np.asarray(spec.scale)
        return v @ rotation.T + centre, np.asarray(t, np.int32)

    @staticmethod
    def _keyframes(spec: BodySpec, centre, quaternion):
        """Pose function t [s] -> (position [3] [m], quaternion (w, x, y, z)) of the motion
        keyframes: positions linear in between, held outside. ``quaternion`` [4] is the body
        frame's rest orientation; with ``rotations`` (the shape's orientation per key, slerped
        in between, held outside) the frame turns with the shape: keyed rotation times the
        frame's rest orientation relative to the shape's (``spec.rotation``)."""
        times = np.asarray(spec.motion.get("times", [0.0]), float)
        positions = np.asarray(spec.motion.get("positions", [centre]), float)
        if "rotations" not in spec.motion:
            return lambda t: (_linear(times, positions, t), quaternion)
        from scipy.spatial.transform import Rotation, Slerp

        keys = Rotation.from_euler("xyz", spec.motion["rotations"], degrees=True)
        w, x, y, z = quaternion
        # A box's frame is the shape's (identity here); a mesh's has the world's axes at rest.
        frame = Rotation.from_euler("xyz", spec.rotation, degrees=True).inv() * Rotation.from_quat([x, y, z, w])
        turn = Slerp(times, keys) if len(times) > 1 else (lambda t: keys[0])

        def pose(t: float):
            x, y, z, w = (turn(np.clip(t, times[0], times[-1])) * frame).as_quat()
            return _linear(times, positions, t), np.array([w, x, y, z])

        return pose

    def drive(self) -> None:
        # Driven nodes move over the step [t, t + dt] at its mean speed, so they land on their path.
        t, dt = self.scene.time, self.dt
        for body, offset in self._driven:
            speed = (offset(t + dt) - offset(t)) / dt  # [3], or [node_count, 3] (an animation)
            body.fixed_velocity[body.fixed] = speed[body.fixed] if speed.ndim == 2 else speed

    def haptic_tick(self) -> None:
        for tool in self.tools:
            if not tool.haptics:
                tool.loop.tick()  # one device reading per step instead of the loop's thousand per second

    def sense(self, solution) -> None:
        for tool in self.tools:
            tool.publish(solution)

    def start(self) -> None:
        # The haptic processes start with the first frame, not with the build: softvr check
        # builds a scene to check its start and never plays it.
        for tool in self.tools:
            if tool.haptics:
                tool.loop.start()

    def close(self) -> None:
        self.settle()  # a frame stepping ahead (Player.overlap) still ticks the tools' loops
        for tool in self.tools:
            tool.loop.stop()
        super().close()

    # -- the demo interface ---------------------------------------------------------------
    def penetration_geometry(self) -> tuple[list, list] | None:
        """The drawn vertices (body index, body-frame points) and the planes, when every drawn
        surface is carried rigidly by a body of the scene and there is no static sphere (the
        scenes the rigid arrays can hold), else None."""
        if not hasattr(self, "_geometry"):
            index = {id(b): i for i, b in enumerate(self.scene.bodies)}
            rigid = [d.rigid for d in self.drawn]
            ok = not self.spheres and all(r is not None and id(r[0]) in index for r in rigid)
            self._geometry = ([(index[id(body)], local) for body, local in rigid],
                              [(n, float(np.asarray(plane.point, float) @ n)) for plane, _ in self.planes
                               for n in (plane.unit_normal(),)]) if ok else None
        return self._geometry

    def penetration(self) -> float:
        """Deepest drawn vertex below any plane or inside any static sphere [m] (off the rigid
        arrays when the scene steps on them: :meth:`~softvr.app.Player.array_metrics`)."""
        metrics = self.array_metrics() if self.penetration_geometry() is not None else None
        if metrics is not None:
            return metrics.penetration()
        deepest = 0.0
        # The planes' offsets n . point once per call: this runs after every step of a frame.
        planes = [(n, float(np.asarray(plane.point, float) @ n)) for plane, _ in self.planes
                  for n in (plane.unit_normal(),)]
        for d in self.drawn:
            x = np.asarray(d.vertices())
            for n, offset in planes:
                deepest = max(deepest, offset - float((x @ n).min()))
            for s in self.spheres:
                deepest = max(deepest, float((s.radius - np.linalg.norm(x - np.asarray(s.center), axis=1)).max()))
        return deepest

    def renderer_options(self) -> dict:
        r = self.file.render
        return {"background": r["background"], "background_top": r["background_top"], "light_kit": r["light_kit"],
                "antialias": r["antialias"]}

    def drawables(self) -> list[Drawable]:
        """The planes (``plane 0``, ...), the static spheres (``sphere 0``, ...), every body's
        drawn surface in the order of the file (a volume's skin on layer ``hidden``: the volume
        draws it), then each tool's haptic handle (``<tool> handle``: a ball of
        :data:`_HANDLE_RADIUS`), the vertices read now."""
        items = [plane_drawable(f"plane {k}", plane.point, plane.normal, size)
                 for k, (plane, size) in enumerate(self.planes)]
        items += [sphere_drawable(f"sphere {k}", s.center, s.radius) for k, s in enumerate(self.spheres)]
        for d in self.drawn:
            pose = None if d.rigid is None else pose_matrix(d.rigid[0].rotation, d.rigid[0].position)
            items.append(Drawable(d.name, "mesh", np.asarray(d.vertices(), float), d.triangles,
                                  tuple(float(c) for c in d.color), float(d.opacity), pose,
                                  "render" if d.visible else "hidden"))
        ball, triangles = self._handle_ball
        for tool in self.tools:
            handle = tool.handle
            items.append(Drawable(f"{tool.tool.name} handle", "mesh", handle.position + _HANDLE_RADIUS * ball,
                                  triangles, _HANDLE_COLOR, 0.5, pose_matrix(handle.rotation, handle.position)))
        return items

    def setup_render(self, renderer) -> None:
        for light in self.file.render["lights"]:
            renderer.add_light(light["position"], light["focal_point"], light["color"], light["intensity"])
        super().setup_render(renderer)
        if self.volume is not None:
            spec = self.volume.spec
            self.volume_handle = renderer.add_volume(self.volume.shown(), preset=spec["preset"], mapper=spec["mapper"],
                                                     sample_distance=spec["sample_distance"])
            self.volume.take_changed()  # drawn whole as it is added

    def update_render(self, renderer) -> None:
        super().update_render(renderer)
        if self.volume is not None:
            renderer.update_volume(self.volume_handle, self.volume.shown(), changed=self.volume.take_changed())

    def update_volume(self) -> dict:
        return self.volume.update() if self.volume is not None else {}

    def describe(self) -> dict:
        facts = {**super().describe(), "scene_file": str(self.file.path),
                 "body_types": {b.name: b.type for b in self.file.bodies}}
        if self.volume is not None:
            v, young = self.volume, self.volume.tissue.young
            facts["volume"] = {"source": repr(v.rest), "tets": len(v.body.tets), "nodes": len(v.body.q),
                               "clamped_nodes": int(v.body.fixed.sum()), "mass_kg": float(v.body.mass.sum()),
                               "young_pa_min_median_max": [float(np.min(young)), float(np.median(young)),
                                                           float(np.max(young))],
                               **{k: v.spec[k] for k in ("incremental", "render_step", "mapper", "sample_distance")}}
        return facts


def _gltf_variants(variants) -> tuple:
    """The problem of variants asked of a glTF scene, which has none."""
    return "variant", "a TOML scene file (a glTF scene has no [variant.NAME] tables)", repr(list(variants))


def read_any(path, variants=()) -> SceneFile:
    """A scene file (TOML; with ``variants``, names of its ``[variant.NAME]`` tables, applied)
    or a glTF / GLB scene with softvr extras (which has no variants), validated."""
    if Path(path).suffix.lower() in (".gltf", ".glb"):
        if variants:
            raise InputError(*_gltf_variants(variants))
        return read_gltf_scene(path)
    return read_scene(path, variants)


def read_any_with_problems(path, variants=()) -> tuple[SceneFile, list]:
    """A scene file (TOML, ``variants`` applied) or glTF / GLB scene without its parts that have
    a problem, and its problems (:func:`~softvr.scene.schema.read_scene_with_problems`)."""
    if Path(path).suffix.lower() in (".gltf", ".glb"):
        scene, problems = read_gltf_scene_with_problems(path)
        return scene, problems + [_gltf_variants(variants)] if variants else problems
    return read_scene_with_problems(path, variants)


def load_scene(path, variants=(), **overrides) -> SceneExample:
    """Read, validate and build a scene (TOML scene file, or glTF / GLB with softvr extras),
    ``variants`` applied (:func:`read_any`); ``overrides`` (frames, width, height,
    steps_per_frame, device, haptics) go to :class:`SceneExample`."""
    return SceneExample(read_any(path, variants), **overrides)


def scene_path(text: str) -> Path:
    """The scene file ``text`` names: an existing file, else a bundled scene by its file name
    (``candy.toml``) or its name without the suffix (``candy``).

    Raises
    ------
    InputError
        Naming ``text`` as the user wrote it: a folder, or neither a file nor a bundled scene.
    """
    path = Path(text)
    bundled = sorted(p.stem for p in _BUNDLED.glob("*.toml"))
    expected = f"a scene file (TOML, glTF / GLB) or a bundled scene: {', '.join(bundled)}"
    if path.is_dir():
        raise InputError("SCENE", expected, f"{text!r} (a folder)")
    # exists(), not is_file(): a FIFO or device given by name is the user's file, refused as such
    # by the reader (softvr.files.checked_file), not a missing bundled scene.
    if path.exists():
        return path
    if path.parent == Path("."):
        for candidate in (_BUNDLED / text, _BUNDLED / f"{text}.toml"):
            if candidate.is_file():
                return candidate
    raise InputError("SCENE", expected, f"{text!r} (no such file)")
