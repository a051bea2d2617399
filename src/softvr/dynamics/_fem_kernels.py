"""Compiled per-tet work of co-rotational FEM: rotations, elastic forces, rotated stiffness.

One Warp thread per tetrahedron (split over the CPU cores by :func:`softvr.device.launch`)
computes what ``FemBody`` needs each step, from one polar decomposition:

    R_e            rotation of F = Ds Dm^-1 = R S (scaled Newton; SVD for inverted tets)
    f_e = -R_e K_e (R_e^T x_e - X_e)                    [12]     element elastic forces
    K_e^R = R_e K_e R_e^T                               [12, 12] element stiffness, rotated

The scatter into the sparse ``A`` stays in NumPy (one ``bincount`` over a precomputed map),
because CPU atomics from several launch threads would race.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from softvr.device import launch, load_kernels, resolve_device, upload

__all__ = ["CorotatedElements"]


#: Newton iterations of the polar decomposition at most (quadratic convergence: 5-7 reach
#: round-off from F itself for the strains of a simulation).
POLAR_ITERATIONS = 12


@wp.func
def polar_rotation(f: wp.mat33d) -> wp.mat33d:
    """The rotation R of the polar decomposition F = R S (S symmetric positive definite).

    Higham's scaled Newton iteration X <- (z X + X^-T / z) / 2, z = (|X^-1|_F / |X|_F)^1/2
    (N. J. Higham, Functions of Matrices, SIAM 2008, alg. 8.20), from X = F: it converges
    quadratically to R and costs ~1/6 of ``wp.svd3`` here (2.7 -> 0.4 us per tet on the
    contact bench's cube). An inverted or flat tet (det F <= 0) has no rotation as its polar
    factor (the iteration would give a reflection): there R = U V^T of the SVD, with U, V
    rotations (``wp.svd3`` lets the last singular value go negative), as before.
    """
    if wp.determinant(f) <= wp.float64(0.0):
        u, sigma, v = wp.svd3(f)
        return u * wp.transpose(v)
    x = f
    for _ in range(POLAR_ITERATIONS):
        inv_t = wp.transpose(wp.inverse(x))
        z = wp.sqrt(wp.sqrt(wp.ddot(inv_t, inv_t) / wp.ddot(x, x)))
        nxt = wp.float64(0.5) * (z * x + inv_t / z)
        d = nxt - x
        x = nxt
        # Quadratic convergence: after a step of 1e-10 the iterate is within ~1e-20 of R.
        if wp.ddot(d, d) <= wp.float64(1e-20):
            break
    return x


#: A warm start's Newton correction [rad] small enough to be its last: the rotation's error
#: after it is ~its square (quadratic convergence), 1e-16, at float64 round-off.
WARM_LAST_STEP = 1e-8

#: Skew part of R^T F relative to its trace below which R is kept as it is: the correction would
#: be ~1e-15 rad (|w| ~ |skew| / (sigma_i + sigma_j)), the round-off of forming R^T F itself. A
#: tet that has not turned (a still, unstrained part) then costs R^T F and no solve.
WARM_SETTLED = 1e-15

#: Newton corrections of a warm start at most before the cold iteration takes over.
WARM_ITERATIONS = 4

#: Largest first correction [rad] a warm start keeps: a farther start (a stale rotation after
#: the positions were set, the zeros before the first step) goes cold (:func:`polar_rotation`),
#: where the Newton iteration on R could reach another R with R^T F symmetric but indefinite.
WARM_REACH = 0.1


@wp.func
def orthonormalized(r: wp.mat33d) -> wp.mat33d:
    """One Newton-Schulz step R (3 I - R^T R) / 2 towards the nearest rotation: |R^T R - I| = e
    becomes ~3 e^2 / 4, round-off from a product of rotations' ~u."""
    return r * (wp.float64(1.5) * wp.identity(n=3, dtype=wp.float64) - wp.float64(0.5) * (wp.transpose(r) * r))


@wp.func
def lagged_polar_rotation(f: wp.mat33d, r0: wp.mat33d, keep: wp.float64) -> wp.mat33d:
    """:func:`polar_rotation` of F started from ``r0``, a rotation near it (last step's R_e),
    or ``r0`` itself where the first Newton correction below is at most ``keep`` [rad]: to
    first order ``r0`` is then within ``keep`` of the polar rotation (Higham, Functions of
    Matrices, 8.1: the correction ``w`` solves the linearized polar condition).

    Newton's method on the rotation: with X = R^T F, the correction R <- R Q(w) that makes
    Q^T X symmetric to first order solves (tr(X) I - X) w = (X32 - X23, X13 - X31, X21 - X12)
    (skew(W X + X^T W) = skew(X - X^T), W = [w]x); Q(w) is the Cayley rotation
    I + 2 / (1 + |h|^2) ([h]x + [h]x^2), h = w / 2, exact to O(|w|^3). A tet that turned by
    theta since last step needs 1 correction for theta <= 1e-8 rad and 2 for theta <= ~1e-4
    (the cold iteration takes ~4 from X = F whatever the start, 1 for a tet without strain).
    No correction at all (R = ``r0`` unchanged) where the skew part of X is at round-off
    (:data:`WARM_SETTLED`). One Newton-Schulz step (:func:`orthonormalized`) after the
    corrections keeps |R^T R - I| at round-off over many steps of products. Falls
    back to :func:`polar_rotation` for an inverted tet, a start off a rotation, a first
    correction over :data:`WARM_REACH` or no convergence in :data:`WARM_ITERATIONS`.
    """
    r = r0
    settled = int(0)
    # One exit to the cold iteration: Warp inlines each call (the SVD included).
    if wp.determinant(f) > wp.float64(0.0) and wp.abs(wp.determinant(r0) - wp.float64(1.0)) <= wp.float64(1e-6):
        for it in range(WARM_ITERATIONS):
            x = wp.transpose(r) * f
            tr = x[0, 0] + x[1, 1] + x[2, 2]
            skew = wp.vec3d(x[2, 1] - x[1, 2], x[0, 2] - x[2, 0], x[1, 0] - x[0, 1])
            if wp.dot(skew, skew) <= (wp.float64(WARM_SETTLED) * tr) * (wp.float64(WARM_SETTLED) * tr):
                if it > 0:
                    r = orthonormalized(r)
                settled = 1
                break
            g = wp.mat33d(tr - x[0, 0], -x[0, 1], -x[0, 2], -x[1, 0], tr - x[1, 1], -x[1, 2], -x[2, 0], -x[2, 1],
                          tr - x[2, 2])
            w = wp.inverse(g) * skew
            ww = wp.dot(w, w)
            if it == 0 and not (ww <= wp.float64(WARM_REACH) * wp.float64(WARM_REACH)):
                break
            if it == 0 and ww <= keep * keep:
                settled = 1
                break
            h = wp.float64(0.5) * w
            k = wp.skew(h)
            r = r * (wp.identity(n=3, dtype=wp.float64)
                     + (wp.float64(2.0) / (wp.float64(1.0) + wp.dot(h, h))) * (k + k * k))
            if ww <= wp.float64(WARM_LAST_STEP) * wp.float64(WARM_LAST_STEP):
                r = orthonormalized(r)
                settled = 1
                break
    if settled == 0:
        r = polar_rotation(f)
    return r


@wp.func
def warm_polar_rotation(f: wp.mat33d, r0: wp.mat33d) -> wp.mat33d:
    """:func:`polar_rotation` of F started from ``r0``, a rotation near it (last step's R_e):
    :func:`lagged_polar_rotation` keeping nothing but round-off."""
    return lagged_polar_rotation(f, r0, wp.float64(0.0))


@wp.func
def element_rotation(q: wp.array(dtype=wp.vec3d), tets: wp.array2d(dtype=wp.int32), dm_inv: wp.array(dtype=wp.mat33d),
                     e: int, corotational: int) -> wp.mat33d:
    """R_e of tet ``e``: the polar rotation of F = Ds Dm^-1 (:func:`polar_rotation`); I for linear FEM."""
    r = wp.identity(n=3, dtype=wp.float64)
    if corotational != 0:
        x0 = q[tets[e, 0]]
        r = polar_rotation(wp.matrix_from_cols(q[tets[e, 1]] - x0, q[tets[e, 2]] - x0, q[tets[e, 3]] - x0)
                           * dm_inv[e])
    return r


@wp.func
def warm_element_rotation(q: wp.array(dtype=wp.vec3d), tets: wp.array2d(dtype=wp.int32),
                          dm_inv: wp.array(dtype=wp.mat33d), e: int, corotational: int,
                          rotations: wp.array(dtype=wp.mat33d), keep: wp.float64) -> wp.mat33d:
    """:func:`element_rotation` started from ``rotations[e]``, kept where it is within ``keep``
    [rad] of it (:func:`lagged_polar_rotation`)."""
    r = wp.identity(n=3, dtype=wp.float64)
    if corotational != 0:
        x0 = q[tets[e, 0]]
        r = lagged_polar_rotation(wp.matrix_from_cols(q[tets[e, 1]] - x0, q[tets[e, 2]] - x0, q[tets[e, 3]] - x0)
                                  * dm_inv[e], rotations[e], keep)
    return r


@wp.func
def element_local(q: wp.array(dtype=wp.vec3d), rest: wp.array(dtype=wp.vec3d), tets: wp.array2d(dtype=wp.int32),
                  e: int, rt: wp.mat33d):
    """R^T x - X [m] of tet ``e``'s four nodes, in the element's rotated frame (``rt`` = R_e^T)."""
    return (rt * q[tets[e, 0]] - rest[tets[e, 0]], rt * q[tets[e, 1]] - rest[tets[e, 1]],
            rt * q[tets[e, 2]] - rest[tets[e, 2]], rt * q[tets[e, 3]] - rest[tets[e, 3]])


@wp.kernel
def _corotated_kernel(q: wp.array(dtype=wp.vec3d), rest: wp.array(dtype=wp.vec3d), tets: wp.array2d(dtype=wp.int32),
                      dm_inv: wp.array(dtype=wp.mat33d), ke: wp.array3d(dtype=wp.float64), corotational: int,
                      rotations: wp.array(dtype=wp.mat33d), forces: wp.array2d(dtype=wp.float64),
                      kr: wp.array3d(dtype=wp.float64), offset: int):
    e = wp.tid() + offset
    r = element_rotation(q, tets, dm_inv, e, corotational)
    rotations[e] = r
    rt = wp.transpose(r)
    local0, local1, local2, local3 = element_local(q, rest, tets, e, rt)
    for a in range(4):
        fa = wp.vec3d()
        for b in range(4):
            kab = wp.mat33d()
            for i in range(3):
                for j in range(3):
                    kab[i, j] = ke[e, 3 * a + i, 3 * b + j]
            lb = local0
            if b == 1:
                lb = local1
            elif b == 2:
                lb = local2
            elif b == 3:
                lb = local3
            fa = fa + kab * lb
            rk = r * kab * rt
            for i in range(3):
                for j in range(3):
                    kr[e, 3 * a + i, 3 * b + j] = rk[i, j]
        fa = -(r * fa)
        for i in range(3):
            forces[e, 3 * a + i] = fa[i]


class CorotatedElements:
    """Per-step element quantities of a co-rotational tet mesh, computed in one launch.

    Parameters
    ----------
    rest : ndarray, shape [node_count, 3] [m]
    tets : ndarray, shape [tet_count, 4]
    dm_inv : ndarray, shape [tet_count, 3, 3] [1/m]
        Inverse rest edge matrices.
    ke : ndarray, shape [tet_count, 12, 12] [N/m]
        Linear element stiffness matrices (rest frame).
    """

    def __init__(self, rest: np.ndarray, tets: np.ndarray, dm_inv: np.ndarray, ke: np.ndarray):
        self._device = resolve_device("cpu")
        load_kernels(_corotated_kernel, self._device)
        d = self._device
        m = len(tets)
        self._rest = wp.array(np.ascontiguousarray(rest, np.float64), dtype=wp.vec3d, device=d)
        self._tets = wp.array(np.ascontiguousarray(tets, np.int32), dtype=wp.int32, device=d)
        self._dm_inv = wp.array(np.ascontiguousarray(dm_inv, np.float64), dtype=wp.mat33d, device=d)
        self._ke = wp.array(np.ascontiguousarray(ke, np.float64), dtype=wp.float64, device=d)
        self._rotations = wp.empty(m, dtype=wp.mat33d, device=d)
        self._forces = wp.empty((m, 12), dtype=wp.float64, device=d)
        self._kr = wp.empty((m, 12, 12), dtype=wp.float64, device=d)
        self._q = wp.empty(len(rest), dtype=wp.vec3d, device=d)  # the positions of each call

    def compute(self, q: np.ndarray, corotational: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rotations R_e [tet_count, 3, 3], element forces f_e [tet_count, 12] [N] and rotated
        stiffness K_e^R [tet_count, 12, 12] [N/m] at node positions ``q`` [node_count, 3] [m]
        (R_e = I when ``corotational`` is False). The arrays are views valid until the next call."""
        upload(self._q, q)
        launch(_corotated_kernel, self._tets.shape[0],
               [self._q, self._rest, self._tets, self._dm_inv, self._ke, int(corotational), self._rotations, self._forces,
                self._kr], self._device, min_chunk=256)
        return self._rotations.numpy(), self._forces.numpy(), self._kr.numpy()
