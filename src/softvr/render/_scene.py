"""The VTK volume pipeline shared by the off-screen renderer and the interactive viewer."""

from __future__ import annotations

import numpy as np

from softvr.errors import InputError
from softvr.render.presets import Preset, label_colors, resolve_preset

__all__ = ["MAPPERS", "VolumeScene", "check_volume"]

#: mapper name -> VTK class. "cpu" is multi-threaded software ray casting, correct on any
#: OpenGL (and the fastest choice on llvmpipe); "gpu" ray casts in a fragment shader.
MAPPERS = {"cpu": "vtkFixedPointVolumeRayCastMapper", "gpu": "vtkGPUVolumeRayCastMapper"}

_NATIVE = {np.dtype(t) for t in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.float32, np.float64)}


def check_volume(volume, what: str = "volume") -> np.ndarray:
    """The voxel array of a :class:`softvr.volume.Volume`-like object, validated."""
    for attr in ("data", "spacing", "origin", "direction"):
        if not hasattr(volume, attr):
            raise InputError(what, "a softvr.volume.Volume", f"{type(volume).__name__} without .{attr}")
    data = np.asarray(volume.data)
    if data.ndim != 3:
        raise InputError(f"{what}.data", "a 3-D array [nx, ny, nz]", f"shape {data.shape}")
    if min(data.shape) < 2:
        raise InputError(f"{what}.data", "at least 2 voxels along each axis for ray casting", f"shape {data.shape}")
    if data.dtype.kind not in "biuf":
        raise InputError(f"{what}.data", "a numeric array", f"dtype {data.dtype}")
    return data


def _vtk_ready(data: np.ndarray) -> np.ndarray:
    """``data`` as a VTK-friendly dtype with x varying fastest, as a 1-D array."""
    if data.dtype == np.bool_:
        data = data.astype(np.uint8)
    elif data.dtype not in _NATIVE:
        data = data.astype(np.float32)
    if data.dtype.kind == "f" and not np.isfinite(data).all():
        data = np.nan_to_num(data, nan=0.0, posinf=np.finfo(data.dtype).max, neginf=np.finfo(data.dtype).min)
    return data.ravel(order="F")  # VTK point order: i (x) fastest, a view when data is F-contiguous


class VolumeScene:
    """A ``vtkVolume`` prop whose image data, pose and transfer function follow a Volume.

    The prop's user matrix carries ``origin`` and ``direction``; the ``vtkImageData``
    carries the grid size and ``spacing`` with origin 0, so every mapper honours all four.
    """

    def __init__(self, preset: "str | Preset" = "ct", mapper: str = "cpu", sample_distance: float = 0.5):
        from vtkmodules.util.numpy_support import numpy_to_vtk  # noqa: PLC0415
        from vtkmodules.vtkCommonDataModel import vtkImageData, vtkPiecewiseFunction  # noqa: PLC0415
        from vtkmodules.vtkCommonMath import vtkMatrix4x4  # noqa: PLC0415
        from vtkmodules.vtkRenderingCore import (  # noqa: PLC0415
            vtkColorTransferFunction,
            vtkVolume,
            vtkVolumeProperty,
        )
        import vtkmodules.vtkRenderingVolume as rv  # noqa: PLC0415
        import vtkmodules.vtkRenderingVolumeOpenGL2 as rvgl  # noqa: PLC0415

        if mapper not in MAPPERS:
            raise InputError("mapper", f"one of {sorted(MAPPERS)}", repr(mapper))
        if not sample_distance > 0:
            raise InputError("sample_distance", "a number > 0 [voxels]", repr(sample_distance))
        self._numpy_to_vtk = numpy_to_vtk
        self._vtk_pwf = vtkPiecewiseFunction
        self._vtk_ctf = vtkColorTransferFunction
        self.mapper_name = mapper
        self.sample_distance = float(sample_distance)
        self.image = vtkImageData()
        cls = getattr(rv, MAPPERS[mapper], None) or getattr(rvgl, MAPPERS[mapper])
        self.mapper = cls()
        self.mapper.SetInputData(self.image)
        if mapper == "cpu":
            self.mapper.AutoAdjustSampleDistancesOff()
            self.mapper.SetImageSampleDistance(1.0)
        else:
            self.mapper.AutoAdjustSampleDistancesOff()
        self.property = vtkVolumeProperty()
        self.matrix = vtkMatrix4x4()
        self.prop = vtkVolume()
        self.prop.SetMapper(self.mapper)
        self.prop.SetProperty(self.property)
        self.prop.SetUserMatrix(self.matrix)
        resolve_preset(preset)  # reject unknown names now, not at the first render
        self._preset_arg = preset
        self._applied_key: tuple | None = None
        self._keep: np.ndarray | None = None  # the array VTK reads from, kept alive
        self.has_data = False

    # ------------------------------------------------------------------ data
    def update(self, volume) -> None:
        """Show ``volume`` (any shape, spacing, origin, direction) from the next render on."""
        data = check_volume(volume)
        flat = _vtk_ready(data)
        spacing = np.asarray(volume.spacing, dtype=np.float64)
        nx, ny, nz = data.shape
        arr = self._numpy_to_vtk(flat, deep=False)
        arr.SetName("voxels")
        self._keep = flat
        if tuple(self.image.GetDimensions()) != (nx, ny, nz):
            self.image.SetDimensions(nx, ny, nz)
        self.image.SetSpacing(*spacing)
        self.image.SetOrigin(0.0, 0.0, 0.0)
        self.image.GetPointData().SetScalars(arr)
        self.image.Modified()
        m = np.eye(4)
        m[:3, :3] = np.asarray(volume.direction, dtype=np.float64)
        m[:3, 3] = np.asarray(volume.origin, dtype=np.float64)
        for r in range(4):
            for c in range(4):
                self.matrix.SetElement(r, c, m[r, c])
        self.matrix.Modified()
        self.prop.Modified()
        step = float(spacing.min())
        self.mapper.SetSampleDistance(self.sample_distance * step)
        if self.mapper_name == "cpu":
            self.mapper.SetInteractiveSampleDistance(2.0 * self.sample_distance * step)
        self.property.SetScalarOpacityUnitDistance(step)
        self._apply_preset(volume, flat)
        self.has_data = True

    def set_preset(self, preset: "str | Preset") -> None:
        """Use ``preset`` from the next :meth:`update` on."""
        resolve_preset(preset)
        self._preset_arg = preset
        self._applied_key = None

    def bounds(self) -> tuple[float, ...]:
        """World bounds (xmin, xmax, ymin, ymax, zmin, zmax) of the current volume."""
        return tuple(self.prop.GetBounds())

    # --------------------------------------------------------------- presets
    def _apply_preset(self, volume, flat: np.ndarray) -> None:
        preset = resolve_preset(self._preset_arg, volume)
        labels = None
        key: tuple
        if preset.categorical:
            labels = _label_values(flat)
            key = (preset, tuple(labels.tolist()))
        else:
            key = (preset,)
        if key == self._applied_key:
            return
        prop = self.property
        ctf, pwf = self._vtk_ctf(), self._vtk_pwf()
        if preset.categorical:
            assert labels is not None  # found above for a categorical preset
            colors = label_colors(labels)
            for value, rgb in zip(labels.tolist(), colors):
                ctf.AddRGBPoint(value, *rgb)
                pwf.AddPoint(value, 0.0 if value == 0 else preset.label_opacity)
            if len(labels) == 1:  # a flat table still needs a range
                ctf.AddRGBPoint(labels[0] + 1, *colors[0])
                pwf.AddPoint(labels[0] + 1, 0.0 if labels[0] == 0 else preset.label_opacity)
        else:
            for value, r, g, b in preset.colors:
                ctf.AddRGBPoint(value, r, g, b)
            for value, a in preset.opacities:
                pwf.AddPoint(value, a)
        prop.SetColor(ctf)
        prop.SetScalarOpacity(pwf)
        if preset.gradient_opacities:
            gof = self._vtk_pwf()
            for g, a in preset.gradient_opacities:
                gof.AddPoint(g, a)
            prop.SetGradientOpacity(gof)
            prop.DisableGradientOpacityOff()
        else:
            prop.DisableGradientOpacityOn()
        if preset.interpolation == "nearest":
            prop.SetInterpolationTypeToNearest()
        else:
            prop.SetInterpolationTypeToLinear()
        prop.SetShade(bool(preset.shade))
        prop.SetAmbient(preset.ambient)
        prop.SetDiffuse(preset.diffuse)
        prop.SetSpecular(preset.specular)
        prop.SetSpecularPower(20.0)
        self._applied_key = key


def _label_values(flat: np.ndarray) -> np.ndarray:
    """Sorted distinct integer labels of a label array (fast path for small ranges)."""
    if flat.dtype.kind in "biu":
        lo, hi = int(flat.min()), int(flat.max())
        if hi - lo <= 65535:
            shift = min(lo, 0)
            counts = np.bincount(flat.astype(np.int64) - shift if shift else flat)
            return np.nonzero(counts)[0] + shift
    return np.unique(np.rint(flat)).astype(np.int64)
