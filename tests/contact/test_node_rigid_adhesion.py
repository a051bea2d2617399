"""Implicit adhesion (thesis ch. 4) of rigid bodies on the whole-scene node arrays: rigid cubes
glued to an adhesive plane, stepped by :class:`softvr.sim._node_step.NodeStepper` with an FEM
block beside them (the arrays hold scenes with at least one), checked against the model's
closed-form pull-off force (tests/contact/test_adhesion.py, docs/adhesion.md).

A cube is either a box primitive (``collision_box``: its bottom corners share the face's area,
the rigid path's detection) or a closed surface of collision points (``RigidPoints``: each
bottom vertex a third of its triangles projected on the plane), both with A = L^2 on the plane.
The rigid cube takes no strain, so the traction is uniform and the per-object path's bounds
apply: at intensity beta = 1 the interface debonds at p* = sqrt(W C) (eq. 4.12 with the
traction law of eq. 4.10), so a cube pulled up by a slowly ramped force F lets go at
F* = m g + A sqrt(W C) (eq. 4.16's bound reached on every contact at once).
"""

from __future__ import annotations

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.collision.contacts import unpack_keys
from softvr.contact import Adhesion
from softvr.dynamics import RigidBody, RigidPoints
from softvr.model.shapes import box_surface
from softvr.sim._node_step import NodeStepper
from tests.contact.test_node_adhesion import _add_block

G = 9.81  # [m/s^2]
EDGE, DENSITY = 0.1, 800.0  # rigid cube [m], [kg/m^3]
DT, RATE = 0.002, 40.0  # [s], force ramp [N/s]
GLUE = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)  # p* = sqrt(W C) = 3162 Pa


def _add_cube(scene, kind: str, x: float, y: float = 0.0) -> RigidBody:
    """A glued rigid cube of edge EDGE resting on the plane at (x, y): a box primitive or a
    closed surface of 4 x 4 quads a face."""
    cube = RigidBody.box((EDGE,) * 3, DENSITY, position=(x, y, EDGE / 2), name=f"{kind} cube at {x}")
    if kind == "box":
        scene.add_body(cube, collision_box=(EDGE / 2,) * 3, adhesion=GLUE)
    else:
        verts, tris = box_surface((EDGE,) * 3, 4)
        scene.add_body(cube, collision_points=RigidPoints(cube, verts - EDGE / 2), collision_triangles=tris,
                       adhesion=GLUE)
    return cube


def _glued(kinds, positions) -> tuple[Scene, list]:
    """An FEM block (body 0) and rigid cubes (bodies 1, 2, ...) on an adhesive plane z = 0,
    settled and bonded over 20 steps, on the node arrays."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5, contact_margin=0.002)
    _add_block(scene, 0.04, 2, (0.3, -0.02, 0.0), None)  # the arrays need an FEM body: one beside, not glued
    cubes = [_add_cube(scene, kind, *at) for kind, at in zip(kinds, positions)]
    scene.add_plane(Plane(friction=0.5), adhesion=GLUE)
    for _ in range(20):
        scene.step(DT)
    assert isinstance(scene._stepper, NodeStepper)  # on the node arrays, not per object
    return scene, cubes


def _bonds(scene, index: int) -> dict:
    """Intensities of body ``index``'s tracked contacts, by key."""
    state = scene.adhesion_state.intensity
    keys = np.array(list(state), np.int64)
    mine = keys[unpack_keys(keys)["body_a"] == index] if len(keys) else keys
    return {int(k): state[int(k)] for k in mine}


def _predicted(cube: RigidBody) -> float:
    """F* = m g + A sqrt(W C) [N], A = EDGE^2 the bottom face."""
    return cube.mass * G + EDGE**2 * GLUE.traction_limit()


@pytest.mark.parametrize("kind", ["box", "surface"])
def test_rigid_cube_on_the_arrays_pulls_off_at_its_weight_plus_area_times_sqrt_w_c(kind):
    """Ramped at 40 N/s (0.08 N a step) at its centre, the cube must hold every bond at beta =
    1 up to 0.99 F* (without the rigid side's area or material it would lift off at m g = 7.8 N
    against F* = 39.5 N) and let go (mean intensity below 1/2) by 1.05 F*: with eta = 1e-3
    J s/m^2 the debonding runs away within a few steps past p* (tests/contact/test_adhesion.py
    allows the per-object path the same 5 %)."""
    scene, (cube,) = _glued([kind], [(0.0,)])
    bonded = _bonds(scene, 1)
    assert len(bonded) == (4 if kind == "box" else 25) and all(b == 1.0 for b in bonded.values())
    predicted = _predicted(cube)
    held, separated = 0.0, None
    for n in range(1, int(1.1 * predicted / (RATE * DT))):
        force = RATE * n * DT
        scene.external[1] = np.array([0.0, 0.0, force, 0.0, 0.0, 0.0])
        scene.step(DT)
        beta = list(_bonds(scene, 1).values())
        if beta and min(beta) == 1.0:
            held = force
        if not beta or np.mean(beta) < 0.5:
            separated = force
            break
    assert isinstance(scene._stepper, NodeStepper)
    assert held >= 0.99 * predicted
    assert separated is not None and separated <= 1.05 * predicted


def test_tearing_one_rigid_cube_off_leaves_the_others_bonds_intact():
    """Three rigid cubes bonded to one plane (two box primitives, one surface); the first box
    is torn off at 1.5 F*. The others carry only their weight, a compression: with no bonding
    rate and no traction, eqs. 4.11-4.12 leave their intensities at exactly 1 and they stay
    where they bonded (to 1 um). Their contacts' keys name their own bodies, so none shares a
    bond with the torn cube's corners (the same corner of another box on the same plane)."""
    scene, (torn, box, surface) = _glued(["box", "box", "surface"], [(-0.15,), (0.0, 0.15), (0.15,)])
    before = {i: _bonds(scene, i) for i in (2, 3)}
    assert [len(before[i]) for i in (2, 3)] == [4, 25]
    assert all(b == 1.0 for i in (2, 3) for b in before[i].values())
    at = [box.position.copy(), surface.position.copy()]
    scene.external[1] = np.array([0.0, 0.0, 1.5 * _predicted(torn), 0.0, 0.0, 0.0])
    for _ in range(100):
        scene.step(DT)
    assert torn.position[2] > EDGE / 2 + 0.005  # torn off, 5 mm up
    assert not _bonds(scene, 1)  # its contacts are forgotten past the debond gap
    assert {i: _bonds(scene, i) for i in (2, 3)} == before
    assert max(np.abs(box.position - at[0]).max(), np.abs(surface.position - at[1]).max()) < 1e-6
