"""The node arrays' edge-edge queries skip a smooth edge against a body without any crease
(``_node_kernels.body_creases``): a pair needs a crease on one side (thesis 5.1.2's edge
contacts, only where an edge is sharp), so the skip must keep every pair whose crease lies on the
queried body.

Truth (geometry, brute force in NumPy): a flat plate (body 0, 40 x 20 x 5 mm in 4 x 4 x 4
cells, top face at z = 0) has only smooth edges on its top face away from its border; a cube of
half edge h (body 1) turned 45 degrees about y shows one crease along y at its bottom, g above
the plate's top, mid-cell in x. It crosses the plate's top-face edges along x and the diagonals
at g (the segment-segment distance to every top-face edge, computed here), and its ends
overhang the plate by 10 mm (> the reach), so no vertex-triangle contact holds the pair. The
plate's edges are the querying side (body 0 < body 1) and the smooth ones: the pairs exist only
if the query against the cube, whose one crease is on the queried side, is made. The gap is g
to float32 rounding of the positions (|x| <= 0.05 m, 1e-7 relative: 1e-6 m allowed, as
tests/collision/test_node_reach.py).

An edge with no pair last step is first tested against the union of the near bodies' grown
boxes (``_node_kernels.near_bodies``' reach_lower / reach_upper) before each body's: the second
test starts the crease 8 mm up (beyond the 6 mm reach: no pair), so that at the second step
every plate edge takes that path, and checks the same truth from the positions then."""

import numpy as np

from softvr import Scene
from softvr.collision.contacts import ContactKind, unpack_keys
from softvr.dynamics import EmbeddedPoints, FemBody, Material
from softvr.dynamics.rigid import quat_from_rotvec, quat_to_matrix
from softvr.sim import node_model_supported
from softvr.volume import Volume, boundary_faces, grid_tet_mesh

PLATE = (0.04, 0.02, 0.005)  # [m] the plate's size, 4 cells along each axis
HALF = 0.02  # [m] the cube's half edge
GAP = 0.002  # [m] between the cube's bottom crease and the plate's top
MARGIN = 0.001  # [m]
DT = 0.01  # [s]
SPEED = 0.5  # [m/s] the cube's fall: reach MARGIN + DT SPEED = 6 mm > GAP


def _segment_distance(p1, q1, p2, q2):
    """Smallest distance [m] between segments p1 q1 and p2 q2 (Ericson, Real-Time Collision
    Detection, 5.1.9: the lines' closest parameters, each clamped to its segment in turn)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, b = d1 @ r, d1 @ d2
    denom = a * e - b * b
    s = np.clip((b * f - c * e) / denom, 0.0, 1.0) if denom > 1e-30 else 0.0
    t = (b * s + f) / e
    if t < 0.0 or t > 1.0:
        t = np.clip(t, 0.0, 1.0)
        s = np.clip((b * t - c) / a, 0.0, 1.0)
    return np.linalg.norm(p1 + s * d1 - (p2 + t * d2))


def _edges(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def _plate_and_cube(gap):
    """The plate and, its bottom crease ``gap`` [m] above the plate's top, the falling cube, in a
    scene; and each body's boundary triangles by name."""
    # 4 x 4 x 4 cells over 40 x 20 x 5 mm, top at z = 0 (a voxel's footprint around its centre).
    plate_nodes, plate_tets = grid_tet_mesh(Volume(np.zeros((1, 1, 1), np.uint8), spacing=PLATE,
                                                   origin=(0.0, 0.0, -PLATE[2] / 2)), 4)
    cube_nodes, cube_tets = grid_tet_mesh(Volume(np.zeros((1, 1, 1), np.uint8), spacing=(2 * HALF,) * 3,
                                                 origin=(0.0, 0.0, 0.0)), 1)
    turn = quat_to_matrix(quat_from_rotvec((0.0, np.pi / 4, 0.0)))
    cube_nodes = (cube_nodes - cube_nodes.mean(axis=0)) @ turn.T + (PLATE[0] / 8, 0.0, HALF * np.sqrt(2) + gap)
    plate = FemBody(plate_nodes, plate_tets, Material(1e6, 0.3, 1000.0), name="plate")
    cube = FemBody(cube_nodes, cube_tets, Material(1e6, 0.3, 1000.0), name="cube")
    cube.v[:] = (0.0, 0.0, -SPEED)
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.0, edge_contacts=True, contact_margin=MARGIN)
    faces = {}
    for body in (plate, cube):
        faces[body.name] = boundary_faces(body.tets)
        n = len(body.q)
        scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(n)[:, None], np.ones((n, 1))),
                       collision_triangles=faces[body.name])
    assert node_model_supported(scene)
    return scene, plate, cube, faces


def _crease_distances(plate, cube, faces):
    """Brute-force truth [m]: the cube's bottom crease's distance to each of the plate's top-face
    edges, from the bodies' positions now."""
    crease = cube.q[np.argsort(cube.q[:, 2])[:2]]
    assert np.ptp(crease[:, 0]) < 1e-9 and np.ptp(crease[:, 2]) < 1e-9  # along y
    top = [e for e in _edges(faces["plate"]) if np.allclose(plate.q[e, 2], 0.0, atol=1e-9)]
    return np.array([_segment_distance(*crease, *plate.q[e]) for e in top])


def _edge_gaps(scene):
    return np.concatenate([c.gap[unpack_keys(c.ids)["kind"] == ContactKind.EDGE_EDGE]
                           for c in scene.last_solution.contacts] or [np.zeros(0)])


def test_a_smooth_edge_meets_the_crease_of_the_body_it_queries():
    scene, plate, cube, faces = _plate_and_cube(GAP)
    distances = _crease_distances(plate, cube, faces)
    assert abs(np.min(distances) - GAP) < 1e-9
    scene.step(DT)
    gaps = _edge_gaps(scene)
    # One contact for each plate edge the crease crosses at g (9: five along x, four diagonals;
    # only the two on the plate's border are creases).
    assert len(gaps) == np.sum(distances < GAP + 1e-6)
    np.testing.assert_allclose(gaps, GAP, atol=1e-6)


def test_an_edge_without_pairs_last_step_meets_a_crease_come_within_reach():
    # Step 1: the crease 8 mm above the plate, beyond the reach MARGIN + DT SPEED = 6 mm: no pair,
    # so at step 2 every edge takes the broad phase's body tests (those with pairs last step skip them).
    scene, plate, cube, faces = _plate_and_cube(0.008)
    scene.step(DT)
    assert len(_edge_gaps(scene)) == 0
    distances = _crease_distances(plate, cube, faces)
    assert np.min(distances) < MARGIN + DT * SPEED - 1e-4
    scene.step(DT)
    gaps = _edge_gaps(scene)
    assert len(gaps) == np.sum(distances < np.min(distances) + 1e-6)
    np.testing.assert_allclose(gaps, np.min(distances), atol=1e-6)
