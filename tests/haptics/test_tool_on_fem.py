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
