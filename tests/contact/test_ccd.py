"""Continuous collision detection against a thin sheet (Warp BVH ray sweeps).

A 2 cm rigid ball at 30 m/s moves 30 cm per 10 ms step: discrete detection with a 5 mm margin
never sees the 1 mm sheet (it tunnels), the swept query catches the crossing and the contact
stops it on the near side.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import TriangleMesh
from softvr.dynamics import RigidBody, RigidPoints

SHEET = TriangleMesh([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]],
                     [[0, 1, 2], [0, 2, 3]], thickness=0.001, friction=0.0)


def _fire(ccd: bool) -> RigidBody:
    ball = RigidBody.sphere(0.01, 1000.0, position=(0.0, 0.0, 0.14), velocity=(0.0, 0.0, -30.0))
    scene = Scene(gravity=(0.0, 0.0, 0.0), ccd=ccd)
    scene.add_body(ball, collision_points=RigidPoints(ball, np.zeros((1, 3))))
    scene.add_mesh(SHEET)
    for _ in range(5):
        scene.step(0.01)
    return ball


def test_fast_object_tunnels_through_a_thin_sheet_without_ccd():
    assert _fire(ccd=False).position[2] < -0.5


def test_fast_object_is_stopped_by_a_thin_sheet_with_ccd():
    ball = _fire(ccd=True)
    assert ball.position[2] == pytest.approx(0.001, abs=1e-6)
    assert abs(ball.v[2]) < 1e-6


def test_resting_proximity_contact_has_the_surface_normal():
    from softvr.collision import points_vs_mesh

    ball = RigidBody.sphere(0.01, 1000.0, position=(0.1, 0.2, 0.003))
    contacts = points_vs_mesh(0, RigidPoints(ball, np.zeros((1, 3))), SHEET, margin=0.005)
    assert len(contacts) == 1
    # Warp's BVH queries run in float32: ~1e-7 m rounding over a 3 mm offset tilts the normal ~3e-5.
    np.testing.assert_allclose(contacts.normal[0], [0, 0, 1], atol=1e-4)
    assert contacts.gap[0] == pytest.approx(0.002, abs=1e-6)


def test_sweep_leaving_a_closed_surface_gets_the_outward_normal():
    """A point 1 cm inside a closed unit cube, moving out through its top face: the sweep meets
    the face from behind, which is no contact (a contact on that side would pull the point back
    in); the proximity query gives the outward normal +z and the penetration depth -1 cm. A
    point above the cube moving down into it is a sweep hit on the outside, gap = its distance."""
    from softvr.collision.mesh import query_points
    from softvr.model.shapes import box_surface

    verts, tris = box_surface((1.0, 1.0, 1.0), 2)
    cube = TriangleMesh(verts - 0.5, tris, thickness=0.0)
    points = np.array([[0.1, 0.1, 0.49], [0.1, 0.1, 0.53]])
    motion = np.array([[0.0, 0.0, 0.05], [0.0, 0.0, -0.05]])
    which, normal, gap, _ = query_points(cube._mesh.id, cube.device, points, motion, 0.02, 0.0, True, closed=True)
    assert which.tolist() == [0, 1]
    np.testing.assert_allclose(normal, [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], atol=1e-6)
    np.testing.assert_allclose(gap, [-0.01, 0.03], atol=1e-6)
