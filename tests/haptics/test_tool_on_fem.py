"""A haptic tool pressed on a soft body, stepped on the whole-scene node arrays: the handle model
the tool publishes blocks exactly the direction its contacts push along.

Truth (thesis 5.4, the rigid-contact limit of [GO09]'s handle-space linearization): a rigid box
tool pressed by its handle onto the flat top of a clamped, stiff FEM block has contacts whose
normals are all the top's normal e_z (the box's corners on the block's triangles, the block's
vertices on the box's bottom triangles), so K = -k e_z e_z^T: pushing the hand further down is
resisted at k, sideways not at all. The block is stiff (E = 10 MPa): under the ~1.2 N the box
and the spring put on its 1e-2 m^2 top its strain is ~1e-5, so the top's normals tilt by ~1e-5
rad (allowed: 1e-4, far below the 1e-3 at which the SVD would keep a second direction); a
tilt t puts k t off the diagonal.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.dynamics import Material, RigidBody, RigidPoints
from softvr.haptics import HapticLoop, HapticTool, MouseDevice
from softvr.model import icosphere

from tests.sim.test_node_rigid import CORNERS, FACES
from tests.sim.test_node_surfaces import _add_with_surface, _block

K = 200.0  # N/m


def test_a_tool_pressed_on_a_soft_block_blocks_only_the_blocks_normal():
    h = 0.1
    scene = Scene(gravity=(0.0, 0.0, -9.81), friction=0.5)
    block = _block(2, h, (0.0, 0.0, h / 2), Material(1e7, 0.3, 1000.0, alpha=0.0, beta=1e-2),
                   fixed=lambda x: x[:, 2] < 1e-9)
    _add_with_surface(scene, block)
    half = np.array([0.02, 0.02, 0.01])
    tool = RigidBody.box(2 * half, 500.0, position=(0.005, -0.004, h + half[2] + 0.0005), name="tool")
    scene.add_body(tool, collision_points=RigidPoints(tool, CORNERS * half), collision_triangles=FACES)
    hand = MouseDevice(position=tool.position - [0.0, 0.0, 0.005])  # 5 mm into the block
    loop = HapticLoop(hand)
    haptic = HapticTool(scene, tool, loop, stiffness=K, damping=1.0)
    for _ in range(60):
        loop.tick()
        model = haptic.publish(scene.step(0.01))
    assert type(scene._stepper).__name__ == "NodeStepper"
    np.testing.assert_allclose(model.stiffness, -K * np.diag([0.0, 0.0, 1.0]), atol=1e-4 * K)
    # Hooke on the hand: the tool rests on the top (it started 0.5 mm above it), the hand 4.5 mm
    # below where the tool rests, less the block's compression and the contact's overlap (some
    # um: allowed 20).
    assert model.force[2] == pytest.approx(K * 0.0045, abs=K * 2e-5)



def test_a_held_ball_dragged_over_a_soft_block_slides_with_coulombs_friction():
    """On the node arrays (the shoulder's path; tests/haptics/test_held_tool.py has the truths):
    a 1 cm ball tool, its icosphere surface on the stiff block's top, held by its coupling
    (angular_stiffness 0.1 N m/rad: it twists by mu N r / k_r ~ 0.1 rad) and dragged along x at
    5 cm/s with the hand 9.5 mm below where it rests, slides: the hand feels Hooke's k 9.5 mm
    down (less the block's give under the ball: allowed 2 %) and Coulomb's mu N back, N = F_z + m g,
    within 2 % of mu N (the contacts' normals tilt with the block's strain and the icosphere's
    facets, and the sweeps stop at a relative change)."""
    h, r, mu, d, speed, dt = 0.1, 0.01, 0.5, 0.0095, 0.05, 0.01
    scene = Scene(gravity=(0.0, 0.0, -9.81), friction=mu)
    block = _block(2, h, (0.0, 0.0, h / 2), Material(1e7, 0.3, 1000.0, alpha=0.0, beta=1e-2),
                   fixed=lambda x: x[:, 2] < 1e-9)
    _add_with_surface(scene, block)
    ball = RigidBody.sphere(r, 1000.0, position=(-0.02, 0.0, h + r + 0.0005), name="ball")
    unit, triangles = icosphere(2)
    scene.add_body(ball, collision_points=RigidPoints(ball, unit * r), collision_triangles=triangles,
                   collision_sphere=r)
    hand = MouseDevice(position=ball.position)
    loop = HapticLoop(hand)
    haptic = HapticTool(scene, ball, loop, stiffness=K, damping=1.0, angular_stiffness=0.1)
    for n in range(60):  # press for 0.2 s, then drag for 0.4 s
        t = max(0.0, (n - 20) * dt)
        hand.move_to((-0.02 + speed * t, 0.0, h + r + 0.0005 - min(d + 0.0005, (d + 0.0005) * n / 10)))
        loop.tick()
        haptic.publish(scene.step(dt))
    assert type(scene._stepper).__name__ == "NodeStepper"
    force = haptic.force()
    normal = force[2] + ball.mass * 9.81
    assert force[2] == pytest.approx(K * d, rel=0.02)
    assert force[0] == pytest.approx(-mu * normal, abs=0.02 * mu * normal)
    assert ball.v[0] == pytest.approx(speed, rel=0.02)
