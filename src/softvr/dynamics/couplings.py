"""Couplings: zero-length springs binding anatomical parts together (thesis 5.3.2, eq. 5.4).

A coupling joins two *semi-couplings*, point entities on two contact objects (a rigid body's
body-frame points, FEM nodes, barycentric points inside tets, cloth vertices): point ``i`` of
side ``a`` is tied to point ``i`` of side ``b`` by a zero-length spring of stiffness ``k``
(and optional damping ``c``). On point ``p_a`` it pulls with

    F_a = -k (p_a - p_b) - c (p_dot_a - p_dot_b),     F_b = -F_a,

so on the objects ``F_qa = J_a^T F_a`` (thesis 5.1.2). Its implicit derivatives fill the
off-diagonal blocks of the step matrix (eq. 5.4): with ``D = [J_a, -J_b]`` mapping the two
objects' velocities to the relative point velocity,

    A += (dt c + dt^2 k) D^T D,      b += -dt k D^T (p_a - p_b),

(backward Euler linearized about the step's start, the rigid bodies' ``J`` held for the step).
:class:`~softvr.dynamics.CouplingIsland` assembles these for every coupling of an island.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from softvr.errors import InputError

__all__ = ["Coupling"]


class Coupling:
    """Zero-length springs between matching points of two point entities.

    Parameters
    ----------
    a, b : RigidPoints or EmbeddedPoints
        The two semi-couplings, on different bodies, with the same number of points.
    stiffness : float [N/m]
        Spring constant ``k`` of each spring, > 0.
    damping : float [N s/m]
        Damping ``c`` of each spring along the relative velocity, >= 0.
    name : str
        Named in errors.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.dynamics import Coupling, RigidBody, RigidPoints
    >>> bone = RigidBody.box((0.1, 0.1, 0.1), 1000.0, name="bone")
    >>> arm = RigidBody.box((0.1, 0.1, 0.1), 1000.0, position=(0.1, 0.0, 0.0), name="arm")
    >>> joint = np.array([[0.05, 0.0, 0.0], [0.05, 0.05, 0.0]])
    >>> c = Coupling(RigidPoints.from_world(bone, joint), RigidPoints.from_world(arm, joint), 1e4)
    >>> float(np.abs(c.stretch()).max())  # bound where they are: the springs start unstretched
    0.0
    """

    def __init__(self, a, b, stiffness: float, *, damping: float = 0.0, name: str = "coupling"):
        self.name = name
        for side, points in (("a", a), ("b", b)):
            if not all(hasattr(points, attr) for attr in ("body", "positions", "velocities", "jacobian")):
                raise InputError(f"{name}.{side}", "a point entity (RigidPoints or EmbeddedPoints)",
                                 type(points).__name__)
        if a.body is b.body:
            raise InputError(f"{name}.b", "points on another body than side a", f"both on {a.body.name!r}")
        na, nb = len(a.positions()), len(b.positions())
        if na != nb or na == 0:
            raise InputError(f"{name}.b", f"as many points as side a ({na}), at least one", f"{nb} points")
        for field, value, positive in (("stiffness", stiffness, True), ("damping", damping, False)):
            ok = isinstance(value, (int, float, np.integer, np.floating)) and math.isfinite(value)
            if not (ok and (value > 0 if positive else value >= 0)):
                raise InputError(f"{name}.{field}", f"a finite value {'>' if positive else '>='} 0 "
                                 f"[{'N/m' if positive else 'N s/m'}]", repr(value))
        self.a, self.b = a, b
        self.stiffness, self.damping = float(stiffness), float(damping)
        self._embedded: dict = {}
        self._normal_key: tuple | None = None

    @property
    def bodies(self) -> tuple:
        """The two coupled contact objects (side a, side b)."""
        return self.a.body, self.b.body

    def __len__(self) -> int:
        return len(self.a.nodes) if hasattr(self.a, "nodes") else len(self.a.local)

    def stretch(self) -> np.ndarray:
        """``p_a - p_b`` [spring_count, 3] [m]: how far each spring is stretched."""
        return self.a.positions() - self.b.positions()

    def forces(self) -> np.ndarray:
        """Spring forces on the side-a points [spring_count, 3] [N] (side b gets the opposite)."""
        relative = self.a.velocities() - self.b.velocities()
        return -self.stiffness * self.stretch() - self.damping * relative

    def energy(self) -> float:
        """Elastic energy ``1/2 k sum |p_a - p_b|^2`` [J]."""
        return 0.5 * self.stiffness * float(np.sum(self.stretch() ** 2))

    def relative_jacobian(self, offsets: dict, size: int) -> sp.csr_matrix:
        """``D = [J_a, -J_b]`` [3 spring_count, size]: relative point velocity of the springs from
        the velocities of an island whose bodies start at ``offsets[id(body)]``.

        An embedded side's ``J`` (fixed barycentric weights) is built once and kept; a rigid
        side's depends on the body's rotation and is rebuilt each call (3 x 6 per spring)."""
        rows, cols, vals = [], [], []
        for points, sign in ((self.a, 1.0), (self.b, -1.0)):
            start = offsets[id(points.body)]
            if hasattr(points, "weights"):
                cache = self._embedded.get(id(points))
                if cache is None:
                    jac = points.jacobian().tocoo()
                    cache = self._embedded[id(points)] = (jac.row, jac.col, jac.data)
                r, c, v = cache
            else:
                jac = points.jacobian()  # [3 p, 6], dense
                r, c = np.nonzero(np.ones_like(jac, bool))
                v = jac.ravel()
            rows.append(r)
            cols.append(c + start)
            vals.append(sign * v)
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(3 * len(self), size))

    def step_terms(self, offsets: dict, size: int, dt: float) -> tuple[sp.coo_matrix, np.ndarray]:
        """This coupling's share of an island's ``A`` [size, size] (COO) and ``b`` [size] (module
        docstring, eq. 5.4). ``D^T D`` is kept while the rigid sides have not turned."""
        key = (size, tuple(offsets[id(p.body)] for p in (self.a, self.b)),
               tuple(p.body.rotation.tobytes() for p in (self.a, self.b) if not hasattr(p, "weights")))
        if self._normal_key != key:
            d = self.relative_jacobian(offsets, size)
            self._d, self._dtd, self._normal_key = d, (d.T @ d).tocoo(), key
        scale = dt * self.damping + dt * dt * self.stiffness
        matrix = sp.coo_matrix((scale * self._dtd.data, (self._dtd.row, self._dtd.col)), shape=self._dtd.shape)
        rhs = -dt * self.stiffness * (self._d.T @ self.stretch().ravel())
        return matrix, rhs
