"""Coupling islands: bodies joined by couplings are stepped as one system (thesis 5.3.2).

Two contact objects belong to the same coupling island if and only if they share a coupling;
islands are found once (couplings are not created or removed while simulating) by union-find
(:func:`coupling_islands`). A body of infinite mass (a fixed or scripted bone) joins no
island: its motion is prescribed, so it couples nothing to anything. Each island that has
couplings to it carries it as a *guest*, whose velocities enter the island's system as known
values (the parts attached to a fixed scapula stay separate islands, solved independently). Each island is one :class:`CouplingIsland`: the members' step
systems ``A_j v_j = b_j`` (eq. 5.2) plus the couplings' off-diagonal blocks (eq. 5.4), solved
together. The island presents the interface of a single contact object (thesis 5.3.3), so the
contact solver treats it like any body: its velocity is the members' velocities one after the
other, cut into blocks of 3 (a rigid member's six are two blocks: linear, angular), and its
Delassus blocks come from the island's own factorization, exactly as for one FEM body.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from softvr.dynamics._sparse_system import SparseNodeSystem
from softvr.dynamics.body import ContactObject
from softvr.dynamics.couplings import Coupling
from softvr.errors import InputError

__all__ = ["CouplingIsland", "connected_components", "coupling_islands"]


def connected_components(count: int, pairs) -> list[list[int]]:
    """Groups of ``range(count)`` linked by ``pairs`` (union-find with path halving).

    Parameters
    ----------
    count : int
    pairs : iterable of (int, int)

    Returns
    -------
    list of list of int
        Every index exactly once; each group sorted, groups ordered by their smallest index.
    """
    parent = list(range(count))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in pairs:
        for i in (a, b):
            if not 0 <= i < count:
                raise InputError("pairs", f"indices in [0, {count - 1}]", repr((a, b)))
        parent[find(a)] = find(b)
    groups: dict[int, list[int]] = {}
    for i in range(count):
        groups.setdefault(find(i), []).append(i)
    return sorted(groups.values())


def coupling_islands(bodies: list, couplings: list) -> list[list[int]]:
    """Indices of ``bodies`` grouped into coupling islands (one group per uncoupled body too);
    couplings to bodies of infinite mass link nothing (module docstring).

    Raises :class:`~softvr.errors.InputError` for a coupling to a body that is not in the list.
    """
    index = {id(b): i for i, b in enumerate(bodies)}
    pairs = []
    for c in couplings:
        ends = []
        for body in c.bodies:
            if id(body) not in index:
                raise InputError(f"{c.name}", "couplings between bodies of the scene", f"{body.name!r} is not in it")
            ends.append(index[id(body)])
        if not any(body.infinite_mass for body in c.bodies):
            pairs.append(tuple(ends))
    return connected_components(len(bodies), pairs)


class CouplingIsland(SparseNodeSystem, ContactObject):
    """Contact objects joined by couplings, stepped and constrained as one (thesis 5.3.2-5.3.3).

    Parameters
    ----------
    members : list of ContactObject
        The coupled bodies (each must offer :meth:`~ContactObject.step_system`).
    couplings : list of Coupling
        Couplings between members, or between a member and a guest.
    guests : list of ContactObject
        Bodies of infinite mass the members are coupled to: their prescribed velocities enter
        the system, but the island neither integrates them nor takes their contacts.
    name : str

    Attributes
    ----------
    v : ndarray, shape [block_count, 3] [m/s, rad/s]
        The members' velocities one after the other, then the guests', cut into blocks of 3.
    offsets : ndarray of int, shape [member_count + guest_count + 1]
        Where each member's (then guest's) flattened velocity starts in the island's.
    fixed : ndarray of bool, shape [block_count]
        Prescribed blocks of the step (fixed nodes, infinite-mass members).
    fixed_velocity : ndarray, shape [block_count, 3]
        Their prescribed velocities.

    The first step's system is solved by sparse LU; later ones by CG preconditioned with the
    last factorization (stiff couplings make plain CG crawl; the exact inverse of a step ago
    needs a few iterations), by LU again if that does not converge in 100. The contact solve's
    Delassus blocks come from a factorization too.
    """

    block_size = 3
    direct_solve = True

    def __init__(self, members: list, couplings: list, *, guests=(), name: str = "coupling island"):
        if not members:
            raise InputError(name, "at least one member body", "none")
        for m in [*members, *guests]:
            if not isinstance(m, ContactObject):
                raise InputError(f"{name} member", "a softvr.dynamics.ContactObject", type(m).__name__)
            if m.velocity_size % 3:
                raise InputError(f"{name} member {m.name!r}", "a velocity size divisible by 3", str(m.velocity_size))
        for g in guests:
            if not g.infinite_mass:
                raise InputError(f"{name} guest {g.name!r}", "a body of infinite mass (fixed, kinematic)",
                                 type(g).__name__)
        ids = {id(m) for m in [*members, *guests]}
        for c in couplings:
            if not isinstance(c, Coupling):
                raise InputError(f"{name} coupling", "a softvr.dynamics.Coupling", type(c).__name__)
            if not all(id(b) in ids for b in c.bodies):
                raise InputError(c.name, f"couplings between members of {name!r}", "a body outside it")
        self.name = name
        self.members = list(members)
        self.guests = list(guests)
        self.couplings = list(couplings)
        self.offsets = np.cumsum([0] + [m.velocity_size for m in [*self.members, *self.guests]])
        self._offset = {id(m): int(o) for m, o in zip([*self.members, *self.guests], self.offsets)}
        blocks = int(self.offsets[-1]) // 3
        self.fixed = np.zeros(blocks, bool)
        self.fixed_velocity = np.zeros((blocks, 3))
        self.step_count = 0
        self.last_cg_iterations = 0
        self.last_cg_converged = True
        self.cg_tolerance = 1e-10
        self.cg_max_iterations = 100

    # -- state ---------------------------------------------------------------------------
    @property
    def v(self) -> np.ndarray:  # type: ignore[override]  # an island's v is read from its bodies' (none of its own)
        bodies = [*self.members, *self.guests]
        return np.concatenate([np.asarray(m.v, float).ravel() for m in bodies]).reshape(-1, 3)

    def member_slices(self) -> list[slice]:
        """Slice of each member's flattened velocity in the island's (guests not included)."""
        return [slice(int(a), int(b)) for a, b in zip(self.offsets[:len(self.members)], self.offsets[1:])]

    def split(self, v) -> list[np.ndarray]:
        """An island velocity [block_count, 3] as the members' velocities (their ``v`` shapes)."""
        flat = np.asarray(v, float).ravel()
        return [flat[s].reshape(np.shape(m.v)) for m, s in zip(self.members, self.member_slices())]

    def block_offset(self, member) -> int:
        """Index of ``member``'s first velocity block in the island's."""
        return self._offset[id(member)] // 3

    def kinetic_energy(self) -> float:
        return sum(float(m.kinetic_energy()) for m in self.members)

    # -- step ----------------------------------------------------------------------------
    def step_system(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None):
        """The island's ``A v = b``: the members' and guests' systems on the block diagonal plus
        every coupling's terms (eq. 5.4). ``external``: None or one entry per member (None or
        the member's generalized force). Returns ``(A, b, prescribed, value)`` over the island."""
        dt = self._check_dt(dt)
        external = [None] * len(self.members) if external is None else list(external)
        if len(external) != len(self.members):
            raise InputError("external", f"one entry per member ({len(self.members)})", f"{len(external)}")
        systems = [m.step_system(dt, gravity, e) for m, e in zip(self.members, external)]
        systems += [g.step_system(dt, gravity, None) for g in self.guests]
        size = int(self.offsets[-1])
        blocks = [sp.block_diag([s.matrix for s in systems], format="coo")]
        b = np.concatenate([np.asarray(s.rhs, float).ravel() for s in systems])
        for c in self.couplings:
            ca, cb = c.step_terms(self._offset, size, dt)
            blocks.append(ca)
            b += cb
        # One summation of every block's triplets (duplicates add up in the CSR conversion).
        a = sp.csr_matrix((np.concatenate([m.data for m in blocks]),
                           (np.concatenate([m.row for m in blocks]), np.concatenate([m.col for m in blocks]))),
                          shape=(size, size))
        prescribed = np.concatenate([s.prescribed for s in systems])
        value = np.concatenate([s.value for s in systems])
        return a.tocsr(), b, prescribed, value

    def unconstrained_velocity(self, dt: float, gravity=(0.0, 0.0, -9.81), external=None) -> np.ndarray:
        """The island's velocity [block_count, 3] solving its ``A v = b`` (eqs. 5.2, 5.4) with the
        prescribed velocities set; prepares :meth:`solve` and :meth:`compliance` for the step."""
        a, b, prescribed, value = self.step_system(dt, gravity, external)
        per_block = prescribed.reshape(-1, 3)
        if (per_block.any(axis=1) != per_block.all(axis=1)).any():
            n = int(np.argmax(per_block.any(axis=1) != per_block.all(axis=1)))
            raise InputError(self.name, "velocity blocks prescribed whole", f"block {n} partly prescribed")
        self.fixed = per_block.all(axis=1)
        self.fixed_velocity = np.where(per_block, value.reshape(-1, 3), 0.0)
        return self._solve_step(a, b)

    def integrate(self, v, dt: float) -> None:
        """Every member integrates its share of ``v`` (each checks itself for divergence); the
        guests are integrated as their own units."""
        dt = self._check_dt(dt)
        for member, vm in zip(self.members, self.split(v)):
            member.integrate(vm, dt)
        self.step_count += 1
