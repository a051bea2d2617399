"""Rigid scenes stepped on whole-scene arrays (softvr.sim.RigidModel, recorded launches)
against analytic results and against the per-object path they replace (``rigid_arrays=False``,
the physics-tested reference, MuJoCo's practice of checking a fast path against an obviously
correct one)."""

import numpy as np
import pytest

from softvr import InputError, Scene, SimulationError
from softvr.collision import Plane, Sphere
from softvr.contact import Adhesion
from softvr.dynamics import FixedBody, RigidBody, RigidPoints
from softvr.model.shapes import box_surface
from softvr.sim import rigid_model_supported

G = 9.81


def _stack(rigid_arrays: bool) -> Scene:
    scene = Scene(friction=0.6, rigid_arrays=rigid_arrays)
    scene.add_plane(Plane(friction=0.6))
    for k in range(4):
        body = RigidBody.box((0.2, 0.2, 0.1), 500.0, position=(0.003 * k, 0.0, 0.0501 + 0.1001 * k))
        scene.add_body(body, collision_box=(0.1, 0.1, 0.05))
    return scene


def _glued_cube(rigid_arrays: bool, edge=0.1, quads=4):
    adhesion = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3)
    verts, tris = box_surface((edge,) * 3, quads)
    cube = RigidBody.box((edge,) * 3, 800.0, position=(0.0, 0.0, edge / 2), name="cube")
    scene = Scene(contact_margin=0.002, rigid_arrays=rigid_arrays)
    scene.add_body(cube, collision_points=RigidPoints(cube, verts - edge / 2), collision_triangles=tris,
                   adhesion=adhesion)
    scene.add_plane(Plane(friction=0.5), adhesion=adhesion)
    return scene, cube, adhesion


def test_free_fall_is_semi_implicit_euler_exactly():
    # v_n = -g n dt, z_n = z0 - g dt^2 n (n + 1) / 2 (velocity first, then position).
    body = RigidBody.box((0.1,) * 3, 1000.0, position=(0.0, 0.0, 5.0))
    scene = Scene()
    scene.add_body(body, collision_box=(0.05,) * 3)
    scene.add_plane(Plane(point=(0.0, 0.0, -100.0)))
    dt, n = 0.01, 50
    assert rigid_model_supported(scene)
    for _ in range(n):
        scene.step(dt)
    assert body.v[2] == pytest.approx(-G * n * dt, rel=1e-12)
    assert body.position[2] == pytest.approx(5.0 - G * dt * dt * n * (n + 1) / 2, rel=1e-12)
    assert scene.path == "rigid arrays on cpu" and body.step_count == n


def test_a_pose_assigned_between_steps_is_the_one_stepped_from():
    body = RigidBody.box((0.1,) * 3, 1000.0, position=(0.0, 0.0, 5.0))
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add_body(body, collision_box=(0.05,) * 3)
    scene.add_plane(Plane(point=(0.0, 0.0, -100.0)))
    scene.step(0.01)
    body.position = np.array([1.0, 2.0, 3.0])
    body.v = np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    scene.step(0.1)
    np.testing.assert_allclose(body.position, [1.05, 2.0, 3.0], rtol=0, atol=1e-15)


def test_torque_free_spin_equals_the_per_object_step():
    # Same formulas (implicit gyroscopic term, eq. 5.2), so the two paths agree to round-off.
    states = []
    for arrays in (True, False):
        body = RigidBody(2.0, [0.1, 0.2, 0.3], angular_velocity=(3.0, 0.5, 1.0))
        scene = Scene(gravity=(0.0, 0.0, 0.0), rigid_arrays=arrays)
        scene.add_body(body, collision_sphere=0.1)
        scene.add_plane(Plane(point=(0.0, 0.0, -10.0)))
        for _ in range(200):
            scene.step(0.01)
        states.append(np.concatenate([body.orientation, body.v]))
    np.testing.assert_allclose(states[0], states[1], rtol=0, atol=1e-12)


def test_box_stack_on_arrays_follows_the_per_object_path():
    # Each step both solve the LCP to 1e-5 m/s (PGS tolerance), so their positions may part
    # by up to ~1e-5 m/s * dt per step: 1e-5 m after 100 steps of 10 ms.
    finals = []
    for arrays in (True, False):
        scene = _stack(arrays)
        for _ in range(100):
            scene.step(0.01)
        assert (scene._stepper is not None) == arrays
        finals.append(np.array([b.position for b in scene.bodies]))
    np.testing.assert_allclose(finals[0], finals[1], rtol=0, atol=1e-5)


def test_pull_off_on_arrays_lets_go_at_the_step_the_per_object_path_does():
    released = []
    for arrays in (True, False):
        scene, cube, _ = _glued_cube(arrays)
        for n in range(1, 700):
            scene.external[0] = np.array([0.0, 0.0, 40.0 * n * 0.002, 0.0, 0.0, 0.0])
            scene.step(0.002)
            if cube.position[2] - 0.05 > 0.004:
                break
        released.append(n)
    assert released[0] == released[1]


def test_bonds_carry_over_when_the_scene_changes_path():
    scene, cube, adhesion = _glued_cube(True, quads=2)
    for _ in range(20):
        scene.step(0.002)
    bonds = dict(scene.adhesion_state.intensity)
    assert len(bonds) == 9 and scene._stepper is not None
    scene.add_sphere(Sphere(center=(5.0, 0.0, 0.0), radius=0.1))  # not an array scene any more
    scene.step(0.002)
    assert scene._stepper is None
    assert scene.adhesion_state.intensity.keys() == bonds.keys()
    np.testing.assert_allclose(list(scene.adhesion_state.intensity.values()), list(bonds.values()), atol=1e-6)


def test_a_diverging_body_is_named_with_its_step():
    body = RigidBody.box((0.1,) * 3, 1000.0, velocity=(5e3, 0.0, 0.0), name="runaway")
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    scene.add_body(body, collision_box=(0.05,) * 3)
    scene.add_plane(Plane(point=(0.0, 0.0, -10.0)))
    with pytest.raises(SimulationError, match=r"runaway: diverged at step 1 \(speed"):
        scene.step(0.01)


def test_fixed_bodies_stay_put_and_hold_what_rests_on_them():
    base = FixedBody(position=(0.0, 0.0, -0.05))
    top = RigidBody.box((0.1,) * 3, 1000.0, position=(0.0, 0.0, 0.0501))
    scene = Scene()
    scene.add_body(base, collision_box=(0.5, 0.5, 0.05))
    scene.add_body(top, collision_box=(0.05,) * 3)
    scene.add_plane(Plane(point=(0.0, 0.0, -10.0)))
    for _ in range(100):
        scene.step(0.01)
    np.testing.assert_array_equal(base.position, [0.0, 0.0, -0.05])
    # Resting on the fixed box's top face: weight carried, no sinking below round-off.
    assert top.position[2] == pytest.approx(0.05, abs=1e-6)
    force = scene.last_solution.force_on(1, 0.01)
    assert force[2] == pytest.approx(1000.0 * 0.1**3 * G, rel=1e-3)


def test_bonds_of_every_kind_survive_a_round_trip_through_the_per_object_path():
    # Bonding from beta0 = 0 under the boxes' weight (eq. 4.11): a bond the arrays failed to find
    # again after the round trip would restart at 0, far below the intensity it had reached.
    glue = Adhesion(stiffness=1e7, max_energy=1.0, viscosity=1e-3, bonding_rate=1e-2, saturation=1e3, initial=0.0)
    scene = Scene()
    scene.add_plane(Plane(), adhesion=glue)
    for k in range(2):
        body = RigidBody.box((0.2, 0.2, 0.1), 500.0, position=(0.0, 0.0, 0.05 + 0.1 * k))
        scene.add_body(body, collision_box=(0.1, 0.1, 0.05), adhesion=glue)
    for _ in range(10):
        scene.step(0.01)
    scene.rigid_arrays = False
    scene.step(0.01)
    scene.rigid_arrays = True
    before = dict(scene.adhesion_state.intensity)
    scene.step(0.01)
    after = scene.adhesion_state.intensity
    kinds = {int(k) >> 60 & 0xF for k in before}
    assert kinds == {7, 8} and before.keys() == after.keys()  # box-plane and box-box bonds
    assert min(before.values()) > 0.05
    np.testing.assert_allclose([after[k] for k in before], list(before.values()), rtol=0.2)


def test_a_malformed_external_force_is_a_clear_error():
    body = RigidBody.box((0.1,) * 3, 1000.0)
    scene = Scene()
    scene.add_body(body, collision_box=(0.05,) * 3)
    scene.add_plane(Plane(point=(0.0, 0.0, -1.0)))
    scene.external[0] = np.zeros(3)  # a rigid body takes force and torque: 6 numbers
    with pytest.raises(InputError, match=r"external: expected a generalized force of 6 numbers"):
        scene.step(0.01)
