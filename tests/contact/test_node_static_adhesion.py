"""Implicit adhesion (thesis ch. 4) on static spheres and triangle meshes, on the whole-scene
node arrays: a block glued to an adhesive static sheet or to the top of a large adhesive
static sphere pulls off at the closed-form force of eq. 4.12, as on a plane
(tests/contact/test_node_adhesion.py, whose blocks and tolerance these reuse)."""

from __future__ import annotations

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane, Sphere, TriangleMesh
from softvr.collision.contacts import ContactKind, unpack_keys
from softvr.sim._node_step import NodeStepper

from tests.contact.test_node_adhesion import DT, EDGE, G, GLUE, _add_block, _bonds, _pull_off

THICKNESS = 0.0005  # [m] the sheet's half thickness
# A sphere of 50 m: the block's bottom face (half diagonal 28 mm) stands off it by at most
# 0.028^2 / (2 R) = 8 um at its corners, under the 39 um the block's weight presses the bonds
# in (m g / (A C)), and its normals turn by at most 0.6 mrad (areas within 2e-7).
RADIUS = 50.0


def _glued_to(static: str):
    """A 2-cell FEM block resting (20 steps of bonding) on an adhesive static sheet at z = 0 or
    the top of a sphere whose top is at z = 0 (the scene's second static of its kind), a plane
    far below."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5, contact_margin=0.002)
    lift = THICKNESS if static == "mesh" else 0.0
    block = _add_block(scene, EDGE, 2, (-EDGE / 2, -EDGE / 2, lift), GLUE)
    scene.add_plane(Plane(point=(0.0, 0.0, -1.0)))
    if static == "mesh":
        square = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
        scene.add_mesh(TriangleMesh(square + (0.0, 0.0, -0.5), [[0, 1, 2], [0, 2, 3]]))
        scene.add_mesh(TriangleMesh(square, [[0, 1, 2], [0, 2, 3]], thickness=THICKNESS, friction=0.5),
                       adhesion=GLUE)
    else:
        scene.add_sphere(Sphere(center=(5.0, 0.0, -3.0), radius=0.3))
        scene.add_sphere(Sphere(center=(0.0, 0.0, -RADIUS), radius=RADIUS, friction=0.5), adhesion=GLUE)
    for _ in range(20):
        scene.step(DT)
    assert isinstance(scene._stepper, NodeStepper)  # on the node arrays, not per object
    return scene, block


@pytest.mark.parametrize("static, kind", [("mesh", ContactKind.POINT_MESH), ("sphere", ContactKind.POINT_SPHERE)])
def test_fem_block_pulls_off_a_static_at_its_weight_plus_area_times_sqrt_w_c(static, kind):
    """F* = m g + A sqrt(W C) (eq. 4.12 with the traction law of eq. 4.10, beta = 1), A the
    block's bottom face: its contacts' areas (the surface around each bottom vertex projected
    on the contact plane) sum to L^2; the bonds are keyed by the static (kind, its index as
    side b). Tolerance 15 %, derived in test_node_adhesion's plane test (the ramp during the
    debonding runaway, the rim letting go first)."""
    scene, block = _glued_to(static)
    mine = [c for c in scene.last_solution.contacts if c.b is None and c.a.body == 0]
    f = unpack_keys(np.concatenate([c.ids for c in mine]))
    np.testing.assert_array_equal(f["kind"], kind)
    np.testing.assert_array_equal(f["body_b"], 1)
    assert sum(float(c.area.sum()) for c in mine) == pytest.approx(EDGE**2, rel=1e-3)
    bonds = _bonds(scene, 0)
    assert bonds and set(unpack_keys(np.array(list(bonds), np.int64))["kind"]) == {kind}
    assert max(bonds.values()) > 0.5
    predicted = block.mass.sum() * G + EDGE**2 * GLUE.traction_limit()
    force = _pull_off(scene, block, predicted)
    assert isinstance(scene._stepper, NodeStepper)
    assert force == pytest.approx(predicted, rel=0.15)
