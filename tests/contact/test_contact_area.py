"""Local contact areas (thesis 4.3.1) against geometry.

A cube of edge L triangulated with q x q quads per face, each split in two, has every triangle
of area (L/q)^2 / 2; so does every vertex and edge (the mean of equal incident areas). A
contact takes the smaller of its two primitives' areas: a finely meshed cube on a coarse one
gets the fine one's, whichever side the vertex is on.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import RigidBody, RigidPoints
from softvr.model.shapes import box_surface


def rigid_cube(edge, quads, centre, name):
    verts, tris = box_surface((edge,) * 3, quads)
    body = RigidBody.box((edge,) * 3, 800.0, position=centre, name=name)
    return body, RigidPoints(body, verts - edge / 2), tris


def test_plane_contacts_carry_the_vertex_area():
    body, points, tris = rigid_cube(0.1, 4, (0.0, 0.0, 0.05 + 1e-4), "cube")
    scene = Scene()
    scene.add_body(body, collision_points=points, collision_triangles=tris)
    scene.add_plane(Plane(friction=0.5))
    (contacts,) = scene.step(0.005).contacts
    assert len(contacts) == 25  # the bottom face's 5 x 5 vertices
    np.testing.assert_allclose(contacts.area, (0.1 / 4) ** 2 / 2, rtol=1e-9)


@pytest.mark.parametrize("fine_on_top", [True, False])
def test_surface_contacts_take_the_smaller_primitive_area(fine_on_top):
    fine, coarse = (0.1, 8), (0.1, 2)
    top_res, bottom_res = (fine, coarse) if fine_on_top else (coarse, fine)
    top, top_points, top_tris = rigid_cube(*top_res, (0.01, 0.013, 0.15 + 1e-4), "top")
    bottom, bottom_points, bottom_tris = rigid_cube(*bottom_res, (0.0, 0.0, 0.05), "bottom")
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add_body(top, collision_points=top_points, collision_triangles=top_tris)
    scene.add_body(bottom, collision_points=bottom_points, collision_triangles=bottom_tris)
    contacts = scene.step(0.005).contacts
    assert contacts
    for c in contacts:
        np.testing.assert_allclose(c.area, (0.1 / 8) ** 2 / 2, rtol=1e-9)
