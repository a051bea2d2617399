"""The interface every contact object shares (thesis 5.1.1).

A contact object has a state vector ``q`` and a velocity vector ``v`` with ``q_dot = G v``
(thesis eq. 5.1). Each step the simulation asks every object for its unconstrained velocity,
the solution of the linearized backward-Euler system ``A v = b`` (eq. 5.2); contact and
coupling solvers then need ``A^-1`` applied to generalized impulses (:meth:`solve`), and
finally the object integrates its state with the constrained velocity (:meth:`integrate`).
Objects are independent (A is block diagonal, eq. 5.3), so each solves its own block; objects
joined by couplings (eq. 5.4) are solved together by a
:class:`~softvr.dynamics.CouplingIsland`, which assembles their :meth:`~ContactObject.step_system`.

Shapes are the subclass's natural ones (node arrays ``[node_count, 3]`` for deformables,
``[6]`` for a rigid body); :attr:`velocity_size` is the flattened length used by Jacobians.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from softvr.errors import InputError, SimulationError

__all__ = ["ContactObject", "StepSystem"]


@dataclass
class StepSystem:
    """One object's backward-Euler step ``A v = b`` (thesis eq. 5.2) over its flattened velocity.

    Attributes
    ----------
    matrix : scipy.sparse matrix, shape [n, n]
        ``A`` [kg, kg m^2] (n = velocity_size).
    rhs : ndarray, shape [n]
        ``b`` [N s, N m s].
    prescribed : ndarray of bool, shape [n]
        Velocities that are set, not solved for (fixed nodes, infinite masses).
    value : ndarray, shape [n] [m/s, rad/s]
        The prescribed velocities (ignored elsewhere).
    """

    matrix: sp.spmatrix
    rhs: np.ndarray
    prescribed: np.ndarray
    value: np.ndarray


class ContactObject(ABC):
    """Base of rigid, FEM, cloth, fixed and kinematic bodies.

    Attributes
    ----------
    name : str
        Named in error and divergence reports.
    v : ndarray [m/s, rad/s]
        Velocity vector (subclass shape).
    step_count : int
        Completed steps.
    """

    name: str
    v: np.ndarray
    step_count: int

    #: True for bodies no force moves (fixed, scripted): couplings to them join no island.
    infinite_mass: bool = False

    @property
    def velocity_size(self) -> int:
        """Length of the flattened velocity vector."""
        return int(np.asarray(self.v).size)

    @abstractmethod
    def unconstrained_velocity(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> np.ndarray:
        """Velocity after one backward-Euler step without constraints: ``A v = b`` (eq. 5.2).

        Also prepares :meth:`solve` for this step (the matrix ``A`` of the current state).

        Parameters
        ----------
        dt : float [s]
        gravity : (3,) [m/s^2]
        external : ndarray, optional
            Generalized external force [N, N m], the shape of ``v``.

        Returns
        -------
        ndarray, the shape of ``v``
        """

    def step_system(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> StepSystem:
        """This step's ``A v = b`` (eq. 5.2) for a coupling island to assemble (eq. 5.4); the
        arguments as for :meth:`unconstrained_velocity`."""
        raise InputError(self.name, "a body that can be coupled (rigid, FEM, cloth, fixed, kinematic)",
                         type(self).__name__)

    @abstractmethod
    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A^-1 rhs`` with the step's ``A`` (prepared by :meth:`unconstrained_velocity`).

        Constraint solvers use it to turn generalized impulses ``J^T lambda`` into velocity
        changes, so it must be symmetric positive definite: an object whose ``A`` is not
        symmetric (a spinning rigid body's implicit gyroscopic term) answers with its
        symmetric part's leading term (``M^-1``), which differs by O(dt). ``rhs`` and the
        result have the shape of ``v``.
        """

    #: Velocities per block: contact Jacobians address blocks (a node's 3; a rigid body's 6).
    block_size: int = 3

    def solve_columns(self, columns: np.ndarray) -> np.ndarray:
        """``A^-1 C`` for a matrix ``C`` [velocity_size, k] (contact compliance, eq. 5.6).

        The default solves column by column with :meth:`solve`; objects with a factorization
        override it.
        """
        shape = np.shape(self.v)
        cols = np.asarray(columns, float)
        return np.stack([np.asarray(self.solve(c.reshape(shape)), float).ravel() for c in cols.T], axis=1) \
            if cols.shape[1] else np.zeros_like(cols)

    def compliance(self, blocks: np.ndarray) -> np.ndarray:
        """Rows and columns of ``A^-1`` at the velocity ``blocks`` [k]: shape
        [k block_size, k block_size], this object's block of the Delassus operator (eq. 5.6).

        The default solves for the unit columns with :meth:`solve_columns`; FEM and cloth
        bodies read it off a factorization that eliminates those velocities last.
        """
        bs = self.block_size
        dofs = (bs * np.asarray(blocks, int).ravel()[:, None] + np.arange(bs)).ravel()
        unit = np.zeros((self.velocity_size, len(dofs)))
        unit[dofs, np.arange(len(dofs))] = 1.0
        return self.solve_columns(unit)[dofs]

    def immovable(self, blocks: np.ndarray) -> np.ndarray:
        """Which velocity ``blocks`` (any shape) no impulse can move: bool, the shape of ``blocks``
        (fixed nodes, bodies of infinite mass). Contacts between immovable blocks only are dropped."""
        return np.zeros(np.shape(blocks), bool)

    @abstractmethod
    def integrate(self, v: np.ndarray, dt: float) -> None:
        """Set the velocity to ``v`` and advance the state: ``q += dt G v``; count the step.

        Raises :class:`~softvr.errors.SimulationError` naming the body and the step if the new
        state is not finite or blows up.
        """

    def step(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> None:
        """One unconstrained backward-Euler step: :meth:`unconstrained_velocity` then :meth:`integrate`."""
        self.integrate(self.unconstrained_velocity(dt, gravity, external), dt)

    @abstractmethod
    def kinetic_energy(self) -> float:
        """Kinetic energy [J]."""

    # -------------------------------------------------------------- shared helpers
    @staticmethod
    def _check_dt(dt: float) -> float:
        if not (isinstance(dt, (int, float, np.floating)) and np.isfinite(dt) and dt > 0):
            raise InputError("dt", "a finite time step > 0 [s]", repr(dt))
        return float(dt)

    def _diverged(self, what: str) -> SimulationError:
        return SimulationError(f"{self.name}: diverged at step {self.step_count + 1} ({what})")
