"""Contact keys are unique in the scene, and name what they join.

Truths: the scene as built. Every contact's key unpacks (:func:`unpack_keys`) to the kind of
contact its producer makes, the bodies of its two sides, the static it touches (the one
whose surface its point b lies on) and the features at its points (the collision point,
surface vertex or edge where point a lies). Keys that once left out the body (static
contacts: ``(static id << 32) | point``) or the sphere (every sphere on a plane had one key)
would collide here: the two boxes have the same vertex numbering and both stand on the
ground and against the sheet, the FEM cube and box A stand against the same wall, and both
spheres lie on the ground.

Independence of bonds: two bodies on one adhesive plane. The interface holds a traction p
with the gap g = p / (C beta^2) (eq. 4.10) and starts to debond at p* = sqrt(W C beta^3)
(tests/contact/test_adhesion.py), so a body pulled up by m g + F lets go beyond
F* = sum(A) sqrt(W C) (sum(A): the areas its contacts carry). Tearing one body off with three
times its F* must leave the other, pulled by 0.6 of its own F* over its weight, where it was:
its bonds keep their intensity, and it rises by no more than its springs would open at the
lowest intensity allowed (0.9). Rigid boxes with a collision surface, sphere primitives and
box primitives alike.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane, Sphere, TriangleMesh
from softvr.collision.contacts import MAX_BODIES, MAX_FEATURES, ContactKind, contact_keys, unpack_keys
from softvr.errors import InputError
from softvr.contact import Adhesion
from softvr.dynamics import EmbeddedPoints, FemBody, Material, RigidBody, RigidPoints
from softvr.model.shapes import box_surface, icosphere
from softvr.volume import Volume, boundary_faces, grid_tet_mesh

EDGE, GAP, R = 0.1, 0.002, 0.04  # cube edge, gap to the statics, sphere body radius [m]
SHEET_THICKNESS = 0.001


def _rigid_cube(scene, corner):
    verts, tris = box_surface((EDGE,) * 3, 2)
    body = RigidBody.box((EDGE,) * 3, 800.0, position=np.asarray(corner) + EDGE / 2)
    points = RigidPoints(body, verts - EDGE / 2)
    return scene.add_body(body, collision_points=points, collision_triangles=tris), points


def _fem_cube(scene, corner):
    sp = np.full(3, EDGE / 2)
    nodes, tets = grid_tet_mesh(Volume(np.zeros((2, 2, 2), np.uint8), spacing=sp, origin=sp / 2 + corner), 2)
    body = FemBody(nodes, tets, Material(1e5, 0.3, 1000.0))
    faces = boundary_faces(tets)
    points = EmbeddedPoints(body, np.arange(len(nodes))[:, None], np.ones((len(nodes), 1)))
    return scene.add_body(body, collision_points=points, collision_triangles=faces), points


def _sphere_body(scene, centre):
    verts, tris = icosphere(2)
    body = RigidBody.sphere(R, 800.0, position=centre)
    points = RigidPoints(body, R * verts)
    return scene.add_body(body, collision_points=points, collision_triangles=tris, collision_sphere=R), points


def _crowded_scene():
    """Ground (plane 0), a wall x = 0 (plane 1), a static sphere half sunk in the ground and a
    vertical sheet y = 0 (static mesh), all within the contact margin of several bodies:
    box A (body 0) in the corner of ground, wall and sheet; box B (1) beside A, on the ground,
    against the sheet and near the static sphere; an FEM cube (2) behind A, on the ground,
    against the wall and near the sphere; two sphere bodies (3, 4) on the ground, against the
    sheet, beside B and each other."""
    scene = Scene(gravity=(0.0, 0.0, -9.81), contact_margin=0.006)
    scene.add_plane(Plane())
    scene.add_plane(Plane(normal=(1.0, 0.0, 0.0)))
    scene.add_sphere(Sphere(center=(0.157, 0.157, 0.0), radius=0.05))
    sheet = np.array([[-0.1, 0.0, -0.1], [0.6, 0.0, -0.1], [0.6, 0.0, 0.3], [-0.1, 0.0, 0.3]])
    scene.add_mesh(TriangleMesh(sheet, [[0, 1, 2], [0, 2, 3]], thickness=SHEET_THICKNESS))
    points = {}
    for corner in ((GAP, GAP, GAP), (EDGE + 0.007, GAP, GAP)):
        index, points[index] = _rigid_cube(scene, corner)
    index, points[index] = _fem_cube(scene, np.array([GAP, EDGE + 0.007, GAP]))
    for x in (0.25, 0.335):
        index, points[index] = _sphere_body(scene, (x, R + 0.004, R + GAP))
    return scene, points


def _distance_to(static, p):
    """Distance [m] of point ``p`` [3] from the surface of a static of :func:`_crowded_scene`."""
    if isinstance(static, Plane):
        return abs((p - np.asarray(static.point)) @ static.unit_normal())
    if isinstance(static, Sphere):
        return abs(np.linalg.norm(p - np.asarray(static.center)) - static.radius)
    return abs(p[1])  # the sheet y = 0


def _segment_distance(p, a, b):
    t = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return np.linalg.norm(p - (a + t * (b - a)))


def test_key_layout_is_the_documented_bit_fields():
    """A key is kind 4 | body a 10 | body b 10 | feature a 20 | feature b 20 bits (contacts.py),
    packed here independently with Python integers; the largest indices fit, one more is refused."""
    rng = np.random.default_rng(7)
    body_a, body_b = rng.integers(0, MAX_BODIES, 50), rng.integers(0, MAX_BODIES, 50)
    feature_a, feature_b = rng.integers(0, MAX_FEATURES, 50), rng.integers(0, MAX_FEATURES, 50)
    keys = contact_keys(ContactKind.EDGE_EDGE, body_a, feature_a, body_b, feature_b)
    for k, ba, bb, fa, fb in zip(keys.tolist(), body_a, body_b, feature_a, feature_b):
        packed = (int(ContactKind.EDGE_EDGE) << 60) | (int(ba) << 50) | (int(bb) << 40) | (int(fa) << 20) | int(fb)
        assert k % (1 << 64) == packed
    fields = unpack_keys(keys)
    assert (fields["body_a"] == body_a).all() and (fields["feature_b"] == feature_b).all()
    assert (fields["kind"] == ContactKind.EDGE_EDGE).all()
    top = contact_keys(ContactKind.BOX_BOX, MAX_BODIES - 1, MAX_FEATURES - 1, MAX_BODIES - 1, MAX_FEATURES - 1)
    assert unpack_keys(top)["feature_a"] == MAX_FEATURES - 1
    with pytest.raises(InputError, match=r"contact body_b: expected an index in \[0, 1023\].*found 1024"):
        contact_keys(ContactKind.POINT_PLANE, 0, np.arange(3), MAX_BODIES, 0)
    with pytest.raises(InputError, match="contact feature_a.*found -1"):
        contact_keys(ContactKind.POINT_PLANE, 0, np.array([0, -1]), 0, 0)


def test_keys_are_unique_and_unpack_to_the_bodies_statics_and_features_touching():
    scene, points = _crowded_scene()
    before = {i: p.positions().copy() for i, p in points.items()}
    surfaces = {s.body_index: s for s in scene.collision_surfaces}
    edge_vertices = {i: s.points.positions().copy() for i, s in surfaces.items()}
    scene.step(0.002)
    sets = scene.last_solution.contacts
    keys = np.concatenate([c.ids for c in sets])
    assert keys.dtype == np.int64 and len(np.unique(keys)) == len(keys)

    statics = {ContactKind.POINT_PLANE: scene.planes, ContactKind.SPHERE_PLANE: scene.planes,
               ContactKind.POINT_SPHERE: scene.spheres, ContactKind.POINT_MESH: scene.meshes}
    seen = set()
    for c in sets:
        f = unpack_keys(c.ids)
        kinds = set(f["kind"].tolist())
        assert len(kinds) == 1  # one producer, one kind per set
        kind = ContactKind(kinds.pop())
        np.testing.assert_array_equal(f["body_a"], c.a.body)
        if c.b is None:
            assert kind in statics
            for k, pb in zip(f["body_b"], c.point_b):
                # Point b lies on the static the key names, and on no other of its kind.
                distances = [_distance_to(s, pb) for s in statics[kind]]
                assert distances[k] < 1e-9 and all(d > 1e-4 for j, d in enumerate(distances) if j != k)
        else:
            np.testing.assert_array_equal(f["body_b"], c.b.body)
        a = c.a.body
        if kind in (ContactKind.POINT_PLANE, ContactKind.POINT_SPHERE, ContactKind.POINT_MESH,
                    ContactKind.VERTEX_TRIANGLE):
            np.testing.assert_allclose(c.point_a, before[a][f["feature_a"]], atol=1e-12)
            np.testing.assert_array_equal(f["feature_b"], 0)  # one contact per point and static / surface
        elif kind == ContactKind.EDGE_EDGE:
            for side, body, edges in (("a", a, f["feature_a"]), ("b", c.b.body, f["feature_b"])):
                ends = edge_vertices[body][surfaces[body].edge_set.edges[edges]]
                at = c.point_a if side == "a" else c.point_b
                assert max(_segment_distance(p, *e) for p, e in zip(at, ends)) < 1e-9
        else:
            assert kind in (ContactKind.SPHERE_PLANE, ContactKind.SPHERE_SPHERE)
            np.testing.assert_array_equal(f["feature_a"], 0)
            np.testing.assert_array_equal(f["feature_b"], 0)
        seen |= {(kind, a, int(b)) for b in f["body_b"]}

    plane, sphere, mesh, vt = (ContactKind.POINT_PLANE, ContactKind.POINT_SPHERE, ContactKind.POINT_MESH,
                               ContactKind.VERTEX_TRIANGLE)
    expected = {
        (plane, 0, 0), (plane, 0, 1), (mesh, 0, 0),  # box A in the corner
        (plane, 1, 0), (mesh, 1, 0), (sphere, 1, 0),  # box B
        (plane, 2, 0), (plane, 2, 1), (sphere, 2, 0),  # the FEM cube
        (ContactKind.SPHERE_PLANE, 3, 0), (ContactKind.SPHERE_PLANE, 4, 0), (mesh, 3, 0), (mesh, 4, 0),
        (ContactKind.SPHERE_SPHERE, 3, 4),
        (vt, 0, 1), (vt, 1, 0), (vt, 0, 2), (vt, 2, 0), (vt, 1, 3), (vt, 3, 1),  # neighbours, both ways
    }
    assert expected <= seen
    # Nothing else than these and edge pairs of the neighbours.
    neighbours = {(0, 1), (0, 2), (1, 3)}
    assert all(k in expected or (k[0] == ContactKind.EDGE_EDGE and k[1:] in neighbours) for k in seen), \
        seen - expected


def _pair_on_a_plane(shape, adhesion):
    """Bodies 0 and 1 of one shape 0.2 m apart on one adhesive ground, settled and bonded;
    with the collision points of each (None for the primitives)."""
    scene = Scene(contact_margin=0.002)
    scene.add_plane(Plane(friction=0.5), adhesion=adhesion)
    verts, tris = box_surface((EDGE,) * 3, 4)
    for x in (-0.1, 0.1):
        if shape == "sphere":
            body = RigidBody.sphere(EDGE / 2, 800.0, position=(x, 0.0, EDGE / 2))
            scene.add_body(body, collision_sphere=EDGE / 2, adhesion=adhesion)
        else:
            body = RigidBody.box((EDGE,) * 3, 800.0, position=(x, 0.0, EDGE / 2))
            if shape == "box":
                scene.add_body(body, collision_box=(EDGE / 2,) * 3, adhesion=adhesion)
            else:
                scene.add_body(body, collision_points=RigidPoints(body, verts - EDGE / 2),
                               collision_triangles=tris, adhesion=adhesion)
    return scene


def _bonds(scene, body):
    """Intensities of the tracked contacts the body has with the plane in the last step, by key
    (found through the contact sets, whatever the keys hold)."""
    keys = [int(k) for c in scene.last_solution.contacts if c.a.body == body and c.b is None for k in c.ids]
    return {k: scene.adhesion_state.intensity[k] for k in keys if k in scene.adhesion_state.intensity}


def _areas(scene, body):
    return sum(float(c.area.sum()) for c in scene.last_solution.contacts if c.a.body == body and c.b is None)


@pytest.mark.parametrize("torn", [0, 1])
@pytest.mark.parametrize("shape", ["mesh", "sphere", "box"])
def test_tearing_one_body_off_a_plane_leaves_the_other_bonded(shape, torn):
    """Either body torn off (the keys once shared, the contact set evaluated last set both
    bodies' intensities: tearing body 1 off loosened body 0, and body 0 could not be torn off)."""
    C, W = 1e7, 1.0
    adhesion = Adhesion(stiffness=C, max_energy=W, viscosity=1e-3)
    scene = _pair_on_a_plane(shape, adhesion)
    held = 1 - torn
    dt, g = 0.002, 9.81
    for _ in range(20):  # settle and bond
        scene.step(dt)
    area = [_areas(scene, i) for i in (0, 1)]
    assert min(area) > 0 and _bonds(scene, 0) and _bonds(scene, 1)
    weight = [b.mass * g for b in scene.bodies]
    limit = [a * np.sqrt(W * C) for a in area]  # F* over the weight
    rest = scene.bodies[held].position[2]
    # The held body pulled at 0.6 of its limit, ramped up (applied at once the pull would
    # overshoot, up to twice the static traction): it settles on its springs, bonds intact.
    hold = 0.6 * limit[held]
    for n in range(1, 81):
        scene.external[held] = np.array([0.0, 0.0, weight[held] + hold * min(n / 50, 1.0), 0.0, 0.0, 0.0])
        scene.step(dt)
    z0, bonds0, bonds_torn = scene.bodies[held].position[2], _bonds(scene, held), _bonds(scene, torn)
    assert min(bonds0.values()) == pytest.approx(1.0)
    p = hold / area[held]  # traction [Pa]: the springs open g = p / (C beta^2) (eq. 4.10)
    assert z0 - rest == pytest.approx(p / C, rel=0.1)
    # The other torn off at three times its F*: it leaves, and its bonds are forgotten.
    scene.external[torn] = np.array([0.0, 0.0, weight[torn] + 3.0 * limit[torn], 0.0, 0.0, 0.0])
    for _ in range(100):
        scene.step(dt)
    assert scene.bodies[torn].position[2] > EDGE / 2 + 10 * adhesion.debond_gap
    assert not bonds_torn.keys() & scene.adhesion_state.intensity.keys()
    bonds = _bonds(scene, held)
    assert bonds.keys() == bonds0.keys() and all(bonds[k] > 0.9 * bonds0[k] for k in bonds0)
    # Still on its springs: at beta >= 0.9 they open at most p / (0.81 C), so the held body
    # rose by at most p / C (1 / 0.81 - 1) (45 um here) since before the tear.
    assert abs(scene.bodies[held].position[2] - z0) <= p / C * (1 / 0.81 - 1)
