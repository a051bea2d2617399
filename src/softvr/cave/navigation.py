"""Keyboard and mouse navigation of the user entity: the master's interactive input (thesis 6.2.2).

The master of a cluster owns the input; nodes only ever see its result, the user pose and the
events, in each frame. :class:`KeyboardNavigation` turns held keys and mouse drags into
first-person motion of the :class:`~softvr.cave.UserPose` (walk at ``speed`` [m/s], turn at
``turn_rate`` [rad/s], integrated over each frame's time step) and single key presses into
application events:

=================  ===========================================
keys               action
=================  ===========================================
w / Up, s / Down   walk forward / back
a, d               step left / right
r, f               rise / sink
q / Left, e / Right  turn left / right
left-button drag   turn (``mouse_gain`` [rad / pixel])
space              event ``toggle paused``
1 ... 9            event ``toggle flag1`` ... ``flag9``
=================  ===========================================

It is a navigation callable for :class:`~softvr.cave.cluster.Master` (``navigation(n, t)``
-> user pose, head, events); :meth:`attach` connects it to a VTK window's interactor.
"""

from __future__ import annotations

import numpy as np

from softvr.cave.rig import UserPose, move, turn
from softvr.errors import InputError

__all__ = ["KeyboardNavigation"]

_WALK = {"w": (1, 0, 0), "up": (1, 0, 0), "s": (-1, 0, 0), "down": (-1, 0, 0), "a": (0, -1, 0), "d": (0, 1, 0),
         "r": (0, 0, 1), "f": (0, 0, -1)}
_TURN = {"q": 1.0, "left": 1.0, "e": -1.0, "right": -1.0}


class KeyboardNavigation:
    """First-person navigation from keys and mouse (module docstring).

    Parameters
    ----------
    start : UserPose or array_like [4, 4], optional
        The user entity's first pose (world <- tracker); default the identity.
    speed : float [m/s]
    turn_rate : float [rad/s]
    mouse_gain : float [rad/pixel]
        Turn per pixel of horizontal drag (right: turn right).
    pivot : array_like, shape [3] [m]
        Point of the tracker frame turns are about (default the viewer's usual spot, the
        CAVE's centre).
    """

    def __init__(self, start=None, *, speed: float = 1.0, turn_rate: float = 0.8, mouse_gain: float = 0.005,
                 pivot=(0.0, 0.0, 0.0)):
        for name, v in (("speed", speed), ("turn_rate", turn_rate), ("mouse_gain", mouse_gain)):
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise InputError(name, "a non-negative number", repr(v))
        self.user = start if isinstance(start, UserPose) else UserPose(matrix=np.eye(4) if start is None else start)
        self.speed, self.turn_rate, self.mouse_gain = float(speed), float(turn_rate), float(mouse_gain)
        self.pivot = np.asarray(pivot, float)
        self.held: set[str] = set()
        self._events: list = []
        self._drag_turn = 0.0
        self._last_t: float | None = None
        self._drag_x: int | None = None

    # ------------------------------------------------------------------- input
    def key_down(self, key: str) -> None:
        """A key went down (VTK key symbols: ``w``, ``Up``, ``space``, ``1`` ...)."""
        k = key.lower()
        if k == "space":
            self._events.append(("toggle", ("paused",)))
        elif len(k) == 1 and k in "123456789":
            self._events.append(("toggle", (f"flag{k}",)))
        elif k in _WALK or k in _TURN:
            self.held.add(k)

    def key_up(self, key: str) -> None:
        self.held.discard(key.lower())

    def drag(self, dx_pixels: float) -> None:
        """Horizontal mouse drag [pixels] with the left button held (right: turn right)."""
        self._drag_turn -= self.mouse_gain * float(dx_pixels)

    # --------------------------------------------------------------- per frame
    def __call__(self, n: int, t: float):
        """The user pose [4, 4] at frame ``n``, time ``t`` [s] (the keys held since the last
        call integrated over the time between), no head (the tracker's), and the events of
        the key presses since the last call."""
        dt = 0.0 if self._last_t is None else max(float(t) - self._last_t, 0.0)
        self._last_t = float(t)
        walk = np.sum([_WALK[k] for k in self.held if k in _WALK], axis=0) if self.held & _WALK.keys() else np.zeros(3)
        yaw = sum(_TURN[k] for k in self.held if k in _TURN) * self.turn_rate * dt + self._drag_turn
        self._drag_turn = 0.0
        if yaw:
            self.user = turn(self.user, yaw, about=self.pivot)
        if walk.any():
            forward, right, up = self.speed * dt * walk
            self.user = move(self.user, forward_m=forward, right_m=right, up_m=up)
        events, self._events = self._events, []
        return self.user.matrix, None, events

    # -------------------------------------------------------------------- VTK
    def attach(self, interactor) -> None:
        """Follow the keys and left-button drags of a ``vtkRenderWindowInteractor`` (call its
        ``ProcessEvents()`` once per frame). Its interactor style becomes a passive one: the
        camera is the screen's off-axis view, and a trackball style would both move it and
        grab the mouse events after a button press."""
        from vtkmodules.vtkInteractionStyle import vtkInteractorStyleUser  # noqa: PLC0415

        interactor.SetInteractorStyle(vtkInteractorStyleUser())
        def key_press(obj, _event) -> None:
            self.key_down(obj.GetKeySym() or "")

        def key_release(obj, _event) -> None:
            self.key_up(obj.GetKeySym() or "")

        def button(obj, event) -> None:
            self._drag_x = obj.GetEventPosition()[0] if event == "LeftButtonPressEvent" else None

        def mouse_move(obj, _event) -> None:
            if self._drag_x is not None:
                x = obj.GetEventPosition()[0]
                self.drag(x - self._drag_x)
                self._drag_x = x

        interactor.AddObserver("KeyPressEvent", key_press)
        interactor.AddObserver("KeyReleaseEvent", key_release)
        interactor.AddObserver("LeftButtonPressEvent", button)
        interactor.AddObserver("LeftButtonReleaseEvent", button)
        interactor.AddObserver("MouseMoveEvent", mouse_move)
