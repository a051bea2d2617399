"""The factored contact solve (:mod:`softvr.contact.node_factored`, thesis eq. 5.2 and 5.5) for
scenes with spring-held rigid bodies and coupling springs: the shoulder (8 soft parts, 279
coupling springs, the fingers and the rigid tendons on springs, ~200 contacts), whose
Gauss-Seidel sweeps take ~35-60 a step while a factorization kept across steps takes 3-7
outer iterations.

What the held FEM bodies' solve does not have, and what it takes here:

* **Rigid bodies' nodes** (a body's linear and angular velocity): a spring-held body's two
  nodes have blocks of ``A`` (``m I``, ``I_w``, the springs' ``(dt c + dt^2 k) B^T B``, eq.
  5.4), so they are rows of the factored ``A_0`` like the FEM nodes. They have no tets to turn
  them by: their ``R`` is the identity, so ``P``'s rows there are ``A_0``'s, and the outer
  iteration takes the change of their blocks since the factorization (the body's turn, its
  levers) like any other part of ``A - P``. They are kept out of the local Woodbury correction:
  a correction of one of a body's two nodes without the other (or of its springs' far ends)
  can leave ``P`` indefinite (the shoulder's finger: a diagonal block of ``W`` with eigenvalue
  -470 1/kg at step 40). The FEM nodes' correction can too: a step whose ``W`` has a diagonal
  block not positive definite goes without it, and an iteration that ends non-finite starts the
  step again on a factorization of its own ``A`` (the palpation's step 512 of 600 did).
* **Coupling springs** are blocks of ``A``: nothing to do.
* **Rigid contact sides**: a contact's Jacobian adds the block ``-[lever]x`` on a rigid side's
  angular node (``NodeContacts.rigid_node``, ``rigid_lever``: the point moves at
  ``v + omega x lever``) to its stencil's node weights.
* **Many speculative contacts**: ``W`` is built over the contacts that may push (a carried
  impulse, or a first-guess gap after the step under half the gap now; 14-24 of the
  shoulder's ~200), the others left at zero and checked by the residual kernel at the stop;
  any that the solved velocities close beyond their target joins them and the iteration goes
  on. The dense ``W`` over all of them took ~100 ms a step.
* **The impulses' response** ``P^-1 J^T lambda`` by a second triangular solve pair (0.09 ms on
  the shoulder) rather than a product with the kept columns of ``A_0^-1``: NumPy's dense
  products over a few hundred columns call OpenBLAS threads, which spin on a loaded machine
  (8 ms for 2 298 x 492 at load 8). ``W`` is built through sparse products with ``J``.
* **The stop** counts a rigid body's angular change at its radius of gyration about the
  centre (``sqrt(trace(I) / 2 m)``, the speed a spin gives its surface, about), in m/s like
  every other change.
"""

from __future__ import annotations

from collections import deque

import numpy as np
import warp as wp

from softvr.contact import _node_factored_kernels as _k
from softvr.contact import _node_factored_rigid_kernels as _rk
from softvr.contact.node_factored import ANDERSON_MEMORY, REFACTOR_AFTER, REFRESH_PERIOD, FactoredSolve, _error
from softvr.device import load_kernels, replayer

__all__ = ["CLOSING_SHARE", "FACTORED_ABOVE_SWEEPS", "WATCHED_STEPS", "RigidFactoredSolve", "SweepWatch",
           "rigid_factored_eligible"]

#: A contact with no carried impulse joins the step's Delassus matrix where the first guess
#: (the step's start velocities) leaves it a gap after the step under this share of its gap now
#: (as the sweeps' sleeping contacts: ``SLEEP_GAP_SHARE``).
CLOSING_SHARE = 0.5
#: The sweeps' steps watched (:class:`SweepWatch`), and the mean sweeps a step over them above
#: which the factored solve takes over: about where the two cost the same, measured on the
#: shoulder's palpation (process CPU, loaded 2-core machine): a factored step ~3.5-4 ms (~2 ms a
#: step, ~0.4 an outer iteration, ~5 of them), a sweep (coarse-corrected Gauss-Seidel) ~0.2 ms.
WATCHED_STEPS = 20
FACTORED_ABOVE_SWEEPS = 20.0


def rigid_factored_eligible(model) -> bool:
    """Whether :class:`RigidFactoredSolve` can step the scene: on the CPU, no cloth (as
    :func:`softvr.contact.node_factored.factored_eligible`), with rigid bodies or coupling
    springs, every rigid body held by springs (its two nodes rows of ``A``: a free body's
    nodes have no blocks, the sweeps solve it exactly)."""
    if not wp.get_device(model.device).is_cpu or model.cloth.spring_count:
        return False
    if model.rigid is None:
        return bool(len(model.couplings.node))
    rows = np.diff(model.row_start.numpy()) > 0
    nodes = np.concatenate([model.rigid.linear_node.numpy(), model.rigid.angular_node.numpy()])
    return bool(rows[nodes].all())


class SweepWatch:
    """The node sweeps' counts over the last :data:`WATCHED_STEPS` steps of a scene that
    :class:`RigidFactoredSolve` can step (:meth:`of`): :meth:`due` once their mean is over
    :data:`FACTORED_ABOVE_SWEEPS` (a choice from what the sweeps did, not from their estimated
    work a decade, which both shoulder scenes are over)."""

    def __init__(self) -> None:
        self._counts: deque[int] = deque(maxlen=WATCHED_STEPS)

    @classmethod
    def of(cls, model) -> SweepWatch | None:
        """A watch for ``model``'s sweeps where :func:`rigid_factored_eligible`, else None; the
        factored solve's kernels compiled (or loaded) now, not in the step that takes it."""
        if not rigid_factored_eligible(model):
            return None
        for kernel in (_k.factor_solve, _rk.delassus):
            load_kernels(kernel, model.device)
        return cls()

    def due(self, sweeps: int) -> bool:
        """Whether the factored solve should take over after a step of ``sweeps`` sweeps."""
        self._counts.append(int(sweeps))
        return len(self._counts) == WATCHED_STEPS and sum(self._counts) > FACTORED_ABOVE_SWEEPS * WATCHED_STEPS


def _skew(r: np.ndarray) -> np.ndarray:
    """``[r]x`` [..., 3, 3] of vectors ``r`` [..., 3]."""
    out = np.zeros(r.shape + (3,))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -r[..., 2], r[..., 1], -r[..., 0]
    return out - np.swapaxes(out, -1, -2)


class RigidFactoredSolve(FactoredSolve):
    """:class:`FactoredSolve` over FEM nodes, spring-held rigid bodies' nodes and coupling
    springs (module docstring); same parameters and attributes, and

    Attributes
    ----------
    added : int
        Contacts that joined the Delassus matrix during the last solve (left out at its start,
        closed beyond their target by the solved velocities).
    """

    def __init__(self, model, state, dt: float, *, max_iterations: int = 100):
        d = model.device
        rigid = model.rigid
        linear = np.zeros(0, np.int64) if rigid is None else rigid.linear_node.numpy().astype(np.int64)
        angular = np.zeros(0, np.int64) if rigid is None else rigid.angular_node.numpy().astype(np.int64)
        self._rigid = np.concatenate([linear, angular])  # nodes without tets: R = I
        # The stop's weight of each velocity component [m/s per unit]: 1, and a rigid body's
        # radius of gyration [m] on its angular node (rad/s).
        weight = np.ones((model.node_count, 3))
        if rigid is not None:
            inertia, inv_mass = rigid.model.body_inertia.numpy(), rigid.model.body_inv_mass.numpy()
            weight[angular] = np.sqrt(np.einsum("bii->b", inertia) * inv_mass / 2.0)[:, None]
        self._weight = weight.ravel()
        self.added = 0
        self._delassus_in: dict | None = None  # the Delassus kernel's arrays (host views), grown
        self._delassus_wp: dict = {}
        self._delassus_launch = lambda: None  # W's replayed kernel on the arrays of _delassus_inputs
        load_kernels(_rk.delassus, d)  # the module: its iteration kernels too
        super().__init__(model, state, dt, max_iterations=max_iterations)
        k = len(self._solved_nodes)
        self._rhs2 = wp.zeros(k, dtype=wp.vec3d, device=d)
        self._y2 = wp.zeros(k, dtype=wp.vec3d, device=d)
        self._work2 = wp.zeros(k, dtype=wp.vec3d, device=d)
        self._host.update(rhs2=self._rhs2.numpy(), y2=self._y2.numpy(), absolute=self._absolute.numpy(),
                          rotation0=self._rotation0.numpy(), gap_after=state.contacts.gap_after.numpy(),
                          rigid_node=state.contacts.rigid_node.numpy(), rigid_lever=state.contacts.rigid_lever.numpy())
        self._rigid_rows = self._index[self._rigid]
        # The outer iteration's kernels' arrays: sizes (3 s, 3 u, contacts), the change and
        # whether it is finite, Anderson's memory, per-step arrays (:meth:`_iteration_arrays`).
        n = model.node_count
        self._sizes = wp.zeros(3, dtype=wp.int32, device=d)
        self._out = wp.zeros(2, dtype=wp.float64, device=d)
        self._index_d: wp.array = wp.array(np.where(self._solved, self._index, -1).astype(np.int32), dtype=wp.int32,
                                           device=d)
        self._weight_d: wp.array = wp.array(self._weight.reshape(-1, 3), dtype=wp.vec3d, device=d)
        self._anderson_wp = {"last_f": wp.zeros(n, dtype=wp.vec3d, device=d),
                             "last_g": wp.zeros(n, dtype=wp.vec3d, device=d),
                             "df": wp.zeros((ANDERSON_MEMORY, n), dtype=wp.vec3d, device=d),
                             "dg": wp.zeros((ANDERSON_MEMORY, n), dtype=wp.vec3d, device=d),
                             "gram": wp.zeros((ANDERSON_MEMORY, ANDERSON_MEMORY), dtype=wp.float64, device=d),
                             "system": wp.zeros((ANDERSON_MEMORY, ANDERSON_MEMORY + 1), dtype=wp.float64, device=d),
                             "gamma": wp.zeros(ANDERSON_MEMORY, dtype=wp.float64, device=d),
                             "ring": wp.zeros(3, dtype=wp.int32, device=d)}
        self._sizes_host = self._sizes.numpy()
        self._host.update(out=self._out.numpy(), ring=self._anderson_wp["ring"].numpy())
        self._iteration_in: dict | None = None
        self._iteration_wp: dict = {}
        self._iteration_for: tuple | None = None
        self._iteration_replays: tuple = ()
        self._unturn_rigid()
        self._solve_impulse = self._record_impulse_solve()
        warp_change = self._warp_change

        def change_off_rigid() -> None:
            warp_change()
            self._host["change"][self._rigid] = 0.0
        self._warp_change = change_off_rigid

    def _record_impulse_solve(self):
        """The replayed block solve ``y2 = A_0^-1 rhs2`` on this factorization."""
        return replayer(wp.launch(_k.factor_solve, dim=1, device=self.model.device, record_cmd=True,
                                  inputs=[*self._factors, self._rhs2, self._work2, self._y2]))

    def _factor(self) -> None:
        super()._factor()
        if hasattr(self, "_rhs2"):  # a factorization after the first: its rigid rows and solve anew
            self._unturn_rigid()
            self._solve_impulse = self._record_impulse_solve()

    def _unturn_rigid(self) -> None:
        """The rigid nodes' rotations (the tets' kernel leaves them undefined: no tets) set to
        the identity, now and at the factorization."""
        h = self._host
        h["absolute"][self._rigid_rows] = np.eye(3)
        h["rotation0"][self._rigid_rows] = np.eye(3)
        h["rotation"][self._rigid] = np.eye(3)

    def _turn(self) -> None:
        """The nodes' rotations since the factorization (rigid nodes: the identity)."""
        self._rotations()
        self._host["absolute"][self._rigid_rows] = np.eye(3)
        self._host["rotation"][self._rigid] = np.eye(3)

    def _candidate_contacts(self, local: tuple, candidate: np.ndarray) -> tuple:
        """The ``candidate`` [count] contacts the impulses can move (a solved node of nonzero
        block in the stencil or on a rigid side): their rows [m], ``W = J P^-1 J^T`` [3 m,
        3 m] in their frames, the touched solved nodes' rows among the solved velocities [3 u],
        ``A_0^-1`` between the local correction's ``S`` and them [3 s, 3 u], and per contact
        and slot (its stencil's nodes, then its rigid sides' angular nodes) [m, t]: the node
        (any; unused slots node 0), ``J``'s block (frames) [m, t, 3, 3], the touched node it
        moves (-1: none) and its block of ``J R`` there [m, t, 3, 3]."""
        h = self._host
        n = min(int(h["count"][0]), len(h["impulse"]))
        used = np.arange(h["stencil_nodes"].shape[1]) < h["stencil_count"][:n, None]
        rigid_node = h["rigid_node"][:n]
        nodes = np.concatenate([np.where(used, h["stencil_nodes"][:n], 0), np.maximum(rigid_node, 0)], axis=1)
        moves = np.concatenate([used & (h["stencil_weights"][:n] != 0.0), rigid_node >= 0], axis=1) & self._solved[nodes]
        movable = moves.any(axis=1)
        h["movable"][:n] = movable
        self._movable_all = movable
        rows = np.flatnonzero(movable & candidate)
        nodes, moves, m = nodes[rows], moves[rows], len(rows)
        stencil = np.where(used[rows], h["stencil_weights"][rows], 0.0)[..., None, None] * np.eye(3)
        rigid = np.where((rigid_node[rows] >= 0)[..., None, None], -_skew(h["rigid_lever"][rows]), 0.0)
        jb = np.matmul(h["frame"][rows][:, None], np.concatenate([stencil, rigid], axis=1))  # J's blocks, frames
        touched, at = np.unique(nodes[moves], return_inverse=True)
        slots = self._slots_of(touched)
        dofs = (3 * self._index[touched][:, None] + np.arange(3)).ravel()
        near = self._columns[np.ix_(local[0], slots)]
        d = self._delassus_inputs(m, len(touched), nodes.shape[1])
        slot, turned = d["slot"][:m], d["turned"][:m]
        d["node"][:m], d["block"][:m] = nodes, jb
        slot[:] = -1
        slot[moves] = at
        turned[:] = np.where(moves[..., None, None], np.matmul(jb, h["rotation"][nodes]), 0.0)  # J R
        inverse = d["inverse"][:len(dofs), :len(dofs)]  # R^T P^-1 R at the touched nodes
        inverse[:] = self._columns[np.ix_(dofs, slots)]
        if len(local[0]):
            inverse -= near.T @ local[2] @ near
        self._sizes_host[:] = len(local[0]), len(dofs), m
        if m:
            self._delassus_launch()
        w = d["w"][:3 * m, :3 * m]
        w = 0.5 * (w + w.T)
        each = np.arange(m)
        h["metric"][:n] = 0.0
        h["metric"][rows] = w.reshape(m, 3, m, 3)[each, :, each, :]
        self._used = np.concatenate([local[1], slots])
        return rows, w, dofs, near, nodes, jb, slot, turned

    def _delassus_inputs(self, m: int, touched: int, slots: int) -> dict:
        """Host views of the Delassus kernel's arrays (:func:`_node_factored_rigid_kernels.delassus`)
        for ``m`` contacts of ``slots`` slots over ``touched`` nodes, grown (twice the size)
        where they are short."""
        have = self._delassus_in
        if have is None or have["slot"].shape[0] < m or have["slot"].shape[1] != slots or \
                have["inverse"].shape[0] < 3 * touched:
            d = self.model.device
            size, nodes = max(2 * m, 16), max(2 * touched, 16)
            self._delassus_wp = {"slot": wp.zeros((size, slots), dtype=wp.int32, device=d),
                                 "turned": wp.zeros((size, slots), dtype=wp.mat33d, device=d),
                                 "node": wp.zeros((size, slots), dtype=wp.int32, device=d),
                                 "block": wp.zeros((size, slots), dtype=wp.mat33d, device=d),
                                 "inverse": wp.zeros((3 * nodes, 3 * nodes), dtype=wp.float64, device=d),
                                 "w": wp.zeros((3 * size, 3 * size), dtype=wp.float64, device=d),
                                 "half": wp.zeros((size, nodes), dtype=wp.mat33d, device=d)}
            have = self._delassus_in = {name: array.numpy() for name, array in self._delassus_wp.items()}
            a = self._delassus_wp
            self._delassus_launch = replayer(wp.launch(
                _rk.delassus, dim=1, device=d, record_cmd=True,
                inputs=[self._sizes, a["slot"], a["turned"], a["inverse"], a["half"], a["w"]]))
        return have



    def _candidates(self) -> np.ndarray:
        """Contacts that may push this step [count] (bool): a carried impulse, or a gap after
        the step in the start velocities under :data:`CLOSING_SHARE` of the gap now (the
        residual kernel's ``gap_after``); the others' impulses are set to zero."""
        h = self._host
        n = min(int(h["count"][0]), len(h["impulse"]))
        self._residual_check()
        gap = h["gap"][:n]
        out = (h["impulse"][:n, 0] > 0.0) | (h["gap_after"][:n] < CLOSING_SHARE * np.maximum(gap, 0.0))
        h["impulse"][:n][~out] = 0.0
        return out

    def _iteration_arrays(self, s_count: int, u_count: int) -> dict:
        """Host views of the outer iteration kernels' per-step arrays for a local correction of
        ``s_count`` and ``u_count`` touched velocities, grown (twice the size) where short."""
        have = self._iteration_in
        if have is None or have["local_t"].shape[0] < s_count or have["near"].shape[1] < u_count:
            d, k = self.model.device, len(self._solved_nodes)
            s_cap = max(2 * s_count, 48, 0 if have is None else have["local_t"].shape[0])
            u_cap = max(2 * u_count, 192, 0 if have is None else have["near"].shape[1])
            self._iteration_wp = {"local_dofs": wp.zeros(s_cap, dtype=wp.int32, device=d),
                                  "local_t": wp.zeros((s_cap, s_cap), dtype=wp.float64, device=d),
                                  "local_columns": wp.zeros((3 * k, s_cap), dtype=wp.float64, device=d),
                                  "z": wp.zeros(s_cap, dtype=wp.float64, device=d),
                                  "dofs": wp.zeros(u_cap, dtype=wp.int32, device=d),
                                  "near": wp.zeros((s_cap, u_cap), dtype=wp.float64, device=d),
                                  "at": wp.zeros(u_cap, dtype=wp.float64, device=d)}
            have = self._iteration_in = {name: array.numpy() for name, array in self._iteration_wp.items()}
        return have

    def _iteration(self, local: tuple, dofs: np.ndarray, near: np.ndarray) -> tuple:
        """The outer iteration's three kernels (:mod:`_node_factored_rigid_kernels`:
        ``contact_velocity``, ``impulse_push``, ``outer_update``) loaded with this step's local
        correction ``local`` (:meth:`_local`), touched velocities ``dofs`` [3 u] and ``near`` [3 s,
        3 u] (the contacts' count is set by :meth:`_candidate_contacts`), recorded again where
        their arrays were replaced."""
        s_count, u_count = len(local[0]), len(dofs)
        a = self._iteration_arrays(s_count, u_count)
        a["local_dofs"][:s_count] = local[0]
        a["local_t"][:s_count, :s_count] = local[2]
        a["local_columns"][:, :s_count] = self._columns[:, local[1]]
        a["dofs"][:u_count] = dofs
        a["near"][:s_count, :u_count] = near
        self._host["rhs2"][:] = 0.0
        arrays = (self._delassus_keep, self._delassus_wp, self._iteration_wp)
        if self._iteration_for is None or any(x is not y for x, y in zip(arrays, self._iteration_for)):
            self._iteration_for = arrays
            self._iteration_replays = self._record_iteration()
        return self._iteration_replays

    def _record_iteration(self) -> tuple:
        """Replayers of the outer iteration's kernels on the current arrays."""
        d, pgs, dl, it = self.model.device, self._delassus_keep, self._delassus_wp, self._iteration_wp
        sizes, a = self._sizes, self._anderson_wp
        return tuple(replayer(wp.launch(kernel, dim=1, device=d, record_cmd=True, inputs=inputs)) for kernel, inputs in (
            (_rk.contact_velocity, [sizes, it["local_dofs"], it["local_t"], it["dofs"], it["near"], self._y,
                                    dl["slot"], dl["node"], dl["block"], dl["turned"], self._v, it["z"], it["at"],
                                    pgs["u"]]),
            (_rk.impulse_push, [sizes, it["dofs"], dl["slot"], dl["turned"], pgs["impulse"], self._rhs2]),
            (_rk.outer_update, [sizes, it["local_dofs"], it["local_t"], it["local_columns"], self._index_d,
                                self._rotation, self._weight_d, self._y, self._y2, it["z"], self._v, self._u,
                                a["last_f"], a["last_g"], a["df"], a["dg"], a["gram"], a["system"], a["gamma"],
                                a["ring"], self._out])))

    def solve(self, tolerance: float) -> tuple[int, wp.array]:
        """:meth:`FactoredSolve.solve` with the contacts of :meth:`_candidates` in ``W`` and any
        the solved velocities close beyond their target added on the way (``added``); the
        impulses' response by a second triangular solve. An outer iteration is a fixed sequence
        of replayed launches (residual, block solve, the contacts' velocities, PGS on ``W``,
        the impulses' solve, update and Anderson's step) and one number read back, its change."""
        st, h = self.state, self._host
        v, buffers = h["v"], h["buffers"]
        v[:] = buffers[0]
        v[self._fixed_nodes] = self._fixed_velocity[self._fixed_nodes]
        start = v.copy()
        # P's turned parts refreshed in turns (REFRESH_PERIOD, as FactoredSolve), both after a factorization.
        self._steps += 1
        fresh = self._kept_local is None
        if fresh or self._steps % REFRESH_PERIOD == 0:
            self._turn()
        self._forget_columns()
        local = self._local() if fresh or self._steps % REFRESH_PERIOD == 1 % REFRESH_PERIOD else self._last_local()
        candidate = self._candidates()
        n = len(candidate)
        self.delassus_passes = self.added = 0
        k = restart = 0
        done = False
        out, ring = h["out"], h["ring"]
        while not done and k < self.max_iterations:
            rows, w, dofs, near, nodes, jb, slot, turned = self._candidate_contacts(local, candidate)
            if len(local[0]) and len(rows) and np.linalg.eigvalsh(h["metric"][rows]).min() <= 0.0:
                # the local correction left P indefinite at the contacts: this step without it
                local = (local[0][:0], local[1][:0], local[2][:0, :0])
                rows, w, dofs, near, nodes, jb, slot, turned = self._candidate_contacts(local, candidate)
            m = len(rows)
            pgs = self._load(rows, w, tolerance)
            lam = pgs["impulse"][:m]
            velocity, push, update = self._iteration(local, dofs, near)
            ring[:] = 0  # Anderson's memory emptied
            changes: list[float] = []
            while k < self.max_iterations:
                if k - restart == REFACTOR_AFTER:  # the deformation has taken A too far from R A_0 R^T
                    self._factor()
                    local = self._local()
                    restart = k
                    break
                k += 1
                self._residual()  # R^T r
                self._solve_r()  # A_0^-1 R^T r
                if m:
                    velocity()  # J v + J P^-1 r
                    self._pgs()
                    self.delassus_passes += int(h["done"][0])
                    push()  # R^T J^T lambda
                    self._solve_impulse()
                update()  # u = v + P^-1 (r + J^T lambda), Anderson's next v
                change = float(out[0])
                if out[1]:  # P went indefinite (module docstring): an exact one
                    v[:] = start
                    self._factor()
                    local = self._local()
                    restart = k
                    break
                h["stats"][0] = change
                changes.append(change)
                if _error(changes) <= tolerance:
                    if self._contacts_met(rows, lam, tolerance):
                        done = True
                        break
                    late = ~candidate & self._movable_all & (h["gap_after"][:n] < -tolerance * self.dt)
                    if late.any():
                        candidate |= late
                        self.added += int(late.sum())
                        break
        if not done:
            self._contacts_met(rows, lam, tolerance)
        buffers[k % 3][:] = v
        return k, st.sweep_buffers[k % 3]
