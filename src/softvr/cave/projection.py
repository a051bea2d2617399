"""Off-axis (asymmetric) frustums from a screen's corners and the eye (thesis 6.2.1).

Generalized perspective projection (after Kooima): a screen with lower-left, lower-right and
upper-left corners ``pa``, ``pb``, ``pc`` [m] has the orthonormal frame

    vr = (pb - pa) / |pb - pa|,   vu = (pc - pa) / |pc - pa|,   vn = vr x vu   (towards the eye),

and seen from the eye ``pe`` its near-plane extents are, with ``d = -(pa - pe) . vn`` the
eye's distance to the screen plane,

    l = vr . (pa - pe) n / d,  r = vr . (pb - pe) n / d,  b = vu . (pa - pe) n / d,  t = vu . (pc - pe) n / d.

The camera sits at the eye looking along ``-vn`` with ``vu`` up; the projection is the OpenGL
frustum (l, r, b, t, n, f). Every screen of a CAVE gets its own, from the same eye, so the
images meet at the screens' seams and together cover the whole view (the thesis' virtual
camera cluster).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softvr.errors import InputError

__all__ = ["ScreenView", "frustum_matrix", "screen_view"]


@dataclass(frozen=True)
class ScreenView:
    """Camera of one screen for one eye.

    Attributes
    ----------
    eye : ndarray, shape [3] [m]
    right, up, normal : ndarray, shape [3]
        The screen's frame ``vr``, ``vu``, ``vn`` (``normal`` points at the eye's side).
    extents : tuple of 4 float [m]
        (l, r, b, t) on the near plane.
    near, far : float [m]
    view : ndarray, shape [4, 4]
        World to eye coordinates (rotation onto the screen frame, then the eye at the origin).
    projection : ndarray, shape [4, 4]
        The off-axis OpenGL frustum.
    """

    eye: np.ndarray
    right: np.ndarray
    up: np.ndarray
    normal: np.ndarray
    extents: tuple
    near: float
    far: float
    view: np.ndarray
    projection: np.ndarray

    def project(self, points) -> np.ndarray:
        """Normalized device coordinates [k, 3] of world points [k, 3] [m] (x, y in [-1, 1] on
        the screen)."""
        p = np.atleast_2d(np.asarray(points, float))
        clip = np.c_[p, np.ones(len(p))] @ (self.projection @ self.view).T
        return clip[:, :3] / clip[:, 3:]


def frustum_matrix(left: float, right: float, bottom: float, top: float, near: float, far: float) -> np.ndarray:
    """The OpenGL perspective frustum [4, 4] (``glFrustum``)."""
    return np.array([
        [2 * near / (right - left), 0.0, (right + left) / (right - left), 0.0],
        [0.0, 2 * near / (top - bottom), (top + bottom) / (top - bottom), 0.0],
        [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
        [0.0, 0.0, -1.0, 0.0],
    ])


def screen_view(lower_left, lower_right, upper_left, eye, *, near: float = 0.05, far: float = 100.0,
                name: str = "screen") -> ScreenView:
    """The off-axis camera of a screen (module docstring) for an eye [3] [m].

    Raises :class:`~softvr.errors.InputError` if the eye is in (or behind) the screen's plane.
    """
    pa, pb, pc, pe = (np.asarray(x, float) for x in (lower_left, lower_right, upper_left, eye))
    if not (0 < near < far):
        raise InputError("near / far", "0 < near < far [m]", f"{near}, {far}")
    vr = (pb - pa) / np.linalg.norm(pb - pa)
    vu = (pc - pa) / np.linalg.norm(pc - pa)
    vn = np.cross(vr, vu)
    vn /= np.linalg.norm(vn)
    va, vb, vc = pa - pe, pb - pe, pc - pe
    d = -float(va @ vn)
    if d <= 1e-9:
        raise InputError(f"{name} eye", "an eye in front of the screen (off its plane, on the side its normal faces)",
                         f"the eye at {pe.tolist()}, {d:.3g} m in front")
    extents = (float(vr @ va) * near / d, float(vr @ vb) * near / d, float(vu @ va) * near / d,
               float(vu @ vc) * near / d)
    rotation = np.eye(4)
    rotation[:3, :3] = np.stack([vr, vu, vn])
    translation = np.eye(4)
    translation[:3, 3] = -pe
    return ScreenView(eye=pe, right=vr, up=vu, normal=vn, extents=extents, near=near, far=far,
                      view=rotation @ translation, projection=frustum_matrix(*extents, near, far))
