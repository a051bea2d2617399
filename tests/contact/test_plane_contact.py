"""Frictional contact against planes (thesis eqs. 5.5-5.6) checked against mechanics.

Truths: a resting body carries its weight with no penetration; Coulomb friction on an incline
(sticks for tan(theta) < mu, slides with a = g (sin(theta) - mu cos(theta)) otherwise), for a
stiff FEM block and a rigid box.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import FemBody, Material, RigidBody
from softvr.dynamics.points import EmbeddedPoints
from softvr.volume import Volume, grid_tet_mesh

G = 9.81


def soft_box(size, cells, origin, material, transform=None):
    """A box [origin, origin + size] of 5-tet cubes, optionally moved by ``transform(nodes)``;
    every node is a collision point."""
    cells = np.broadcast_to(cells, 3)
    sp = np.broadcast_to(np.asarray(size, float), 3) / cells
    nodes, tets = grid_tet_mesh(Volume(np.zeros(tuple(cells), np.uint8), spacing=sp,
                                       origin=sp / 2 + np.asarray(origin, float)), tuple(cells))
    if transform is not None:
        nodes = transform(nodes)
    body = FemBody(nodes, tets, material)
    return body, EmbeddedPoints(body, np.arange(len(nodes))[:, None], np.ones((len(nodes), 1)))


def test_soft_cube_dropped_on_a_plane_rests_without_penetration():
    """dt = 5 ms, 0.2 m soft cube (E = 250 kPa) from 10 cm: penetration < 1 mm, then at rest."""
    body, points = soft_box(0.2, 4, (0, 0, 0.1), Material(2.5e5, 0.25, 1000.0, alpha=1.0, beta=1e-3))
    scene = Scene()
    scene.add_body(body, collision_points=points)
    scene.add_plane(Plane(friction=0.5))
    deepest = 0.0
    for _ in range(160):
        solution = scene.step(0.005)
        deepest = min(deepest, body.q[:, 2].min())
    assert deepest > -1e-3
    assert np.abs(body.v).max() < 1e-3
    # The contact impulses carry the weight: sum lambda_n = m g dt per step.
    carried = solution.impulses[0][:, 0].sum()
    assert carried == pytest.approx(body.mass.sum() * G * 0.005, rel=0.02)


def _incline_block(theta, mu, kind):
    """A 10 cm block on a plane tilted by ``theta``: a stiff FEM block (every node a collision
    point) or a rigid box (its 8 corners); returns the scene, a function giving the block's
    centre-of-mass velocity [3] and the downhill direction."""
    n = np.array([np.sin(theta), 0.0, np.cos(theta)])
    down = np.array([np.cos(theta), 0.0, -np.sin(theta)])  # downhill tangent
    frame = np.stack([down, np.cross(n, down), n], axis=1)  # local x -> downhill, z -> normal
    scene = Scene(contact_margin=0.002)
    if kind == "fem":
        body, points = soft_box(0.1, 2, (-0.05, -0.05, 0.0), Material(1e7, 0.3, 1000.0, alpha=0.0, beta=1e-4),
                                transform=lambda x: x @ frame.T)
        scene.add_body(body, collision_points=points)
        velocity = lambda: np.average(body.v, axis=0, weights=body.mass)  # noqa: E731
    else:
        body = RigidBody.box((0.1, 0.1, 0.1), 1000.0, position=frame @ [0.0, 0.0, 0.05],
                             orientation=Rotation.from_matrix(frame).as_quat(scalar_first=True))
        scene.add_body(body, collision_box=(0.05, 0.05, 0.05))
        velocity = lambda: body.v[:3]  # noqa: E731
    scene.add_plane(Plane(normal=tuple(n), friction=mu))
    return scene, velocity, down


@pytest.mark.parametrize("kind", ["fem", "rigid"])
def test_block_sticks_when_tan_theta_is_below_mu(kind):
    scene, velocity, down = _incline_block(np.radians(20.0), 0.5, kind)  # tan 20 deg = 0.36 < 0.5
    for _ in range(100):
        scene.step(0.005)
    assert abs(velocity() @ down) < 1e-3


@pytest.mark.parametrize("kind", ["fem", "rigid"])
def test_block_slides_with_coulomb_acceleration(kind):
    theta, mu, dt = np.radians(35.0), 0.3, 0.005
    scene, velocity, down = _incline_block(theta, mu, kind)
    speeds = []
    for _ in range(80):
        scene.step(dt)
        speeds.append(velocity() @ down)
    # After settling on the surface, the COM speed grows linearly: fit its slope.
    t = np.arange(len(speeds)) * dt
    a = np.polyfit(t[20:], np.array(speeds[20:]), 1)[0]
    assert a == pytest.approx(G * (np.sin(theta) - mu * np.cos(theta)), rel=0.02)
