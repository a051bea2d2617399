"""The node arrays' edge-edge broad phase reaches as far as thesis 5.1.2's speculative contact:
an edge pair is a contact candidate when its edges come within margin + dt |u - u_b| (the
edge's largest vertex motion relative to the other body's mean motion over the step), however
that motion is shared between the bodies.

Truth (geometry): cube b (at rest) turned 45 degrees about y shows an edge along y on top;
cube a above it, turned 45 degrees about x, an edge along x at the bottom. A cube of half edge
h turned 45 degrees reaches h sqrt(2) from its centre, so with centres 2 h sqrt(2) + g apart
along z the two edges cross at right angles a distance g apart. Cube a falls at speed v: the
pair is within reach iff g < margin + v dt (the reach of b's edge is v dt relative to a's mean
motion, all of it a's). The contact's gap is g to float32 rounding of the positions (the edge
BVHs are float32: |x| <= 0.2 m, 1e-7 relative -> ~1e-7 m; 1e-6 m allowed). A third cube far
off is never met: its box is the case the broad phase skips.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision.contacts import ContactKind, unpack_keys
from softvr.dynamics import EmbeddedPoints, FemBody, Material
from softvr.dynamics.rigid import quat_from_rotvec, quat_to_matrix
from softvr.sim import node_model_supported
from softvr.volume import Volume, boundary_faces, grid_tet_mesh

HALF = 0.02  # [m]
GAP = 0.004  # [m] between the crossing edges
MARGIN = 0.001  # [m]
DT = 0.01  # [s]


def _cube(centre, rotvec, name):
    nodes, tets = grid_tet_mesh(Volume(np.zeros((1, 1, 1), np.uint8), spacing=(2 * HALF,) * 3,
                                       origin=(0.0, 0.0, 0.0)), 1)
    turn = quat_to_matrix(quat_from_rotvec(rotvec))
    nodes = (nodes - nodes.mean(axis=0)) @ turn.T + np.asarray(centre, float)
    return FemBody(nodes, tets, Material(1e6, 0.3, 1000.0), name=name)


def _edge_gaps(speed):
    """Gaps [m] of the first step's edge-edge contacts between cubes a and b, a falling at ``speed``."""
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.0, edge_contacts=True, contact_margin=MARGIN)
    b = _cube((0.0, 0.0, 0.0), (0.0, np.pi / 4, 0.0), "b")
    a = _cube((0.0, 0.0, 2 * HALF * np.sqrt(2) + GAP), (np.pi / 4, 0.0, 0.0), "a")
    far = _cube((0.15, 0.15, 0.0), (0.0, 0.0, 0.0), "far")
    a.v[:] = (0.0, 0.0, -speed)
    for body in (b, a, far):
        faces = boundary_faces(body.tets)
        scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(8)[:, None], np.ones((8, 1))),
                       collision_triangles=faces)
    assert node_model_supported(scene)
    scene.step(DT)
    contacts = scene.last_solution.contacts
    gaps = [c.gap[unpack_keys(c.ids)["kind"] == ContactKind.EDGE_EDGE] for c in contacts]
    return np.concatenate(gaps) if gaps else np.zeros(0)


@pytest.mark.parametrize("speed", [1.0, 0.4])
def test_an_edge_pair_within_the_motion_grown_reach_is_found(speed):
    # reach of b's edge: MARGIN + DT speed = 0.011 / 0.005 m > GAP, all from a's motion.
    gaps = _edge_gaps(speed)
    assert len(gaps) >= 1
    assert np.min(np.abs(gaps - GAP)) < 1e-6


def test_an_edge_pair_beyond_the_reach_is_not_found():
    # MARGIN + DT 0.2 = 0.003 m < GAP.
    assert len(_edge_gaps(0.2)) == 0
