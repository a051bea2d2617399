"""The user entity carries the whole CAVE through the world (thesis 6.2.2).

Truths: a rigid motion M of the user moves screens and eye together, so a world point moved
by M projects to the same normalized device coordinates as the unmoved point did, and every
view matrix becomes V M^-1; with the identity user the world is the tracker frame; the eyes
sit -/+ separation / 2 along the head's right axis (and :meth:`Display.eyes` says where).
Tolerances 1e-9: the transforms are exact up to floating-point rounding of a few products.
"""

import math

import numpy as np
import pytest

from softvr.cave import CameraRig, HeadPose, UserPose, move, preset, quaternion_about, turn
from softvr.errors import InputError


@pytest.mark.parametrize("eye", ["mono", "left", "right"])
def test_moving_and_turning_the_user_moves_every_camera_exactly(eye):
    display = preset("rave-cube")
    rig = CameraRig(display)
    head = HeadPose((0.4, -0.3, 1.65), quaternion_about((0.2, 0.1, 1.0), 0.7))
    theta, shift = 0.8, np.array([12.0, -3.5, 0.25])
    user = UserPose(shift, theta)
    rotation = np.array([[math.cos(theta), -math.sin(theta), 0], [math.sin(theta), math.cos(theta), 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rotation, shift
    still, moved = rig.views(None, head, eye), rig.views(user, head, eye)
    rng = np.random.default_rng(3)
    points = rng.uniform([-1.5, -1.5, 0.2], [1.5, 1.5, 3.0], (20, 3))  # inside the cube, in the tracker frame
    for name in still:
        np.testing.assert_allclose(moved[name].eye, rotation @ still[name].eye + shift, atol=1e-9)
        np.testing.assert_allclose(moved[name].view, still[name].view @ np.linalg.inv(m), atol=1e-9)
        np.testing.assert_allclose(moved[name].projection, still[name].projection, atol=1e-9)
        np.testing.assert_allclose(moved[name].project(points @ rotation.T + shift), still[name].project(points),
                                   atol=1e-9)
    assert rig.master == "front"


def test_identity_user_is_the_tracker_frame_and_eyes_follow_the_head():
    """No user (or the identity) gives the screens' own cameras (Screen.view); the left and
    right eyes are the head -/+ 0.065 / 2 m along its right axis, which a 90-degree turn of
    the head about z makes +y."""
    display = preset("cube")
    rig = CameraRig(display)
    head = HeadPose((0.1, 0.2, 1.7), quaternion_about((0, 0, 1), math.pi / 2))
    for name, view in rig.views(UserPose(), head).items():
        reference = display.screen(name).view(head.position)
        np.testing.assert_allclose(view.view, reference.view, atol=1e-12)
        np.testing.assert_allclose(view.projection, reference.projection, atol=1e-12)
    left, right = rig.eye(head, "left"), rig.eye(head, "right")
    np.testing.assert_allclose(left, [0.1, 0.2 - 0.0325, 1.7], atol=1e-12)
    np.testing.assert_allclose(right, [0.1, 0.2 + 0.0325, 1.7], atol=1e-12)
    np.testing.assert_allclose(np.stack([left, right]), np.stack(display.eyes(head.position, head.right)), atol=0)
    np.testing.assert_allclose(rig.view("front", None, head, "right").eye, right, atol=0)
    with pytest.raises(InputError, match=r"mono \| left \| right"):
        rig.eye(head, "centre")


def test_navigation_is_relative_to_the_users_heading():
    """Walking forward 2 m after a 90-degree left turn goes to -x; right then goes to +y. Turning
    about the head's position (in the tracker frame) keeps the head where it is in the world.
    Exact up to rounding (1e-12)."""
    user = move(turn(UserPose((1.0, 1.0, 0.0)), math.pi / 2), forward_m=2.0, right_m=0.5, up_m=0.1)
    np.testing.assert_allclose(user.position, [1.0 - 2.0, 1.0 + 0.5, 0.1], atol=1e-12)
    assert user.yaw == pytest.approx(math.pi / 2, abs=1e-12)
    head = np.array([0.3, -0.2, 1.7])
    spun = turn(user, 1.1, about=head)
    np.testing.assert_allclose(spun.to_world(head), user.to_world(head), atol=1e-12)
    assert spun.yaw == pytest.approx(math.pi / 2 + 1.1, abs=1e-12)
    general = UserPose(matrix=spun.matrix)
    np.testing.assert_allclose(general.matrix, spun.matrix, atol=0)
    with pytest.raises(InputError, match="rigid"):
        UserPose(matrix=np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(InputError, match="yaw"):
        UserPose((0, 0, 0), yaw=math.inf)
