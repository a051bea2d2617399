"""From a validated scene file to a running simulation: :class:`SceneExample`.

Each ``[[body]]`` becomes a contact object with its collision geometry and a drawn surface:

=========  =====================================================================================
rigid      box (box collider), sphere (sphere collider) or mesh (its vertices and triangles
           collide; mass, centre and inertia of the closed mesh): of the material's density.
           Box and sphere colliders meet planes and each other only, so in a scene with fem or
           cloth bodies every rigid shape collides through its surface instead
fem        box: a grid of ``cells``^3 cubes, 5 tets each; sphere (an icosphere) or mesh: the model
           pipeline's dynamics mesh (cubes of ``cells`` metres touching the surface) with the
           surface embedded in it; co-rotational FEM of the material
cloth      a ``cloth = [w, h]`` sheet of ``quads`` in the body's x-y plane (or a glTF mesh),
           mass-spring cloth
fixed      box (box collider of a fixed body) or mesh (a static triangle mesh obstacle)
kinematic  box or sphere moved through ``motion`` keyframes (linear in between, held after)
=========  =====================================================================================

The scene runs, draws and records like every demo (:class:`~softvr.examples.run.PhysicsExample`):
``softvr run SCENE.toml``, ``softvr view SCENE.toml``.
"""

from __future__ import annotations

import numpy as np

from softvr.examples.run import PhysicsExample
from softvr.scene.schema import BodySpec, SceneFile, read_scene

__all__ = ["SceneExample", "load_scene", "read_any"]


def _rotation(degrees) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrix [3, 3] and quaternion (w, x, y, z) of x-then-y-then-z angles [deg]."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_euler("xyz", degrees, degrees=True)
    x, y, z, w = r.as_quat()
    return r.as_matrix(), np.array([w, x, y, z])


class _Drawn:
    """A body's drawn surface: ``vertices()`` [n, 3] [m] now, ``triangles`` [t, 3]."""

    def __init__(self, vertices, triangles, color):
        self.vertices, self.triangles, self.color = vertices, np.asarray(triangles, np.int32), color


class SceneExample(PhysicsExample):
    """A scene file played as a demo (module docstring).

    Parameters
    ----------
    scene_file : SceneFile
        From :func:`~softvr.scene.read_scene`.
    frames : int, optional
        Override the file's ``simulation.frames``.
    width, height : int, optional
        Override the file's ``render.size``.
    """

    def __init__(self, scene_file: SceneFile, frames: int | None = None, width: int | None = None,
                 height: int | None = None):
        from softvr import Scene
        from softvr.collision import Plane, Sphere
        from softvr.contact import Adhesion
        from softvr.render import Camera

        self.file = scene_file
        self.name = scene_file.path.stem
        sim, ren = scene_file.simulation, scene_file.render
        self.adhesions = {k: Adhesion(**v) for k, v in scene_file.adhesions.items()}
        scene = Scene(gravity=sim["gravity"], friction=sim["friction"], pgs_iterations=sim["pgs_iterations"],
                      contact_margin=sim["contact_margin"])
        self.planes = []
        for i, p in enumerate(scene_file.planes):
            plane = Plane(point=p["point"], normal=p["normal"], friction=p["friction"], id=i)
            scene.add_plane(plane, adhesion=self.adhesions.get(p["adhesion"]))
            self.planes.append((plane, p["size"]))
        self.spheres = []
        for i, s in enumerate(scene_file.spheres):
            sphere = Sphere(center=s["center"], radius=s["radius"], friction=s["friction"], id=len(self.planes) + i)
            scene.add_sphere(sphere, adhesion=self.adhesions.get(s["adhesion"]))
            self.spheres.append(sphere)
        self.bodies, self.drawn, self.index, self._drawn_by_name = {}, [], {}, {}
        self._soft_scene = any(b.type in ("fem", "cloth") for b in scene_file.bodies)
        for spec in scene_file.bodies:
            self._add(scene, spec)
        for a, b in scene_file.filters:
            scene.disable_collision(self.index[a], self.index[b])
        for c in scene_file.couplings:
            self._couple(scene, c)
        w, h = ren["size"]
        camera = Camera(ren["camera"], azimuth=ren["azimuth"], elevation=ren["elevation"], zoom=ren["zoom"])
        super().__init__(scene, sim["dt"], sim["steps_per_frame"], frames or sim["frames"], width or w, height or h,
                         bounds=ren["bounds"], camera=camera)

    # -- building ----------------------------------------------------------------------
    def _add(self, scene, spec: BodySpec) -> None:
        from softvr.dynamics import EmbeddedPoints, FemBody, FixedBody, KinematicBody, Material, RigidBody
        from softvr.model.shapes import BOX_TRIANGLES, box_corners, icosphere

        rotation, quaternion = _rotation(spec.rotation)
        centre = np.asarray(spec.position, float)
        adhesion = self.adhesions.get(spec.adhesion)
        material = self.file.materials.get(spec.material)
        if spec.type == "rigid" and spec.shape == "mesh":
            from softvr.dynamics import RigidPoints
            from softvr.model import rigid_properties

            v, t = self._surface(spec, rotation, centre)
            mass, com, inertia = rigid_properties(v, t, material["density"], f"body {spec.name!r}")
            body = RigidBody(mass, inertia, position=com, velocity=spec.velocity,
                             angular_velocity=spec.angular_velocity, name=spec.name)
            local = v - com
            index = scene.add_body(body, collision_points=RigidPoints(body, local), collision_triangles=t,
                                   adhesion=adhesion)
            self.drawn.append(_Drawn(lambda b=body, p=local: b.position + p @ b.rotation.T, t, spec.color))
        elif spec.type in ("rigid", "fixed", "kinematic") and spec.shape in ("box", "sphere"):
            if spec.type == "rigid":
                make = RigidBody.box if spec.shape == "box" else RigidBody.sphere
                body = make(spec.size, material["density"], position=centre, orientation=quaternion,
                            velocity=spec.velocity, angular_velocity=spec.angular_velocity, name=spec.name)
            elif spec.type == "fixed":
                body = FixedBody(centre, quaternion, name=spec.name)
            else:
                body = KinematicBody(self._keyframes(spec, centre, quaternion), name=spec.name)
            if spec.shape == "box":
                collider = {"collision_box": np.asarray(spec.size) / 2}
                local, triangles = box_corners(np.asarray(spec.size) / 2), BOX_TRIANGLES
            else:
                collider = {"collision_sphere": spec.size}
                unit, triangles = icosphere(3)
                local = unit * spec.size
            if self._soft_scene:
                # Box and sphere colliders meet only planes and each other: with soft bodies
                # about, rigid shapes collide through their surface (points and triangles).
                from softvr.dynamics import RigidPoints

                collider = {"collision_points": RigidPoints(body, local), "collision_triangles": triangles}
            index = scene.add_body(body, adhesion=adhesion, **collider)
            self.drawn.append(_Drawn(lambda b=body, p=local: b.position + p @ b.rotation.T, triangles, spec.color))
        elif spec.type == "fixed":  # a mesh: a static obstacle, not a body
            from softvr.collision import TriangleMesh

            v, t = self._surface(spec, rotation, centre)
            scene.add_mesh(TriangleMesh(v, t, id=100 + len(self.drawn)), adhesion=adhesion)
            self.drawn.append(_Drawn(lambda v=v: v, t, spec.color))
            return
        elif spec.type == "fem":
            from softvr.model import rigid_properties

            m = Material(material["young"], material["poisson"], material["density"], alpha=material["alpha"],
                         beta=material["beta"])
            nodes, tets, surface, embedding = self._tet_mesh(spec, rotation, centre)
            if spec.shape != "box":
                # The embedding cubes reach past the surface: the object weighs rho times the
                # volume its surface encloses, spread over them.
                inside = rigid_properties(*self._surface(spec, rotation, centre), 1.0, f"body {spec.name!r}")[0]
                tet_volume = np.abs(np.linalg.det(nodes[tets[:, 1:]] - nodes[tets[:, :1]])).sum() / 6.0
                m = Material(m.young, m.poisson, m.density * inside / tet_volume, alpha=m.alpha, beta=m.beta)
            body = FemBody(nodes, tets, m, fixed=self._clamped(spec, nodes), name=spec.name)
            self._set_velocity(body, spec, centre)
            tet_nodes, weights = embedding
            points = EmbeddedPoints(body, tet_nodes, weights)
            index = scene.add_body(body, collision_points=points, collision_triangles=surface, adhesion=adhesion)
            self.drawn.append(_Drawn(points.positions, surface, spec.color))
        else:  # cloth
            from softvr.dynamics import ClothBody

            c = spec.cloth
            springs = dict(density=c["area_density"], stretch=c["stretch"], shear=c["shear"], bend=c["bend"],
                           damping=c["damping"], alpha=c["alpha"], name=spec.name)
            if spec.mesh_data is not None:
                body = ClothBody(*self._surface(spec, rotation, centre), **springs)
            else:
                w, h = spec.size
                origin = centre - rotation @ np.array([w / 2, h / 2, 0.0])
                body = ClothBody.grid(w, h, *c["quads"], origin=origin, u_axis=rotation[:, 0],
                                      v_axis=rotation[:, 1], **springs)
            body.fixed[:] = self._clamped(spec, body.q)
            self._set_velocity(body, spec, centre)
            n = len(body.q)
            points = EmbeddedPoints(body, np.arange(n)[:, None], np.ones((n, 1)))
            # The triangles give the contacts their areas (adhesion works on tractions) and
            # meet other bodies' surfaces.
            index = scene.add_body(body, collision_points=points, collision_triangles=body.triangles,
                                   adhesion=adhesion)
            self.drawn.append(_Drawn(lambda b=body: b.q, body.triangles, spec.color))
        self.bodies[spec.name] = body
        self.index[spec.name] = index
        self._drawn_by_name[spec.name] = self.drawn[-1]

    def _couple(self, scene, c: dict) -> None:
        """Springs from the nodes of body ``a`` within ``radius`` of body ``b``'s surface."""
        from softvr.dynamics import Coupling, EmbeddedPoints, RigidPoints, embed_in_tets
        from softvr.errors import InputError
        from softvr.model import nodes_near_surface

        a, b = self.bodies[c["a"]], self.bodies[c["b"]]
        surface = self._drawn_by_name[c["b"]]
        nodes = np.flatnonzero(np.ones(len(a.q), bool))
        near = nodes[nodes_near_surface(a.q, surface.vertices(), surface.triangles, c["radius"])]
        if len(near) == 0:
            raise InputError(f"coupling {c['a']} - {c['b']}", f"nodes of {c['a']!r} within {c['radius']} m of "
                             f"{c['b']!r}", "none", source=str(self.file.path))
        springs = a.q[near]
        side_a = EmbeddedPoints(a, near[:, None], np.ones((len(near), 1)))
        if hasattr(b, "tets"):
            ti, w = embed_in_tets(b.q, b.tets, springs, tolerance=np.inf)
            side_b = EmbeddedPoints(b, b.tets[ti], w)
        else:
            side_b = RigidPoints.from_world(b, springs)
        scene.add_coupling(Coupling(side_a, side_b, c["stiffness"], damping=c["damping"],
                                    name=f"{c['a']} - {c['b']}"), collide=c["collide"])

    def start_problems(self) -> list:
        """(what, expected, found) for bodies that start intersecting each other (crossing
        surface triangles; pairs that may not collide are left out) or below a plane."""
        from softvr.model import intersecting_triangle_pairs

        out = []
        names = list(self._drawn_by_name)
        for i, a in enumerate(names):
            da = self._drawn_by_name[a]
            for plane, _ in self.planes:
                depth = float(-((da.vertices() - np.asarray(plane.point)) @ plane.unit_normal()).min())
                if depth > 1e-6:
                    out.append((f"body {a!r}", "a start above every plane", f"{depth * 1e3:.2f} mm below one"))
            for b in names[i + 1:]:
                # Cloth is an open sheet (no crossing test); coupled or filtered pairs may overlap.
                if "cloth" in (self.file.body(a).type, self.file.body(b).type) or \
                        not self.scene.collision_enabled(self.index[a], self.index[b]):
                    continue
                db = self._drawn_by_name[b]
                crossing = intersecting_triangle_pairs(da.vertices(), da.triangles, db.vertices(), db.triangles)
                if len(crossing):
                    out.append((f"bodies {a!r} and {b!r}", "surfaces apart at the start",
                                f"{len(crossing)} crossing triangle pairs"))
        return out

    @staticmethod
    def _tet_mesh(spec: BodySpec, rotation, centre):
        """Nodes [n, 3] [m], tets, the collision / drawn surface over the embedded points and
        the embedding (tet node indices [k, 4] or [k, 1], weights)."""
        from softvr.volume import Volume, boundary_faces, grid_tet_mesh

        if spec.shape == "box":
            size, cells = np.asarray(spec.size, float), int(spec.cells)
            spacing = size / cells
            grid = Volume(np.zeros((cells,) * 3, np.uint8), spacing=spacing, origin=spacing / 2 - size / 2)
            nodes, tets = grid_tet_mesh(grid, cells)
            nodes = nodes @ rotation.T + centre
            faces = boundary_faces(tets)
            on_surface, local = np.unique(faces, return_inverse=True)
            return nodes, tets, local.reshape(-1, 3).astype(np.int32), (on_surface[:, None],
                                                                        np.ones((len(on_surface), 1)))
        from softvr.model import dynamics_mesh, embed_surface

        v, t = SceneExample._surface(spec, rotation, centre)
        nodes, tets = dynamics_mesh(v, t, float(spec.cells))
        tet_index, weights = embed_surface(nodes, tets, v)
        return nodes, tets, t, (tets[tet_index], weights)

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
    def _surface(spec: BodySpec, rotation, centre) -> tuple[np.ndarray, np.ndarray]:
        """The body's mesh (from its file, or given in memory) placed in the world [m]."""
        from softvr.model import load_mesh

        if spec.mesh_data is not None:
            v, t = spec.mesh_data
        elif spec.shape == "sphere":
            from softvr.model.shapes import icosphere

            v, t = icosphere(3)
            v = v * spec.size
        else:
            v, t = load_mesh(spec.mesh)
        return np.asarray(v, float) @ rotation.T + centre, np.asarray(t, np.int32)

    @staticmethod
    def _keyframes(spec: BodySpec, centre, quaternion):
        times = np.asarray(spec.motion.get("times", [0.0]), float)
        positions = np.asarray(spec.motion.get("positions", [centre]), float)

        def pose(t: float):
            p = np.array([np.interp(t, times, positions[:, k]) for k in range(3)])
            return p, quaternion

        return pose

    # -- the demo interface ---------------------------------------------------------------
    def penetration(self) -> float:
        """Deepest drawn vertex below any plane or inside any static sphere [m]."""
        deepest = 0.0
        for d in self.drawn:
            x = np.asarray(d.vertices())
            for plane, _ in self.planes:
                n = plane.unit_normal()
                deepest = max(deepest, float(-((x - np.asarray(plane.point)) @ n).min()))
            for s in self.spheres:
                deepest = max(deepest, float((s.radius - np.linalg.norm(x - np.asarray(s.center), axis=1)).max()))
        return deepest

    def setup_render(self, renderer) -> None:
        for plane, size in self.planes:
            renderer.add_plane(point=plane.point, normal=plane.normal, size=size, tiles=12)
        for s in self.spheres:
            renderer.add_sphere(s.center, s.radius)
        self._handles = [renderer.add_mesh(d.vertices(), d.triangles, color=d.color) for d in self.drawn]

    def update_render(self, renderer) -> None:
        for handle, d in zip(self._handles, self.drawn):
            renderer.update(handle, d.vertices())

    def describe(self) -> dict:
        return {**super().describe(), "scene_file": str(self.file.path),
                "body_types": {b.name: b.type for b in self.file.bodies}}


def read_any(path) -> SceneFile:
    """A scene file (TOML) or a glTF / GLB scene with softvr extras, validated."""
    from pathlib import Path

    if Path(path).suffix.lower() in (".gltf", ".glb"):
        from softvr.scene.gltf import read_gltf_scene

        return read_gltf_scene(path)
    return read_scene(path)


def load_scene(path, **overrides) -> SceneExample:
    """Read, validate and build a scene (TOML scene file, or glTF / GLB with softvr extras);
    ``overrides`` (frames, width, height) go to :class:`SceneExample`."""
    return SceneExample(read_any(path), **overrides)
