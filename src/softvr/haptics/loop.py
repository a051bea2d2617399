"""The 1 kHz haptic loop, coupled multi-rate to the simulation (thesis 5.4, after [GO09]).

The simulation runs at tens of hertz, a hand needs forces at 1 kHz. After each simulation step
the tool publishes a *handle-space linearization* of its force: the force ``F0`` it feels at
handle position ``x0`` and the stiffness ``K = dF/dx`` around it (:class:`HandleModel`).
In between, the loop reads the device every millisecond and renders

    F = F0 + K (x - x0),

which responds to the hand at 1 kHz (pressing further into tissue pushes back harder at once)
while the deformation itself is computed at the simulation's rate.

The loop runs in its own process (``process=True``: the thesis gives it its own core; a
thread shares the interpreter lock with the simulation, whose long calls delay it by
milliseconds) or thread. Both talk through one block of shared memory: the model (written
under a sequence counter, so the loop never reads half of one), the last handle position and
force, the simulation clock, and a ring of the last 65 536 loop periods. Ticks are scheduled
on absolute times (``t0 + n T``), so a late tick does not shift the ones after it; the loop
sleeps until just before each tick, then spins. How long before is learnt from how late its
sleeps wake (:class:`_SpinWindow`): every microsecond it spins is taken from the simulation on a
2-core machine. Its period statistics are what ``softvr bench shoulder`` reports.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softvr.errors import InputError
from softvr.haptics.devices import HapticDevice

__all__ = ["HandleModel", "HapticLoop"]

# Shared block layout (float64 slots).
_X0, _F0, _K = slice(0, 3), slice(3, 6), slice(6, 15)
_SEQ, _TIME, _TICKS, _COUNT = 15, 16, 17, 18
_POS, _FORCE = slice(19, 22), slice(22, 25)
_RING_START, _RING = 25, 65536


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


def _render(data: np.ndarray, device: HapticDevice, max_force: float) -> np.ndarray:
    """One loop iteration on the shared block: read the device, render the model's force."""
    x = np.asarray(device.position(), float).tolist()
    while True:  # seqlock read: retry while the simulation is writing a model
        seq = data[_SEQ]
        model = data[:_SEQ].tolist()  # x0, F0, K row-major
        if seq == data[_SEQ] and seq % 2 == 0:
            break
    # In floats, not NumPy: a dozen NumPy calls a tick were ~25 us of the loop's 1 kHz (and the
    # forked loop process must not touch a BLAS thread pool); same sums in the same order.
    d = [x[i] - model[i] for i in range(3)]
    force = [model[3 + r] + (model[6 + 3 * r] * d[0] + model[7 + 3 * r] * d[1] + model[8 + 3 * r] * d[2])
             for r in range(3)]
    magnitude = (force[0] * force[0] + force[1] * force[1] + force[2] * force[2]) ** 0.5
    if magnitude > max_force:
        force = [f * (max_force / magnitude) for f in force]
    out = np.array(force)
    device.send_force(out)
    data[_POS], data[_FORCE] = x, force
    data[_TICKS] += 1
    return out


class _SpinWindow:
    """How long before a tick the loop stops sleeping and spins [s]: the 99th percentile of
    its last :data:`SPIN_SAMPLES` sleeps' overshoots (how much later than asked a sleep woke)
    plus :data:`SPIN_MARGIN`, within [:data:`SPIN_FLOOR`, :data:`SPIN_CAP`], recomputed every
    :data:`SPIN_UPDATE` sleeps; :data:`SPIN_CAP` until the first recomputation. An idle
    machine's sleeps overshoot by tens of microseconds, so the loop spins that long instead of
    a fixed 0.2 ms; a loaded one's 99th percentile is a preemption of milliseconds, which no
    spin fixes (the spinning process is preempted as well), hence the cap."""

    __slots__ = ("overshoots", "count", "seconds")

    def __init__(self):
        self.overshoots = np.zeros(SPIN_SAMPLES)
        self.count = 0
        self.seconds = SPIN_CAP

    def record(self, overshoot: float) -> None:
        """One sleep's overshoot [s] (negative where it woke early)."""
        self.overshoots[self.count % SPIN_SAMPLES] = overshoot
        self.count += 1
        if self.count % SPIN_UPDATE == 0:
            seen = self.overshoots[:min(self.count, SPIN_SAMPLES)]
            worst = float(np.partition(seen, int(0.99 * (len(seen) - 1)))[int(0.99 * (len(seen) - 1))])
            self.seconds = min(SPIN_CAP, max(SPIN_FLOOR, worst + SPIN_MARGIN))


#: Spin window bounds [s] (:class:`_SpinWindow`). A tick later than the cap is still 14 times within
#: the period p99 target's 0.5 ms slack (issue 16: p99 <= 1.5 ms); the fixed window was 0.2 ms and
#: spun ~120 us a tick at load 10, the capped one ~70 (sleeps woken with 1 us slack, ~30 us late).
SPIN_FLOOR, SPIN_CAP = 5e-5, 1e-4
#: Added to the overshoots' 99th percentile [s] (:class:`_SpinWindow`).
SPIN_MARGIN = 2e-5
#: Overshoots the window is learnt from, and how often it is recomputed (:class:`_SpinWindow`).
SPIN_SAMPLES, SPIN_UPDATE = 1024, 128


def _fine_timer_slack() -> None:
    """Ask Linux to wake this thread's sleeps within 1 us of their time instead of the default
    50 us slack (``prctl(PR_SET_TIMERSLACK)``); elsewhere nothing."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None).prctl(29, 1000, 0, 0, 0)


def _run(shared, device: HapticDevice, period: float, max_force: float, stop, *,
         clock=time.perf_counter, sleep=time.sleep) -> None:
    """The loop: ticks at ``t0 + n period`` until ``stop`` is set, then a zero force. It sleeps
    until :class:`_SpinWindow` before each tick and spins the rest (``clock`` [s] and ``sleep``
    are the time's, replaced in tests)."""
    _fine_timer_slack()
    data = np.frombuffer(shared, dtype=np.float64)
    ring = data[_RING_START:]
    window = _SpinWindow()
    t0 = clock()
    last = None
    n = 0
    while not stop.is_set():
        n += 1
        target = t0 + n * period
        remaining = target - clock()
        if remaining > window.seconds + SPIN_FLOOR:  # a shorter sleep would overshoot its whole length
            sleep(remaining - window.seconds)
            window.record(clock() - (target - window.seconds))
        while clock() < target:
            pass
        now = clock()
        if last is not None:
            count = int(data[_COUNT])
            ring[count % _RING] = now - last
            data[_COUNT] = count + 1
        last = now
        _render(data, device, max_force)
    device.send_force(np.zeros(3))


class HapticLoop:
    """Reads a device and sends it forces at ``rate`` Hz, in a process or a thread.

    Parameters
    ----------
    device : HapticDevice
        In a process, the loop works on a copy of the device (fork): its inputs must come
        through shared memory (:class:`~softvr.haptics.MouseDevice` does; a
        :class:`~softvr.haptics.ScriptedDevice` should use :meth:`simulation_clock`).
    rate : float [Hz]
        Loop rate (1000 by default).
    max_force : float [N]
        Forces are clipped to this magnitude (protects the device and the hand).
    process : bool
        Run in a separate process (its own interpreter lock) instead of a thread.
    """

    def __init__(self, device: HapticDevice, *, rate: float = 1000.0, max_force: float = 10.0, process: bool = False):
        if not isinstance(device, HapticDevice):
            raise InputError("device", "a softvr.haptics.HapticDevice", type(device).__name__)
        if not (np.isfinite(rate) and 1.0 <= rate <= 20000.0):
            raise InputError("rate", "a loop rate in [1, 20000] Hz", repr(rate))
        if not (np.isfinite(max_force) and max_force > 0):
            raise InputError("max_force", "a force limit > 0 [N]", repr(max_force))
        self.device = device
        self.period = 1.0 / float(rate)
        self.max_force = float(max_force)
        self.process = bool(process)
        self._shared = multiprocessing.RawArray("d", _RING_START + _RING)
        self._data = np.frombuffer(self._shared, dtype=np.float64)
        self._data[_POS] = np.asarray(device.position(), float)
        self._runner: Any = None  # while running: a multiprocessing Process or a threading Thread
        self._stop: Any = None  # and its Event (of multiprocessing or threading)
        self._switch_interval: float | None = None

    # -- the simulation's side -------------------------------------------------------------
    def publish(self, model: HandleModel, time: float | None = None) -> None:
        """Hand the loop a new linearization (and the simulation ``time`` [s], see
        :meth:`simulation_clock`)."""
        d = self._data
        d[_SEQ] += 1  # odd: writing
        d[_X0], d[_F0], d[_K] = model.position, model.force, np.asarray(model.stiffness, float).ravel()
        d[_SEQ] += 1
        if time is not None:
            d[_TIME] = time

    def simulation_clock(self) -> float:
        """The simulation time [s] last published: a clock a scripted device can follow from
        the loop's process."""
        return float(self._data[_TIME])

    def handle_position(self) -> np.ndarray:
        """The device position [3] [m] the loop read last (the simulation's handle target)."""
        return self._data[_POS].copy()

    @property
    def ticks(self) -> int:
        """Loop iterations so far."""
        return int(self._data[_TICKS])

    def last_force(self) -> np.ndarray:
        """The force [3] [N] the loop sent last."""
        return self._data[_FORCE].copy()

    # -- the loop --------------------------------------------------------------------------
    def start(self) -> "HapticLoop":
        """Start the loop's process or thread."""
        if self._runner is not None:
            raise InputError("HapticLoop.start", "a loop that is not running", "already started")
        args = (self._shared, self.device, self.period, self.max_force)
        if self.process:
            context = multiprocessing.get_context("fork")
            self._stop = context.Event()
            self._runner = context.Process(target=_run, args=(*args, self._stop), name="softvr-haptics", daemon=True)
        else:
            # The interpreter hands its lock over every 5 ms by default; a 1 ms loop needs it sooner.
            self._switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(min(self._switch_interval, 1e-4))
            self._stop = threading.Event()
            self._runner = threading.Thread(target=_run, args=(*args, self._stop), name="softvr-haptics", daemon=True)
        self._runner.start()
        return self

    def stop(self) -> None:
        """Stop the loop and wait for it (it sends a zero force last)."""
        if self._runner is None:
            return
        self._stop.set()
        self._runner.join(timeout=5.0)
        if self.process and self._runner.is_alive():
            self._runner.terminate()
        self._runner = None
        if self._switch_interval is not None:
            sys.setswitchinterval(self._switch_interval)
            self._switch_interval = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def tick(self) -> np.ndarray:
        """One iteration here and now (no loop running): read the device, render the model's
        force; returns it [3] [N]."""
        return _render(self._data, self.device, self.max_force)

    def period_stats(self) -> dict:
        """Loop periods of the last 65 536 ticks: ``count`` (all ticks timed), ``p50_ms``,
        ``p99_ms``, ``max_ms``, ``rate_hz`` (mean rate over the window)."""
        count = int(self._data[_COUNT])
        if count == 0:
            return {"count": 0, "p50_ms": None, "p99_ms": None, "max_ms": None, "rate_hz": None}
        periods = self._data[_RING_START:_RING_START + min(count, _RING)] * 1e3
        return {"count": count, "p50_ms": float(np.percentile(periods, 50)), "p99_ms": float(np.percentile(periods, 99)),
                "max_ms": float(periods.max()), "rate_hz": float(1e3 / periods.mean())}
