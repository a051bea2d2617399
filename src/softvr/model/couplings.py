"""Where parts are coupled (thesis 5.2.2): nodes of one part close to another part's surface."""

from __future__ import annotations

import numpy as np

from softvr.collision import TriangleMesh
from softvr.errors import InputError

__all__ = ["nodes_near_surface"]


def nodes_near_surface(nodes, vertices, triangles, radius: float) -> np.ndarray:
    """Indices of ``nodes`` [n, 3] [m] within ``radius`` [m] of a triangle surface (its inside
    too, when the surface is closed): the coupling nodes of a soft part attached to it."""
    if not (np.isfinite(radius) and radius >= 0):
        raise InputError("radius", "a distance >= 0 [m]", repr(radius))
    distance = TriangleMesh(np.asarray(vertices, float), np.asarray(triangles)).signed_distance(nodes)
    return np.flatnonzero(distance <= radius)
