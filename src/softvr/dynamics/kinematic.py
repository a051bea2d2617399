"""Contact objects of infinite mass: fixed carriers and scripted (kinematic) bodies.

Both share the rigid-frame state of :class:`~softvr.dynamics.rigid.RigidFrame` (position ``c``
[3], orientation quaternion (w, x, y, z), ``v = (v_lin, omega)`` [6] with ``omega`` in the world
frame), so point entities treat them like rigid bodies. Their mass is infinite: no force or
impulse changes their motion, so ``A^-1 = 0`` and :meth:`solve` returns zeros.

* :class:`FixedBody` never moves: ground, walls, a clamped bone.
* :class:`KinematicBody` follows a scripted pose ``pose(t) -> (position, quaternion)``: a tool,
  a finger, a moving wall. Its step velocity is the finite difference that carries it from
  ``pose(t)`` to ``pose(t + dt)``::

      v_lin = (c(t + dt) - c(t)) / dt,   omega = log(quat(t + dt) (x) quat(t)^*) / dt

  (``log`` the rotation vector of the relative rotation, the shortest one), i.e. exactly the
  constant velocity whose :class:`~softvr.dynamics.rigid.RigidBody`-style integration
  (``c += dt v_lin``, ``quat = exp(omega dt) (x) quat``) lands on ``pose(t + dt)``. It is a first-order
  (mean-over-the-step) approximation of the instantaneous velocity ``pose'(t)``: the error is at
  most ``dt/2 max |c''|`` (linear) and, for rotation about a fixed axis, ``dt/2 max |theta''|``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction

import numpy as np
import scipy.sparse as sp

from softvr.dynamics.body import StepSystem
from softvr.dynamics.rigid import RigidFrame, _unit_quaternion, _vector, quat_conjugate, quat_multiply, quat_to_rotvec
from softvr.errors import InputError

__all__ = ["FixedBody", "KinematicBody"]

#: How far from 1 a pose's quaternion norm may be and be kept bit for bit (round-off).
_UNIT_TOLERANCE = 4 * np.finfo(float).eps


def _finite_copy(value, n: int) -> np.ndarray | None:
    """A copy of ``value`` if it is a float64 array of shape [n] with finite entries (what a
    pose function gives), else None (the caller checks and reports it as ``_vector`` does)."""
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (n,) and \
            all(map(math.isfinite, value.tolist())):
        return value.copy()
    return None


class _InfiniteMass(RigidFrame):
    """Shared behaviour of bodies no force can move."""

    mass = math.inf
    infinite_mass = True

    def solve(self, rhs) -> np.ndarray:
        """``A^-1 rhs = 0``: infinite mass, impulses change nothing. ``rhs`` [6] or [k, 6]."""
        rhs = np.asarray(rhs, float)
        if rhs.shape[-1:] != (6,) or rhs.ndim > 2:
            raise InputError("rhs", "shape [6] or [k, 6]", f"shape {rhs.shape}")
        return np.zeros_like(rhs)

    def solve_columns(self, columns) -> np.ndarray:
        """``A^-1 C = 0`` for ``C`` [6, k]."""
        cols = np.asarray(columns, float)
        if cols.ndim != 2 or cols.shape[0] != 6:
            raise InputError("columns", "shape [6, k]", f"shape {cols.shape}")
        return np.zeros_like(cols)

    def step_system(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> StepSystem:
        """All six velocities prescribed at this step's :meth:`unconstrained_velocity` (``A = I``)."""
        v = self.unconstrained_velocity(dt, gravity, external)
        return StepSystem(sp.identity(6, format="csr"), v.copy(), np.ones(6, bool), v)

    def immovable(self, blocks) -> np.ndarray:
        """All of them: no impulse moves an infinite mass (bool, the shape of ``blocks``)."""
        return np.ones(np.shape(blocks), bool)

    def kinetic_energy(self) -> float:
        """0 [J]: the motion is prescribed, not dynamic (the mass is infinite)."""
        return 0.0

    def _check_finite(self, v) -> np.ndarray:
        # The solver's [6] float64 velocity (every step, every such body) on its floats.
        v1 = v.copy() if type(v) is np.ndarray and v.dtype == np.float64 and v.shape == (6,) \
            else self._check_velocity(v)
        if not all(map(math.isfinite, v1.tolist())):
            raise self._diverged("velocity NaN/inf")
        return v1


class FixedBody(_InfiniteMass):
    """A body that never moves (infinite mass, ``v = 0``): ground, wall, clamped bone.

    Parameters
    ----------
    position : array_like, shape [3] [m]
        Frame origin in the world.
    orientation : array_like, shape [4]
        Quaternion (w, x, y, z), body to world; normalized (zero or non-finite is rejected).
    name : str

    Attributes
    ----------
    position, orientation, v (zeros [6]), step_count, mass (``inf``)
    """

    def __init__(self, position=(0.0, 0.0, 0.0), orientation=(1.0, 0.0, 0.0, 0.0), *, name: str = "fixed body"):
        self.name = name
        self.position = _vector(position, 3, "position", "m")
        self.orientation = _unit_quaternion(orientation, "orientation")
        self.v = np.zeros(6)
        self.step_count = 0

    def unconstrained_velocity(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> np.ndarray:
        """Zeros [6]: forces (gravity, ``external``) cannot move an infinite mass."""
        self._check_dt(dt)
        self._check_external(external)
        return np.zeros(6)

    def integrate(self, v, dt: float) -> None:
        """Count the step; the body stays put. ``v`` (the solver's, ``0 + A^-1 J^T lambda = 0``)
        is only checked to be finite."""
        self._check_dt(dt)
        self._check_finite(v)
        self.step_count += 1


class KinematicBody(_InfiniteMass):
    """A body moving along a scripted pose, unaffected by forces (infinite mass).

    Parameters
    ----------
    pose : callable
        ``pose(t) -> (position [3] [m], quaternion [4] (w, x, y, z))`` at time ``t`` [s], body
        to world. Quaternions that are unit to round-off are kept bit for bit; others are
        normalized.
    t0 : float [s]
        Start time.
    name : str

    Attributes
    ----------
    position, orientation
        ``pose(time)`` exactly.
    v : ndarray, shape [6] [m/s, rad/s]
        Velocity of the last step (zeros before the first).
    time : float [s]
        ``t0`` plus the sum of the steps' ``dt``, accumulated exactly (then rounded once), so
        after ``n`` steps of ``dt`` from 0 it is the float ``n * dt``.
    step_count, mass (``inf``)
    """

    def __init__(self, pose: Callable, *, t0: float = 0.0, name: str = "kinematic body"):
        if not callable(pose):
            raise InputError("pose", "a callable pose(t) -> (position [3], quaternion (w, x, y, z))",
                             type(pose).__name__)
        if not (isinstance(t0, (int, float, np.floating)) and np.isfinite(t0)):
            raise InputError("t0", "a finite start time [s]", repr(t0))
        self.name = name
        self.pose = pose
        self._t = Fraction(float(t0))
        self.position, self.orientation = self._evaluate(self._t)
        self.v = np.zeros(6)
        self.step_count = 0
        self._target: tuple | None = None  # (t1, position, orientation, velocity) of the next key
        self._target_for: tuple = (None, 0.0)  # (time object, dt) _target was made for
        # (dt, Fraction(dt)) of the last step: Fraction of a float checks it against numbers.Rational
        # (an ABC), ~13 us a step in a palpation step's cold cache, the same every step.
        self._exact_dt: tuple = (None, None)
        self._still: tuple = (None, None)  # (q1, orientation, dt) and the angular velocity of _angular

    @property
    def time(self) -> float:
        """Current time [s]."""
        return float(self._t)

    def _evaluate(self, t: Fraction) -> tuple[np.ndarray, np.ndarray]:
        tf = float(t)
        out = self.pose(tf)
        try:
            c, q = out
        except (TypeError, ValueError):
            raise InputError(f"{self.name}: pose({tf!r})", "a pair (position [3], quaternion (w, x, y, z))",
                             "something else") from None
        c, q = _finite_copy(c, 3), _finite_copy(q, 4)
        if c is None or q is None:  # named and reported as the checks do
            what = f"{self.name}: pose({tf!r})"
            c = _vector(out[0], 3, f"{what} position", "m")
            q = _vector(out[1], 4, f"{what} quaternion", "(w, x, y, z)")
        # np.linalg.norm of a vector is sqrt(q . q): the same bits, without its dispatch (each
        # kinematic body evaluates its pose every step).
        if abs(math.sqrt(q.dot(q)) - 1.0) > _UNIT_TOLERANCE:
            q = _unit_quaternion(q, f"{self.name}: pose({tf!r}) quaternion")
        return c, q

    def _step_to(self, dt: float):
        """Pose at ``time + dt`` and the velocity that reaches it (cached for this step: the
        integration asks again with the same time and ``dt``, answered without the exact
        time's arithmetic)."""
        if self._target is not None and self._target_for[0] is self._t and self._target_for[1] == dt:
            return self._target
        if self._exact_dt[0] != dt:
            self._exact_dt = (dt, Fraction(dt))
        t1 = self._t + self._exact_dt[1]
        if self._target is None or self._target[0] != t1:
            c1, q1 = self._evaluate(t1)
            v = np.empty(6)
            v[:3] = (c1 - self.position) / dt
            v[3:] = self._angular(q1, dt)
            self._target = (t1, c1, q1, v)
        self._target_for = (self._t, dt)
        return self._target

    def _angular(self, q1: np.ndarray, dt: float) -> np.ndarray:
        """Angular velocity [3] [rad/s] turning ``orientation`` into ``q1`` over ``dt`` [s]: the
        last step's answer again while both quaternions and ``dt`` are bit for bit the same (a
        probe pressed without turning: three quaternion helpers cost ~20 us in a step's cold
        cache), else computed (and kept)."""
        key = (q1.tobytes(), self.orientation.tobytes(), dt)
        if self._still[0] != key:
            self._still = (key, quat_to_rotvec(quat_multiply(q1, quat_conjugate(self.orientation))) / dt)
        return self._still[1]

    def unconstrained_velocity(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> np.ndarray:
        """The velocity [6] (linear, world angular) carrying the body from ``pose(t)`` to
        ``pose(t + dt)`` (module docstring); gravity and ``external`` are ignored."""
        dt = self._check_dt(dt)
        self._check_external(external)
        return self._step_to(dt)[3].copy()

    def integrate(self, v, dt: float) -> None:
        """Advance the time by ``dt`` and set the pose to ``pose(t + dt)`` exactly.

        The scripted motion wins: ``v`` is only checked to be finite (raises
        :class:`~softvr.errors.SimulationError` naming the body and step otherwise); :attr:`v`
        becomes the step's scripted velocity.
        """
        dt = self._check_dt(dt)
        self._check_finite(v)
        t1, c1, q1, v1 = self._step_to(dt)
        self._t, self.position, self.orientation, self.v = t1, c1, q1, v1.copy()
        self._target = None
        self.step_count += 1
