"""Local contact areas (thesis 4.3.1, projected onto the contact plane) against geometry.

A contact stands for its feature's share of the surface projected onto the contact plane: a
third of every triangle at a vertex or an edge, a triangle's own area, each times the cosine
between the triangle's normal and the contact's, of the triangles of a closed surface that face
the contact (:meth:`CollisionSurface.facing_vertex_area`). A cube of
edge L meshed with q x q quads per face, each split in two along one diagonal, touches with
one face: its side faces stand perpendicular to the contact plane and project to nothing, so
a vertex of the touching face carries a third of each of that face's triangles at it (each
h^2 / 2, h = L / q): h^2 inside the face (six triangles), h^2 / 2 on its border (three), h^2 / 3
or h^2 / 6 at a corner (two or one, as the diagonals fall), L^2 over the face. A vertex on
another body's triangle takes its own area (each way's vertices tile a face-to-face patch, and
one way bonds: docs/adhesion.md), two edges the smaller of their areas.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.collision.contacts import ContactKind, unpack_keys
from softvr.collision.edges import surface_edges
from softvr.dynamics import RigidBody, RigidPoints
from softvr.model.shapes import box_surface


def rigid_cube(edge, quads, centre, name):
    verts, tris = box_surface((edge,) * 3, quads)
    body = RigidBody.box((edge,) * 3, 800.0, position=centre, name=name)
    return body, RigidPoints(body, verts - edge / 2), tris


def box_face_shares(edge, quads):
    """The faces of the cube [0, edge]^3 as :func:`box_surface` meshes it: their outward normals
    [6, 3], and every vertex's [6, vertex_count] and every edge's (:func:`surface_edges` order)
    [6, edge_count] share of each face, a third of each of that face's triangles at it [m^2]."""
    verts, tris = box_surface((edge,) * 3, quads)
    edges, _ = surface_edges(tris)
    index = {pair: k for k, pair in enumerate(map(tuple, edges.tolist()))}
    normals, vertex_share, edge_share = np.zeros((6, 3)), np.zeros((6, len(verts))), np.zeros((6, len(edges)))
    for f, (axis, side) in enumerate((axis, side) for axis in range(3) for side in (0, 1)):
        normals[f, axis] = 1.0 if side else -1.0
        on_face = np.isclose(verts[:, axis], side * edge)
        for triangle in tris[on_face[tris].all(axis=1)].tolist():
            a, b, c = verts[triangle]
            third = np.linalg.norm(np.cross(b - a, c - a)) / 6
            for k in range(3):
                vertex_share[f, triangle[k]] += third
                edge_share[f, index[tuple(sorted((triangle[k], triangle[(k + 1) % 3])))]] += third
    return normals, vertex_share, edge_share


def facing(normals, share, into):
    """Contact areas [c] [m^2] of features with face shares ``share`` [6, c] on contact planes of
    unit normals ``into`` [c, 3] pointing into the cube: each face's share projected onto the
    plane, of the faces that turn towards the contact (outward normal against ``into``)."""
    return np.einsum("fc,fc->c", share, np.maximum(-normals @ into.T, 0.0))


def test_plane_contacts_carry_the_facing_vertex_area():
    edge, quads = 0.1, 4
    h = edge / quads
    body, points, tris = rigid_cube(edge, quads, (0.0, 0.0, edge / 2 + 1e-4), "cube")
    scene = Scene()
    scene.add_body(body, collision_points=points, collision_triangles=tris)
    scene.add_plane(Plane(friction=0.5))
    (contacts,) = scene.step(0.005).contacts
    assert len(contacts) == 25  # the bottom face's 5 x 5 vertices
    vertex = unpack_keys(contacts.ids)["feature_a"]
    normals, vertex_share, _ = box_face_shares(edge, quads)
    np.testing.assert_allclose(contacts.area, facing(normals, vertex_share[:, vertex], contacts.normal), rtol=1e-9)
    verts, _ = box_surface((edge,) * 3, quads)
    borders = (np.isclose(verts[vertex, :2], 0.0) | np.isclose(verts[vertex, :2], edge)).sum(axis=1)
    np.testing.assert_allclose(contacts.area[borders == 0], h**2, rtol=1e-9)
    np.testing.assert_allclose(contacts.area[borders == 1], h**2 / 2, rtol=1e-9)
    np.testing.assert_allclose(np.sort(contacts.area[borders == 2]), [h**2 / 6] * 2 + [h**2 / 3] * 2, rtol=1e-9)
    np.testing.assert_allclose(contacts.area.sum(), edge**2, rtol=1e-9)  # the side faces count nothing


@pytest.mark.parametrize("fine_on_top", [True, False])
def test_surface_contacts_take_their_vertex_area_and_the_smaller_edge_area(fine_on_top):
    """Each vertex-triangle contact's area is its vertex's share of its faces, projected: a fine
    vertex's (at most h^2 = 1.6 cm^2) and a coarse one's (at least (4 h)^2 / 6 = 4.2 cm^2), not
    the fine triangle's h^2 / 2 under it; an edge-edge contact's the fine edge's third of its
    face triangles (at most h^2 / 3; a coarse edge has at least (4 h)^2 / 6). Vertices just
    beyond the other cube's rim touch it with a tilted normal and so count less of their face."""
    edge, fine, coarse = 0.1, 8, 2
    top_quads, bottom_quads = (fine, coarse) if fine_on_top else (coarse, fine)
    top, top_points, top_tris = rigid_cube(edge, top_quads, (0.01, 0.013, 0.15 + 1e-4), "top")
    bottom, bottom_points, bottom_tris = rigid_cube(edge, bottom_quads, (0.0, 0.0, 0.05), "bottom")
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add_body(top, collision_points=top_points, collision_triangles=top_tris)
    scene.add_body(bottom, collision_points=bottom_points, collision_triangles=bottom_tris)
    fine_body = 0 if fine_on_top else 1
    normals, vertex_share, edge_share = box_face_shares(edge, fine)
    coarse_vertex_share = box_face_shares(edge, coarse)[1]
    contacts = scene.step(0.005).contacts
    kinds = set()
    for c in contacts:
        key = unpack_keys(c.ids)
        kinds |= set(key["kind"].tolist())
        # The normal points from side b into side a: into the fine cube where it is side a.
        fine_a = key["body_a"] == fine_body
        into_fine = np.where(fine_a[:, None], c.normal, -c.normal)
        expected = np.empty(len(c))
        vertex_triangle = key["kind"] == ContactKind.VERTEX_TRIANGLE
        vertex = vertex_triangle & fine_a
        expected[vertex] = facing(normals, vertex_share[:, key["feature_a"][vertex]], into_fine[vertex])
        on_fine = vertex_triangle & ~fine_a  # a coarse vertex on a fine triangle: the normal points into it
        expected[on_fine] = facing(normals, coarse_vertex_share[:, key["feature_a"][on_fine]], c.normal[on_fine])
        fine_edge = np.where(fine_a, key["feature_a"], key["feature_b"])[~vertex_triangle]
        expected[~vertex_triangle] = facing(normals, edge_share[:, fine_edge], into_fine[~vertex_triangle])
        np.testing.assert_allclose(c.area, expected, rtol=1e-9)
    assert kinds == {ContactKind.VERTEX_TRIANGLE, ContactKind.EDGE_EDGE}
