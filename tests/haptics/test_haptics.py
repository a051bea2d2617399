"""The haptic loop and the virtual-coupling tool against statics and their own definitions.

Truths: a tool resting on the ground with its handle pushed d below it stretches the coupling
spring by d, so the hand feels k d (Hooke); between simulation steps the loop renders the
linear model F0 + K (x - x0) with K = -k n n^T for a contact normal n: a further push by e
adds k e, a sideways move adds nothing. The loop's thread keeps its rate (ticks over a wall
interval) while the simulation steps in the main thread.
"""

import time

import numpy as np
import pytest

from softvr import Scene
from softvr.collision import Plane
from softvr.dynamics import RigidBody
from softvr.errors import InputError
from softvr.haptics import HandleModel, HapticLoop, HapticTool, MouseDevice, ScriptedDevice

K = 200.0  # N/m


def finger_on_ground(hand):
    scene = Scene()
    scene.add_plane(Plane(friction=0.0))
    finger = RigidBody.sphere(0.01, 1000.0, position=(0.0, 0.0, 0.02), name="finger")
    scene.add_body(finger, collision_sphere=0.01)
    loop = HapticLoop(hand)
    return scene, finger, loop, HapticTool(scene, finger, loop, stiffness=K, damping=1.0)


def test_pressing_the_handle_into_the_ground_renders_hookes_force():
    hand = MouseDevice(position=(0.0, 0.0, 0.02))
    scene, finger, loop, tool = finger_on_ground(hand)
    depth = 0.01
    for n in range(120):  # the hand goes down to 1 cm below where the finger rests, slowly
        hand.move_to((0.0, 0.0, max(0.01 - depth, 0.02 - 0.0005 * n)))
        loop.tick()
        tool.publish(scene.step(0.005))
    assert finger.position[2] == pytest.approx(0.01, abs=1e-4)  # on the ground, not through it
    force = loop.tick()
    np.testing.assert_allclose(force, [0.0, 0.0, K * depth], atol=0.01 * K * depth)
    # Between simulation steps: 1 mm further down adds k * 1 mm; 1 mm sideways adds nothing.
    hand.move_to((0.0, 0.0, -0.001))
    np.testing.assert_allclose(loop.tick(), [0.0, 0.0, K * (depth + 0.001)], atol=0.01 * K * depth)
    hand.move_to((0.001, 0.0, -0.001))
    np.testing.assert_allclose(loop.tick(), [0.0, 0.0, K * (depth + 0.001)], atol=0.01 * K * depth)


def test_free_tool_follows_the_hand_and_renders_no_stiffness():
    """In the air the model has K = 0 and the spring carries only the finger's weight (and its
    lag): F = k (x_tool - x_hand) with |F| ~ m g."""
    hand = MouseDevice(position=(0.0, 0.0, 0.2))
    scene, finger, loop, tool = finger_on_ground(hand)
    finger.position = np.array([0.0, 0.0, 0.2])
    for _ in range(200):
        model = tool.publish(scene.step(0.005))
    assert np.abs(model.stiffness).max() == 0.0
    np.testing.assert_allclose(model.force, [0.0, 0.0, -finger.mass * 9.81], atol=0.05 * finger.mass * 9.81)


@pytest.mark.parametrize("process", [False, True])
def test_loop_keeps_its_rate_while_the_simulation_steps(process):
    """A hand the loop reads from its thread or process while the simulation steps here for
    0.5 s: ~500 ticks (1 ms median period in a process); the hand follows the published
    simulation clock; forces are clipped to max_force."""
    hand = ScriptedDevice(lambda t: np.array([0.0, 0.0, 0.02 - 0.02 * min(t, 0.25)]))
    scene, finger, loop, tool = finger_on_ground(hand)
    hand.clock = loop.simulation_clock
    loop.process = process
    loop.max_force = 1.5
    started = time.perf_counter()
    with loop:
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 0.5:
            tool.publish(scene.step(0.005))
            if scene.time > 0.3:
                # A stiff model: the clipped force must come back.
                loop.publish(HandleModel(stiffness=-1e4 * np.eye(3)), time=scene.time)
        time.sleep(0.01)
        clipped = np.linalg.norm(loop.last_force())
    ran_ms = 1e3 * (time.perf_counter() - started)
    stats = loop.period_stats()
    # Ticks are scheduled on absolute times (t0 + n T), so late ones catch up: never more than
    # one tick per millisecond the test ran (+2: the tick at t0 and the one stop() may meet), and
    # over the loop's own span (first tick to last) a mean rate of 1 kHz. Only the last tick can
    # stay late: up to 40 ms over >= 400 periods moves the mean by 10 %. The span is the loop's,
    # not the test's, because a forked runner starts 30-150 ms after start() on a loaded 2-core
    # machine (CI). A thread shares the interpreter lock with the stepping, so only the process
    # keeps every period at 1 ms; the thread's median merely stays near it.
    assert stats["count"] <= ran_ms + 2, (ran_ms, stats)
    assert stats["count"] >= 400, stats
    assert stats["rate_hz"] == pytest.approx(1000.0, rel=0.1), stats
    if process:
        assert stats["p50_ms"] == pytest.approx(1.0, abs=0.1), stats
    else:
        assert stats["p50_ms"] < 1.5, stats
    assert loop.handle_position()[2] == pytest.approx(0.015, abs=1e-9)  # path(t >= 0.25) in simulated time
    assert clipped == pytest.approx(1.5)
    assert np.linalg.norm(loop.last_force()) == pytest.approx(1.5)  # the zero of stop() goes to the device
    if not process:
        assert np.linalg.norm(hand.last_force) == 0.0 and hand.forces_sent == loop.ticks + 1


def test_bad_haptic_input_is_reported():
    with pytest.raises(InputError, match="device"):
        HapticLoop(object())
    with pytest.raises(InputError, match="rate"):
        HapticLoop(MouseDevice(), rate=0.0)
    with pytest.raises(InputError, match="position"):
        MouseDevice().move_to((0.0, np.nan, 0.0))
    with pytest.raises(InputError, match="path"):
        ScriptedDevice(lambda t: [0.0, 0.0]).position()
    scene = Scene()
    with pytest.raises(InputError, match="already added"):
        HapticTool(scene, RigidBody.sphere(0.01, 1000.0), HapticLoop(MouseDevice()), stiffness=K)
