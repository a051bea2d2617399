"""The node arrays' broad phases reach as far as thesis 5.1.2's speculative contact: a vertex
meets a triangle, or an edge another edge, when they come within margin + dt |u - u_b| (the
vertex's, or the edge's largest vertex's, motion relative to the other body's mean motion over
the step), whether the motion is the vertex's own or the other body's.

Vertex-triangle truth: two equal axis-aligned cubes, one above the other, g apart: each bottom
corner of the upper cube is g above a top corner of the lower (its closest surface point), and
each top corner of the lower g below one of the upper; the upper falls at speed v, so a
lower corner's reach is all the upper body's mean motion, an upper corner's its own.

Truth (geometry): cube b (at rest) turned 45 degrees about y shows an edge along y on top;
cube a above it, turned 45 degrees about x, an edge along x at the bottom. A cube of half edge
h turned 45 degrees reaches h sqrt(2) from its centre, so with centres 2 h sqrt(2) + g apart
along z the two edges cross at right angles a distance g apart. Cube a falls at speed v: the
pair is within reach iff g < margin + v dt (the reach of b's edge is v dt relative to a's mean
motion, all of it a's). The contact's gap is g to float32 rounding of the positions (the edge
BVHs are float32: |x| <= 0.2 m, 1e-7 relative -> ~1e-7 m; 1e-6 m allowed). A third cube far
off is never met: its box is the case the broad phase skips.

A body's reach is bounded from its points' speeds relative to its own mean motion (its
spread) plus the other body's mean motion relative to it. Truth for a deforming body: the
upper cube's bottom corners fall at s, its top corners are still (both cubes also slide
sideways at a common U, which moves neither relative to the other): a bottom corner's reach
towards the lower cube is margin + dt s, though the upper body's mean moves at s / 2 relative
to the lower. Edges likewise: cube b's top edge rises at s towards a, its other corners still:
the edge's reach is margin + dt s, b's mean moving s / 4.
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
SLIDE = np.array([0.5, 0.0, 0.0])  # [m/s] both cubes' common motion in the deforming cases


def _cube(centre, rotvec, name):
    nodes, tets = grid_tet_mesh(Volume(np.zeros((1, 1, 1), np.uint8), spacing=(2 * HALF,) * 3,
                                       origin=(0.0, 0.0, 0.0)), 1)
    turn = quat_to_matrix(quat_from_rotvec(rotvec))
    nodes = (nodes - nodes.mean(axis=0)) @ turn.T + np.asarray(centre, float)
    return FemBody(nodes, tets, Material(1e6, 0.3, 1000.0), name=name)


def _vertex_gaps(speed, squeeze=False):
    """Gaps [m] of the first step's vertex-triangle contacts by body (side a), the upper cube
    (body 1) falling at ``speed`` onto the lower (body 0); ``squeeze``: only its bottom
    corners fall, and both cubes slide sideways at SLIDE."""
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.0, edge_contacts=False, contact_margin=MARGIN)
    lower = _cube((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), "lower")
    upper = _cube((0.0, 0.0, 2 * HALF + GAP), (0.0, 0.0, 0.0), "upper")
    far = _cube((0.15, 0.15, 0.0), (0.0, 0.0, 0.0), "far")
    upper.v[:] = (0.0, 0.0, -speed)
    if squeeze:
        upper.v[upper.q[:, 2] > 2 * HALF + GAP] = 0.0
        lower.v[:] += SLIDE
        upper.v[:] += SLIDE
    for body in (lower, upper, far):
        scene.add_body(body, collision_points=EmbeddedPoints(body, np.arange(8)[:, None], np.ones((8, 1))),
                       collision_triangles=boundary_faces(body.tets))
    scene.step(DT)
    gaps: dict[int, list] = {0: [], 1: [], 2: []}
    for c in scene.last_solution.contacts:
        if (unpack_keys(c.ids)["kind"] == ContactKind.VERTEX_TRIANGLE).all():
            gaps[c.a.body].extend(c.gap)
    return gaps


def test_a_vertex_within_the_motion_grown_reach_meets_the_other_surface():
    # reach MARGIN + DT 1.0 = 0.011 m > GAP: the upper cube's own motion for its corners,
    # the upper body's mean motion for the lower cube's.
    gaps = _vertex_gaps(1.0)
    for body in (0, 1):
        assert len(gaps[body]) == 4
        np.testing.assert_allclose(gaps[body], GAP, atol=1e-6)
    assert not gaps[2]


def test_a_vertex_beyond_the_reach_meets_nothing():
    gaps = _vertex_gaps(0.2)  # MARGIN + DT 0.2 = 0.003 m < GAP
    assert not any(gaps.values())


def _edge_gaps(speed, rise=False):
    """Gaps [m] of the first step's edge-edge contacts between cubes a and b, a falling at
    ``speed``; ``rise``: a still, b's top edge rising at ``speed`` instead."""
    scene = Scene(gravity=(0.0, 0.0, 0.0), friction=0.0, edge_contacts=True, contact_margin=MARGIN)
    b = _cube((0.0, 0.0, 0.0), (0.0, np.pi / 4, 0.0), "b")
    a = _cube((0.0, 0.0, 2 * HALF * np.sqrt(2) + GAP), (np.pi / 4, 0.0, 0.0), "a")
    far = _cube((0.15, 0.15, 0.0), (0.0, 0.0, 0.0), "far")
    if rise:
        b.v[b.q[:, 2] > b.q[:, 2].max() - 1e-9] = (0.0, 0.0, speed)
    else:
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


def test_a_deforming_body_reaches_as_far_as_its_fastest_vertex():
    # Bottom corners: MARGIN + DT 0.5 = 0.006 m > GAP; the upper mean's motion alone,
    # MARGIN + DT 0.25 = 0.0035 m, is < GAP: so is the lower corners' reach.
    gaps = _vertex_gaps(0.5, squeeze=True)
    assert len(gaps[1]) == 4
    np.testing.assert_allclose(gaps[1], GAP, atol=1e-6)
    assert not gaps[0] and not gaps[2]


def test_a_deforming_body_reaches_as_far_as_its_fastest_edge():
    # b's top edge: MARGIN + DT 0.5 = 0.006 m > GAP; b's mean motion alone, MARGIN + DT 0.125 < GAP.
    gaps = _edge_gaps(0.5, rise=True)
    assert len(gaps) >= 1
    assert np.min(np.abs(gaps - GAP)) < 1e-6
