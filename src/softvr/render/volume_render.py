"""Off-screen volume ray casting of :class:`softvr.volume.Volume` frames to numpy images."""

from __future__ import annotations

import numpy as np

from softvr.render._offscreen import OffscreenView
from softvr.errors import InputError
from softvr.render._backend import new_offscreen_window, offscreen_backend
from softvr.render._scene import VolumeScene
from softvr.render.camera import Camera
from softvr.render.presets import Preset, resolve_preset
from softvr.render.raycast import RayCaster, volume_bounds

__all__ = ["VolumeRenderer", "render_volume"]

_SOFTWARE_GL = ("llvmpipe", "softpipe", "swrast", "swr ", "software")


class VolumeRenderer(OffscreenView):
    """Render volumes to RGB images off-screen, reusing one VTK pipeline across frames.

    Works without a display (EGL, else OSMesa; see :func:`offscreen_backend`). Each
    :meth:`render` call may pass a different volume (shape, spacing, origin and direction
    may all change, as after a deformation); the camera is placed from the first volume's
    bounds and then stays fixed, so successive frames line up, until :meth:`reset_camera`
    or :meth:`set_camera`.

    Parameters
    ----------
    width, height : int [pixels]
        Image size.
    preset : {"ct", "mri", "labels", "auto"} or Preset
        Transfer function, see :data:`softvr.render.PRESETS`. ``"auto"`` picks per volume
        (labels for ``is_label``, MRI for uint8, else CT).
    camera : Camera or str, optional
        A :class:`Camera` or a view name (``"front"``, ``"side"``, ``"top"``, ``"iso"``, ...);
        default ``Camera("front")``.
    background : tuple of 3 float
        Background RGB in [0, 1].
    mapper : {"auto", "cpu", "gpu", "warp"}
        ``"cpu"``: ``vtkFixedPointVolumeRayCastMapper``, multi-threaded software ray
        casting. ``"gpu"``: ``vtkGPUVolumeRayCastMapper``. ``"auto"`` uses ``"cpu"`` on
        software OpenGL (Mesa llvmpipe, where it is ~3x faster than the shader ray caster)
        and ``"gpu"`` on a hardware GPU. ``"warp"``: softvr's :class:`~softvr.render.RayCaster`
        (Warp, CPU or CUDA; continuous presets only), drawn over and hidden by the surfaces
        (actors added to :attr:`vtk_renderer`) at their depth.
    sample_distance : float [voxels]
        Ray step in units of the smallest voxel spacing.
    backend : {"egl", "osmesa"}, optional
        Force an off-screen OpenGL window kind.
    device : str, optional
        Warp device of ``mapper="warp"`` (default CUDA when present, else CPU).

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.volume import Volume
    >>> from softvr.render import VolumeRenderer
    >>> x, y, z = np.mgrid[-20:20, -20:20, -20:20]
    >>> ct = np.where(x**2 + y**2 + z**2 < 15**2, 1000, -1000).astype(np.int16)
    >>> with VolumeRenderer(160, 120, preset="ct", camera="iso") as renderer:
    ...     image = renderer.render(Volume(ct, spacing=(1, 1, 1)))
    >>> image.shape, image.dtype
    ((120, 160, 3), dtype('uint8'))
    >>> bool(image.max() > 100)
    True
    """

    def __init__(
        self,
        width: int = 640,
        height: int = 480,
        preset: "str | Preset" = "ct",
        camera: "Camera | str | None" = None,
        *,
        background: tuple[float, float, float] = (0.0, 0.0, 0.0),
        mapper: str = "auto",
        sample_distance: float = 0.5,
        backend: str | None = None,
        device: str | None = None,
    ):
        for name, v in (("width", width), ("height", height)):
            if not isinstance(v, (int, np.integer)) or not 1 <= v <= 16384:
                raise InputError(name, "an integer number of pixels in [1, 16384]", repr(v))
        from vtkmodules.vtkRenderingCore import vtkRenderer  # noqa: PLC0415

        self.width, self.height = int(width), int(height)
        self._camera = Camera.coerce(camera)
        self._window = new_offscreen_window(self.width, self.height, backend)
        self.backend = offscreen_backend(backend)
        self._renderer = vtkRenderer()
        self._renderer.SetBackground(*background)
        self._background = np.asarray(background, float)
        self._window.AddRenderer(self._renderer)
        if mapper == "auto":
            mapper = "cpu" if self.is_software_gl else "gpu"
        self.mapper = mapper
        self._caster: RayCaster | None = None  # the Warp mapper's
        if mapper == "warp":
            resolve_preset(preset)  # reject unknown names now, not at the first render
            self._preset_arg = preset
            self._caster = RayCaster(resolve_preset(preset), sample_distance, device=device)
        else:
            self._scene = VolumeScene(preset, mapper, sample_distance)
            self._renderer.AddVolume(self._scene.prop)
        self._opened()
        self._camera_pending = True

    # ------------------------------------------------------------- properties
    @property
    def gl_renderer(self) -> str:
        """The OpenGL renderer string, e.g. ``"llvmpipe (LLVM 15.0.6, 256 bits)"``."""
        if not getattr(self, "_gl_renderer", None):
            self._window.Render()  # creates the context
            caps = self._window.ReportCapabilities() or ""
            self._window.ReleaseCurrent()
            lines = [ln for ln in caps.splitlines() if "renderer string" in ln]
            self._gl_renderer = lines[0].split(":", 1)[1].strip() if lines else "unknown"
        return self._gl_renderer

    @property
    def ray_caster(self) -> RayCaster | None:
        """The Warp mapper's :class:`~softvr.render.RayCaster` (None with VTK's mappers), e.g.
        for :attr:`~softvr.render.RayCaster.cast_pixels`."""
        return self._caster

    @property
    def is_software_gl(self) -> bool:
        """True on a software OpenGL (llvmpipe, softpipe, swrast)."""
        name = self.gl_renderer.lower()
        return any(s in name for s in _SOFTWARE_GL)

    # ---------------------------------------------------------------- control
    def set_camera(self, camera: "Camera | str | None" = None, **changes) -> None:
        """Use ``camera`` (default: the current one) with ``changes`` from the next render.

        The view is fitted to the bounds of the volume rendered next.

        Examples
        --------
        >>> from softvr.render import VolumeRenderer
        >>> r = VolumeRenderer(64, 48)
        >>> r.set_camera("side", azimuth=30)
        >>> r.camera.view, r.camera.azimuth
        ('side', 30)
        >>> r.close()
        """
        cam = Camera.coerce(camera) if camera is not None else self._camera
        self._camera = cam.with_(**changes) if changes else cam
        self._camera_pending = True

    def reset_camera(self) -> None:
        """Refit the current camera to the bounds of the volume rendered next."""
        self._camera_pending = True

    def set_preset(self, preset: "str | Preset") -> None:
        """Change the transfer function from the next render on."""
        if self._caster is not None:
            resolve_preset(preset)
            self._preset_arg = preset
        else:
            self._scene.set_preset(preset)

    # ----------------------------------------------------------------- render
    def render(self, volume, *, changed=True) -> np.ndarray:
        """Render ``volume``.

        Parameters
        ----------
        volume : softvr.volume.Volume
            Voxels ``data`` [nx, ny, nz] (at least 2 along each axis) placed in world
            space by ``spacing``, ``origin`` and ``direction``.
        changed : True, False or (lo, hi)
            ``mapper="warp"`` only: which voxels changed since the last call (all, none, or
            the inclusive index box ``lo`` .. ``hi``), so that only those bricks of the
            empty-space grid are re-derived and, with the same camera and clipping range, only
            the rays that can see the change or a moved surface are cast again
            (:meth:`~softvr.render.RayCaster.cast`). VTK's mappers always take the whole volume.

        Returns
        -------
        numpy.ndarray, shape [height, width, 3], uint8
            RGB image, row 0 at the top.
        """
        if self._closed:
            raise InputError("VolumeRenderer", "an open renderer", "a closed one")
        if self._caster is not None:
            return self._render_warp(volume, changed)
        self._scene.update(volume)
        return self._draw(self._scene.bounds)

    def _render_warp(self, volume, changed) -> np.ndarray:
        """VTK draws the surfaces (if any), then the Warp ray caster composites the volume
        over their colour, each ray stopped at their depth."""
        assert self._caster is not None  # made with the Warp mapper
        self._apply_camera(lambda: volume_bounds(volume))
        self._caster.preset = resolve_preset(self._preset_arg, volume)
        return self._cast_over_surfaces([(self._caster, volume, changed)],
                                        surfaces=bool(self._renderer.VisibleActorCount()),
                                        background=self._background)


def render_volume(
    volume,
    width: int = 640,
    height: int = 480,
    preset: "str | Preset" = "auto",
    camera: "Camera | str | None" = None,
    **options,
) -> np.ndarray:
    """Render one volume to an RGB image [height, width, 3] uint8 (see :class:`VolumeRenderer`).

    For several frames, keep a :class:`VolumeRenderer`: it reuses the pipeline and
    keeps the camera fixed.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.volume import Volume
    >>> from softvr.render import render_volume
    >>> mri = np.zeros((32, 32, 32), np.uint8); mri[8:24, 8:24, 8:24] = 200
    >>> render_volume(Volume(mri), 80, 60, preset="mri").shape
    (60, 80, 3)
    """
    with VolumeRenderer(width, height, preset, camera, **options) as renderer:
        return renderer.render(volume)
