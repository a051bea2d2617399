"""Static triangle meshes (``Scene.add_mesh``) on the whole-scene node arrays: every collision
point meets every mesh at its closest point within the point's margin, or at the first crossing
of its motion over the step (``Scene.ccd``), with the mesh's half thickness kept (as
:func:`softvr.collision.points_vs_mesh`), in the same sweeps (thesis eq. 5.6) as the rest.

Held to physics: Coulomb's friction angle on a tilted sheet (a rigid box sticks below it and
slides above it at a = g (sin theta - mu cos theta)); a soft block resting on a sheet is carried
by it with its weight and rests its half thickness above it. Tolerances come from the sweeps'
stopping rule (SWEEP_TOLERANCE = 1e-5 m/s on the velocities, 3x allowed).
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import TriangleMesh
from softvr.collision.contacts import ContactKind, unpack_keys
from softvr.dynamics import Material
from softvr.sim import node_model_supported

from tests.sim.test_node_rigid import VELOCITY_TOL, _check_incline, _rigid_box
from tests.sim.test_node_surfaces import _add_with_surface, _block

G = 9.81
THICKNESS = 0.001  # [m] the sheets' half thickness
SQUARE = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])


def _sheet(rotation=np.eye(3), friction=0.5):
    """A 2 m square sheet through the origin, turned by ``rotation``, of two triangles."""
    return TriangleMesh(SQUARE @ rotation.T, [[0, 1, 2], [0, 2, 3]], thickness=THICKNESS, friction=friction)


@pytest.mark.parametrize("primitive", [False, True])
@pytest.mark.parametrize("slope, slides", [(20.0, False), (35.0, True)])
def test_a_rigid_box_on_a_tilted_static_mesh_sticks_below_the_friction_angle_and_slides_above(slope, slides,
                                                                                              primitive):
    """Coulomb (mu = 0.5, friction angle 26.6 degrees): the box's corners on a static sheet
    turned by theta about y; at 20 degrees it stays, at 35 it slides from rest with
    v_n = n a dt, a = g (sin theta - mu cos theta) (implicit Euler, every contact sliding).
    A fixed FEM block stands apart on the same arrays (sheet 0 is elsewhere). With a box
    primitive too (which meets planes and other primitives only) its corners still meet the
    sheet."""
    mu, dt, steps = 0.5, 0.005, 40
    theta = np.radians(slope)
    turn = np.array([[np.cos(theta), 0.0, np.sin(theta)], [0.0, 1.0, 0.0], [-np.sin(theta), 0.0, np.cos(theta)]])
    normal = turn[:, 2]
    scene = Scene(gravity=(0.0, 0.0, -G), friction=mu)
    block = _block(2, 0.1, (5.0, 0.0, 0.0), Material(5e4, 0.3, 1000.0), fixed=lambda x: np.ones(len(x), bool))
    _add_with_surface(scene, block)
    scene.add_mesh(TriangleMesh(SQUARE + (0.0, 0.0, -3.0), [[0, 1, 2], [0, 2, 3]]))
    scene.add_mesh(_sheet(turn, mu))
    half = np.array([0.05, 0.05, 0.02])
    q = (np.cos(theta / 2), 0.0, np.sin(theta / 2), 0.0)  # the same turn about y
    box = _rigid_box(scene, half, 500.0, tuple((half[2] + THICKNESS) * normal), primitive=primitive, orientation=q)
    assert node_model_supported(scene)
    for _ in range(steps):
        solution = scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    f = unpack_keys(np.concatenate([c.ids for c in solution.contacts]))
    np.testing.assert_array_equal(f["kind"], ContactKind.POINT_MESH)
    np.testing.assert_array_equal(f["body_b"], 1)
    _check_incline(box, turn[:, 0], normal, theta, mu, dt, steps, slides)  # turn[:, 0] points down the slope


def test_a_soft_block_rests_on_a_static_mesh_its_half_thickness_above_and_is_carried_by_it():
    """Newton's first law at rest: the sheet's contacts' world impulses over a step sum to the
    block's weight (within the mass times the velocity tolerance per step), and the block's
    lowest nodes rest the sheet's half thickness above it (within a step's travel at the
    velocity tolerance)."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5)
    block = _block(3, 0.1, (0.0, 0.0, 0.05 + 2 * THICKNESS), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2))
    _add_with_surface(scene, block)
    scene.add_mesh(_sheet())
    dt = 0.01
    for _ in range(60):
        solution = scene.step(dt)
    assert type(scene._stepper).__name__ == "NodeStepper"
    force = sum(np.einsum("ci,cij->j", lam, frames) for lam, frames in zip(solution.impulses, solution.frames)) / dt
    np.testing.assert_allclose(force, [0.0, 0.0, block.mass.sum() * G], atol=block.mass.sum() * VELOCITY_TOL / dt)
    assert block.q[:, 2].min() == pytest.approx(THICKNESS, abs=VELOCITY_TOL * dt)
