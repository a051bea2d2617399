"""The whole-scene contact kernels (softvr.collision.rigid_detection) against the per-pair
NumPy functions they are the array form of: the same contacts, keys, points, gaps, normals
and areas.

Both evaluate the same float64 formulas in a different order, so they agree to round-off:
coordinates of at most ~1 m carry relative errors of a few 1e-16 per operation over a few
hundred operations, hence the 1e-12 m (and m^2) tolerance. The NumPy functions are the
physics-tested reference (tests/contact/test_box_pyramid.py, test_adhesion.py).
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane, box_vs_box, box_vs_plane, points_vs_plane, sphere_vs_plane, sphere_vs_sphere
from softvr.collision.contacts import unpack_keys
from softvr.collision.rigid_detection import record_detection
from softvr.contact import Adhesion
from softvr.dynamics import RigidBody, RigidPoints
from softvr.dynamics.rigid import quat_from_rotvec
from softvr.dynamics.rigid_arrays import record_unconstrained
from softvr.model.shapes import box_surface
from softvr.sim import build_rigid_model

DT = 0.01
TOL = 1e-12


def _detect(scene, device):
    """The contacts the kernels find in ``scene`` (NumPy copies) and the unconstrained
    velocities they used."""
    model, state = build_rigid_model(scene, device)
    record_unconstrained(model, state, DT, scene.gravity).launch()
    record_detection(model, state, DT).launch()
    return state.contacts.numpy(), state.free_velocity.numpy()


def _by_key(found):
    order = np.argsort(found["key"])
    return {name: value[order] for name, value in found.items()}


def _assert_same(found, reference, offset_a=None):
    found = _by_key(found)
    order = np.argsort(reference.ids)
    np.testing.assert_array_equal(found["key"], reference.ids[order])
    for name, expected in (("point_a", reference.point_a), ("point_b", reference.point_b),
                           ("normal", reference.normal), ("gap", reference.gap), ("area", reference.area),
                           ("friction", reference.friction)):
        np.testing.assert_allclose(found[name], expected[order], rtol=0, atol=TOL, err_msg=name)


def test_box_pairs_equal_box_vs_box_on_random_pairs(device):
    rng = np.random.default_rng(7)
    total = 0
    for trial in range(150):
        ha, hb = rng.uniform(0.02, 0.3, 3), rng.uniform(0.02, 0.3, 3)
        # A third of the pairs unrotated (face-face stacks), a third with one box turned.
        turn_a, turn_b = float(trial % 3 > 0), float(trial % 3 > 1)
        a = RigidBody.box(2 * ha, 500.0, position=rng.normal(0, 0.15, 3),
                          orientation=quat_from_rotvec(turn_a * rng.normal(0, 1, 3)), velocity=rng.normal(0, 0.3, 3),
                          angular_velocity=rng.normal(0, 0.3, 3))
        b = RigidBody.box(2 * hb, 500.0, position=rng.normal(0, 0.15, 3),
                          orientation=quat_from_rotvec(turn_b * rng.normal(0, 1, 3)))
        scene = Scene(gravity=(0.0, 0.0, 0.0), contact_margin=0.01)
        scene.add_body(a, collision_box=ha)
        scene.add_body(b, collision_box=hb)
        found, free = _detect(scene, device)
        reference = box_vs_box(0, a, ha, 1, b, hb, friction=scene.friction, margin=0.01, velocity_a=free[0],
                               velocity_b=free[1], dt=DT)
        _assert_same(found, reference)
        points = reference.point_a[np.argsort(reference.ids)]
        np.testing.assert_allclose(_by_key(found)["offset_b"], points - b.position, atol=TOL)
        total += len(reference)
    assert total > 200  # the pairs do touch: face manifolds and edge contacts, not empty sets


def test_plane_kernels_equal_points_boxes_and_spheres_against_planes(device):
    adhesion = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)
    scene = Scene(contact_margin=0.004)
    tilted = Plane(point=(0.0, 0.0, 0.02), normal=(0.3, 0.0, 1.0), friction=0.3)
    ground = Plane(friction=0.6)
    scene.add_plane(ground, adhesion=adhesion)
    scene.add_plane(tilted)
    edge = 0.1
    verts, tris = box_surface((edge,) * 3, 3)
    cube = RigidBody.box((edge,) * 3, 800.0, position=(0.0, 0.0, edge / 2 + 0.001),
                         orientation=quat_from_rotvec([0.02, -0.01, 0.3]), velocity=(0.0, 0.0, -0.2))
    points = RigidPoints(cube, verts - edge / 2)
    scene.add_body(cube, collision_points=points, collision_triangles=tris, adhesion=adhesion)
    h = np.array([0.05, 0.08, 0.03])
    box = RigidBody.box(2 * h, 500.0, position=(0.5, 0.0, 0.031), orientation=quat_from_rotvec([0.0, 0.05, 0.0]))
    scene.add_body(box, collision_box=h)
    s1 = RigidBody.sphere(0.05, 500.0, position=(-0.5, 0.0, 0.052))
    s2 = RigidBody.sphere(0.04, 500.0, position=(-0.5, 0.0, 0.145))
    scene.add_body(s1, collision_sphere=0.05, adhesion=adhesion)
    scene.add_body(s2, collision_sphere=0.04)
    found, free = _detect(scene, device)
    kinds = unpack_keys(found["key"])["kind"]
    surface = scene.collision_surfaces[0]
    for k, plane in enumerate(scene.planes):
        margin = max(scene.contact_margin, adhesion.debond_gap)  # the cube's adhesive collider
        reference = points_vs_plane(0, points, plane, margin=margin, velocities=points.velocities(free[0]), dt=DT,
                                    static_index=k)
        reference.area = surface.facing_vertex_area(unpack_keys(reference.ids)["feature_a"], reference.normal)
        mine = (found["body_a"] == 0) & (unpack_keys(found["key"])["body_b"] == k) & (kinds == 0)
        _assert_same({n: v[mine] for n, v in found.items()}, reference)
        margin = scene._pair_margin(("body", 1), ("static", id(plane)))
        reference = box_vs_plane(1, box, h, plane, margin=margin, velocity=free[1], dt=DT, static_index=k)
        mine = (found["body_a"] == 1) & (unpack_keys(found["key"])["body_b"] == k)
        _assert_same({n: v[mine] for n, v in found.items()}, reference)
        margin = scene._pair_margin(("body", 2), ("static", id(plane)))
        reference = sphere_vs_plane(2, s1, 0.05, plane, margin=margin, velocity=free[2], dt=DT, static_index=k)
        mine = (found["body_a"] == 2) & (found["body_b"] < 0) & (unpack_keys(found["key"])["body_b"] == k)
        _assert_same({n: v[mine] for n, v in found.items()}, reference)
    reference = sphere_vs_sphere(2, s1, 0.05, 3, s2, 0.04, friction=scene.friction,
                                 margin=scene._pair_margin(("body", 2), ("body", 3)), velocity_a=free[2],
                                 velocity_b=free[3], dt=DT)
    _assert_same({n: v[found["body_b"] == 3] for n, v in found.items()}, reference)
    # Every kind met something: the comparison is not over empty sets.
    assert {0, 5, 6, 7} <= set(kinds.tolist())
