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
  -470 1/kg at step 40).
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

import numpy as np
import scipy.sparse as sp
import warp as wp

from softvr.contact import _node_factored_kernels as _k
from softvr.contact.node_factored import ANDERSON_MEMORY, REFACTOR_AFTER, FactoredSolve, _Anderson, _error
from softvr.device import replayer

__all__ = ["CLOSING_SHARE", "RigidFactoredSolve", "rigid_factored_eligible"]

#: A contact with no carried impulse joins the step's Delassus matrix where the first guess
#: (the step's start velocities) leaves it a gap after the step under this share of its gap now
#: (as the sweeps' sleeping contacts: ``SLEEP_GAP_SHARE``).
CLOSING_SHARE = 0.5


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
        super().__init__(model, state, dt, max_iterations=max_iterations)
        k = len(self._solved_nodes)
        self._rhs2 = wp.zeros(k, dtype=wp.vec3d, device=d)
        self._y2 = wp.zeros(k, dtype=wp.vec3d, device=d)
        self._work2 = wp.zeros(k, dtype=wp.vec3d, device=d)
        self._host.update(rhs2=self._rhs2.numpy(), y2=self._y2.numpy(), absolute=self._absolute.numpy(),
                          rotation0=self._rotation0.numpy(), gap_after=state.contacts.gap_after.numpy())
        self._rigid_rows = self._index[self._rigid]
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

    def _contacts(self, local: tuple, candidate: np.ndarray) -> tuple:
        """The ``candidate`` [count] contacts the impulses can move (a solved node of nonzero
        block in the stencil or on a rigid side): their rows [m], ``W = J P^-1 J^T`` [3 m,
        3 m] in their frames, the touched solved nodes' rows among the solved velocities [3 u],
        their columns among the kept ones [3 u], ``R^T J^T`` there (sparse) [3 u, 3 m],
        ``A_0^-1`` between the local correction's ``S`` and them [3 s, 3 u], every stencil
        node of theirs [a] and ``J`` over those (sparse, frames) [3 m, 3 a]."""
        h = self._host
        n = min(int(h["count"][0]), len(h["impulse"]))
        c = self.state.contacts
        used = np.arange(h["stencil_nodes"].shape[1]) < h["stencil_count"][:n, None]
        rigid_node = c.rigid_node.numpy()[:n]
        nodes = np.concatenate([np.where(used, h["stencil_nodes"][:n], 0), np.maximum(rigid_node, 0)], axis=1)
        blocks = np.concatenate([np.where(used, h["stencil_weights"][:n], 0.0)[..., None, None] * np.eye(3),
                                 np.where((rigid_node >= 0)[..., None, None], -_skew(c.rigid_lever.numpy()[:n]),
                                          0.0)], axis=1)  # [n, slots, 3, 3]
        acts = np.concatenate([used, rigid_node >= 0], axis=1) & (np.abs(blocks).sum(axis=(2, 3)) > 0.0)
        moves = acts & self._solved[nodes]
        movable = moves.any(axis=1)
        h["movable"][:n] = movable
        self._movable_all = movable
        rows = np.flatnonzero(movable & candidate)
        nodes, blocks, acts, moves = nodes[rows], blocks[rows], acts[rows], moves[rows]
        m = len(rows)
        jb = np.einsum("cij,csjk->csik", h["frame"][rows], blocks)  # J's blocks, frames
        contact, slot = np.nonzero(acts)
        every, at = np.unique(nodes[acts], return_inverse=True)
        j = self._sparse(jb[contact, slot], contact, at, m, len(every))
        contact, slot = np.nonzero(moves)
        touched, at = np.unique(nodes[moves], return_inverse=True)
        turned = np.einsum("cji,cjk->cik", h["rotation"][touched[at]], np.swapaxes(jb[contact, slot], 1, 2))
        jt = self._sparse(np.swapaxes(turned, 1, 2), contact, at, m, len(touched)).T.tocsr()  # R^T J^T
        slots = self._slots_of(touched)
        dofs = (3 * self._index[touched][:, None] + np.arange(3)).ravel()
        near = self._columns[np.ix_(local[0], slots)]
        inverse = self._columns[np.ix_(dofs, slots)] - near.T @ local[2] @ near  # R^T P^-1 R at the touched
        w = jt.T @ np.asarray(jt.T @ inverse).T
        w = 0.5 * (w + w.T)
        each = np.arange(m)
        h["metric"][:n] = 0.0
        h["metric"][rows] = w.reshape(m, 3, m, 3)[each, :, each, :]
        self._used = np.concatenate([local[1], slots])
        return rows, w, dofs, jt, near, every, j

    @staticmethod
    def _sparse(blocks: np.ndarray, contact: np.ndarray, node: np.ndarray, m: int, nodes: int) -> sp.csr_matrix:
        """The sparse [3 m, 3 nodes] matrix of 3 x 3 ``blocks`` [q, 3, 3] at block rows
        ``contact`` [q] and block columns ``node`` [q] (repeats summed)."""
        i = (3 * contact[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
        k = (3 * node[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
        return sp.csr_matrix((blocks.ravel(), (i.ravel(), k.ravel())), shape=(3 * m, 3 * nodes))

    def _load(self, rows: np.ndarray, w: np.ndarray, tolerance: float) -> dict:
        """The PGS launch's arrays (:meth:`_delassus`) loaded with contacts ``rows`` and ``W``."""
        h = self._host
        m = len(rows)
        pgs = self._delassus(m, tolerance)
        pgs["count"][0] = m
        pgs["w"][:3 * m, :3 * m] = w
        for name in ("frame", "gap", "friction", "stiffness", "slip", "impulse"):
            pgs[name][:m] = h[name][rows]
        return pgs

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

    def solve(self, tolerance: float) -> tuple[int, wp.array]:
        """:meth:`FactoredSolve.solve` with the contacts of :meth:`_candidates` in ``W`` and any
        the solved velocities close beyond their target added on the way (``added``); the
        impulses' response by a second triangular solve."""
        st, h = self.state, self._host
        wp.copy(self._v, st.sweep_buffers[0])
        v, y, y2, rhs2 = h["v"], h["y"].ravel(), h["y2"].ravel(), h["rhs2"].ravel()
        v[self._fixed_nodes] = self._fixed_velocity[self._fixed_nodes]
        self._turn()
        self._forget_columns()
        local = self._local()
        candidate = self._candidates()
        n = len(candidate)
        self.delassus_passes = self.added = 0
        k = restart = 0
        done = False
        while not done and k < self.max_iterations:
            rows, w, dofs, jt, near, every, j = self._contacts(local, candidate)
            m = len(rows)
            pgs = self._load(rows, w, tolerance)
            lam, u_f = pgs["impulse"][:m], pgs["u"][:m]
            columns_s = self._columns[:, local[1]]  # A_0^-1 at S (Woodbury), gathered once
            anderson, changes = _Anderson(ANDERSON_MEMORY), []
            while k < self.max_iterations:
                if k - restart == REFACTOR_AFTER:  # the deformation has taken A too far from R A_0 R^T
                    self._factor()
                    local = self._local()
                    restart = k
                    break
                k += 1
                self._residual()  # R^T r
                self._solve_r()  # A_0^-1 R^T r
                at_s = y[local[0]]
                if m:
                    at = y[dofs] - near.T @ (local[2] @ at_s)  # R^T P^-1 r at the touched nodes
                    u_f[:] = (j @ v[every].ravel() + jt.T @ at).reshape(m, 3)  # J v + J P^-1 r
                    self._pgs()
                    self.delassus_passes += int(h["done"][0])
                    rhs2[:] = 0.0
                    rhs2[dofs] = jt @ lam.ravel()  # R^T J^T lambda
                    self._solve_impulse()
                    y += y2
                    at_s = y[local[0]]
                if len(local[0]):  # P^-1 = R (A_0^-1 - C_S T C_S^T) R^T
                    y -= np.einsum("ij,j->i", columns_s, local[2] @ at_s)
                self._update()  # u = v + R y
                u = h["u"].ravel()
                change = float(np.max(np.abs(u - v.ravel()) * self._weight, initial=0.0))
                v[:] = anderson.next(v.ravel(), u.copy()).reshape(-1, 3)
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
        out = st.sweep_buffers[k % 3]
        wp.copy(out, self._v)
        return k, out
