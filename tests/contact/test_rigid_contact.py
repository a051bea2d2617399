"""Rigid bodies in contact: momentum in a free collision, a box resting on the ground.

Truths: with no external forces the contact impulses are equal and opposite, so total linear
and angular momentum are conserved through a collision (to the PGS tolerance); a body at rest
on the ground is carried by impulses summing to m g dt.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import RigidBody, RigidPoints


def _angular_momentum_about_origin(bodies):
    return sum(np.cross(b.position, b.mass * b.v[:3]) + b.angular_momentum() for b in bodies)


@pytest.mark.parametrize("offset", [0.0, 0.05])
def test_momentum_is_conserved_in_a_free_collision(offset):
    a = RigidBody.sphere(0.1, 1000.0, position=(-0.5, 0.0, 0.0), velocity=(2.0, 0.0, 0.0), name="a")
    b = RigidBody.sphere(0.15, 700.0, position=(0.5, offset, 0.0), velocity=(-1.0, 0.0, 0.0), name="b")
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.3)
    scene.add_body(a, collision_sphere=0.1)
    scene.add_body(b, collision_sphere=0.15)
    p0 = a.linear_momentum() + b.linear_momentum()
    l0 = _angular_momentum_about_origin([a, b])
    collided = False
    for _ in range(60):
        solution = scene.step(0.005)
        collided |= any(len(i) and i[:, 0].max() > 0 for i in solution.impulses)
    assert collided and a.v[0] < 2.0
    np.testing.assert_allclose(a.linear_momentum() + b.linear_momentum(), p0, atol=1e-9)
    np.testing.assert_allclose(_angular_momentum_about_origin([a, b]), l0, atol=1e-9)
    # Never interpenetrating more than the solver tolerance allows.
    assert np.linalg.norm(a.position - b.position) > 0.25 - 1e-6


def test_box_rests_on_the_ground_carried_by_its_weight():
    box = RigidBody.box((0.2, 0.2, 0.1), 500.0, position=(0.0, 0.0, 0.08))
    corners = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1) for z in (-0.05, 0.05)])
    scene = Scene()
    scene.add_body(box, collision_points=RigidPoints(box, corners))
    scene.add_plane(Plane(friction=0.6))
    for _ in range(200):
        solution = scene.step(0.005)
    assert box.position[2] == pytest.approx(0.05, abs=1e-4)
    assert np.abs(box.v).max() < 1e-6
    assert solution.impulses[0][:, 0].sum() == pytest.approx(box.mass * 9.81 * 0.005, rel=1e-6)


@pytest.mark.slow
def test_stack_of_five_boxes_rests_ten_seconds_with_drift_below_a_millimetre():
    half = np.array([0.1, 0.1, 0.05])
    scene = Scene(friction=0.6)
    scene.add_plane(Plane(friction=0.6))
    boxes = []
    for level in range(5):
        box = RigidBody.box(2 * half, 500.0, position=(0.0, 0.0, half[2] * (2 * level + 1) + 1e-4), name=f"box {level}")
        scene.add_body(box, collision_box=half)
        boxes.append(box)
    for _ in range(50):  # settle onto each other (they start 0.1 mm apart)
        scene.step(0.01)
    start = np.array([b.position for b in boxes])
    for _ in range(1000):
        solution = scene.step(0.01)
    drift = np.linalg.norm(np.array([b.position for b in boxes]) - start, axis=1)
    assert drift.max() < 1e-3
    heights = np.array([b.position[2] for b in boxes])
    np.testing.assert_allclose(heights, half[2] * (2 * np.arange(5) + 1), atol=1e-3)
    # Static equilibrium: the contacts above and below each box (the ground under the bottom
    # one) add up to its weight, m g up. A velocity residual of 1e-5 m/s (the PGS tolerance)
    # over dt = 10 ms is 1e-3 m/s^2 of a 9.81 m/s^2 acceleration: 1e-4 relative.
    for i, box in enumerate(boxes):
        np.testing.assert_allclose(solution.force_on(i, 0.01), [0.0, 0.0, box.mass * 9.81], rtol=0,
                                   atol=1e-3 * box.mass * 9.81)


def test_collision_filter_lets_a_pair_pass_through_each_other():
    a = RigidBody.sphere(0.1, 1000.0, position=(-0.3, 0.0, 0.0), velocity=(2.0, 0.0, 0.0))
    b = RigidBody.sphere(0.1, 1000.0, position=(0.3, 0.0, 0.0), velocity=(-2.0, 0.0, 0.0))
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    ia = scene.add_body(a, collision_sphere=0.1)
    ib = scene.add_body(b, collision_sphere=0.1)
    scene.disable_collision(ia, ib)
    for _ in range(40):
        scene.step(0.005)
    assert a.position[0] > 0.0 > b.position[0]  # passed through each other untouched
    np.testing.assert_allclose([a.v[0], b.v[0]], [2.0, -2.0])


def test_sphere_dropped_on_the_ground_rests_carried_by_its_weight():
    """A rigid sphere body falling onto a plane (Scene sphere-plane contact, speculative over
    the step) stops at the plane, and its single contact carries m g dt per step."""
    ball = RigidBody.sphere(0.05, 1000.0, position=(0.0, 0.0, 0.3), name="ball")
    scene = Scene()
    scene.add_body(ball, collision_sphere=0.05)
    scene.add_plane(Plane(friction=0.5))
    for _ in range(200):
        solution = scene.step(0.005)
    assert ball.position[2] == pytest.approx(0.05, abs=1e-6)
    assert abs(ball.v[2]) < 1e-6
    assert solution.impulses[0][:, 0].sum() == pytest.approx(ball.mass * 9.81 * 0.005, rel=1e-6)


def test_a_primitive_with_a_surface_meets_planes_and_its_kind_exactly_and_the_rest_by_its_surface():
    """Scene.add_body with a box collider and a box surface: on the ground only the box-plane
    test makes contacts (4 corners, none from the surface's points), two such boxes meet box to
    box, and a static sphere (which a box collider alone never meets) holds the box up through
    its surface: at rest the vertex at its bottom face's centre lies on the sphere's top, so its
    centre is at z = 2 r + h (points meet the sphere: the surface has one at the face centre)."""
    from softvr.collision import Sphere
    from softvr.model.shapes import box_surface

    half = np.array([0.1, 0.1, 0.05])
    vertices, triangles = box_surface(2 * half, 8)

    def box(position):
        body = RigidBody.box(2 * half, 500.0, position=position)
        return body, dict(collision_box=half, collision_points=RigidPoints(body, vertices - half),
                          collision_triangles=triangles)

    scene = Scene(friction=0.6)
    scene.add_plane(Plane(friction=0.6))
    lower, options = box((0.0, 0.0, 0.05 + 1e-4))
    scene.add_body(lower, **options)
    upper, options = box((0.0, 0.0, 0.15 + 2e-4))
    scene.add_body(upper, **options)
    for _ in range(30):
        solution = scene.step(0.01)
    kinds = sorted(len(c.gap) for c in solution.contacts if len(c.gap))
    assert kinds == [4, 4]  # box-plane and box-box: 4 corners each, no surface duplicates
    np.testing.assert_allclose([lower.position[2], upper.position[2]], [0.05, 0.15], atol=5e-4)

    r = 0.2
    scene = Scene(friction=0.6)
    scene.add_sphere(Sphere(center=(0.0, 0.0, r), radius=r, friction=0.6))
    on_ball, options = box((0.0, 0.0, 2 * r + half[2] + 1e-3))
    scene.add_body(on_ball, **options)
    for _ in range(60):
        scene.step(0.01)
    # Its surface's points meet the sphere: the box rests on the sphere's top.
    assert on_ball.position[2] == pytest.approx(2 * r + half[2], abs=2e-3)
