"""The user entity and its camera rig: navigating a whole CAVE through a virtual world (thesis 6.2.2).

The thesis builds the virtual camera cluster as a hierarchy: a *user entity* (the invisible
character the viewer navigates with), the master camera attached to it, and every other
screen's camera relative to the master. Because the screens do not move in the real room, all
the cameras move together: navigation changes only the user entity's pose in the world.

Here the user entity is a :class:`UserPose`, the rigid transform from the tracker frame (where
the screens and the tracked head live, metres, z up) to the world. :class:`CameraRig` composes
it with the head pose: each screen's corners and the eye are carried into the world and the
off-axis camera of :func:`~softvr.cave.screen_view` is built there, so a world point moved
along with the user lands on the same pixel. :func:`move` and :func:`turn` are first-person
navigation relative to the user's heading.

Examples
--------
>>> import math
>>> from softvr.cave import CameraRig, HeadPose, UserPose, move, preset, turn
>>> rig = CameraRig(preset("cube"))
>>> user = move(turn(UserPose(), math.pi / 2), forward_m=10.0)     # face -x, then walk 10 m
>>> user.position.round(6).tolist(), round(user.yaw, 6)
([-10.0, 0.0, 0.0], 1.570796)
>>> views = rig.views(user, HeadPose((0.0, 0.0, 1.7)), eye="left")
>>> views["front"].eye.round(4).tolist()                          # the left eye, 3.25 cm to the user's left
[-10.0, -0.0325, 1.7]
"""

from __future__ import annotations

import math

import numpy as np

from softvr.cave.display import Display, Screen
from softvr.cave.projection import ScreenView, screen_view
from softvr.cave.tracking import HeadPose
from softvr.errors import InputError

__all__ = ["EYES", "CameraRig", "UserPose", "move", "turn", "world_view"]

EYES = ("mono", "left", "right")


def _rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _number(value, what: str, unit: str) -> float:
    ok = (isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
          and math.isfinite(value))
    if not ok:
        raise InputError(what, f"a finite number [{unit}]", repr(value))
    return float(value)


class UserPose:
    """The user entity's pose: the rigid transform from the tracker frame to the world.

    Give either a position and a heading, or a general rigid ``matrix``.

    Parameters
    ----------
    position : array_like, shape [3] [m]
        Where the tracker origin (the centre of the CAVE floor, for the presets) is in the world.
    yaw : float [rad]
        Heading: rotation about the world's +z; 0 keeps the tracker's +y (towards the front
        screen) along the world's +y, pi / 2 turns it to the world's -x (a left turn).
    matrix : array_like, shape [4, 4], optional
        A general rigid transform (rotation with determinant +1, then translation [m], last
        row 0 0 0 1) instead of ``position`` and ``yaw``.
    """

    def __init__(self, position=(0.0, 0.0, 0.0), yaw: float = 0.0, *, matrix=None):
        if matrix is None:
            p = np.asarray(position, float) if np.ndim(position) == 1 else np.full(0, np.nan)
            if p.shape != (3,) or not np.isfinite(p).all():
                raise InputError("position", "3 finite numbers [m]", repr(position))
            m = np.eye(4)
            m[:3, :3] = _rotation_z(_number(yaw, "yaw", "rad"))
            m[:3, 3] = p
        else:
            if np.any(np.asarray(position, float) != 0) or yaw != 0:
                raise InputError("user pose", "either position and yaw, or matrix", "both")
            m = np.array(matrix, float)
            r = m[:3, :3] if m.shape == (4, 4) else None
            rigid = (r is not None and np.isfinite(m).all() and np.allclose(m[3], [0, 0, 0, 1], atol=1e-9)
                     and np.allclose(r.T @ r, np.eye(3), atol=1e-6) and np.linalg.det(r) > 0)
            if not rigid:
                raise InputError("matrix", "a rigid 4x4 transform (rotation with det +1, translation [m], "
                                 "last row 0 0 0 1)", repr(matrix))
        m.flags.writeable = False
        self.matrix = m

    @property
    def position(self) -> np.ndarray:
        """The tracker origin in the world [3] [m]."""
        return self.matrix[:3, 3].copy()

    @property
    def yaw(self) -> float:
        """Heading [rad] about +z of the tracker's +y axis, in (-pi, pi]."""
        forward = self.matrix[:3, 1]
        return math.atan2(-forward[0], forward[1])

    @property
    def right(self) -> np.ndarray:
        """The tracker's +x in the world [3]."""
        return self.matrix[:3, 0].copy()

    @property
    def forward(self) -> np.ndarray:
        """The tracker's +y (towards the front screen) in the world [3]."""
        return self.matrix[:3, 1].copy()

    @property
    def up(self) -> np.ndarray:
        """The tracker's +z in the world [3]."""
        return self.matrix[:3, 2].copy()

    def to_world(self, points) -> np.ndarray:
        """World positions [k, 3] [m] of tracker-frame points [k, 3] (or one point [3]) [m]."""
        p = np.asarray(points, float)
        return p @ self.matrix[:3, :3].T + self.matrix[:3, 3]

    def __repr__(self) -> str:
        return f"UserPose(position={self.position.round(6).tolist()}, yaw={self.yaw:.6g})"


def move(user: UserPose, forward_m: float = 0.0, right_m: float = 0.0, up_m: float = 0.0) -> UserPose:
    """``user`` moved [m] along its own forward (the front screen's direction), right and up
    axes (first-person walking; with a pure heading, forward and right stay horizontal)."""
    step = np.eye(4)
    step[:3, 3] = [_number(right_m, "right_m", "m"), _number(forward_m, "forward_m", "m"), _number(up_m, "up_m", "m")]
    return UserPose(matrix=user.matrix @ step)


def turn(user: UserPose, yaw_rad: float, about=(0.0, 0.0, 0.0)) -> UserPose:
    """``user`` turned by ``yaw_rad`` [rad] (positive: to the left) about its up axis through
    ``about`` [3] [m] in the tracker frame: the origin turns about the CAVE's centre, the
    head's position turns the viewer in place."""
    c = np.asarray(about, float)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise InputError("about", "a point [3] [m] in the tracker frame", repr(about))
    spin = np.eye(4)
    spin[:3, :3] = _rotation_z(_number(yaw_rad, "yaw_rad", "rad"))
    spin[:3, 3] = c - spin[:3, :3] @ c
    return UserPose(matrix=user.matrix @ spin)


def world_view(screen: Screen, eye, user: UserPose | None = None, *, near: float = 0.05,
               far: float = 100.0) -> ScreenView:
    """The off-axis camera of ``screen`` for an ``eye`` [3] [m] in the tracker frame, with the
    screen and the eye carried into the world by ``user`` (default: world = tracker frame)."""
    if user is None:
        return screen.view(eye, near=near, far=far)
    ll, lr, ul, pe = user.to_world(np.array([screen.lower_left, screen.lower_right, screen.upper_left, eye], float))
    try:
        return screen_view(ll, lr, ul, pe, near=near, far=far, name=screen.name)
    except InputError as exc:
        if screen.source is None or exc.source is not None:
            raise
        # An eye in the plane of a screen read from a file: the file is named, as Screen.view does.
        raise InputError(exc.what, exc.expected, exc.found, source=screen.source) from None


class CameraRig:
    """The virtual camera cluster of a display, attached to a user entity (thesis 6.2).

    Parameters
    ----------
    display : Display
        The screens (tracker frame) and the eye separation [m].
    near, far : float [m]
        Clipping distances of every camera.

    Attributes
    ----------
    master : str
        The master screen: ``"front"`` when there is one (the thesis' choice), else the first.
    """

    def __init__(self, display: Display, *, near: float = 0.05, far: float = 100.0):
        if not isinstance(display, Display):
            raise InputError("display", "a Display (softvr.cave.preset or load_display)", type(display).__name__)
        if not (0 < near < far):
            raise InputError("near / far", "0 < near < far [m]", f"{near}, {far}")
        self.display, self.near, self.far = display, float(near), float(far)
        names = [s.name for s in display.screens]
        self.master = "front" if "front" in names else names[0]

    def eye(self, head: HeadPose, eye: str = "mono") -> np.ndarray:
        """The eye position [3] [m] in the tracker frame: the head's for ``"mono"``, else -/+
        half the display's eye separation along the head's right axis."""
        if not isinstance(head, HeadPose):
            raise InputError("head", "a HeadPose", type(head).__name__)
        if eye not in EYES:
            raise InputError("eye", " | ".join(EYES), repr(eye))
        if eye == "mono":
            return np.asarray(head.position, float)
        left, right = self.display.eyes(head.position, head.right)
        return left if eye == "left" else right

    def view(self, name: str, user: UserPose | None, head: HeadPose, eye: str = "mono") -> ScreenView:
        """The world-space camera of screen ``name`` (see :meth:`views`)."""
        return world_view(self.display.screen(name), self.eye(head, eye), user, near=self.near, far=self.far)

    def views(self, user: UserPose | None, head: HeadPose, eye: str = "mono") -> dict:
        """Screen name -> world-space :class:`~softvr.cave.ScreenView` for the ``user`` entity
        (None: world = tracker frame), the tracked ``head`` and ``eye`` ("mono", "left",
        "right")."""
        e = self.eye(head, eye)
        return {s.name: world_view(s, e, user, near=self.near, far=self.far) for s in self.display.screens}
