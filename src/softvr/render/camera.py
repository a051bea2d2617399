"""Camera set-up for volume rendering: named views plus azimuth/elevation/zoom.

Views are defined on the world axes of :class:`softvr.volume.Volume` (axis 0 = x,
1 = y, 2 = z) in the RAS+ patient convention (x towards the patient's right, y towards
the face, z up) of NIfTI files and of the volumes in :mod:`softvr.datasets`, so
``"front"`` looks at the face. For LPS+ data (DICOM, NRRD, MetaImage: y towards the
back) ``"front"`` shows the back of the head; use ``"back"`` there.

========  ======================  ==========  ==========================================
view      camera sits at          screen up   RAS+ meaning
========  ======================  ==========  ==========================================
front     +y of the focal point   +z          anterior view; +x (patient right) on the left
back      -y                      +z          posterior view
side      +x                      +z          same as ``"right"``
right     +x                      +z          right lateral view
left      -x                      +z          left lateral view
top       +z                      +y          superior view, face at the top
bottom    -z                      +y          inferior view
iso       front, then azimuth 45 and elevation 30 (a three-quarter view)
========  ======================  ==========  ==========================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from softvr.errors import InputError

__all__ = ["VIEWS", "Camera"]

#: view name -> (unit vector from focal point to camera, view-up vector, extra azimuth, extra elevation)
VIEWS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float], float, float]] = {
    "front": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0), 0.0, 0.0),
    "back": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0), 0.0, 0.0),
    "side": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.0, 0.0),
    "right": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.0, 0.0),
    "left": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.0, 0.0),
    "top": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), 0.0, 0.0),
    "bottom": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 0.0, 0.0),
    "iso": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0), 45.0, 30.0),
}


@dataclass(frozen=True)
class Camera:
    """Where to look from, relative to the bounding box of the first rendered volume.

    Parameters
    ----------
    view : str
        One of :data:`VIEWS`: ``"front"``, ``"back"``, ``"side"`` (= ``"left"``),
        ``"right"``, ``"top"``, ``"bottom"``, ``"iso"``.
    azimuth, elevation : float [degrees]
        Rotation about the view-up axis, then about the screen's horizontal axis,
        both about the focal point, applied after ``view``.
    zoom : float
        > 1 magnifies. 1 fits the bounding sphere of the volume in the image.
    parallel : bool
        Orthographic projection instead of perspective.
    parallel_scale : float, optional [world units]
        Half the image height in world units (orthographic only); default fits the
        bounding sphere. Fixes the scale: pixels per world unit = ``height / (2 * parallel_scale)``.
    focal_point : tuple of 3 float, optional [world units]
        Point at the image centre; default the centre of the volume's bounding box.
    view_angle : float [degrees]
        Vertical field of view of the perspective projection.

    Examples
    --------
    >>> from softvr.render import Camera
    >>> Camera("side", azimuth=20, elevation=10).view
    'side'
    >>> Camera("top").with_(zoom=2.0).zoom
    2.0
    """

    view: str = "front"
    azimuth: float = 0.0
    elevation: float = 0.0
    zoom: float = 1.0
    parallel: bool = False
    parallel_scale: float | None = None
    focal_point: tuple[float, float, float] | None = None
    view_angle: float = 30.0

    def __post_init__(self) -> None:
        if self.view not in VIEWS:
            raise InputError("Camera.view", f"one of {sorted(VIEWS)}", repr(self.view))
        if not (math.isfinite(self.zoom) and self.zoom > 0):
            raise InputError("Camera.zoom", "a number > 0", repr(self.zoom))
        if self.parallel_scale is not None and not self.parallel_scale > 0:
            raise InputError("Camera.parallel_scale", "a number > 0 or None", repr(self.parallel_scale))
        if not 0 < self.view_angle < 180:
            raise InputError("Camera.view_angle", "degrees in (0, 180)", repr(self.view_angle))
        if self.focal_point is not None:
            fp = np.asarray(self.focal_point, dtype=float).reshape(-1)
            if fp.shape != (3,) or not np.all(np.isfinite(fp)):
                raise InputError("Camera.focal_point", "three finite numbers", repr(self.focal_point))
            object.__setattr__(self, "focal_point", tuple(float(v) for v in fp))

    def with_(self, **changes) -> "Camera":
        """A copy with some fields changed."""
        return replace(self, **changes)

    @classmethod
    def coerce(cls, camera: "Camera | str | None") -> "Camera":
        """``None`` -> ``Camera()``, a view name -> ``Camera(view)``, a Camera -> itself."""
        if camera is None:
            return cls()
        if isinstance(camera, str):
            return cls(camera)
        if isinstance(camera, Camera):
            return camera
        raise InputError("camera", "a Camera, a view name or None", type(camera).__name__)

    def apply(self, vtk_camera, bounds, aspect: float = 1.0) -> None:
        """Set a ``vtkCamera`` to look at world ``bounds`` (xmin, xmax, ymin, ymax, zmin, zmax).

        The eight corners of the bounding box are fitted into the image (``aspect`` =
        width / height) with a 5 % margin, then ``zoom`` is applied.
        """
        b = np.asarray(bounds, dtype=float).reshape(3, 2)
        if not np.all(np.isfinite(b)) or np.any(b[:, 1] < b[:, 0]):
            b = np.array([[-1.0, 1.0]] * 3)
        centre = b.mean(axis=1) if self.focal_point is None else np.asarray(self.focal_point)
        to_camera, up, extra_az, extra_el = VIEWS[self.view]
        # Orient a unit-distance camera first, then read its frame back.
        vtk_camera.SetViewAngle(self.view_angle)
        vtk_camera.SetFocalPoint(*centre)
        vtk_camera.SetPosition(*(centre + np.asarray(to_camera)))
        vtk_camera.SetViewUp(*up)
        vtk_camera.Azimuth(extra_az + self.azimuth)
        vtk_camera.Elevation(extra_el + self.elevation)
        vtk_camera.OrthogonalizeViewUp()
        back = np.asarray(vtk_camera.GetPosition()) - centre
        back /= np.linalg.norm(back)  # focal point -> camera
        v_up = np.asarray(vtk_camera.GetViewUp())
        right = np.cross(-back, v_up)
        corners = np.array([[x, y, z] for x in b[0] for y in b[1] for z in b[2]]) - centre
        cx, cy, cz = np.abs(corners @ right), np.abs(corners @ v_up), corners @ back
        margin = 1.05
        half_h = max(float(cy.max()), float(cx.max()) / aspect, 1e-9) * margin
        tan_v = math.tan(math.radians(self.view_angle) / 2)
        # Distance at which every corner lies inside the perspective frustum.
        need = np.maximum(cy * margin / tan_v, cx * margin / (tan_v * aspect)) + cz
        distance = max(float(need.max()), half_h / tan_v, 1e-6)
        vtk_camera.SetPosition(*(centre + distance * back))
        vtk_camera.SetParallelProjection(bool(self.parallel))
        vtk_camera.SetParallelScale(self.parallel_scale if self.parallel_scale is not None else half_h)
        if self.zoom != 1.0:
            vtk_camera.Zoom(self.zoom)
