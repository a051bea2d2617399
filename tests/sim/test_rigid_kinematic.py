"""A kinematic body (infinite mass, its script's velocity) on the rigid arrays: a box pushed
across a rough floor by a ram moving at constant speed, against the analytic impulses of
eq. 5.5's contact problem, on both paths."""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import KinematicBody, RigidBody
from softvr.scene import bundled, load_scene
from softvr.sim import rigid_model_supported

G, MU, U, DT = 9.81, 0.4, 0.5, 0.01
EDGE, DENSITY = 0.2, 500.0  # [m], [kg/m^3]: m = 4 kg
# The rigid solve stops when no row's velocity changes by more than 1e-5 m/s in a sweep
# (contact/rigid_pgs.py); a set's summed impulse is then within (rows) m 1e-5 N s of the
# fixed point, 4 rows (the clipped face's corners): 1.6e-4 N s, against mu m g dt = 0.157.
TOL_V = 1e-5


def _pushed_box(rigid_arrays: bool):
    scene = Scene(friction=0.0, rigid_arrays=rigid_arrays)  # the ram's face is frictionless
    scene.add_plane(Plane(friction=MU))
    box = RigidBody.box((EDGE,) * 3, DENSITY, position=(0.0, 0.0, EDGE / 2), name="box")
    scene.add_body(box, collision_box=(EDGE / 2,) * 3)
    half = (0.05, 0.15, 0.08)
    start = -EDGE / 2 - half[0]  # touching the box's -x face at t = 0

    def pose(t):
        return (start + U * t, 0.0, EDGE / 2), (1.0, 0.0, 0.0, 0.0)

    ram = KinematicBody(pose, name="ram")
    scene.add_body(ram, collision_box=half)
    return scene, box, ram, pose


@pytest.mark.parametrize("rigid_arrays", [True, False])
def test_a_ram_at_constant_speed_pushes_a_box_with_the_floor_friction_impulse(rigid_arrays):
    """Eq. 5.5 each step: the ram's contacts (frictionless, normal -x) close their gap, so the
    box's x velocity becomes the ram's U; the first step's impulse from the ram is the box's
    momentum m U plus the floor's sliding friction mu m g dt, every later step's just
    mu m g dt (the box slides at U, the floor carries m g dt); every contact complementary
    (lambda_n >= 0, gap after >= 0, one of them 0)."""
    scene, box, ram, pose = _pushed_box(rigid_arrays)
    m = box.mass
    assert rigid_model_supported(scene)
    for n in range(1, 31):
        solution = scene.step(DT)
        assert (type(scene._stepper).__name__ == "RigidStepper") == rigid_arrays
        np.testing.assert_array_equal(ram.position, pose(n * DT)[0])  # the script's pose exactly
        assert ram.time == pytest.approx(n * DT, abs=1e-15)
        assert box.v[0] == pytest.approx(U, abs=TOL_V)
        on_ram = solution.force_on(1, DT) * DT  # [N s] the ram's share of the impulses, -(on the box)
        expected = MU * m * G * DT + (m * U if n == 1 else 0.0)
        assert -on_ram[0] == pytest.approx(expected, abs=4 * m * TOL_V)
        np.testing.assert_allclose(on_ram[1:], 0.0, atol=4 * m * TOL_V)
        floor = solution.force_on(0, DT) * DT + on_ram  # the plane's impulse on the box
        np.testing.assert_allclose(floor, [-MU * m * G * DT, 0.0, m * G * DT], atol=4 * m * TOL_V)
        for contacts, impulse, after in zip(solution.contacts, solution.impulses, solution.gaps_after):
            assert (impulse[:, 0] >= 0).all()
            assert (after >= -DT * TOL_V).all()
            assert ((impulse[:, 0] <= m * TOL_V) | (after <= DT * TOL_V)).all()


def test_box_knock_steps_on_the_rigid_arrays():
    scene = load_scene(bundled("box-knock.toml")).scene
    assert rigid_model_supported(scene)
    scene.step(0.01)
    assert type(scene._stepper).__name__ == "RigidStepper"
