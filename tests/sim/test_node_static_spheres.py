"""Static spheres (``Scene.add_sphere``) on the whole-scene node arrays: every collision point
meets every sphere along the radius through it (gap ``|x - c| - R``, normal ``(x - c) / |x - c|``,
as :func:`softvr.collision.points_vs_sphere`), in the same sweeps (thesis eq. 5.6) as the rest.

Held to physics: each step solves the MLCP of eq. 5.5 (the check of test_node_rigid.py), the
contacts lie on the sphere's geometry, and at rest the sphere carries the body's weight
(Newton's first law). Tolerances come from the sweeps' stopping rule (SWEEP_TOLERANCE =
1e-5 m/s on the velocities, 3x allowed): a velocity error e is a force error m e / dt.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane, Sphere
from softvr.collision.contacts import ContactKind, unpack_keys
from softvr.contact import Adhesion
from softvr.dynamics import Material
from softvr.sim import node_model_supported

from tests.sim.test_node_rigid import VELOCITY_TOL, _check_mlcp, _system
from tests.sim.test_node_surfaces import _add_with_surface, _block

G = 9.81
CENTRE, RADIUS = np.array([0.0, 0.0, 0.0]), 0.5  # [m] the sphere the block rests on (the scene's second)


def _block_on_sphere():
    """A soft block dropped 1 mm above the top of a static sphere (the scene's sphere 1; sphere
    0 is far away), a plane well below."""
    scene = Scene(gravity=(0.0, 0.0, -G), friction=0.5)
    block = _block(3, 0.1, (0.0, 0.0, RADIUS + 0.05 + 0.001), Material(5e4, 0.3, 1000.0, alpha=0.0, beta=1e-2))
    _add_with_surface(scene, block)
    scene.add_plane(Plane(point=(0.0, 0.0, -2.0), friction=0.5))
    scene.add_sphere(Sphere(center=(5.0, 0.0, 0.0), radius=0.3, friction=0.5))
    scene.add_sphere(Sphere(center=tuple(CENTRE), radius=RADIUS, friction=0.5))
    return scene, block


def test_a_soft_block_on_a_static_sphere_solves_the_mlcp_on_the_spheres_geometry_and_rests_on_it():
    scene, block = _block_on_sphere()
    assert node_model_supported(scene)
    dt = 0.01
    for _ in range(60):
        systems = [_system(b, dt, scene.gravity) for b in scene.bodies]
        start = block.q.copy()
        solution = scene.step(dt)
        assert type(scene._stepper).__name__ == "NodeStepper"
        _check_mlcp(scene, systems, solution, dt, 0.5)
        for contacts in solution.contacts:
            # Every contact is a block node against sphere 1, along the radius through the node
            # where the step started.
            f = unpack_keys(contacts.ids)
            np.testing.assert_array_equal(f["kind"], ContactKind.POINT_SPHERE)
            np.testing.assert_array_equal(f["body_b"], 1)
            x = start[contacts.a.blocks[:, 0]]
            d = np.linalg.norm(x - CENTRE, axis=1)
            np.testing.assert_allclose(contacts.normal, (x - CENTRE) / d[:, None], atol=1e-12)
            np.testing.assert_allclose(contacts.gap, d - RADIUS, atol=1e-12)
    assert len(solution.contacts) == 1 and len(solution.contacts[0].gap) >= 4
    # At rest the contacts' world impulses carry the weight: sum frame^T lambda / dt = (0, 0, m g),
    # within the mass times the velocity tolerance per step.
    force = sum(np.einsum("ci,cij->j", lam, frames) for lam, frames in zip(solution.impulses, solution.frames)) / dt
    weight = block.mass.sum() * G
    np.testing.assert_allclose(force, [0.0, 0.0, weight], atol=block.mass.sum() * VELOCITY_TOL / dt)
    np.testing.assert_allclose(block.v, 0.0, atol=1e-4)


def test_a_static_sphere_in_an_adhesive_scene_takes_the_node_arrays():
    """The node arrays' adhesion knows static spheres and meshes (kinds 4 and 5; their physics:
    tests/contact/test_node_static_adhesion.py): such a scene steps on the arrays."""
    scene, _ = _block_on_sphere()
    scene.add_plane(Plane(point=(0.0, 0.0, -3.0)), adhesion=Adhesion(1e6, 0.05, 0.05))
    assert node_model_supported(scene)
