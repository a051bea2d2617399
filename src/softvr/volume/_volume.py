"""The :class:`Volume` data class: a dense scalar field on a regular 3-D grid."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from softvr.errors import InputError

__all__ = ["SUPPORTED_DTYPES", "Volume"]

#: Voxel types that :func:`softvr.volume.deform` accepts and returns unchanged.
SUPPORTED_DTYPES = (np.dtype(np.uint8), np.dtype(np.int16), np.dtype(np.uint16), np.dtype(np.float32))
_EYE = np.eye(3)


@dataclass(eq=False)
class Volume:
    """A scalar volume on a regular grid.

    Voxel ``(i, j, k)`` holds ``data[i, j, k]`` and sits at world position
    ``origin + direction @ (spacing * (i, j, k))``; with the default identity
    ``direction`` that is ``origin + spacing * (i, j, k)``. Axis 0 is x, 1 is y, 2 is z.

    Attributes
    ----------
    data : numpy.ndarray, shape [nx, ny, nz]
        Voxel values, any of :data:`SUPPORTED_DTYPES` for deformation (others load fine).
    spacing : numpy.ndarray, shape [3] [m or file units]
        Distance between neighbouring voxel centres along x, y, z; all > 0.
    origin : numpy.ndarray, shape [3] [m or file units]
        World position of voxel (0, 0, 0).
    direction : numpy.ndarray, shape [3, 3]
        Orthonormal matrix whose columns are the world directions of the i, j, k axes.
    is_label : bool
        True for segmentations: deformation then uses nearest-neighbour fetches so
        that the set of labels is preserved.
    """

    data: np.ndarray
    spacing: np.ndarray = field(default_factory=lambda: np.ones(3))
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.eye(3))
    is_label: bool = False

    def __post_init__(self) -> None:
        data = np.asarray(self.data)
        if data.ndim != 3:
            raise InputError("Volume.data", "a 3-D array [nx, ny, nz]", f"shape {data.shape}")
        if data.size == 0:
            raise InputError("Volume.data", "a non-empty array", f"shape {data.shape}")
        self.data = data
        self.spacing = _vec3(self.spacing, "Volume.spacing")
        if np.any(self.spacing <= 0):
            raise InputError("Volume.spacing", "three values > 0", str(self.spacing.tolist()))
        self.origin = _vec3(self.origin, "Volume.origin")
        d = np.asarray(self.direction, dtype=np.float64)
        if d.shape != (3, 3) or not np.all(np.isfinite(d)):
            raise InputError("Volume.direction", "a finite 3x3 matrix", f"{d.shape} {d.tolist()}")
        # np.allclose(d.T @ d, I, atol=1e-4) written out: allclose's generality cost ~4x this
        # (~0.1 ms of each Volume, one a rasterized frame).
        if not bool(np.all(np.abs(d.T @ d - _EYE) <= 1e-4 + 1e-5 * _EYE)):
            raise InputError("Volume.direction", "an orthonormal 3x3 matrix", str(d.round(4).tolist()))
        self.direction = d

    @property
    def shape(self) -> tuple[int, int, int]:
        """Grid size ``(nx, ny, nz)``."""
        return tuple(int(n) for n in self.data.shape)  # type: ignore[return-value]

    @property
    def dtype(self) -> np.dtype:
        return self.data.dtype

    @property
    def extent(self) -> np.ndarray:
        """Distance from the first to the last voxel centre along each axis, shape [3]."""
        return self.spacing * (np.asarray(self.shape) - 1)

    def index_to_world(self, ijk: np.ndarray) -> np.ndarray:
        """World positions [..., 3] of continuous voxel indices [..., 3]."""
        ijk = np.asarray(ijk, dtype=np.float64)
        return self.origin + (ijk * self.spacing) @ self.direction.T

    def world_to_index(self, xyz: np.ndarray) -> np.ndarray:
        """Continuous voxel indices [..., 3] of world positions [..., 3]."""
        xyz = np.asarray(xyz, dtype=np.float64)
        return ((xyz - self.origin) @ self.direction) / self.spacing

    def with_data(self, data: np.ndarray) -> "Volume":
        """A volume on the same grid holding ``data``."""
        return Volume(data, self.spacing.copy(), self.origin.copy(), self.direction.copy(), self.is_label)

    def __repr__(self) -> str:
        # direction rows with 4 significant digits (``softvr info`` prints this); + 0.0 drops "-0"
        rows = ", ".join("[" + ", ".join(f"{v + 0.0:.4g}" for v in row) + "]" for row in self.direction)
        return (
            f"Volume(shape={self.shape}, dtype={self.dtype}, spacing={self.spacing.tolist()}, "
            f"origin={self.origin.tolist()}, direction=[{rows}], is_label={self.is_label})"
        )


def _vec3(value, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InputError(name, "three finite numbers", repr(np.asarray(value).tolist()))
    return v
