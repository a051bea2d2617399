"""Compiled projected Gauss-Seidel sweeps over the contacts of one island (thesis eq. 5.6).

The loop is sequential by nature (each contact sees the impulses just updated), so it runs as
one Warp thread on the CPU: compiled, it costs microseconds per sweep where the same loop in
Python cost milliseconds.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from softvr.device import load_kernels, resolve_device

__all__ = ["pgs_sweeps"]


@wp.func
def _relax_row(delassus: wp.array2d(dtype=wp.float64), target: wp.array(dtype=wp.float64),
               row_inv: wp.array(dtype=wp.float64), lam: wp.array(dtype=wp.float64), rel: wp.array(dtype=wp.float64),
               r: int, lower: wp.float64, upper: wp.float64) -> wp.float64:
    """One projected Gauss-Seidel update of row ``r`` within [lower, upper]; keeps ``rel``
    consistent and returns the velocity correction it made on its own row [m/s]: unlike the
    impulse change, that vanishes at a solution even where redundant contacts leave the
    impulses free to drift without changing any velocity."""
    value = wp.clamp(lam[r] + row_inv[r] * (target[r] - rel[r]), lower, upper)
    change = value - lam[r]
    if change != wp.float64(0.0):
        for i in range(delassus.shape[0]):
            rel[i] = rel[i] + delassus[r, i] * change  # B is symmetric: row r = column r
        lam[r] = value
    return wp.abs(change) * delassus[r, r]


@wp.func
def _adhesive_bound(delassus: wp.array2d(dtype=wp.float64), target: wp.array(dtype=wp.float64),
                    lam: wp.array(dtype=wp.float64), rel: wp.array(dtype=wp.float64), r: int,
                    k: wp.float64) -> wp.float64:
    """The implicit adhesive impulse limit of row ``r`` (thesis eq. 4.16, steps 3, 6-7 of
    4.3.2): ``k d_bar / (1 + k B_rr)`` with ``d_bar = B_rr lambda_r + target_r - rel_r`` (the
    row's right-hand side without its own impulse) and ``k = dt^2 A C beta^2``; 0 for k = 0.
    On a bonded contact's tangent row the target is ``-t . u / dt`` (u its slip since bonding),
    so this is the impulse of the tangential spring stretched by the slip at the end of the
    step, ``dt A C beta^2 t . (u + dt v)`` (:mod:`softvr.contact.adhesion`)."""
    b = delassus[r, r]
    d_bar = b * lam[r] + target[r] - rel[r]
    return k * d_bar / (wp.float64(1.0) + k * b)


@wp.kernel
def _pgs_kernel(delassus: wp.array2d(dtype=wp.float64), target: wp.array(dtype=wp.float64),
                friction: wp.array(dtype=wp.float64), adhesion: wp.array(dtype=wp.float64),
                row_inv: wp.array(dtype=wp.float64), lam: wp.array(dtype=wp.float64), rel: wp.array(dtype=wp.float64),
                max_sweeps: int, tolerance: wp.float64, sweeps: wp.array(dtype=wp.int32)):
    count = delassus.shape[0] / 3
    zero = wp.float64(0.0)
    unbounded = wp.float64(1.0e300)
    done = int(0)
    for sweep in range(max_sweeps):
        if done == 0:
            biggest = zero
            for n in range(count):
                r0 = 3 * n
                k = adhesion[n]
                # The normal row alone first: a joint 3x3 solve can ask for a negative normal
                # impulse on oblique approach, which the projection would then zero. Adhesion
                # lowers the bound below 0 by the implicit spring of eq. 4.16.
                lower = wp.min(_adhesive_bound(delassus, target, lam, rel, r0, k), zero)
                change = _relax_row(delassus, target, row_inv, lam, rel, r0, lower, unbounded)
                # Then the tangent rows one at a time, each within the larger of the Coulomb
                # pyramid of the new normal impulse and the implicit tangential adhesion: row-
                # wise projection converges to the box-constrained solution, where a joint 2x2
                # solve clamped afterwards can stall with one row at its bound and the other off.
                coulomb = friction[n] * wp.max(lam[r0], zero)
                for t in range(1, 3):
                    bound = wp.max(coulomb, wp.abs(_adhesive_bound(delassus, target, lam, rel, r0 + t, k)))
                    change = wp.max(change, _relax_row(delassus, target, row_inv, lam, rel, r0 + t, -bound, bound))
                biggest = wp.max(biggest, change)
            sweeps[0] = sweep + 1
            if biggest <= tolerance:
                done = 1


def pgs_sweeps(delassus: np.ndarray, target: np.ndarray, friction: np.ndarray, lam: np.ndarray, rel: np.ndarray,
               max_sweeps: int, tolerance: float, adhesion: np.ndarray | None = None) -> int:
    """Projected Gauss-Seidel on ``0 <= lambda _|_ B lambda - target >= 0`` with friction.

    Per contact (3 rows: normal, tangent 1, tangent 2) the normal impulse is updated and
    clamped at 0, then each tangent impulse in turn, clamped to the 4-sided pyramid
    ``|lambda_t| <= mu lambda_n`` of the new normal impulse. With ``adhesion`` the bounds
    widen to the implicit adhesive limits of thesis eq. 4.16 (:mod:`softvr.contact.adhesion`).

    Parameters
    ----------
    delassus : ndarray, shape [3c, 3c]
        Symmetric Delassus operator B [m/s per N s].
    target : ndarray, shape [3c] [m/s]
        Constraint velocities aimed at (normal: -gap/dt; tangents: 0, or ``-t . u / dt`` on a
        bonded contact with slip u since bonding).
    friction : ndarray, shape [c]
        Coulomb coefficients mu.
    lam : ndarray, shape [3c] [N s]
        Impulses: the warm start in, the solution out (updated in place).
    rel : ndarray, shape [3c] [m/s]
        Constraint velocities ``B lambda + J v_free`` of ``lam``, kept consistent (in place).
    max_sweeps : int
    tolerance : float [m/s]
        Stop after a sweep whose largest velocity correction ``B_ii |delta lambda_i|`` is
        below ``tolerance``.
    adhesion : ndarray, shape [c] [kg], optional
        ``k = dt^2 A C beta^2`` per contact (0: no adhesion).

    Returns
    -------
    int
        Sweeps made.
    """
    device = resolve_device("cpu")
    load_kernels(_pgs_kernel, device)
    count = len(friction)
    diagonal = np.diagonal(delassus)
    row_inv = np.where(diagonal > 1e-300, 1.0 / np.maximum(diagonal, 1e-300), 0.0)  # an immovable row: no update

    def alias(x) -> wp.array:
        # The kernel reads (and for lambda and rel writes) the NumPy memory itself: wrapping
        # costs a third of a copy, and this runs once or more per island and step.
        return wp.array(x, dtype=wp.float64, device=device, copy=False)

    lam_c, rel_c = np.ascontiguousarray(lam, dtype=np.float64), np.ascontiguousarray(rel, dtype=np.float64)
    sweeps = wp.zeros(1, dtype=wp.int32, device=device)
    wp.launch(_pgs_kernel, dim=1, device=device,
              inputs=[alias(np.ascontiguousarray(delassus, dtype=np.float64)),
                      alias(np.ascontiguousarray(target, dtype=np.float64)),
                      alias(np.ascontiguousarray(friction, dtype=np.float64)),
                      alias(np.zeros(count) if adhesion is None else np.ascontiguousarray(adhesion, dtype=np.float64)),
                      alias(row_inv), alias(lam_c), alias(rel_c), int(max_sweeps), float(tolerance), sweeps])
    if lam_c is not lam:
        lam[:] = lam_c
    if rel_c is not rel:
        rel[:] = rel_c
    return int(sweeps.numpy()[0])
