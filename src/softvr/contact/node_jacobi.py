"""The contact solve of the FEM bodies of a whole scene (thesis eq. 5.6: outer Jacobi over the
node velocities with D_A the 3x3 node blocks, inner PGS over the contacts), Chebyshev
accelerated, as recorded launches replayed sweep by sweep (kernels and the derivation in
:mod:`softvr.contact._node_jacobi_kernels`). Works on :class:`softvr.sim.NodeModel` /
:class:`softvr.sim.NodeState` or any objects with those attributes. No factorization: the same
sweeps also solve eq. 5.2, so there is no separate unconstrained solve.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from softvr.contact import _node_jacobi_kernels as _k
from softvr.device import load_kernels, replayer

__all__ = ["NodeSolve", "chebyshev_weights"]


def chebyshev_weights(rho: float, count: int) -> np.ndarray:
    """omega_k [count] of the Chebyshev semi-iteration for an iteration of spectral radius
    ``rho`` < 1: 1, 2 / (2 - rho^2), then 4 / (4 - rho^2 omega_{k-1}) (Golub and Van Loan,
    Matrix Computations, 11.2.8; Wang 2015 for projected iterations)."""
    omega = np.ones(max(count, 1))
    for k in range(1, len(omega)):
        omega[k] = 2.0 / (2.0 - rho * rho) if k == 1 else 4.0 / (4.0 - rho * rho * omega[k - 1])
    return omega


class NodeSolve:
    """The recorded sweeps of one step size, and the loop that runs them.

    Parameters
    ----------
    model, state
        :class:`softvr.sim.NodeModel`, :class:`softvr.sim.NodeState`.
    dt : float [s]
    spectrum : tuple of float
        (lo, hi): bounds of the eigenvalues of D_A^-1 A (lo > 0), for the Chebyshev weights.
    max_sweeps : int
    passes : int
        PGS passes over the contacts per sweep.
    """

    def __init__(self, model, state, dt: float, spectrum: tuple[float, float], *, max_sweeps: int = 500,
                 passes: int = 2):
        lo, hi = spectrum
        self.gamma, self.rho = 2.0 / (lo + hi), (hi - lo) / (hi + lo)
        #: Asymptotic error reduction per Chebyshev sweep.
        self.rate = (1.0 - np.sqrt(1.0 - self.rho * self.rho)) / self.rho if self.rho > 0 else 0.0
        self.max_sweeps = int(max_sweeps)
        d = model.device
        for kernel in (_k.jacobi, _k.contacts, _k.chebyshev, _k.residual):
            load_kernels(kernel, d)
        self.weights: wp.array = wp.array(chebyshev_weights(self.rho, self.max_sweeps), dtype=wp.float64, device=d)
        self.sweep = wp.zeros(1, dtype=wp.int32, device=d)
        self.stats = wp.zeros(2, dtype=wp.float64, device=d)
        self.change = wp.zeros(model.node_count, dtype=wp.float64, device=d)
        self._change = self.change.numpy()
        self._sweep = self.sweep.numpy()
        # A rigid body's nodes take their sweep's update unextrapolated: their D_A is all of
        # their A, so the update is exact for the sweep's impulses, and the Chebyshev step only
        # made them overshoot their contacts (a box resting on a block: 2.4x the sweeps, a plate
        # 3.4x).
        exact = np.zeros(model.node_count, np.int32)
        if model.rigid is not None:
            exact[model.rigid.linear_node.numpy()] = 1
            exact[model.rigid.angular_node.numpy()] = 1
        self.exact: wp.array = wp.array(exact, dtype=wp.int32, device=d)
        c = state.contacts
        buf = state.sweep_buffers
        jacobi, cheb = [], []
        for r in range(3):
            v, v_prev, v_next = buf[r], buf[(r + 2) % 3], buf[(r + 1) % 3]
            jacobi.append(wp.launch(_k.jacobi, dim=model.node_count, device=d, record_cmd=True,
                                    inputs=[model.row_start, model.block_col, state.blocks, state.d_inv, state.b,
                                            model.fixed, state.fixed_velocity, v, state.v_hat]))
            cheb.append(wp.launch(_k.chebyshev, dim=model.node_count, device=d, record_cmd=True,
                                  inputs=[state.v_hat, v, v_prev, self.weights, float(self.gamma), self.sweep,
                                          model.fixed, self.exact, v_next, self.change]))
        contacts = wp.launch(_k.contacts, dim=1, device=d, record_cmd=True,
                             inputs=[c.count, c.stencil_count, c.stencil_nodes, c.stencil_weights, c.frame, c.gap,
                                     c.friction, c.rigid_node, c.rigid_lever, state.d_inv, model.fixed, float(dt),
                                     int(passes), c.impulse, state.v_hat, self.sweep, c.stiffness, c.slip])
        self._launches = (jacobi, contacts, cheb)
        self._sweeps = [(replayer(jacobi[r]), replayer(contacts), replayer(cheb[r])) for r in range(3)]
        self._residual_launches = [replayer(wp.launch(_k.residual, dim=1, device=d, record_cmd=True,
                                                      inputs=[c.count, c.stencil_count, c.stencil_nodes,
                                                              c.stencil_weights, c.frame, c.gap, c.rigid_node,
                                                              c.rigid_lever, float(dt), buf[r],
                                                              c.impulse, c.gap_after, self.stats]))
                                   for r in range(3)]
        self._buffers = buf

    def solve(self, tolerance: float, check_every: int = 2) -> tuple[int, wp.array]:
        """Sweeps from the velocity in ``state.sweep_buffers[0]`` (and [2], the one before it)
        until the velocities are within ``tolerance`` [m/s] of the fixed point, or
        ``max_sweeps``. The error left is about ``rate / (1 - rate)`` times the last sweep's
        largest change (a geometric tail), so the sweeps stop when the change falls below
        ``tolerance (1 - rate) / rate`` (checked every ``check_every``) and no contact's normal
        velocity is more than ``tolerance`` short of its target, nor a pushing one's more than
        that from it (contacts between bodies couple them, and the node change alone
        understates their error). Returns the sweeps
        made and the buffer holding the solved velocities; ``stats[1]`` then holds the largest
        normal-velocity error [m/s]."""
        stop = tolerance * (1.0 - self.rate) / max(self.rate, 1e-300)
        self._sweep[0] = 0
        stats = self.stats.numpy()
        k = 0
        while k < self.max_sweeps:
            jacobi, contacts, cheb = self._sweeps[k % 3]
            jacobi()
            contacts()
            cheb()
            k += 1
            if k % check_every == 0:
                change = float(self._change.max(initial=0.0))
                if not np.isfinite(change):  # NaN: the integration reports it
                    break
                if change <= stop:
                    self._residual_launches[k % 3]()
                    if stats[1] <= tolerance:
                        break
        self._residual_launches[k % 3]()
        stats[0] = k
        return k, self._buffers[k % 3]
