"""Fixtures for the rendering tests: synthetic volumes (the Xvfb server is in tests/conftest.py)."""

from __future__ import annotations

import numpy as np
import pytest

from softvr.render import Preset
from softvr.volume import Volume

#: White where the value is >= 0.5, fully opaque, no shading: pixels are 0 or 255.
OPAQUE = Preset(
    "opaque",
    colors=((0.0, 1.0, 1.0, 1.0), (1.0, 1.0, 1.0, 1.0)),
    opacities=((0.0, 0.0), (0.499, 0.0), (0.501, 1.0), (1.0, 1.0)),
    shade=False,
)


def sphere_volume(radius: float, spacing, shape, origin=None) -> Volume:
    """float32 volume: 1 at voxel centres within ``radius`` of the grid centre, 0 elsewhere.

    With ``origin=None`` the grid centre is at world (0, 0, 0).
    """
    spacing = np.asarray(spacing, float)
    shape = np.asarray(shape)
    centre = (shape - 1) / 2 * spacing
    axes = [np.arange(n) * s - c for n, s, c in zip(shape, spacing, centre)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    data = (x**2 + y**2 + z**2 <= radius**2).astype(np.float32)
    return Volume(data, spacing=spacing, origin=-centre if origin is None else origin)


def ct_phantom(n: int = 40) -> Volume:
    """A small int16 'head' in Hounsfield units: soft tissue, a skull shell and a bony nose (+y)."""
    c = (n - 1) / 2
    x, y, z = np.meshgrid(*(np.arange(n) - c,) * 3, indexing="ij")
    r = np.sqrt((x / 1.0) ** 2 + (y / 1.15) ** 2 + (z / 1.05) ** 2)
    data = np.full((n, n, n), -1000, np.int16)
    data[r < 0.45 * n] = 40
    data[(r < 0.40 * n) & (r > 0.33 * n)] = 1200
    data[(np.abs(x) < 0.06 * n) & (y > 0.3 * n) & (y < 0.5 * n) & (np.abs(z) < 0.12 * n)] = 700
    return Volume(data, spacing=(1.0, 1.0, 1.2), origin=(-c, -c, -1.2 * c))


@pytest.fixture
def opaque_preset() -> Preset:
    """The :data:`OPAQUE` transfer function."""
    return OPAQUE


@pytest.fixture
def make_sphere():
    """The :func:`sphere_volume` factory."""
    return sphere_volume


@pytest.fixture
def phantom() -> Volume:
    """A 40^3 int16 CT phantom (see :func:`ct_phantom`)."""
    return ct_phantom()
