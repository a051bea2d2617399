"""A simulated tool driven by a haptic device through a virtual coupling (thesis 5.4).

The device's handle enters the scene as a :class:`~softvr.dynamics.KinematicBody` placed at the
position the haptic loop read last; the tool (a rigid body with collision geometry: a finger,
a probe, an arthroscope tip) is tied to it by a zero-length spring of stiffness ``k`` (a
:class:`~softvr.dynamics.Coupling`, so the coupling is implicit and stable at any ``k``). The
tool therefore stops at tissue while the hand goes on, and the stretched spring is the force
the hand feels, ``F = k (x_tool - x_handle)``.

A hand holds the tool's orientation too: a stylus, a probe or a fingertip does not roll
over the tissue like a free ball. With ``angular_stiffness`` ``k_r`` > 0 the one spring at the
tip becomes six, of ``k / 6`` and ``c / 6``, at ``tip +- l e_i`` on the tool's axes and at the
same offsets (turned as the tool started) about the handle, ``l = sqrt(3 k_r / (2 k))``: the
orientation springs of a 6-dof virtual coupling [OL06] built of the thesis's zero-length springs
(eq. 5.4). Their stretches sum to six times the tip's, for any rotation, so the translation
and the hand's force ``k (x_tip - x_handle)`` are the one spring's; a turn by ``theta`` about
any axis stores ``(2/3) k l^2 (1 - cos theta)``, a restoring torque ``k_r sin theta`` damped
by ``c_r = c k_r / k``. The torque is the hand's grip, which a 3-dof device does not render
(its gimbal only reads the stylus's orientation): the hand feels the force alone, but now with
the friction a held tool meets, ``mu`` times the normal force when it slides, instead of the
free ball's rolling. (It also keeps the light tool's spin out of its contacts' iteration: see
docs/physics-core.md, "A held tool's orientation".)

After every simulation step :meth:`HapticTool.publish` gives the loop its linearization
(:class:`~softvr.haptics.HandleModel`): ``F0`` as above and ``K = -k P``, ``P`` the projector
onto the directions the tool's contacts block (the span of the normals of its pushing
contacts). Moving the hand further along a blocked direction stretches the spring one for
one; along a free one the tool follows. This is the rigid-contact limit of the handle-space
linearization of [GO09].
"""

from __future__ import annotations

import math

import numpy as np

from softvr.dynamics import Coupling, KinematicBody, RigidPoints
from softvr.errors import InputError
from softvr.haptics.loop import HandleModel, HapticLoop

__all__ = ["RANK_TOLERANCE", "HapticTool", "blocked_span"]

#: A direction whose singular value of the pushing normals is at most this fraction of the
#: largest is left free: normals that only nearly span it block the directions they share.
RANK_TOLERANCE = 1e-3


def _unit_null(m: list, scale: float) -> list | None:
    """A unit vector [3] spanning the null space of the symmetric 3x3 ``m`` (rows, of rank 2):
    the largest cross product of two of its rows; None where every one is below round-off of
    ``scale`` (|m|^2: rank < 2)."""
    best, size = None, 0.0
    for r, t in ((0, 1), (0, 2), (1, 2)):
        c = _cross(m[r], m[t])
        n = _dot(c, c)
        if n > size:
            best, size = c, n
    if best is None or size <= 1e-28 * scale * scale:
        return None
    n = math.sqrt(size)
    return [best[0] / n, best[1] / n, best[2] / n]


def _cross(a, b) -> list:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def blocked_span(normals: list) -> tuple[list, list]:
    """Orthonormal rows [m][3] spanning ``normals`` [k][3] (k >= 1, not all zero): the right
    singular vectors of the k x 3 matrix N whose singular values s exceed :data:`RANK_TOLERANCE`
    times the largest, and the projector [3][3] onto their span, as plain floats (what NumPy's
    SVD gives, without its wrapper and LAPACK: ~10 us a call hot, ~10x that from a cold cache,
    after every shoulder step the tool pushes).

    The s^2 are the eigenvalues l1 >= l2 >= l3 of G = N^T N, the roots of
    l^3 - c2 l^2 + c1 l - c0 with the coefficients summed from the normals themselves (Cauchy-Binet:
    c2 = sum |n_i|^2, c1 = sum_{i<j} |n_i x n_j|^2, c0 = sum_{i<j<k} det(n_i, n_j, n_k)^2; sums of
    squares, each to a few u, the double's round-off): l1 from O. K. Smith's closed form (Comm. ACM
    4(4), 1961; to a few u of itself, ~sqrt(u) only where l2 is as large, which leaves the rank
    and l3's eigenvector as they are), then l2 + l3 = (c1 - c0 / l1) / l1 and l2 l3 = c0 / l1,
    to a few u of themselves where l1 is simple (the cut only needs l2, l3 to ~1e-6 l1). The projector is
    u u^T (rank 1, u the eigenvector of l1), I - w w^T (rank 2, w that of l3) or I (rank 3); the
    eigenvector of a simple l is the largest cross product of two rows of G - l I, to
    ~u l1 / (its distance to the other eigenvalues)."""
    # Unrolled: Python's loops and comprehensions would cost more than the SVD they replace.
    g00 = g11 = g22 = g01 = g02 = g12 = c1 = c0 = 0.0
    crosses: list = []  # [j]: n_m x n_j for m < j
    for i, (x, y, z) in enumerate(normals):
        g00, g11, g22, g01, g02, g12 = g00 + x * x, g11 + y * y, g22 + z * z, g01 + x * y, g02 + x * z, g12 + y * z
        mine = []
        for (u, v, w), earlier in zip(normals[:i], crosses):
            for a, b, d in earlier:  # det(n_m, n_j, n_i) = (n_m x n_j) . n_i, m < j < i
                c0 += (a * x + b * y + d * z) ** 2
            cross = (v * z - w * y, w * x - u * z, u * y - v * x)  # n_j x n_i
            c1 += cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]
            mine.append(cross)
        crosses.append(mine)
    g = [[g00, g01, g02], [g01, g11, g12], [g02, g12, g22]]
    c2 = g00 + g11 + g22
    # Smith's largest root: G = q I + p B, l1 = q + 2 p cos(acos(det(B) / 2) / 3).
    q = c2 / 3.0
    a, b, c = g00 - q, g11 - q, g22 - q
    p = math.sqrt((a * a + b * b + c * c + 2.0 * (g01 * g01 + g02 * g02 + g12 * g12)) / 6.0)
    largest = q  # G = q I
    if p > 0.0:
        half_det = 0.5 * (a * (b * c - g12 * g12) - g01 * (g01 * c - g12 * g02) + g02 * (g01 * g12 - b * g02)) / p ** 3
        largest = q + 2.0 * p * math.cos(math.acos(min(1.0, max(-1.0, half_det))) / 3.0)
    product = c0 / largest  # l2 l3
    total = max(0.0, (c1 - product) / largest)  # l2 + l3
    middle = 0.5 * (total + math.sqrt(max(0.0, total * total - 4.0 * product)))
    smallest = product / middle if middle > 0.0 else 0.0
    cut = RANK_TOLERANCE ** 2 * largest
    rank = 1 + (middle > cut) + (smallest > cut)
    if rank == 3:
        identity = [[1.0 if j == i else 0.0 for j in range(3)] for i in range(3)]
        return identity, identity
    vector = None
    if rank == 2:
        vector = _unit_null([[g[i][j] - (smallest if i == j else 0.0) for j in range(3)] for i in range(3)], largest)
        # None: the two smaller values are one within round-off, and cut alike.
        rank = 2 if vector is not None else 1
    if rank == 1:  # l1 is simple: every other is below its cut
        vector = _unit_null([[g[i][j] - (largest if i == j else 0.0) for j in range(3)] for i in range(3)], largest)
    assert vector is not None
    if rank == 1:
        return [vector], [[vector[i] * vector[j] for j in range(3)] for i in range(3)]
    # Rank 2: the plane normal to the free direction, spanned from the axis least along it.
    axis = min(range(3), key=lambda i: abs(vector[i]))
    first = _cross(vector, [1.0 if i == axis else 0.0 for i in range(3)])
    n = math.sqrt(_dot(first, first))
    first = [t / n for t in first]
    projector = [[(1.0 if i == j else 0.0) - vector[i] * vector[j] for j in range(3)] for i in range(3)]
    return [first, _cross(vector, first)], projector


class HapticTool:
    """Couple a tool body of ``scene`` to a haptic loop's handle.

    Parameters
    ----------
    scene : softvr.Scene
        Holds the tool; the handle and the coupling are added to it.
    tool : RigidBody
        The tool, already added to ``scene`` (with its collision geometry).
    loop : HapticLoop
    stiffness : float [N/m]
        Virtual coupling ``k``: the hand feels ``k`` per metre the tool lags behind it.
    damping : float [N s/m]
        Damping of the coupling (on the simulated tool; the rendered force is the spring's).
    tip : array_like, shape [3] [m]
        The point of the tool (body frame) tied to the handle.
    angular_stiffness : float [N m/rad]
        ``k_r`` holding the tool's orientation to the one it starts with (module docstring);
        0: one spring at the tip, the tool free to turn.

    Attributes
    ----------
    handle : KinematicBody
    coupling : Coupling
        One spring of ``k`` at the tip, or six of ``k / 6`` holding the orientation.
    stiffness : float [N/m]
        ``k``: what the hand feels per metre the tip lags (whatever the coupling's split).
    tool_index : int
        The tool's index in ``scene.bodies``.
    """

    #: Whether its loop runs in a process of its own; set by the scene builder, from the scene file.
    haptics: bool

    def __init__(self, scene, tool, loop: HapticLoop, *, stiffness: float, damping: float = 0.0, tip=(0.0, 0.0, 0.0),
                 angular_stiffness: float = 0.0):
        if not isinstance(loop, HapticLoop):
            raise InputError("loop", "a softvr.haptics.HapticLoop", type(loop).__name__)
        index = [i for i, b in enumerate(scene.bodies) if b is tool]
        if not index:
            raise InputError("tool", "a body already added to the scene", repr(getattr(tool, "name", tool)))
        if not hasattr(tool, "position"):
            raise InputError("tool", "a rigid body (RigidBody)", type(tool).__name__)
        for field, value, expected in (("stiffness", stiffness, "a finite value > 0 [N/m]"),
                                       ("angular_stiffness", angular_stiffness, "a finite value >= 0 [N m/rad]")):
            number = isinstance(value, (int, float, np.integer, np.floating)) and np.isfinite(value)
            if not (number and (value > 0 if field == "stiffness" else value >= 0)):
                raise InputError(field, expected, repr(value))
        self.scene, self.tool, self.loop, self.tool_index = scene, tool, loop, index[0]
        self.stiffness = float(stiffness)
        self.handle = KinematicBody(self._handle_pose, t0=scene.time, name="haptic handle")
        scene.add_body(self.handle)
        offsets = np.zeros((1, 3))
        if angular_stiffness > 0:
            offsets = np.sqrt(1.5 * angular_stiffness / stiffness) * np.concatenate([np.eye(3), -np.eye(3)])
        share = len(offsets)
        self.coupling = Coupling(RigidPoints(tool, np.asarray(tip, float) + offsets),
                                 RigidPoints(self.handle, offsets @ tool.rotation.T), stiffness / share,
                                 damping=damping / share, name="virtual coupling")
        scene.add_coupling(self.coupling)
        # The sides' mean body-frame points [2][3] [m] (:meth:`force`).
        self._mean_points = tuple(side.local.mean(axis=0).tolist() for side in (self.coupling.a, self.coupling.b))

    def _handle_pose(self, t: float):
        return self.loop.handle_position(), np.array([1.0, 0.0, 0.0, 0.0])

    def force(self) -> np.ndarray:
        """Force on the hand now [3] [N]: ``k (x_tip - x_handle)``, the sum of the coupling's
        springs (their stretches' mean is the tip's): ``k`` times the mean of
        ``c_a + R_a r_a,i - c_b - R_b r_b,i``, that is of ``c_a + R_a m_a - c_b - R_b m_b`` with
        ``m`` the sides' mean body-frame points, each turned by its body's unit quaternion
        (w, v): ``R m = m + 2 w (v x m) + 2 v x (v x m)``. In plain floats: NumPy's products of
        the six springs' points cost ~15 us hot and ~5x that from a cold cache, after every step."""
        total = [0.0, 0.0, 0.0]
        for points, mean, sign in ((self.coupling.a, self._mean_points[0], 1.0),
                                   (self.coupling.b, self._mean_points[1], -1.0)):
            w, x, y, z = points.body.orientation.tolist()
            m0, m1, m2 = mean
            t0, t1, t2 = y * m2 - z * m1, z * m0 - x * m2, x * m1 - y * m0  # v x m
            u0, u1, u2 = y * t2 - z * t1, z * t0 - x * t2, x * t1 - y * t0  # v x (v x m)
            c = points.body.position.tolist()
            total = [total[0] + sign * (c[0] + m0 + 2.0 * (w * t0 + u0)),
                     total[1] + sign * (c[1] + m1 + 2.0 * (w * t1 + u1)),
                     total[2] + sign * (c[2] + m2 + 2.0 * (w * t2 + u2))]
        k = self.stiffness
        return np.array([k * total[0], k * total[1], k * total[2]])

    def blocked_directions(self, solution) -> np.ndarray:
        """Orthonormal rows [m, 3] spanning the normals of the tool's pushing contacts in
        ``solution`` (m = 0..3; :func:`blocked_span`)."""
        # Read from a step on arrays without building its sets' Jacobians (~2.5 ms a shoulder
        # step), nor (on the node arrays) splitting its contacts into sets.
        n = solution.pushing_normals(self.tool_index)
        if not len(n):
            return n
        return np.array(blocked_span(n.tolist())[0]).reshape(-1, 3)

    def publish(self, solution) -> HandleModel:
        """Give the loop this step's handle model (call after every ``scene.step``)."""
        n = solution.pushing_normals(self.tool_index)
        projector = blocked_span(n.tolist())[1] if len(n) else np.zeros((3, 3))
        model = HandleModel(position=self.handle.position.copy(), force=self.force(),
                            stiffness=-self.stiffness * np.asarray(projector))
        self.loop.publish(model, time=self.scene.time)
        return model
