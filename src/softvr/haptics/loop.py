"""The 1 kHz haptic loop, coupled multi-rate to the simulation (thesis 5.4, after [GO09]).

The simulation runs at tens of hertz, a hand needs forces at 1 kHz. After each simulation step
the tool publishes a *handle-space linearization* of its force: the force ``F0`` it feels at
handle position ``x0`` and the stiffness ``K = dF/dx`` around it (:class:`HandleModel`).
In between, the loop reads the device every millisecond and renders

    F = F0 + K (x - x0),

which responds to the hand at 1 kHz (pressing further into tissue pushes back harder at once)
while the deformation itself is computed at the simulation's rate.

The loop runs in a daemon thread; its ticks are scheduled on absolute times (``t0 + n T``), so
a late tick does not shift the ones after it, and it sleeps until just before each tick, then
spins, to keep the period within tens of microseconds. Its period statistics are what
``softvr bench shoulder`` reports.
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from softvr.errors import InputError
from softvr.haptics.devices import HapticDevice

__all__ = ["HandleModel", "HapticLoop"]


@dataclass(frozen=True)
class HandleModel:
    """The tool's force linearized at the handle (what the simulation tells the loop).

    Attributes
    ----------
    position : ndarray, shape [3] [m]
        Handle position ``x0`` the model was made at.
    force : ndarray, shape [3] [N]
        Force ``F0`` on the hand there.
    stiffness : ndarray, shape [3, 3] [N/m]
        ``K = dF/dx`` (negative semi-definite: pushing in is resisted).
    """

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    stiffness: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    def force_at(self, x: np.ndarray) -> np.ndarray:
        """``F0 + K (x - x0)`` [3] [N]."""
        return self.force + self.stiffness @ (np.asarray(x, float) - self.position)


class HapticLoop:
    """Reads a device and sends it forces at ``rate`` Hz from a thread.

    Parameters
    ----------
    device : HapticDevice
    rate : float [Hz]
        Loop rate (1000 by default).
    max_force : float [N]
        Forces are clipped to this magnitude (protects the device and the hand).

    Attributes
    ----------
    ticks : int
        Loop iterations so far.
    """

    def __init__(self, device: HapticDevice, *, rate: float = 1000.0, max_force: float = 10.0):
        if not isinstance(device, HapticDevice):
            raise InputError("device", "a softvr.haptics.HapticDevice", type(device).__name__)
        if not (np.isfinite(rate) and 1.0 <= rate <= 20000.0):
            raise InputError("rate", "a loop rate in [1, 20000] Hz", repr(rate))
        if not (np.isfinite(max_force) and max_force > 0):
            raise InputError("max_force", "a force limit > 0 [N]", repr(max_force))
        self.device = device
        self.period = 1.0 / float(rate)
        self.max_force = float(max_force)
        self.ticks = 0
        self._model = HandleModel()
        self._position = np.asarray(device.position(), float)
        self._stamps: list[float] = []
        self._stop = threading.Event()
        self._thread = None
        self._switch_interval = None

    # -- the simulation's side -------------------------------------------------------------
    def publish(self, model: HandleModel) -> None:
        """Hand the loop a new linearization (one reference swap: no lock needed)."""
        self._model = model

    def handle_position(self) -> np.ndarray:
        """The device position [3] [m] the loop read last (the simulation's handle target)."""
        return self._position.copy()

    # -- the loop --------------------------------------------------------------------------
    def start(self) -> "HapticLoop":
        """Start the thread."""
        if self._thread is not None:
            raise InputError("HapticLoop.start", "a loop that is not running", "already started")
        # The interpreter hands the GIL over every 5 ms by default; a 1 ms loop needs it faster.
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch_interval, 1e-4))
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="softvr-haptics", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and wait for it; sends a zero force last."""
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join()
        self._thread = None
        sys.setswitchinterval(self._switch_interval)
        self.device.send_force(np.zeros(3))

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _run(self) -> None:
        t0 = time.perf_counter()
        n = 0
        while not self._stop.is_set():
            n += 1
            target = t0 + n * self.period
            remaining = target - time.perf_counter()
            if remaining > 3e-4:
                time.sleep(remaining - 2e-4)
            while time.perf_counter() < target:
                pass
            self._stamps.append(time.perf_counter())
            self.tick()

    def tick(self) -> np.ndarray:
        """One loop iteration: read the device, render the linearized force; returns it [3] [N]."""
        x = np.asarray(self.device.position(), float)
        self._position = x
        force = self._model.force_at(x)
        magnitude = float(np.linalg.norm(force))
        if magnitude > self.max_force:
            force = force * (self.max_force / magnitude)
        self.device.send_force(force)
        self.ticks += 1
        return force

    def period_stats(self) -> dict:
        """Loop periods so far: ``count``, ``p50_ms``, ``p99_ms``, ``max_ms``, ``rate_hz`` (the
        mean rate)."""
        stamps = np.array(self._stamps)
        if len(stamps) < 2:
            return {"count": 0, "p50_ms": None, "p99_ms": None, "max_ms": None, "rate_hz": None}
        periods = np.diff(stamps) * 1e3
        return {"count": int(len(periods)), "p50_ms": float(np.percentile(periods, 50)),
                "p99_ms": float(np.percentile(periods, 99)), "max_ms": float(periods.max()),
                "rate_hz": float(len(periods) / (stamps[-1] - stamps[0]))}
