"""Keyboard / mouse navigation against kinematics: a key held for T seconds walks speed * T
along the heading (or turns turn_rate * T), exactly up to round-off since each frame adds
speed * dt; drags turn by gain * pixels; presses become toggle events; a real VTK interactor
under Xvfb drives it through the same observers."""

import math

import numpy as np
import pytest

from softvr.cave import UserPose
from softvr.cave.navigation import KeyboardNavigation
from softvr.errors import InputError


def _hold(nav, seconds, fps=60):
    for n in range(int(seconds * fps) + 1):
        out = nav(n, n / fps)
    return out


def test_held_keys_walk_and_turn_at_their_rates():
    nav = KeyboardNavigation(UserPose((1.0, 2.0, 0.0), yaw=math.pi / 2), speed=1.5, turn_rate=0.8)
    nav.key_down("w")
    _hold(nav, 2.0)
    # Heading pi/2 faces world -x: 2 s at 1.5 m/s = 3 m along -x.
    np.testing.assert_allclose(nav.user.position, [1.0 - 3.0, 2.0, 0.0], atol=1e-9)
    nav.key_up("w")
    nav.key_down("Left")
    nav._last_t = None  # a new run of frames
    _hold(nav, 1.0)
    assert nav.user.yaw == pytest.approx(math.pi / 2 + 0.8, abs=1e-9)
    np.testing.assert_allclose(nav.user.position, [-2.0, 2.0, 0.0], atol=1e-9)  # turned about the user's origin


def test_drags_turn_and_presses_become_events():
    nav = KeyboardNavigation(mouse_gain=0.01)
    nav.drag(-50)  # 50 pixels to the left: turn left by 0.5 rad
    nav.key_down("space")
    nav.key_down("3")
    user, head, events = nav(0, 0.0)
    assert UserPose(matrix=user).yaw == pytest.approx(0.5) and head is None
    assert events == [("toggle", ("paused",)), ("toggle", ("flag3",))]
    assert nav(1, 1 / 60)[2] == []
    with pytest.raises(InputError, match="speed"):
        KeyboardNavigation(speed=-1.0)


def test_a_vtk_interactor_drives_it(display):
    from vtkmodules.vtkRenderingCore import vtkRenderWindowInteractor

    from softvr.render import SurfaceRenderer

    with SurfaceRenderer(64, 48, onscreen=True) as r:
        r.add_sphere((0, 2, 1), 0.3)
        r.render()
        interactor = vtkRenderWindowInteractor()
        interactor.SetRenderWindow(r.vtk_renderer.GetRenderWindow())
        interactor.Initialize()
        nav = KeyboardNavigation(speed=2.0)
        nav.attach(interactor)
        interactor.SetKeySym("w")
        interactor.InvokeEvent("KeyPressEvent")
        nav(0, 0.0)
        nav(1, 0.5)
        interactor.InvokeEvent("KeyReleaseEvent")
        nav(2, 1.0)
        np.testing.assert_allclose(nav.user.position, [0.0, 1.0, 0.0], atol=1e-9)  # 0.5 s at 2 m/s along +y
        interactor.SetEventPosition(10, 20)
        interactor.InvokeEvent("LeftButtonPressEvent")
        interactor.SetEventPosition(40, 20)
        interactor.InvokeEvent("MouseMoveEvent")
        interactor.InvokeEvent("LeftButtonReleaseEvent")
        nav(3, 1.1)
        assert nav.user.yaw == pytest.approx(-30 * nav.mouse_gain)
        interactor.SetRenderWindow(None)
