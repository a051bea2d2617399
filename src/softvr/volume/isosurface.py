"""Surfaces of a volume: the iso-surface of a scalar level, or the boundary of a label."""

from __future__ import annotations

import numpy as np

from softvr.errors import InputError
from softvr.volume._volume import Volume

__all__ = ["iso_surface"]


def iso_surface(volume: Volume, level: float, *, step: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The triangle surface where ``volume`` crosses ``level`` (VTK's flying edges).

    Parameters
    ----------
    volume : Volume
    level : float
        Iso-value in the volume's units (HU for CT; 0.5 between a label and the rest of a
        0 / 1 mask).
    step : int
        Use every ``step``-th voxel per axis (coarser, faster surfaces).

    Returns
    -------
    vertices : ndarray, shape [n, 3] [volume world units]
    triangles : ndarray, shape [t, 3] int32
        Consistently oriented; none when the level is never crossed.
    """
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy  # noqa: PLC0415
    from vtkmodules.vtkCommonDataModel import vtkImageData  # noqa: PLC0415
    from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D  # noqa: PLC0415

    if not isinstance(volume, Volume):
        raise InputError("volume", "a softvr.volume.Volume", type(volume).__name__)
    if not (isinstance(step, int) and step >= 1):
        raise InputError("step", "an integer >= 1", repr(step))
    data = np.ascontiguousarray(volume.data[::step, ::step, ::step], dtype=np.float32)
    image = vtkImageData()
    image.SetDimensions(*data.shape)
    # VTK's x varies fastest: Fortran order of the [x, y, z] array.
    image.GetPointData().SetScalars(numpy_to_vtk(data.ravel(order="F"), deep=True))
    surface = vtkFlyingEdges3D()
    surface.SetInputData(image)
    surface.SetValue(0, float(level))
    surface.ComputeNormalsOff()
    surface.ComputeGradientsOff()
    surface.Update()
    poly = surface.GetOutput()
    if poly.GetNumberOfPoints() == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    ijk = vtk_to_numpy(poly.GetPoints().GetData()).astype(float) * step
    cells = vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).reshape(-1, 3).astype(np.int32)
    return volume.index_to_world(ijk), cells
