"""Frictional contact as an LCP, solved by projected Gauss-Seidel (thesis eqs. 5.5-5.6, [OTSG09]).

For each contact island the MLCP (eq. 5.5)

    A v = b + J^T lambda,    0 <= lambda_n  _|_  J_n v >= c

is reduced to the LCP of eq. 5.6 on the impulses, ``0 <= lambda _|_ B lambda - d >= 0`` with
``B = J D_A^-1 J^T`` and ``d = c - J v_free``, where ``v_free = A^-1 b`` is every object's
unconstrained velocity and ``D_A`` the block diagonal of A with **one block per contact
object**: objects are independent until couplings join them (eq. 5.3), so ``D_A^-1`` can be
each object's own ``A^-1`` (``M^-1`` for rigid bodies; for FEM and cloth bodies and coupling
islands read off a reordered sparse LU), and the outer Jacobi loop over velocities of eq. 5.6
then converges in one pass. Node bodies keep their factorization over steps
(:meth:`softvr.dynamics.FemBody.compliance`), so their ``D_A`` is an earlier step's ``A``: the
outer loop then runs for real, moving ``(B - B~) lambda`` to the right-hand side with ``B``
applied exactly through the bodies' own solves, until that term changes by less than the PGS
tolerance (at most :data:`OUTER_ITERATIONS` passes within one sweep budget).

The LCP is solved by compiled projected Gauss-Seidel (:mod:`._pgs_kernels`) over contacts,
each a 3x3 block taken as its normal row, then its two tangent rows one at a time, on a
working set of the contacts that can act (the others are checked after each solve).
Friction is a 4-sided Coulomb pyramid, |lambda_t1|, |lambda_t2| <= mu lambda_n, with t1 along
the unconstrained tangential velocity. Adhesive contacts (:mod:`.adhesion`) widen the bounds
by the implicit adhesion constraints of thesis eq. 4.16. Their tangent rows aim at undoing the
contact's stored slip ``u`` [m] within the step, ``t . v = -t . u / dt`` instead of 0, so that
the implicit bound of eq. 4.16 on those rows is the impulse of a tangential spring stretched by
the slip at the end of the step, ``dt A C beta^2 t . (u + dt v)``, and each tangent impulse
lies within the larger of that and the Coulomb bound (steps 6-8 of 4.3.2): a bonded contact
holds like a spring instead of creeping. ``u`` is the slip since bonding; past the debonding
limit a contact under normal traction keeps all of it and debonds by eq. 4.12, and one under
compression slides at its limit (``u`` capped at ``sqrt(W / (C beta))``, with the thesis'
one-step tangential gap ``dt v`` on top): :class:`softvr.contact.AdhesionState` debonds by
``u`` and caps it after the step. Impulses lambda are in N s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from softvr.collision.contacts import Contacts
from softvr.contact._pgs_kernels import pgs_sweeps
from softvr.contact.islands import contact_islands
from softvr.errors import InputError

__all__ = ["ContactSolution", "contact_force_on", "pushing_normals", "solve_contacts"]

#: Most passes of eq. 5.6's outer loop per island when a body's compliance is a kept
#: factorization's (:attr:`softvr.dynamics.FemBody.compliance_is_exact`); one pass otherwise.
OUTER_ITERATIONS = 8
#: Outer passes above which a body's kept factorization is given up (measured: on the cube
#: most kept steps need 2, on the lips 3-8, where refactoring each step is cheaper).
KEPT_FACTOR_PASSES = 2


@dataclass
class ContactSolution:
    """What the contact solve did.

    Attributes
    ----------
    velocities : list of ndarray
        Constrained velocity of every body (the shape of its ``v``).
    impulses : list of ndarray, each [contact_count, 3] [N s]
        Per contact set, per contact: (normal, tangent 1, tangent 2) impulse.
    frames : list of ndarray, each [contact_count, 3, 3]
        Rows: normal, tangent 1, tangent 2 (world).
    iterations : int
        PGS sweeps (summed over islands).
    residual : float [m/s]
        Largest violation of a normal velocity constraint by the final velocities.
    islands : list of list of int
    contacts : list of Contacts
        The non-empty contact sets solved, in the order of ``impulses`` and ``frames``.
    gaps_after : list of ndarray, each [contact_count] [m]
        Linearized normal gap at the end of the step (``gap + dt n . v_rel``).
    """

    velocities: list
    impulses: list
    frames: list
    iterations: int
    residual: float
    islands: list
    contacts: list
    gaps_after: list

    def set_bodies(self) -> list[tuple[int, int | None]]:
        """(side a's body, side b's body or None for a static) of each contact set, in the order
        of ``impulses`` and ``frames``."""
        return [(c.a.body, None if c.b is None else c.b.body) for c in self.contacts]

    def force_on(self, body: int, dt: float) -> np.ndarray:
        """Net contact force [3] [N] on body ``body`` over the step, ``sum F^T lambda / dt``
        (F the contact frame; + on side a, - on side b): negative along a contact normal where
        adhesion pulls. A force sensor on a tool or a jaw."""
        return contact_force_on(self, body, dt)

    def pushing_normals(self, body: int) -> np.ndarray:
        """Normals [m, 3] of body ``body``'s pushing contacts (normal impulse > 0), from the
        other side towards it (a frame's normal, negated where ``body`` is side b), in set
        order: the directions they block (a haptic tool's stiffness)."""
        return pushing_normals(self.set_bodies(), self.impulses, self.frames, body)


def pushing_normals(set_bodies: list, impulses: list, frames: list, body: int) -> np.ndarray:
    """:meth:`ContactSolution.pushing_normals` from a solution's ``set_bodies()``, ``impulses``
    and ``frames`` (per set: [c, 3] [N s], [c, 3, 3])."""
    normals = [np.zeros((0, 3))]
    for (a, b), impulse, frame in zip(set_bodies, impulses, frames):
        if body not in (a, b):
            continue
        normal = frame[impulse[:, 0] > 0, 0]
        if a == body:
            normals.append(normal)
        if b == body:
            normals.append(-normal)
    return np.concatenate(normals)


def contact_force_on(solution, body: int, dt: float) -> np.ndarray:
    """:meth:`ContactSolution.force_on` of any solution with ``set_bodies()``, ``impulses`` and
    ``frames`` (a step on arrays answers these without building its sets' Jacobians)."""
    total = np.zeros(3)
    for (a, b), impulses, frames in zip(solution.set_bodies(), solution.impulses, solution.frames):
        if body not in (a, b):
            continue
        world = np.einsum("ci,cij->j", impulses, frames)
        if a == body:
            total += world
        if b == body:
            total -= world
    return total / float(dt)


def solve_contacts(bodies, v_free, contact_sets, dt: float, *, iterations: int = 500, tolerance: float = 1e-5,
                   warm_start: dict | None = None, adhesion: list | None = None,
                   slip: dict | None = None) -> ContactSolution:
    """Constrained velocities of all bodies (thesis eq. 5.5), contact island by island.

    Parameters
    ----------
    bodies : list of ContactObject
        Each has run ``unconstrained_velocity`` for this step (its ``solve_columns`` uses
        that step's ``A``).
    v_free : list of ndarray
        The unconstrained velocity of each body (the shape of its ``v``).
    contact_sets : list of Contacts
    dt : float [s]
        The normal constraint is ``n . (p_dot_a - p_dot_b) >= -gap / dt``: penetration is
        removed within the step, and a positive gap may close but not be crossed.
    iterations : int
        Most PGS sweeps per island.
    tolerance : float [m/s]
        A sweep whose largest velocity correction (``B_ii |delta lambda_i|`` over the rows) is
        below ``tolerance`` ends the loop: 1e-5 m/s leaves ~1e-5 dt of penetration per step
        (80 nm at 8 ms).
    warm_start : dict, optional
        ``{contact id: world impulse vector (3,)}`` of the previous step, filled in with this
        step's. Kept in world coordinates because the friction frame follows the tangential
        velocity and turns from step to step.
    adhesion : list of ndarray, optional
        Per contact set, ``A C beta^2`` [N/m] of each contact (implicit adhesion, thesis eq.
        4.16; :meth:`softvr.contact.AdhesionState.stiffness`); None or zeros: plain contact.
    slip : dict, optional
        ``{contact id: tangential slip u (3,) [m], world}`` of the bonded contacts
        (:attr:`softvr.contact.AdhesionState.slip`): the stretch of their tangential adhesive
        springs, missing for 0. Updated in place for every contact with adhesion (``A C beta^2
        > 0``) to its slip at the end of the step, ``u + dt v_t`` (``v_t`` the final relative
        velocity in the tangent plane), not capped at the limit stretch: its spring's
        traction is the tangential adhesive traction that
        :meth:`softvr.contact.AdhesionState.evolve` debonds by before capping it. Kept in world
        coordinates because the tangent frame follows the tangential velocity and turns from
        step to step.
    """
    if adhesion is None:
        adhesion = [None] * len(contact_sets)
    if len(adhesion) != len(contact_sets):
        raise InputError("adhesion", f"one entry per contact set ({len(contact_sets)})", f"{len(adhesion)} entries")
    kept = [(c, a) for c, a in zip(contact_sets, adhesion) if len(c)]
    contact_sets = [c for c, _ in kept]
    stiffness = [np.zeros(len(c)) if a is None else np.asarray(a, float) for c, a in kept]
    velocities = [np.array(v, float, copy=True) for v in v_free]
    impulses = [np.zeros((len(c), 3)) for c in contact_sets]
    frames = [np.zeros((len(c), 3, 3)) for c in contact_sets]
    islands = contact_islands(len(bodies), [(c.a.body, None if c.b is None else c.b.body) for c in contact_sets])
    sweeps = 0
    for island in islands:
        sets = [k for k, c in enumerate(contact_sets) if c.a.body in island]
        if sets:
            sweeps += _solve_island(bodies, v_free, island, contact_sets, sets, velocities, impulses, frames, dt,
                                    iterations, tolerance, warm_start, stiffness, slip or {})
    residual = 0.0
    gaps_after = []
    for k, c in enumerate(contact_sets):
        rel = _relative_velocity(c, [v.reshape(-1, bodies[j].block_size) for j, v in enumerate(velocities)])
        approach = -np.einsum("ci,ci->c", rel, c.normal)
        violation = approach - c.gap / dt
        residual = max(residual, float(np.max(violation, initial=0.0)))
        gaps_after.append(c.gap - dt * approach)
        bonded = stiffness[k] > 0
        if slip is not None and bonded.any():
            # The spring's stretch at the end of the step, in the current tangent plane (the
            # cap at the limit is the adhesion state's, after it has debonded by this stretch).
            n = c.normal[bonded]
            u = _slips(slip, c.ids[bonded], n) + dt * rel[bonded]
            u -= np.einsum("ci,ci->c", u, n)[:, None] * n
            slip.update(zip(c.ids[bonded].tolist(), u))
        if warm_start is not None:
            warm_start.update(zip(c.ids.tolist(), np.einsum("cr,crx->cx", impulses[k], frames[k])))
    return ContactSolution(velocities, impulses, frames, sweeps, residual, islands, contact_sets, gaps_after)


def _side_velocity(side, v_blocks: np.ndarray) -> np.ndarray:
    """World point velocities [c, 3] of one contact side."""
    return np.einsum("ckij,ckj->ci", side.jac, v_blocks[side.blocks])


def _relative_velocity(c: Contacts, v_blocks: list) -> np.ndarray:
    rel = _side_velocity(c.a, v_blocks[c.a.body])
    if c.b is not None:
        rel = rel - _side_velocity(c.b, v_blocks[c.b.body])
    return rel


def _frames(contacts: Contacts, rel_velocity: np.ndarray) -> np.ndarray:
    """Contact frames [c, 3, 3]: rows n, t1 (along the tangential velocity), t2 = n x t1."""
    n = contacts.normal
    vt = rel_velocity - np.einsum("ci,ci->c", rel_velocity, n)[:, None] * n
    speed = np.linalg.norm(vt, axis=1)
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.where(speed[:, None] > 1e-9, vt / np.maximum(speed, 1e-300)[:, None], np.cross(n, helper))
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return np.stack([n, t1, np.cross(n, t1)], axis=1)


def _slips(slip: dict, ids: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Tangential slips [c, 3] [m] of contacts ``ids`` (0 where none is stored), in the plane
    normal to ``normal`` [c, 3] (the normal turns a little between steps)."""
    u = np.array([slip.get(int(i), (0.0, 0.0, 0.0)) for i in ids], float).reshape(-1, 3)
    return u - np.einsum("ci,ci->c", u, normal)[:, None] * normal


def _solve_island(bodies, v_free, island, contact_sets, sets, velocities, impulses, frames, dt, iterations, tol,
                  warm, stiffness, slip):
    v_free = [np.asarray(v, float).reshape(-1, b.block_size) for b, v in zip(bodies, v_free)]
    offsets = np.cumsum([0] + [len(contact_sets[k]) for k in sets])
    rows = 3 * int(offsets[-1])
    # Only the velocity blocks the contacts touch enter the Delassus operator.
    touched = {j: [] for j in island}
    for k in sets:
        for side in (contact_sets[k].a, contact_sets[k].b):
            if side is not None:
                touched[side.body].append(side.blocks.ravel())
    touched = {j: np.unique(np.concatenate(b)) for j, b in touched.items() if b}
    # G_j: the island's contact rows (frame-projected point velocities) on body j's touched
    # blocks, sparse (a row touches one stencil): gathered as COO triplets per body.
    triplets = {j: ([], [], []) for j in touched}
    target = np.zeros(rows)
    mu = np.zeros(int(offsets[-1]))
    k_adhesion = np.zeros(int(offsets[-1]))  # dt^2 A C beta^2 per contact [kg]
    lam = np.zeros(rows)
    for s, k in enumerate(sets):
        c = contact_sets[k]
        f = _frames(c, _relative_velocity(c, v_free))
        frames[k] = f
        r0 = 3 * offsets[s]
        contact_rows = r0 + 3 * np.arange(len(c))[:, None] + np.arange(3)  # [c, 3]
        for side, sign in ((c.a, 1.0), (c.b, -1.0)):
            if side is None:
                continue
            bs = bodies[side.body].block_size
            w = sign * np.einsum("crx,ckxb->ckrb", f, side.jac)  # [c, k, 3 rows, bs]
            local = np.searchsorted(touched[side.body], side.blocks)
            cols = bs * local[:, :, None] + np.arange(bs)  # [c, k, bs]
            rr = np.broadcast_to(contact_rows[:, None, :, None], w.shape)
            cc = np.broadcast_to(cols[:, :, None, :], w.shape)
            for store, values in zip(triplets[side.body], (rr, cc, w)):
                store.append(values.ravel())
        target[contact_rows[:, 0]] = -c.gap / dt
        # Bonded contacts' tangent rows aim at undoing their slip within the step: with the
        # implicit bound of eq. 4.16 that is a tangential spring on the slip (module docstring).
        bonded = stiffness[k] > 0
        if bonded.any():
            u = _slips(slip, c.ids[bonded], c.normal[bonded])
            target[contact_rows[bonded, 1:]] = -np.einsum("ctx,cx->ct", f[bonded, 1:], u) / dt
        mu[offsets[s] : offsets[s + 1]] = c.friction
        k_adhesion[offsets[s] : offsets[s + 1]] = dt * dt * stiffness[k]
        if warm:
            for n, cid in enumerate(c.ids.tolist()):
                if cid in warm:
                    start = f[n] @ np.asarray(warm[cid], float)
                    # An adhesive contact may keep a pulling (negative) normal impulse.
                    lam[contact_rows[n]] = start if stiffness[k][n] > 0 else _project(start, c.friction[n])

    g = {j: sp.csr_matrix((np.concatenate(v), (np.concatenate(r), np.concatenate(c))),
                          shape=(rows, len(touched[j]) * bodies[j].block_size)) for j, (r, c, v) in triplets.items()}
    rel_free = sum(g[j] @ v_free[j][blocks].ravel() for j, blocks in touched.items())
    # Bodies whose compliance is a kept (earlier) A^-1: the PGS solves with that D_A and the
    # outer loop of eq. 5.6 moves the rest, (B - B~) lambda, to the right-hand side, with B
    # applied exactly through the bodies' own solves, until it stops changing.
    lagged = [j for j in touched if not getattr(bodies[j], "compliance_is_exact", True)]
    rhs, sweeps = rel_free, 0
    for passes in range(1, OUTER_ITERATIONS + 1):
        # The passes share the sweep budget: where PGS cannot converge (redundant contacts) the
        # outer loop must not multiply its cost.
        done, lam, predicted = _solve_working_set(bodies, touched, g, rhs, target, mu, k_adhesion, lam,
                                                  max(iterations - sweeps, 1), tol)
        sweeps += done
        for j, blocks in touched.items():
            bs = bodies[j].block_size
            impulse = np.zeros_like(v_free[j])
            impulse[blocks] = (g[j].T @ lam).reshape(-1, bs)
            velocities[j] = (v_free[j] + np.asarray(bodies[j].solve(impulse.reshape(velocities[j].shape)),
                                                      float).reshape(v_free[j].shape)).reshape(velocities[j].shape)
        if not lagged:
            break
        actual = sum(g[j] @ np.asarray(velocities[j], float).reshape(v_free[j].shape)[blocks].ravel()
                     for j, blocks in touched.items())
        # actual = rel_free0 + B lambda; predicted = rhs + B~ lambda.
        corrected = actual - (predicted - rhs)
        change = float(np.abs(corrected - rhs).max(initial=0.0))
        rhs = corrected
        if change <= tol or sweeps >= iterations:
            break
    if lagged and passes > KEPT_FACTOR_PASSES:
        # The kept A has drifted too far to pay for itself: refactor on the next step.
        for j in lagged:
            bodies[j].discard_kept_factorization()
    for s, k in enumerate(sets):
        impulses[k] = lam[3 * offsets[s] : 3 * offsets[s + 1]].reshape(-1, 3)
    return sweeps


def _solve_working_set(bodies, touched, g, rel_free, target, mu, k_adhesion, lam, iterations, tol):
    """PGS on the contacts that can push (working set), grown until no other one is violated.

    Most contacts near a resting pile are speculative (a gap within the margin, not closing)
    and end with zero impulse; PGS over all of them pays ``O(rows)`` per update for nothing.
    The working set starts with the warm-started contacts, the adhesive ones (they may pull)
    and those whose unconstrained motion violates their constraint; after each solve the
    normal rows outside it are checked with the columns of the Delassus operator
    ``B = sum_j G_j (A_j^-1)_touched G_j^T`` (eq. 5.6) of the working rows, and violated ones
    join. The columns are computed once per contact.
    Returns (PGS sweeps, impulses [rows], the contact rows' velocities ``rel_free + B lambda``
    [rows] [m/s] predicted with the bodies' compliances).
    """
    rows = len(target)
    compliance = {j: bodies[j].compliance(blocks) for j, blocks in touched.items()}
    columns = np.zeros((rows, 0))  # B[:, working rows]
    working = np.zeros(0, int)  # working rows, 3 per contact
    normal = np.arange(0, rows, 3)
    joining = normal[(lam[normal] != 0) | (k_adhesion > 0) | (rel_free[normal] < target[normal] - tol)]
    sweeps = 0
    while len(joining):
        new_rows = (joining[:, None] + np.arange(3)).ravel()
        block = np.zeros((rows, len(new_rows)))
        for j, gj in g.items():
            sub = gj[new_rows]
            if sub.nnz:
                block += gj @ (compliance[j] @ sub.T.toarray())
        columns = np.hstack([columns, block])
        working = np.concatenate([working, new_rows])
        w_lam = lam[working]
        w_rel = rel_free[working] + columns[working] @ w_lam
        contacts = working[0::3] // 3
        sweeps += pgs_sweeps(np.ascontiguousarray(columns[working]), target[working], mu[contacts], w_lam, w_rel,
                             iterations, tol, k_adhesion[contacts])
        lam = np.zeros(rows)
        lam[working] = w_lam
        rel = rel_free + columns @ w_lam
        outside = np.ones(rows, bool)
        outside[working] = False
        joining = normal[outside[normal] & (rel[normal] < target[normal] - tol)]
    return sweeps, lam, rel_free + columns @ lam[working]


def _project(lam: np.ndarray, mu: float) -> np.ndarray:
    """Signorini + 4-sided Coulomb pyramid: lambda_n >= 0, |lambda_t| <= mu lambda_n per tangent."""
    n = max(lam[0], 0.0)
    bound = mu * n
    return np.array([n, min(max(lam[1], -bound), bound), min(max(lam[2], -bound), bound)])
