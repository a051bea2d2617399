"""A body's crease BVH (``NodeModel.crease_bvhs``), which the smooth edges' edge-edge queries
walk instead of its full edge BVH (``_node_kernels.edge_edge``: a pair needs a crease on one
side), holds exactly the body's crease and border edges at the step's positions, and yields them
in the full BVH's order, so that the pairs an edge takes (the first ``PAIRS_PER_EDGE`` of the
order) and their slots are those of the full BVH's query.

Truth (geometry, brute force in NumPy): a cube of 4 x 4 x 4 cells (20 mm) whose nodes are moved
at random by up to 1.5 mm, so that some of its face edges fold past the sharp angle (30 degrees
between the two faces' normals, ``SHARP_EDGE_ANGLE``) and others not, falls at 0.5 m/s onto a
plate; its edges' faces, their normals' angles and its edges' boxes are computed here from the
positions at the second step's start (after the cube has moved 5 mm from where the BVHs were
built: a crease BVH not refitted to them fails). Every one of 300 random query boxes around the
cube must meet exactly the crease edges whose (float32) boxes it meets, in the full BVH's order.
An edge whose angle lies within 1e-4 rad of the threshold is left out of the comparison (the
kernel's float32 normals are off by ~1e-6 rad; at most 2 such edges, checked)."""

import numpy as np
import warp as wp

from softvr import Scene
from softvr.collision.edges import SHARP_EDGE_ANGLE
from softvr.dynamics import FemBody, Material
from softvr.sim import node_model_supported
from softvr.volume import Volume, boundary_faces, grid_tet_mesh
from tests.sim.test_node_surfaces import _add_with_surface

CELL = 0.005  # [m]
JITTER = 0.0015  # [m] each node's random move, each axis
SPEED = 0.5  # [m/s] the cube's fall
DT = 0.01  # [s]
MAXHITS = 4096


@wp.kernel
def _query(bvh: wp.uint64, lower: wp.array(dtype=wp.vec3), upper: wp.array(dtype=wp.vec3),
           hits: wp.array2d(dtype=wp.int32), count: wp.array(dtype=wp.int32)):
    k = wp.tid()
    query = wp.bvh_query_aabb(bvh, lower[k], upper[k])
    j = int(0)
    n = int(0)
    while wp.bvh_query_next(query, j):
        if n < hits.shape[1]:
            hits[k, n] = j
        n += 1
    count[k] = n


def _hits(bvh_id, lower, upper):
    hits = wp.zeros((len(lower), MAXHITS), dtype=wp.int32, device="cpu")
    count = wp.zeros(len(lower), dtype=wp.int32, device="cpu")
    wp.launch(_query, dim=len(lower), inputs=[wp.uint64(bvh_id), wp.array(lower, dtype=wp.vec3, device="cpu"),
                                              wp.array(upper, dtype=wp.vec3, device="cpu"), hits, count], device="cpu")
    h, c = hits.numpy(), count.numpy()
    assert c.max() <= MAXHITS
    return [list(h[k, :c[k]]) for k in range(len(lower))]


def _scene():
    rng = np.random.default_rng(7)
    plate_nodes, plate_tets = grid_tet_mesh(Volume(np.zeros((1, 1, 1), np.uint8), spacing=(0.04, 0.04, 0.005),
                                                   origin=(0.0, 0.0, -0.0025)), 4)
    cube_nodes, cube_tets = grid_tet_mesh(Volume(np.zeros((1, 1, 1), np.uint8), spacing=(4 * CELL,) * 3,
                                                 origin=(0.0, 0.0, 0.0)), 4)
    cube_nodes = cube_nodes - cube_nodes.mean(axis=0) + (0.0, 0.0, 2 * CELL + 0.008)
    cube_nodes = cube_nodes + rng.uniform(-JITTER, JITTER, cube_nodes.shape)
    plate = FemBody(plate_nodes, plate_tets, Material(1e6, 0.3, 1000.0), name="plate")
    cube = FemBody(cube_nodes, cube_tets, Material(1e6, 0.3, 1000.0), name="cube")
    cube.v[:] = (0.0, 0.0, -SPEED)
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.0, edge_contacts=True, contact_margin=0.001)
    for body in (plate, cube):
        _add_with_surface(scene, body)
    assert node_model_supported(scene)
    # The cube's collision points are its boundary nodes, ascending (_add_with_surface).
    faces = boundary_faces(cube.tets)
    used = np.unique(faces)
    return scene, cube, used, np.searchsorted(used, faces), rng


def _crease_truth(x, faces, edges):
    """Per edge (rows of ``edges`` over ``x`` [m]): whether it is a crease or border, and the
    angle [rad] between its two faces' normals (pi for a border)."""
    normal = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    angle = np.full(len(edges), np.pi)
    for k, (p, q) in enumerate(edges):
        touching = np.flatnonzero((faces == p).any(axis=1) & (faces == q).any(axis=1))
        assert len(touching) in (1, 2)
        if len(touching) == 2:
            angle[k] = np.arccos(np.clip(normal[touching[0]] @ normal[touching[1]], -1.0, 1.0))
    return angle > SHARP_EDGE_ANGLE, angle


def test_a_crease_bvh_yields_the_creases_a_box_meets_in_the_full_bvhs_order():
    scene, cube, used, faces, rng = _scene()
    scene.step(DT)  # builds the BVHs at these positions; the cube is beyond the reach, 8 mm up
    x = cube.q[used]  # the second step's start (a copy)
    scene.step(DT)
    model = scene._stepper.model
    start = model.body_edge_start.numpy()
    edges = model.edges.numpy()[start[1]:start[2]] - model.body_point_start[1]
    crease, angle = _crease_truth(x, faces, edges)
    unsure = np.abs(angle - SHARP_EDGE_ANGLE) < 1e-4
    assert unsure.sum() <= 2
    assert 0.05 < np.mean(crease[angle < np.pi]) < 0.95  # face edges both folded and flat
    x32 = x.astype(np.float32)
    lo, hi = np.minimum(x32[edges[:, 0]], x32[edges[:, 1]]), np.maximum(x32[edges[:, 0]], x32[edges[:, 1]])
    centre = rng.uniform(x32.min(axis=0) - 0.002, x32.max(axis=0) + 0.002, (300, 3)).astype(np.float32)
    half = rng.uniform(0.0005, 0.004, (300, 3)).astype(np.float32)
    qlo, qhi = centre - half, centre + half
    full = _hits(model.bvh_ids.numpy()[1], qlo, qhi)
    creases = _hits(model.crease_bvh_ids.numpy()[1], qlo, qhi)
    met = 0
    for k in range(len(qlo)):
        truth = np.flatnonzero(crease & ~unsure & (lo <= qhi[k]).all(axis=1) & (hi >= qlo[k]).all(axis=1))
        found = [j for j in creases[k] if not unsure[j]]
        assert sorted(found) == list(truth)
        assert found == [j for j in full[k] if crease[j] and not unsure[j]]
        met += len(truth)
    assert met > 300  # the boxes meet creases (about 5 a box)
