"""A frame's metrics read off the rigid arrays (softvr.sim.frame_metrics.RigidFrameMetrics, the
counts of LazySolution.contact_counts) against closed forms: the lowest corner of a tilted box,
the kinetic and potential energy of a spinning box, the four corners of a box resting flat."""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import FixedBody, RigidBody
from softvr.model.shapes import box_corners
from softvr.sim._rigid_step import RigidStepper
from softvr.sim.frame_metrics import RigidFrameMetrics, rigid_stepper

G = 9.81
SIZE = np.array([0.2, 0.3, 0.1])  # box edges [m]
DENSITY = 500.0  # [kg/m^3]


def _quat_x(degrees: float) -> np.ndarray:
    half = np.radians(degrees) / 2
    return np.array([np.cos(half), np.sin(half), 0.0, 0.0])


def test_penetration_is_the_lowest_corner_of_a_tilted_box_below_either_plane():
    # Box turned 30 deg about x: its corners reach hy sin 30 + hz cos 30 below its centre on
    # z, and hx along x. Planes z = 0.01 (up) and x = 1 (normal -x, offset -1).
    hx, hy, hz = SIZE / 2
    box = RigidBody.box(SIZE, DENSITY, position=(0.0, 0.0, 0.1), orientation=_quat_x(30.0))
    wall = FixedBody((0.98, 0.0, 2.0))  # its one point 2 cm short of the wall, 1.99 m above the floor
    scene = Scene(gravity=(0.0, 0.0, -G))
    scene.add_body(box, collision_box=SIZE / 2)
    scene.add_body(wall)
    floor, side = Plane(point=(0.0, 0.0, 0.01)), Plane(point=(1.0, 0.0, 0.0), normal=(-1.0, 0.0, 0.0))
    scene.add_plane(floor)
    scene.add_plane(side)
    stepper = RigidStepper(scene)
    planes = [((0.0, 0.0, 1.0), 0.01), ((-1.0, 0.0, 0.0), -1.0)]
    metrics = RigidFrameMetrics(stepper, [(0, box_corners(SIZE / 2)), (1, np.zeros((1, 3)))], planes)
    low = hy * np.sin(np.radians(30.0)) + hz * np.cos(np.radians(30.0))
    assert metrics.penetration() == pytest.approx(0.01 - (0.1 - low), rel=0, abs=1e-15)
    # A pose assigned after the stepper was built is the one measured: 3 mm into the wall.
    box.position = np.array([1.003 - hx, 0.0, 1.0])
    assert metrics.penetration() == pytest.approx(0.003, rel=0, abs=1e-15)
    assert stepper._position[0, 0] == 1.003 - hx  # copied into the arrays


def test_energies_are_the_closed_form_of_a_spinning_box_and_leave_out_fixed_bodies():
    # Turned 90 deg about x, the body's z axis is the world's -y: omega = 3 rad/s about world y
    # spins it about its own z, I_zz = m (a^2 + b^2) / 12.
    a, b, c = SIZE
    m = DENSITY * a * b * c
    box = RigidBody.box(SIZE, DENSITY, position=(0.5, -0.2, 0.7), orientation=_quat_x(90.0),
                        velocity=(1.0, 2.0, 0.0), angular_velocity=(0.0, 3.0, 0.0))
    scene = Scene(gravity=(0.0, 0.0, -G))
    scene.add_body(box, collision_box=SIZE / 2)
    scene.add_body(FixedBody((0.0, 0.0, 5.0)))
    scene.add_plane(Plane())
    metrics = RigidFrameMetrics(RigidStepper(scene))
    kinetic, total = metrics.energies(scene.gravity)
    spin = 0.5 * m * (a * a + b * b) / 12.0 * 9.0
    assert kinetic == pytest.approx(0.5 * m * 5.0 + spin, rel=1e-12)
    assert total - kinetic == pytest.approx(m * G * 0.7, rel=1e-12)
    # Gravity is read at each call: along -x the same box's potential is m g x.
    assert metrics.energies((-G, 0.0, 0.0))[1] - kinetic == pytest.approx(m * G * 0.5, rel=1e-12)


def test_a_box_resting_flat_counts_its_four_bottom_corners_all_pushing():
    box = RigidBody.box(SIZE, DENSITY, position=(0.0, 0.0, SIZE[2] / 2))
    scene = Scene(gravity=(0.0, 0.0, -G))
    scene.add_body(box, collision_box=SIZE / 2)
    scene.add_plane(Plane())
    for _ in range(3):
        solution = scene.step(0.01)
    assert rigid_stepper(scene) is not None
    assert solution.contact_counts() == (4, 4)
    # Together the corners hold the box's weight over the step: sum of normal impulses m g dt.
    normal = sum(i[:, 0].sum() for i in solution.impulses)
    assert normal == pytest.approx(DENSITY * SIZE.prod() * G * 0.01, rel=1e-4)
    assert solution.contact_counts() == (4, 4)  # the same once the sets are split


def test_a_held_solution_keeps_its_contacts_after_later_steps_write_its_buffer_again():
    # A step's solution views the contact buffer that the step after next writes again: held,
    # it is copied out first. Later steps stand the box on an edge (two contacts, other
    # impulses) in the rows the held solution's four corners used.
    box = RigidBody.box(SIZE, DENSITY, position=(0.0, 0.0, SIZE[2] / 2))
    scene = Scene(gravity=(0.0, 0.0, -G))
    scene.add_body(box, collision_box=SIZE / 2)
    scene.add_plane(Plane())
    for _ in range(3):
        held = scene.step(0.01)
    hy, hz = SIZE[1:] / 2
    box.orientation = _quat_x(30.0)
    box.position = np.array([0.0, 0.0, hy * np.sin(np.radians(30.0)) + hz * np.cos(np.radians(30.0))])
    box.v = np.zeros(6)
    for _ in range(4):
        edge = scene.step(0.01)
    assert edge.contact_counts()[0] == 2
    assert held.contact_counts() == (4, 4)
    normal = sum(i[:, 0].sum() for i in held.impulses)
    assert normal == pytest.approx(DENSITY * SIZE.prod() * G * 0.01, rel=1e-4)
    assert len(scene.adhesion_state.intensity) == 0  # no adhesion: nothing tracked
