"""Whole-scene arrays of a rigid scene: the static :class:`RigidModel` and the mutable
:class:`RigidState` (after NVIDIA Newton's Model / State).

:func:`build_rigid_model` finalizes them from a :class:`~softvr.sim.Scene` built with the
object API (``RigidBody``, ``FixedBody``, ``KinematicBody``, ``Scene.add_body`` / ``add_plane``), so user code
and scene files are unchanged; :func:`rigid_model_supported` says whether a scene is one the
arrays can hold (otherwise the scene steps per object). The arrays are Warp arrays on one
device; on the CPU their NumPy views share the memory, and the scene's body objects read
their ``position``, ``orientation`` and ``v`` through those views.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from softvr.collision.contact_buffer import ContactBuffer
from softvr.dynamics import FixedBody, KinematicBody, RigidBody, RigidPoints

__all__ = ["RigidModel", "RigidState", "build_rigid_model", "rigid_model_supported"]

_NO_MATERIAL = -1
# Adhesion parameters per material row (softvr.contact.Adhesion), in this column order.
ADHESION_COLUMNS = ("stiffness", "max_energy", "viscosity", "bonding_rate", "saturation", "initial", "debond_gap")


@dataclass
class RigidModel:
    """Everything static of a rigid scene, as flat arrays (``n`` bodies, ``p`` collision
    points, ``t`` collision triangles, ``k`` planes, ``b`` boxes, ``s`` spheres).

    Attributes
    ----------
    device : str
    body_count : int
    body_inv_mass : wp.array(float64) [n] [1/kg]
        0 for a fixed or kinematic body (infinite mass).
    body_inertia : wp.array(mat33d) [n] [kg m^2]
        Inertia about the centre of mass, body frame (0 for a fixed or kinematic body).
    body_implicit_gyro : wp.array(int32) [n]
        1 where the gyroscopic torque is implicit (``RigidBody.gyroscopic``).
    body_speed_limit : wp.array(float64) [n] [m/s]
        Divergence threshold ``max(max_rate * extent, max_speed)`` on ``|v_lin|``.
    body_spin_limit : wp.array(float64) [n] [rad/s]
        Divergence threshold ``max_rate`` on ``|omega|``.
    point_body, point_feature : wp.array(int32) [p]
        Body of each collision point and its index among that body's points (its key feature).
    point_local : wp.array(vec3d) [p] [m]
        Body-frame position.
    point_margin : wp.array(float64) [p] [m]
        Detection margin (the scene's, or the body's adhesion's debond gap).
    point_material : wp.array(int32) [p]
        Adhesion material row of the body (-1: none).
    point_two_sided : wp.array(int32) [p]
        1 on an open collision surface (both sides touch, :class:`~softvr.collision.CollisionSurface`).
    point_triangles : wp.array(int32) [p + 1]
        CSR start of each point's incident triangles in ``triangle_normal`` / ``triangle_area``.
    triangle_normal : wp.array(vec3d) [t]
        Unit outward normal of each incident triangle, body frame.
    triangle_area : wp.array(float64) [t] [m^2]
    plane_point, plane_normal : wp.array(vec3d) [k] [m], [k]
        A point and the unit outward normal of each static plane.
    plane_friction : wp.array(float64) [k]
    plane_material : wp.array(int32) [k]
    box_body : wp.array(int32) [b]
    box_half : wp.array(vec3d) [b] [m]
        Half extents along the body axes.
    box_plane_margin : wp.array(float64) [b, k] [m]
        Detection margin of each box-plane pair (the combined adhesion's debond gap or the scene's).
    box_material : wp.array(int32) [b]
    box_pairs : wp.array(int32) [q, 2]
        Box index pairs (into ``box_body``) that may collide; ``box_pair_margin`` [q] [m].
    sphere_body : wp.array(int32) [s]
    sphere_radius : wp.array(float64) [s] [m]
    sphere_material : wp.array(int32) [s]
    sphere_plane_margin : wp.array(float64) [s, k] [m]
    sphere_pairs : wp.array(int32) [r, 2]; sphere_pair_margin [r] [m]
    materials : wp.array2d(float64) [m, 7]
        Adhesion parameters per material, columns :data:`ADHESION_COLUMNS` (SI units of
        :class:`~softvr.contact.Adhesion`).
    friction : float
        Coulomb coefficient between two bodies.
    contact_capacity : int
        Upper bound on the contacts of one step (every point on every plane, 8 per box and
        plane, 8 per box pair, 1 per sphere pair or sphere and plane).
    """

    device: str
    body_count: int
    body_inv_mass: wp.array
    body_inertia: wp.array
    body_implicit_gyro: wp.array
    body_speed_limit: wp.array
    body_spin_limit: wp.array
    point_body: wp.array
    point_feature: wp.array
    point_local: wp.array
    point_margin: wp.array
    point_material: wp.array
    point_two_sided: wp.array
    point_triangles: wp.array
    triangle_normal: wp.array
    triangle_area: wp.array
    plane_point: wp.array
    plane_normal: wp.array
    plane_friction: wp.array
    plane_material: wp.array
    box_body: wp.array
    box_half: wp.array
    box_material: wp.array
    box_plane_margin: wp.array
    box_pairs: wp.array
    box_pair_margin: wp.array
    sphere_body: wp.array
    sphere_radius: wp.array
    sphere_material: wp.array
    sphere_plane_margin: wp.array
    sphere_pairs: wp.array
    sphere_pair_margin: wp.array
    materials: wp.array
    friction: float
    contact_capacity: int


@dataclass
class RigidState:
    """What changes from step to step: body poses and velocities, the step's contacts and what
    the contacts carry over to the next step (warm starts, adhesion intensities, slips).

    Attributes
    ----------
    body_position : wp.array(vec3d) [n] [m]
        Centre of mass (frame origin of a fixed body).
    body_orientation : wp.array(vec4d) [n]
        Unit quaternion (w, x, y, z), body to world.
    body_velocity : wp.array(spatial_vectord) [n] [m/s, rad/s]
        (linear velocity, world angular velocity).
    free_velocity : wp.array(spatial_vectord) [n] [m/s, rad/s]
        The step's unconstrained velocity (thesis eq. 5.2), then the constrained one; a
        kinematic body's is its script's over the step (the stepper writes it after eq. 5.2's
        launch, which gives infinite masses 0).
    inv_inertia_world : wp.array(mat33d) [n] [1/(kg m^2)]
        ``I_w^-1`` at the step's start (0 for a fixed body).
    external : wp.array(spatial_vectord) [n] [N, N m]
        External force and torque of the step (``Scene.external``).
    diverged : wp.array(int32) [n]
        Per body, 0 or the reason a step stopped it (1 velocity NaN/inf, 2 speed, 3 spin).
    contacts : ContactBuffer
        This step's contacts and their solution.
    """

    body_position: wp.array
    body_orientation: wp.array
    body_velocity: wp.array
    free_velocity: wp.array
    inv_inertia_world: wp.array
    external: wp.array
    diverged: wp.array
    contacts: ContactBuffer


def rigid_model_supported(scene) -> bool:
    """Whether ``scene`` is one :class:`RigidModel` holds: rigid, fixed and kinematic bodies
    only, no couplings, static meshes or static spheres, rigid collision points only against
    planes, and no two collision surfaces that would meet each other (their bodies' primitives
    meet instead)."""
    if scene.couplings or scene.meshes or scene.spheres or not scene.bodies:
        return False
    if not all(type(b) in (RigidBody, FixedBody, KinematicBody) for b in scene.bodies):
        return False
    if not all(isinstance(c.points, RigidPoints) and c.points.body is scene.bodies[c.body] for c in scene._colliders):
        return False
    primitive = {i: "sphere" for i, _ in scene._sphere_bodies} | {i: "box" for i, _ in scene._box_bodies}
    surfaces = scene._surfaces
    for n, a in enumerate(surfaces):
        for b in surfaces[n + 1:]:
            if scene.collision_enabled(a.body_index, b.body_index) and \
                    primitive.get(a.body_index, "a") != primitive.get(b.body_index, "b"):
                return False
    return True


def _materials(scene) -> tuple[dict, np.ndarray]:
    """Row of each distinct Adhesion of the scene and the table [m, 7] of their parameters."""
    rows: dict[int, int] = {}
    table: list[list[float]] = []
    for adhesion in scene._adhesion.values():
        if adhesion is not None and id(adhesion) not in rows:
            rows[id(adhesion)] = len(table)
            table.append([getattr(adhesion, c) for c in ADHESION_COLUMNS])
    return rows, np.asarray(table, float).reshape(-1, len(ADHESION_COLUMNS))


def _array(values, dtype, device, shape=None):
    a = np.asarray(values)
    if shape is not None:
        a = a.reshape(shape)
    return wp.array(a, dtype=dtype, device=device)


def build_rigid_model(scene, device: str = "cpu") -> tuple[RigidModel, RigidState]:
    """The arrays of a scene :func:`rigid_model_supported` accepts, at its bodies' current state."""
    bodies = scene.bodies
    n = len(bodies)
    rows, table = _materials(scene)

    def material(key) -> int:
        adhesion = scene._adhesion.get(key)
        return _NO_MATERIAL if adhesion is None else rows[id(adhesion)]

    dynamic = [isinstance(b, RigidBody) for b in bodies]
    inv_mass = [1.0 / b.mass if d else 0.0 for b, d in zip(bodies, dynamic)]
    inertia = [b.inertia_body if d else np.zeros((3, 3)) for b, d in zip(bodies, dynamic)]
    gyro = [int(d and b.gyroscopic == "implicit") for b, d in zip(bodies, dynamic)]
    speed = [max(b.max_rate * b.extent, b.max_speed) if d else np.inf for b, d in zip(bodies, dynamic)]
    spin = [b.max_rate if d else np.inf for b, d in zip(bodies, dynamic)]

    primitive = {i for i, _ in scene._sphere_bodies} | {i for i, _ in scene._box_bodies}
    surfaces = {id(s.points): s for s in scene._surfaces}
    p_body, p_feature, p_local, p_margin, p_material, p_two = [], [], [], [], [], []
    starts, normals, areas = [0], [], []
    for c in scene._colliders:
        if c.body in primitive:
            continue  # a primitive meets the planes exactly
        surface = surfaces.get(id(c.points))
        local = c.points.local
        if surface is not None:
            t = surface.triangles
            v = local[t]
            cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
            size = np.linalg.norm(cross, axis=1)
            tri_normal = cross / np.maximum(size, 1e-300)[:, None]
            tri_area = 0.5 * size
            incident: list[list[int]] = [[] for _ in range(len(local))]
            for f, tri in enumerate(t):
                for vtx in tri:
                    incident[vtx].append(f)
        for k in range(len(local)):
            p_body.append(c.body)
            p_feature.append(k)
            p_local.append(local[k])
            p_margin.append(c.margin)
            p_material.append(material(("body", c.body)))
            p_two.append(int(surface is not None and surface.two_sided))
            faces = incident[k] if surface is not None else []
            normals += [tri_normal[f] for f in faces]
            areas += [tri_area[f] for f in faces]
            starts.append(starts[-1] + len(faces))

    planes = scene.planes
    plane_keys = [("static", id(p)) for p in planes]

    def pair_margin(a, b) -> float:
        return scene._pair_margin(a, b)

    boxes = scene._box_bodies
    spheres = scene._sphere_bodies
    box_pairs = [(i, j) for i in range(len(boxes)) for j in range(i + 1, len(boxes))
                 if scene.collision_enabled(boxes[i][0], boxes[j][0])]
    sphere_pairs = [(i, j) for i in range(len(spheres)) for j in range(i + 1, len(spheres))
                    if scene.collision_enabled(spheres[i][0], spheres[j][0])]
    k = len(planes)
    capacity = len(p_body) * k + 8 * len(boxes) * k + 8 * len(box_pairs) + len(spheres) * k + len(sphere_pairs)

    f64, i32, v3 = wp.float64, wp.int32, wp.vec3d
    model = RigidModel(
        device=device, body_count=n,
        body_inv_mass=_array(inv_mass, f64, device), body_inertia=_array(inertia, wp.mat33d, device, (n, 3, 3)),
        body_implicit_gyro=_array(gyro, i32, device), body_speed_limit=_array(speed, f64, device),
        body_spin_limit=_array(spin, f64, device),
        point_body=_array(p_body, i32, device), point_feature=_array(p_feature, i32, device),
        point_local=_array(p_local, v3, device, (-1, 3)), point_margin=_array(p_margin, f64, device),
        point_material=_array(p_material, i32, device), point_two_sided=_array(p_two, i32, device),
        point_triangles=_array(starts, i32, device), triangle_normal=_array(normals, v3, device, (-1, 3)),
        triangle_area=_array(areas, f64, device),
        plane_point=_array([p.point for p in planes], v3, device, (-1, 3)),
        plane_normal=_array([p.unit_normal() for p in planes], v3, device, (-1, 3)),
        plane_friction=_array([p.friction for p in planes], f64, device),
        plane_material=_array([material(key) for key in plane_keys], i32, device),
        box_body=_array([i for i, _ in boxes], i32, device),
        box_half=_array([h for _, h in boxes], v3, device, (-1, 3)),
        box_material=_array([material(("body", i)) for i, _ in boxes], i32, device),
        box_plane_margin=_array([[pair_margin(("body", i), key) for key in plane_keys] for i, _ in boxes], f64,
                                device, (len(boxes), k)),
        box_pairs=_array(box_pairs, i32, device, (-1, 2)),
        box_pair_margin=_array([pair_margin(("body", boxes[i][0]), ("body", boxes[j][0])) for i, j in box_pairs],
                               f64, device),
        sphere_body=_array([i for i, _ in spheres], i32, device),
        sphere_radius=_array([r for _, r in spheres], f64, device),
        sphere_material=_array([material(("body", i)) for i, _ in spheres], i32, device),
        sphere_plane_margin=_array([[pair_margin(("body", i), key) for key in plane_keys] for i, _ in spheres], f64,
                                   device, (len(spheres), k)),
        sphere_pairs=_array(sphere_pairs, i32, device, (-1, 2)),
        sphere_pair_margin=_array([pair_margin(("body", spheres[i][0]), ("body", spheres[j][0]))
                                   for i, j in sphere_pairs], f64, device),
        materials=wp.array(table, dtype=f64, device=device),
        friction=float(scene.friction), contact_capacity=max(capacity, 1),
    )
    state = RigidState(
        body_position=_array([b.position for b in bodies], v3, device, (n, 3)),
        body_orientation=_array([b.orientation for b in bodies], wp.vec4d, device, (n, 4)),
        body_velocity=_array([b.v for b in bodies], wp.spatial_vectord, device, (n, 6)),
        free_velocity=wp.zeros(n, dtype=wp.spatial_vectord, device=device),
        inv_inertia_world=wp.zeros(n, dtype=wp.mat33d, device=device),
        external=wp.zeros(n, dtype=wp.spatial_vectord, device=device),
        diverged=wp.zeros(n, dtype=i32, device=device),
        contacts=ContactBuffer.allocate(model.contact_capacity, device),
    )
    return model, state
