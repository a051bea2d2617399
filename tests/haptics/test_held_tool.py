"""A haptic tool whose virtual coupling holds its orientation (``angular_stiffness``), against
statics.

Truths: the coupling's six springs of k/6 at +-l on the tool's axes (l = sqrt(3 k_r / (2 k)))
store (2/3) k l^2 (1 - cos theta) when the tool turns by theta about an axis, so a torque tau
holds it at k_r sin theta = tau, while their stretches still sum to six times the tip's: the
hand feels k (x_tip - x_handle), nothing from the turn. A held ball dragged over a plane with
friction mu slides (Coulomb): the hand feels mu N along the drag, N = k d + m g the plane's
push (the hand d below where the ball rests); a ball free to turn rolls instead, and at a
steady drag no friction force is needed (rolling without slipping), so the hand feels none.
"""

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import RigidBody
from softvr.errors import InputError
from softvr.haptics import HapticLoop, HapticTool, MouseDevice
from softvr.scene import load_scene

K = 200.0  # N/m
R = 0.01  # m, the ball's radius


def held_ball(hand_at, angular_stiffness, gravity=(0.0, 0.0, -9.81), plane=None):
    scene = Scene(gravity=gravity, friction=0.5)
    if plane is not None:
        scene.add_plane(plane)
    ball = RigidBody.sphere(R, 1000.0, position=hand_at, name="finger")
    scene.add_body(ball, collision_sphere=R)
    hand = MouseDevice(position=hand_at)
    loop = HapticLoop(hand)
    return scene, ball, hand, loop, HapticTool(scene, ball, loop, stiffness=K, damping=1.0,
                                               angular_stiffness=angular_stiffness)


def test_a_torque_turns_a_held_tool_as_its_springs_potential_says_and_the_hand_feels_no_force():
    k_r, tau = 0.01, 0.005  # [N m/rad], [N m]: sin theta = 1/2, theta = 30 degrees (linear law: 28.6)
    scene, ball, hand, loop, tool = held_ball((0.0, 0.0, 0.0), k_r, gravity=(0.0, 0.0, 0.0))
    scene.external[scene.bodies.index(ball)] = np.array([0.0, 0.0, 0.0, 0.0, 0.0, tau])
    for _ in range(300):
        loop.tick()
        tool.publish(scene.step(0.005))
    r = ball.rotation
    theta = np.arctan2(r[1, 0], r[0, 0])
    # The static fixed point of the implicit springs is exact: only the settling is left
    # (~1e-6 rad after 300 steps of a mode damped by c k_r / k).
    assert k_r * np.sin(theta) == pytest.approx(tau, rel=1e-4)
    assert abs(r[2, 2] - 1.0) < 1e-9  # about z only
    assert np.linalg.norm(tool.force()) < 1e-6 * K * R  # the turn stretches the tip's spring by nothing


def test_pressing_a_held_tool_into_the_ground_renders_hookes_force_and_stiffness():
    """As tests/haptics/test_haptics.py's free finger: the ball on a frictionless plane with the
    hand d below it feels k d, and the loop's linear model adds k per metre pushed further."""
    d = 0.01
    scene, ball, hand, loop, tool = held_ball((0.0, 0.0, R), 0.01, plane=Plane(friction=0.0))
    for n in range(60):
        hand.move_to((0.0, 0.0, R - min(d, d * n / 40)))
        loop.tick()
        model = tool.publish(scene.step(0.005))
    np.testing.assert_allclose(model.force, [0.0, 0.0, K * d], atol=1e-3 * K * d)
    np.testing.assert_allclose(model.stiffness, -K * np.diag([0.0, 0.0, 1.0]), atol=1e-9 * K)
    hand.move_to((0.0, 0.0, R - d - 0.001))
    np.testing.assert_allclose(loop.tick(), [0.0, 0.0, K * (d + 0.001)], atol=1e-3 * K * d)


@pytest.mark.parametrize("held", [True, False])
def test_a_dragged_ball_slides_with_coulombs_friction_when_held_and_rolls_when_free(held):
    mu, d, speed = 0.5, 0.01, 0.05  # [-], [m] the hand below the resting ball, [m/s] the drag
    plane = Plane(friction=mu)
    scene, ball, hand, loop, tool = held_ball((0.0, 0.0, R), 0.1 if held else 0.0, plane=plane)
    dt, t = 0.005, 0.0
    for n in range(200):  # press, then drag along x for 0.6 s (the held ball's twist is mu N R / k_r: 0.1 rad)
        t = max(0.0, (n - 80) * dt)
        hand.move_to((speed * t, 0.0, R - min(d, d * n / 40)))
        loop.tick()
        tool.publish(scene.step(dt))
    normal = K * d + ball.mass * 9.81
    force = tool.force()
    assert force[2] == pytest.approx(K * d, rel=1e-3)  # Hooke on the hand, as without the hold
    # The drag's friction on the ball pulls the spring back: the hand is pulled along -x.
    expected = -mu * normal if held else 0.0
    assert force[0] == pytest.approx(expected, abs=0.01 * mu * normal)
    assert ball.v[0] == pytest.approx(speed, rel=1e-3)


def test_bad_stiffnesses_are_reported():
    scene = Scene()
    ball = RigidBody.sphere(R, 1000.0)
    scene.add_body(ball, collision_sphere=R)
    with pytest.raises(InputError, match="angular_stiffness"):
        HapticTool(scene, ball, HapticLoop(MouseDevice()), stiffness=K, angular_stiffness=-1.0)
    with pytest.raises(InputError, match="stiffness"):
        HapticTool(scene, ball, HapticLoop(MouseDevice()), stiffness=float("nan"), angular_stiffness=0.01)


def test_a_scene_files_angular_stiffness_holds_its_tool(tmp_path):
    """The TOML field reaches the tool: the same torque law, on a tool built from a scene file."""
    k_r, tau = 0.01, 0.005
    toml = tmp_path / "held.toml"
    toml.write_text(f'''format = "softvr-scene 1"
[simulation]
dt = 0.005
[material.finger]
density = 1000.0
[[body]]
name = "finger"
type = "tool"
sphere = {R}
material = "finger"
position = [0.0, 0.0, 0.3]
stiffness = {K}
angular_stiffness = {k_r}
damping = 1.0
[body.motion]
times = [0.0]
positions = [[0.0, 0.0, 0.3]]
''')
    with load_scene(toml, haptics=False) as example:
        ball = example.bodies["finger"]
        example.scene.external[example.scene.bodies.index(ball)] = np.array([0.0, 0.0, 0.0, 0.0, 0.0, tau])
        for _ in range(300):
            example.step()
        r = ball.rotation
        assert k_r * np.sin(np.arctan2(r[1, 0], r[0, 0])) == pytest.approx(tau, rel=1e-4)


@pytest.mark.parametrize("angular_stiffness", [0.0, 0.01])
def test_the_hand_feels_k_times_the_tips_lag_behind_the_handle_at_any_pose(angular_stiffness):
    """HapticTool.force = k (x_tip - x_handle) (thesis 5.4, the virtual coupling's spring; with
    the orientation springs their stretches' mean is the tip's), x_tip = c + R(q) tip with R
    from SciPy's Rotation, for a tool turned and moved anywhere and the hand elsewhere. Positions
    ~1 m and a product of unit quaternions: tolerance 1e-12 k |x|."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    scene = Scene(gravity=(0.0, 0.0, 0.0))
    tool_body = RigidBody.box([0.02, 0.01, 0.05], 1000.0, position=(0.1, -0.2, 0.3), name="probe")
    scene.add_body(tool_body)
    hand = MouseDevice(position=(0.1, -0.2, 0.3))
    loop = HapticLoop(hand)
    tip = np.array([0.0, 0.0, 0.025])
    tool = HapticTool(scene, tool_body, loop, stiffness=K, tip=tip, angular_stiffness=angular_stiffness)
    for _ in range(20):
        w, x, y, z = rng.standard_normal(4)
        turn = np.array([w, x, y, z]) / np.linalg.norm([w, x, y, z])
        tool_body.orientation[:] = turn
        tool_body.position[:] = rng.uniform(-1.0, 1.0, 3)
        tool.handle.position = rng.uniform(-1.0, 1.0, 3)
        x_tip = tool_body.position + Rotation.from_quat([x, y, z, w]).apply(tip)
        expected = K * (x_tip - tool.handle.position)
        np.testing.assert_allclose(tool.force(), expected, rtol=0, atol=1e-12 * K)
