"""Rigid bodies (thesis 5.1.1, 5.3.1) and the quaternion algebra they use.

State and velocity (thesis eq. 5.1)::

    q = (c, quat)          c [3] centre of mass (world) [m], quat [4] orientation (w, x, y, z)
    v = (v_lin, omega)     [6]: linear velocity [m/s], angular velocity in WORLD frame [rad/s]
    q_dot = G v,           c_dot = v_lin,   quat_dot = 1/2 [0, omega] (x) quat

``(x)`` is the Hamilton product; ``[0, omega]`` multiplies from the left because ``omega`` is a
world-frame vector. A body point with body-frame offset ``r`` is at ``p = c + R r`` (thesis
5.1.2) and moves with ``p_dot = v_lin + omega x (p - c) = J v``, ``J = [I, -[p - c]x]`` [3 x 6].

Time step: backward Euler with the forces linearized at the start of the step (thesis eq. 5.2,
``A v1 = b``, ``A = M - dt dF/dv``, ``b = dt F(v0) + A v0``), with

    M = blockdiag(m I3, I_w),   I_w = R I_body R^T   (held for the step)
    F = (m g + f_ext,  tau_ext - omega x (I_w omega))

The gyroscopic torque ``-omega x (I_w omega)`` is treated either *implicitly* (default,
``A_rot = I_w + dt ([omega]x I_w - [I_w omega]x)``, one Newton step of backward Euler on Euler's
equations) or *explicitly* (``A_rot = I_w``, i.e. ``A = M``). Both are first order in ``dt``; the
implicit one is stable at large spin rates (its momentum error is a dissipation), the explicit
one makes ``|L|^2`` grow by exactly ``dt^2 |omega x L|^2`` per step and can blow up. The ``dt^2 G dF/dq``
term of eq. 5.2 is dropped (only the gyroscopic torque depends on ``q``, through ``I_w``).

Constraint impulses act through ``M^-1`` (:meth:`RigidBody.solve`), the body's instantaneous
impulse response, in both treatments: it differs from the implicit ``A^-1`` by
``O(dt |omega|)`` (the same first order as the step) and keeps the contact Delassus operator
``J M^-1 J^T`` symmetric positive semi-definite, as projected Gauss-Seidel needs. The true
step matrix is :meth:`RigidBody.system_matrix` (for solvers that assemble ``A``, e.g. couplings).

The orientation is advanced with the exact exponential map of ``omega dt``::

    quat1 = exp(omega dt) (x) quat0,    c1 = c0 + dt v_lin

so a constant ``omega`` rotates the body at exactly ``|omega|``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from softvr.dynamics.body import ContactObject, StepSystem
from softvr.errors import InputError

__all__ = [
    "RigidBody",
    "RigidFrame",
    "quat_conjugate",
    "quat_from_rotvec",
    "quat_multiply",
    "quat_to_matrix",
    "quat_to_rotvec",
    "skew",
]

GYROSCOPIC_MODES = ("implicit", "explicit")


# ------------------------------------------------------------------ quaternion algebra
# softvr's one quaternion helper, (w, x, y, z) first (SciPy's Rotation is (x, y, z, w)). All five
# run per body per step. Timed per call on one quaternion (timeit, best of 7, the shared 2-core
# machine at load ~2), hand-written vs SciPy: product 19 vs 59 us, conjugate 1.1 vs 31 us
# (``Rotation.inv``), matrix 3.4 vs 16 us -- there a Rotation object costs 3-27x the arithmetic,
# so those stay written out; rotation vector from / to 17 vs 24 us and 15 vs 24 us -- within 1.5x,
# and the small-angle and near-pi branches are the hard part, so those are SciPy's now.
# tests/test_quaternion.py holds all five to SciPy.
_TO_SCIPY, _FROM_SCIPY = [1, 2, 3, 0], [3, 0, 1, 2]  # (w, x, y, z) <-> (x, y, z, w)


def quat_multiply(a, b) -> np.ndarray:
    """Hamilton product ``a (x) b`` of quaternions (w, x, y, z), shapes [..., 4] (broadcast).

    19 us per call vs 59 us for SciPy's ``Rotation`` product (the comment above); two single
    quaternions (a kinematic body's step, every step) in plain floats, ~2 us, the same bits."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.shape == b.shape == (4,):
        aw, ax, ay, az = a.tolist()
        bw, bx, by, bz = b.tolist()
        return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                         aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])


def quat_conjugate(q) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion), shape [..., 4]; 1.1 us vs 31 us for ``Rotation.inv``."""
    return np.asarray(q, float) * _CONJUGATE


def quat_from_rotvec(phi) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of the rotation vector ``phi`` [rad] (axis * angle), [..., 3] -> [..., 4].

    ``(cos(|phi|/2), sin(|phi|/2) phi / |phi|)``, SciPy's ``Rotation.from_rotvec`` (exact at
    small angles too).
    """
    return Rotation.from_rotvec(np.asarray(phi, float)).as_quat()[..., _FROM_SCIPY]


def quat_to_rotvec(q) -> np.ndarray:
    """Rotation vector [rad] (axis * angle, angle in [0, pi]) of a unit quaternion, [..., 4] -> [..., 3].

    ``q`` and ``-q`` give the same (shortest) rotation; SciPy's ``Rotation.as_rotvec``. One
    quaternion of no rotation (zero vector part, ``w > 0``: a kinematic body that does not
    turn over a step) is SciPy's small-angle map at angle 0, ``2 (x, y, z)`` (zeros of the same
    signs), without its ~30 us.
    """
    q = np.asarray(q, float)
    if q.shape == (4,):
        w, x, y, z = q.tolist()  # plain floats: the test below on array elements costs ~2 us
        if w > 0.0 and not (x or y or z):
            return 2.0 * q[1:]
    return Rotation.from_quat(q[..., _TO_SCIPY]).as_rotvec()


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z), [..., 4] -> [..., 3, 3]; one quaternion
    3.4 us vs 16 us for ``Rotation.as_matrix``."""
    q = np.asarray(q, float)
    if q.shape == (4,):
        # One body's rotation, asked for many times per step: plain floats are 20x faster
        # than the stacked array expression below.
        w, x, y, z = q.tolist()
        return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def skew(a) -> np.ndarray:
    """Cross-product matrix ``[a]x`` with ``[a]x b = a x b``, [..., 3] -> [..., 3, 3]."""
    x, y, z = np.moveaxis(np.asarray(a, float), -1, 0)
    o = np.zeros_like(x)
    return np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2)


# ------------------------------------------------------------------ input checks
def _vector(value, n: int, what: str, unit: str) -> np.ndarray:
    try:
        arr = np.asarray(value, float)
    except (TypeError, ValueError):
        raise InputError(what, f"{n} finite numbers [{unit}]", repr(value)) from None
    if arr.shape != (n,):
        raise InputError(what, f"{n} finite numbers [{unit}]", f"shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(what, f"{n} finite numbers [{unit}]", repr(arr.tolist()))
    return arr.copy()


def _unit_quaternion(value, what: str) -> np.ndarray:
    q = _vector(value, 4, what, "quaternion (w, x, y, z)")
    norm = float(np.linalg.norm(q))
    if not norm > 1e-12:
        raise InputError(what, "a nonzero quaternion (w, x, y, z)", repr(q.tolist()))
    return q / norm


def _positive(value, what: str, unit: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(what, f"a finite value > 0 [{unit}]", repr(value)) from None
    if not (np.isfinite(x) and x > 0):
        raise InputError(what, f"a finite value > 0 [{unit}]", repr(value))
    return x


def _inertia(value) -> np.ndarray:
    """Body-frame inertia tensor [3, 3] (or principal moments [3]): symmetric positive definite,
    principal moments satisfying the triangle inequality of a real mass distribution."""
    expected = "a symmetric positive definite 3x3 inertia tensor (or 3 principal moments) [kg m^2]"
    try:
        arr = np.asarray(value, float)
    except (TypeError, ValueError):
        raise InputError("inertia", expected, repr(value)) from None
    if arr.shape == (3,):
        arr = np.diag(arr)
    if arr.shape != (3, 3):
        raise InputError("inertia", expected, f"shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError("inertia", expected, "NaN/inf entries")
    scale = float(np.abs(arr).max())
    if np.abs(arr - arr.T).max() > 1e-9 * scale:
        raise InputError("inertia", expected, f"an asymmetric matrix {arr.tolist()}")
    arr = 0.5 * (arr + arr.T)
    moments = np.linalg.eigvalsh(arr)
    if not moments[0] > 1e-12 * scale:
        raise InputError("inertia", expected, f"principal moments {moments.tolist()}")
    if moments[0] + moments[1] < moments[2] * (1 - 1e-9):
        raise InputError("inertia", "principal moments with I1 + I2 >= I3 (a real mass distribution)",
                         f"principal moments {moments.tolist()}")
    return arr


# ------------------------------------------------------------------ shared frame
class RigidFrame(ContactObject):
    """A contact object whose state is a rigid frame: position ``c`` [3] and orientation (w, x, y, z).

    Base of :class:`RigidBody`, :class:`~softvr.dynamics.kinematic.FixedBody` and
    :class:`~softvr.dynamics.kinematic.KinematicBody`, so point entities (thesis 5.1.2) treat all
    three alike: ``p = c + R r`` and ``p_dot = J v`` with ``v = (v_lin, omega)`` [6], ``omega``
    in the world frame.

    Attributes
    ----------
    position : ndarray, shape [3] [m]
        Frame origin ``c`` in the world (the centre of mass for a :class:`RigidBody`).
    orientation : ndarray, shape [4]
        Unit quaternion (w, x, y, z), body to world.
    v : ndarray, shape [6] [m/s, rad/s]
        Linear velocity of ``c`` and angular velocity (world frame).
    """

    position: np.ndarray
    orientation: np.ndarray
    #: Contact Jacobians address the whole body as one block of 6 velocities.
    block_size: int = 6

    @property
    def rotation(self) -> np.ndarray:
        """Rotation matrix R [3, 3], body to world (a read-only array, recomputed when the
        orientation changes: point entities ask for it many times per step)."""
        key = self.orientation.tobytes()
        cached = getattr(self, "_rotation_cache", None)
        if cached is None or cached[0] != key:
            r = quat_to_matrix(self.orientation)
            r.flags.writeable = False
            cached = self._rotation_cache = (key, r)
        return cached[1]

    @property
    def velocity(self) -> np.ndarray:
        """Linear velocity of ``position`` [3] [m/s] (a view of ``v[:3]``)."""
        return self.v[:3]

    @property
    def angular_velocity(self) -> np.ndarray:
        """Angular velocity [3] [rad/s], world frame (a view of ``v[3:]``)."""
        return self.v[3:]

    def G(self) -> np.ndarray:
        """The [7 x 6] matrix of ``q_dot = G v`` (thesis eq. 5.1) for ``q = (c, quat)``.

        ``G = [[I3, 0], [0, 1/2 Q]]`` with ``Q`` [4 x 3] the map ``omega -> [0, omega] (x) quat``:
        ``Q = [[-quat_xyz^T], [quat_w I3 - [quat_xyz]x]]``.
        """
        w, xyz = self.orientation[0], self.orientation[1:]
        g = np.zeros((7, 6))
        g[:3, :3] = np.eye(3)
        g[3, 3:] = -0.5 * xyz
        g[4:, 3:] = 0.5 * (w * np.eye(3) - skew(xyz))
        return g

    def to_world(self, r_body) -> np.ndarray:
        """World position ``c + R r`` [m] of body-frame offsets ``r`` [..., 3]."""
        return self.position + np.asarray(r_body, float) @ self.rotation.T

    def to_body(self, p_world) -> np.ndarray:
        """Body-frame offsets ``R^T (p - c)`` [m] of world points [..., 3]."""
        return (np.asarray(p_world, float) - self.position) @ self.rotation

    def point_velocity(self, p_world) -> np.ndarray:
        """Velocity ``v_lin + omega x (p - c)`` [m/s] of body points at world positions [..., 3]."""
        r = np.asarray(p_world, float) - self.position
        return self.v[:3] + np.cross(self.v[3:], r)

    def point_jacobian(self, p_world) -> np.ndarray:
        """``J = [I3, -[p - c]x]`` [..., 3, 6] with ``p_dot = J v`` (thesis 5.1.2) for world points [..., 3]."""
        r = np.asarray(p_world, float) - self.position
        j = np.zeros(r.shape[:-1] + (3, 6))
        j[..., :3] = np.eye(3)
        j[..., 3:] = -skew(r)
        return j

    def _check_velocity(self, v) -> np.ndarray:
        try:
            arr = np.asarray(v, float)
        except (TypeError, ValueError):
            raise InputError("v", "6 numbers (linear [m/s], angular [rad/s])", repr(v)) from None
        if arr.size != 6:
            raise InputError("v", "6 numbers (linear [m/s], angular [rad/s])", f"shape {arr.shape}")
        return arr.reshape(6).copy()

    @staticmethod
    def _check_external(external) -> np.ndarray:
        if external is None:
            return np.zeros(6)
        try:
            arr = np.asarray(external, float)
        except (TypeError, ValueError):
            raise InputError("external", "a generalized force of 6 numbers (force [N], torque [N m])",
                             repr(external)) from None
        if arr.size != 6:
            raise InputError("external", "a generalized force of 6 numbers (force [N], torque [N m])",
                             f"shape {arr.shape}")
        return arr.reshape(6)


# ------------------------------------------------------------------ rigid body
class RigidBody(RigidFrame):
    """A rigid body: centre of mass, orientation quaternion, linear and world angular velocity.

    Parameters
    ----------
    mass : float [kg]
        Finite, > 0.
    inertia : array_like, shape [3, 3] or [3] [kg m^2]
        Inertia tensor about the centre of mass in the body frame (or its principal moments):
        symmetric positive definite, moments obeying I1 + I2 >= I3.
    position : array_like, shape [3] [m]
        Centre of mass in the world.
    orientation : array_like, shape [4]
        Quaternion (w, x, y, z), body to world; normalized here (zero or non-finite is rejected).
    velocity : array_like, shape [3] [m/s]
        Linear velocity of the centre of mass.
    angular_velocity : array_like, shape [3] [rad/s]
        Angular velocity in the WORLD frame.
    gyroscopic : {"implicit", "explicit"}
        Treatment of the gyroscopic torque ``-omega x (I_w omega)`` in the unconstrained velocity
        (module docstring). With "implicit" the step's ``A`` (:meth:`system_matrix`) is ``M``
        plus a non-symmetric ``dt`` term whenever the body spins off a principal axis; with
        "explicit" ``A = M``. :meth:`solve` applies ``M^-1`` either way.
    name : str
        Named in error and divergence reports.

    Attributes
    ----------
    mass : float [kg]
    inertia_body : ndarray, shape [3, 3] [kg m^2]
    position : ndarray, shape [3] [m]
    orientation : ndarray, shape [4]
    v : ndarray, shape [6] [m/s, rad/s]
        (linear velocity, world angular velocity).
    extent : float [m]
        Largest edge of the uniform box with the same mass and inertia (the body's size).
    max_rate : float [1/s]
        Divergence threshold: a step with ``|v_lin| > max(max_rate * extent, max_speed)`` or
        ``|omega| > max_rate`` has blown up. Default 1e3.
    max_speed : float [m/s]
        Floor of the linear-speed threshold (so tiny bodies may still fall for a while). Default 100.
    step_count : int
    """

    def __init__(self, mass, inertia, *, position=(0.0, 0.0, 0.0), orientation=(1.0, 0.0, 0.0, 0.0),
                 velocity=(0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0), gyroscopic: str = "implicit",
                 name: str = "rigid body"):
        self.name = name
        self.mass = _positive(mass, "mass", "kg")
        self.inertia_body = _inertia(inertia)
        if gyroscopic not in GYROSCOPIC_MODES:
            raise InputError("gyroscopic", f"one of {GYROSCOPIC_MODES}", repr(gyroscopic))
        self.gyroscopic = gyroscopic
        self.position = _vector(position, 3, "position", "m")
        self.orientation = _unit_quaternion(orientation, "orientation")
        self.v = np.concatenate([_vector(velocity, 3, "velocity", "m/s"),
                                 _vector(angular_velocity, 3, "angular_velocity", "rad/s")])
        moments = np.linalg.eigvalsh(self.inertia_body)
        # Uniform box with the same moments: edge_i^2 = 6 (I_j + I_k - I_i) / m.
        edges2 = 6.0 * (moments.sum() - 2.0 * moments) / self.mass
        self.extent = float(np.sqrt(max(edges2.max(), 0.0)))
        self.max_rate = 1e3
        self.max_speed = 100.0
        self.step_count = 0
        self._a_rot: np.ndarray | None = None

    # ------------------------------------------------------------- constructors
    @classmethod
    def box(cls, size, density, **kwargs) -> RigidBody:
        """A uniform box of edge lengths ``size`` = (a, b, c) [m] (body axes) and ``density`` [kg/m^3].

        ``m = rho a b c``, ``I = m / 12 diag(b^2 + c^2, a^2 + c^2, a^2 + b^2)``. Other keyword
        arguments go to :class:`RigidBody`.
        """
        size = _vector(size, 3, "size", "m")
        if not (size > 0).all():
            raise InputError("size", "3 edge lengths > 0 [m]", repr(size.tolist()))
        density = _positive(density, "density", "kg/m^3")
        a, b, c = size
        m = density * a * b * c
        inertia = m / 12.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
        kwargs.setdefault("name", "box")
        return cls(m, inertia, **kwargs)

    @classmethod
    def sphere(cls, radius, density, **kwargs) -> RigidBody:
        """A uniform solid sphere: ``m = 4/3 pi r^3 rho``, ``I = 2/5 m r^2`` about every axis.

        ``radius`` [m], ``density`` [kg/m^3]; other keyword arguments go to :class:`RigidBody`.
        """
        r = _positive(radius, "radius", "m")
        density = _positive(density, "density", "kg/m^3")
        m = 4.0 / 3.0 * np.pi * r**3 * density
        kwargs.setdefault("name", "sphere")
        return cls(m, np.full(3, 0.4 * m * r * r), **kwargs)

    # ------------------------------------------------------------- physics
    @property
    def inertia_world(self) -> np.ndarray:
        """``I_w = R I_body R^T`` [3, 3] [kg m^2] at the current orientation."""
        r = self.rotation
        iw = r @ self.inertia_body @ r.T
        return 0.5 * (iw + iw.T)

    def mass_matrix(self) -> np.ndarray:
        """``M = blockdiag(m I3, I_w)`` [6, 6] at the current orientation."""
        m = np.zeros((6, 6))
        m[:3, :3] = self.mass * np.eye(3)
        m[3:, 3:] = self.inertia_world
        return m

    def system_matrix(self) -> np.ndarray:
        """The step's ``A`` [6, 6] (prepared by :meth:`unconstrained_velocity`); see the module docstring."""
        self._require_step()
        a = np.zeros((6, 6))
        a[:3, :3] = self.mass * np.eye(3)
        a[3:, 3:] = self._a_rot
        return a

    def linear_momentum(self) -> np.ndarray:
        """``m v_lin`` [3] [kg m/s]."""
        return self.mass * self.v[:3]

    def angular_momentum(self) -> np.ndarray:
        """``I_w omega`` [3] [kg m^2/s], world frame, about the centre of mass."""
        return self.inertia_world @ self.v[3:]

    def kinetic_energy(self) -> float:
        """``1/2 m |v_lin|^2 + 1/2 omega . I_w omega`` [J]."""
        w = self.v[3:]
        return 0.5 * self.mass * float(self.v[:3] @ self.v[:3]) + 0.5 * float(w @ self.inertia_world @ w)

    def unconstrained_velocity(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> np.ndarray:
        """Velocity [6] solving ``A v1 = b`` (thesis eq. 5.2) without constraints.

        ``v_lin1 = v_lin0 + dt (g + f_ext / m)`` and
        ``A_rot omega1 = A_rot omega0 + dt (tau_ext - omega0 x I_w omega0)`` with ``A_rot`` the
        implicit or explicit gyroscopic matrix (module docstring), ``I_w`` at the current
        orientation. Prepares :meth:`solve`.

        Parameters
        ----------
        dt : float [s]
        gravity : (3,) [m/s^2]
        external : array_like, shape [6], optional
            Force [N] at the centre of mass and torque [N m] about it, world frame.
        """
        dt = self._check_dt(dt)
        g = _vector(gravity, 3, "gravity", "m/s^2")
        ext = self._check_external(external)
        if not np.isfinite(self.v).all():
            raise self._diverged("velocity NaN/inf")
        iw = self.inertia_world
        w0 = self.v[3:]
        l0 = iw @ w0
        a_rot = iw.copy()
        if self.gyroscopic == "implicit":
            # -dt dF/domega for F = -omega x (I_w omega), I_w held for the step.
            a_rot += dt * (skew(w0) @ iw - skew(l0))
        try:
            a_inv = np.linalg.inv(a_rot)
        except np.linalg.LinAlgError:
            raise self._diverged("singular rotational system matrix") from None
        self._a_rot, self._iw_inv = a_rot, np.linalg.inv(iw)
        v1 = np.empty(6)
        v1[:3] = self.v[:3] + dt * (g + ext[:3] / self.mass)
        v1[3:] = w0 + a_inv @ (dt * (ext[3:] - np.cross(w0, l0)))
        return v1

    def step_system(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> StepSystem:
        """``A = M = blockdiag(m I3, I_w)`` and ``b = M v0 + dt (m g + f_ext, tau_ext - omega0 x
        I_w omega0)`` (eq. 5.2 with the gyroscopic torque explicit: a coupling island needs a
        symmetric ``A``; an uncoupled body keeps its :attr:`gyroscopic` setting)."""
        dt = self._check_dt(dt)
        g = _vector(gravity, 3, "gravity", "m/s^2")
        ext = self._check_external(external)
        if not np.isfinite(self.v).all():
            raise self._diverged("velocity NaN/inf")
        m = self.mass_matrix()
        w0 = self.v[3:]
        force = np.concatenate([self.mass * g + ext[:3], ext[3:] - np.cross(w0, m[3:, 3:] @ w0)])
        return StepSystem(sp.csr_matrix(m), m @ self.v + dt * force, np.zeros(6, bool), np.zeros(6))

    def solve(self, rhs) -> np.ndarray:
        """``M^-1 rhs`` with the step's ``M = blockdiag(m I3, I_w)`` (``I_w`` at the step's start).

        The velocity change of a generalized impulse [N s, N m s] (or force): exactly the step's
        ``A^-1`` with explicit gyroscopic treatment, its symmetric first-order approximation
        with implicit (module docstring). ``rhs`` : shape [6] or [k, 6] (k at once).
        """
        self._require_step()
        rhs = np.asarray(rhs, float)
        if rhs.shape[-1:] != (6,) or rhs.ndim > 2:
            raise InputError("rhs", "shape [6] or [k, 6]", f"shape {rhs.shape}")
        out = np.empty_like(rhs)
        out[..., :3] = rhs[..., :3] / self.mass
        out[..., 3:] = rhs[..., 3:] @ self._iw_inv.T
        return out

    def solve_columns(self, columns) -> np.ndarray:
        """``M^-1 C`` for ``C`` [6, k] (contact compliance, eq. 5.6); see :meth:`solve`."""
        cols = np.asarray(columns, float)
        if cols.ndim != 2 or cols.shape[0] != 6:
            raise InputError("columns", "shape [6, k]", f"shape {cols.shape}")
        return self.solve(cols.T).T

    def _require_step(self) -> None:
        if self._a_rot is None:
            raise InputError("solve", "a call after unconstrained_velocity() of this step", "no step prepared")

    def integrate(self, v, dt: float) -> None:
        """Set ``v`` and advance: ``c += dt v_lin``, ``quat = exp(omega dt) (x) quat`` (renormalized).

        Raises :class:`~softvr.errors.SimulationError` (body and step named) if ``v`` is not
        finite or exceeds the divergence thresholds (:attr:`max_rate`, :attr:`max_speed`).
        """
        dt = self._check_dt(dt)
        v1 = self._check_velocity(v)
        if not np.isfinite(v1).all():
            raise self._diverged("velocity NaN/inf")
        speed, spin = float(np.linalg.norm(v1[:3])), float(np.linalg.norm(v1[3:]))
        if speed > max(self.max_rate * self.extent, self.max_speed):
            raise self._diverged(f"speed {speed:.3g} m/s for a body of size {self.extent:.3g} m")
        if spin > self.max_rate:
            raise self._diverged(f"angular speed {spin:.3g} rad/s")
        c1 = self.position + dt * v1[:3]
        q1 = quat_multiply(quat_from_rotvec(dt * v1[3:]), self.orientation)
        q1 /= np.linalg.norm(q1)
        if not (np.isfinite(c1).all() and np.isfinite(q1).all()):
            raise self._diverged("position or orientation NaN/inf")
        self.v, self.position, self.orientation = v1, c1, q1
        self.step_count += 1
