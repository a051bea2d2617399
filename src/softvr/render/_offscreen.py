"""What the off-screen renderers share: a window, its pixel grabber, and their lifetime."""

from __future__ import annotations

from typing import Any

import numpy as np

from softvr.render.raycast import volume_bounds

__all__ = ["OffscreenView"]


class OffscreenView:
    """Base of :class:`VolumeRenderer` and :class:`SurfaceRenderer`.

    Subclasses set ``self._window`` (an off-screen ``vtkRenderWindow``), ``self._renderer`` and
    ``self._camera``, and call :meth:`_opened` once the window exists.
    """

    _window: Any = None  # the subclass's vtkRenderWindow (vtk is imported with the first renderer)
    _renderer: Any  # its vtkRenderer
    _camera: Any  # the softvr.render.Camera in use
    _camera_pending: bool  # whether _camera is still to be applied (at the next frame)
    width: int  # [pixels]
    height: int
    _closed = True
    _rgba: Any = None  # the vtkUnsignedCharArray the RGBA read-back fills (made at the first)
    _backdrop_key: tuple | None = None  # the size and colours _backdrop_image was drawn for
    _backdrop_image: np.ndarray | None = None

    def _opened(self) -> None:
        self._closed = False

    @property
    def camera(self):
        """The :class:`~softvr.render.Camera` in use (applied at the next render if just set)."""
        return self._camera

    @property
    def vtk_camera(self):
        """The underlying ``vtkCamera``, for fine control (changes stick across frames)."""
        return self._renderer.GetActiveCamera()

    @property
    def vtk_renderer(self):
        """The underlying ``vtkRenderer`` (to add actors such as meshes)."""
        return self._renderer

    def grab(self) -> np.ndarray:
        """The last rendered image, shape [height, width, 3] uint8, row 0 at the top."""
        return np.ascontiguousarray(self._grab_rgba()[:, :, :3])

    def _draw(self, bounds) -> np.ndarray:
        """Draw the window and return its image (:meth:`grab`). A camera set since the last
        frame is applied first, fitted to ``bounds()`` (a function: the bounds are only worked
        out then) and replacing an explicit projection (:meth:`SurfaceRenderer.set_view`). No
        context is left current: an on-screen GLX context (the viewer) cannot be made while an
        EGL one is current (BadAccess on Mesa; :mod:`softvr.render._backend`)."""
        self._apply_camera(bounds)
        self._renderer.ResetCameraClippingRange()
        self._window.Render()
        image = self.grab()
        self._window.ReleaseCurrent()
        return image

    def _apply_camera(self, bounds) -> None:
        """Apply a camera set since the last frame, fitted to ``bounds()`` (a function: the
        bounds are only worked out then), replacing an explicit projection
        (:meth:`SurfaceRenderer.set_view`)."""
        if self._camera_pending:
            self.vtk_camera.UseExplicitProjectionTransformMatrixOff()
            self._camera.apply(self.vtk_camera, bounds(), self.width / self.height)
            self._camera_pending = False

    def _cast_over_surfaces(self, volumes: list, *, surfaces: bool = True, background=None) -> np.ndarray:
        """Draw the surfaces with VTK, then ray cast each of ``volumes`` [(RayCaster, Volume,
        changed), ...] over their colour with the Warp caster, each ray stopped at their depth
        (later volumes over earlier ones). The clipping range covers the volumes and the
        surfaces. ``surfaces=False``: nothing opaque is drawn, OpenGL is skipped and the flat
        ``background`` RGB [0, 1] lies everywhere at the far plane."""
        from vtkmodules.vtkCommonCore import vtkFloatArray  # noqa: PLC0415
        from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: PLC0415

        both = np.array([volume_bounds(v) for _, v, _ in volumes]).reshape(-1, 3, 2)
        both = np.column_stack([both[:, :, 0].min(axis=0), both[:, :, 1].max(axis=0)])
        if surfaces:
            props = np.asarray(self._renderer.ComputeVisiblePropBounds()).reshape(3, 2)
            if np.all(props[:, 1] >= props[:, 0]):
                both = np.column_stack([np.minimum(both[:, 0], props[:, 0]), np.maximum(both[:, 1], props[:, 1])])
        self._renderer.ResetCameraClippingRange(*both.ravel())
        if surfaces:
            backdrop = self._backdrop()
            if backdrop is not None:  # a flat clear instead: the gradient quad is most of llvmpipe's pass
                self._renderer.GradientBackgroundOff()
            try:
                self._window.Render()
            finally:
                if backdrop is not None:
                    self._renderer.GradientBackgroundOn()
            image = self._grab_rgba()
            z = vtkFloatArray()
            self._window.GetZbufferData(0, 0, self.width - 1, self.height - 1, z)
            depth = vtk_to_numpy(z).reshape(self.height, self.width)
            self._window.ReleaseCurrent()
            if backdrop is not None:  # where nothing was drawn (cleared depth; its rows run up)
                np.copyto(image.view(np.uint32)[..., 0], backdrop.view(np.uint32)[..., 0], where=(depth == 1.0)[::-1])
        else:
            image = np.empty((self.height, self.width, 4), np.uint8)
            image[:, :, :3] = np.round(255 * np.asarray(background, float)).astype(np.uint8)
            image[:, :, 3] = 255
            depth = np.ones((self.height, self.width), np.float32)
        cam = self.vtk_camera
        world_to_ndc = cam.GetCompositeProjectionTransformMatrix(self.width / self.height, -1.0, 1.0)
        m = np.array([[world_to_ndc.GetElement(r, c) for c in range(4)] for r in range(4)])
        light = np.subtract(cam.GetPosition(), cam.GetFocalPoint())  # a head light
        for caster, volume, changed in volumes:
            image = caster.cast(volume, np.linalg.inv(m), light / np.linalg.norm(light), image, depth,
                                changed=changed)
        return image

    def _grab_rgba(self) -> np.ndarray:
        """The window's back buffer, shape [height, width, 4] uint8 RGBA (the window's own size:
        a user may resize an on-screen one), row 0 at the top: one read into a kept array (~0.1 ms
        at 512 x 512, where ``vtkWindowToImageFilter`` took ~0.45 ms), whose pixels compare as
        32-bit words."""
        from vtkmodules.vtkCommonCore import vtkUnsignedCharArray  # noqa: PLC0415
        from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: PLC0415

        if self._rgba is None:
            self._rgba = vtkUnsignedCharArray()
        width, height = self._window.GetSize()
        self._window.GetRGBACharPixelData(0, 0, width - 1, height - 1, 0, self._rgba)
        return np.ascontiguousarray(vtk_to_numpy(self._rgba).reshape(height, width, 4)[::-1])

    def _backdrop(self) -> np.ndarray | None:
        """The gradient background alone [height, width, 4] uint8 RGBA (row 0 at the top), drawn once
        per size and colours, for :meth:`_cast_over_surfaces` to put where no surface is: the
        same pixels as drawing it every frame, which costs llvmpipe ~2 of its ~3 ms at 512 x
        512. None where it cannot stand in: no gradient, or FXAA or depth peeling (translucent
        surfaces), which blend the background into pixels that surfaces cover."""
        r = self._renderer
        if not r.GetGradientBackground() or r.GetUseFXAA() or r.GetUseDepthPeeling():
            return None
        key = (self.width, self.height, r.GetBackground(), r.GetBackground2())
        if key != self._backdrop_key or self._backdrop_image is None:
            props = r.GetViewProps()
            shown = [props.GetItemAsObject(i) for i in range(props.GetNumberOfItems())]
            shown = [p for p in shown if p.GetVisibility()]
            for p in shown:
                p.VisibilityOff()
            try:
                self._window.Render()
                self._backdrop_image = self._grab_rgba()
            finally:
                for p in shown:
                    p.VisibilityOn()
                self._window.ReleaseCurrent()
            self._backdrop_key = key
        return self._backdrop_image

    def close(self) -> None:
        """Release the OpenGL context. The renderer cannot be used afterwards."""
        if not self._closed:
            self._closed = True
            self._window.Finalize()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass
