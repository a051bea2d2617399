"""Haptic devices: where the user's hand is, and where the force goes back to.

A device is anything with ``position() -> [3] [m]`` and ``send_force(force [3] [N])``: the
haptic loop reads one and writes the other at 1 kHz from its own thread, so both must be
cheap and thread-safe. :class:`ScriptedDevice` follows a path (tests, benchmarks, demos run
headless); :class:`MouseDevice` is moved by the viewer. A real device (a Phantom, a Falcon,
a Virtuose through its SDK) plugs in by subclassing :class:`HapticDevice`.
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable

import numpy as np

from softvr.errors import InputError

__all__ = ["HapticDevice", "MouseDevice", "ScriptedDevice"]


def _point(value, what: str) -> np.ndarray:
    p = np.asarray(value, float)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise InputError(what, "a finite 3-vector [m]", repr(value))
    return p


class HapticDevice:
    """The plug-in point for haptic devices.

    Subclasses implement :meth:`position` and may override :meth:`send_force` (the default
    keeps the last force, for devices without force output and for inspection).

    Attributes
    ----------
    last_force : ndarray, shape [3] [N]
        The force most recently sent.
    forces_sent : int
    """

    def __init__(self):
        self.last_force = np.zeros(3)
        self.forces_sent = 0

    def position(self) -> np.ndarray:
        """Current handle position [3] [m], in the scene's frame."""
        raise NotImplementedError

    def send_force(self, force: np.ndarray) -> None:
        """Render ``force`` [3] [N] on the user's hand."""
        self.last_force = np.asarray(force, float).copy()
        self.forces_sent += 1


class ScriptedDevice(HapticDevice):
    """A hand that follows ``path(t) -> [3] [m]``.

    ``t`` is ``clock()`` when a clock is given (e.g. ``lambda: scene.time``: the hand moves
    with simulated time, so a headless run slower than real time follows the same path), else
    wall-clock seconds since :meth:`start` (or since the first reading).
    """

    def __init__(self, path: Callable[[float], np.ndarray], *, clock: Callable[[], float] | None = None):
        super().__init__()
        if not callable(path):
            raise InputError("path", "a callable t [s] -> position [3] [m]", type(path).__name__)
        if clock is not None and not callable(clock):
            raise InputError("clock", "a callable () -> time [s]", type(clock).__name__)
        self.path = path
        self.clock = clock
        self._t0: float | None = None

    def start(self) -> None:
        """Start the path's wall clock now."""
        self._t0 = time.perf_counter()

    def elapsed(self) -> float:
        """The path's time [s]: ``clock()``, or seconds since :meth:`start`."""
        if self.clock is not None:
            return float(self.clock())
        if self._t0 is None:
            self.start()
        assert self._t0 is not None  # set by start()
        return time.perf_counter() - self._t0

    def position(self) -> np.ndarray:
        return _point(self.path(self.elapsed()), "ScriptedDevice.path(t)")


class MouseDevice(HapticDevice):
    """A hand moved by mouse events (the viewer calls :meth:`move_to`). Its position lives in
    shared memory, so a haptic loop in another process sees the moves."""

    def __init__(self, position=(0.0, 0.0, 0.0)):
        super().__init__()
        self._shared = multiprocessing.RawArray("d", 3)
        self._position = np.frombuffer(self._shared, dtype=np.float64)
        self._position[:] = _point(position, "position")

    def move_to(self, position) -> None:
        """Set the handle position [3] [m]."""
        self._position[:] = _point(position, "position")

    def position(self) -> np.ndarray:
        return self._position.copy()
