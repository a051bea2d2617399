"""A volume kept drawn through a moving tet mesh, re-rasterized only where the mesh moved."""

from __future__ import annotations

import time

import numpy as np

from softvr.errors import InputError
from softvr.volume._volume import Volume
from softvr.volume.rasterize import Rasterizer, _moved_nodes

__all__ = ["DeformedVolume"]


class DeformedVolume:
    """``volume`` drawn through its embedding tets as their nodes move (thesis eqs. 3.1, 3.2),
    on the rest volume's grid.

    Each :meth:`update` rasterizes only the box around the tets with a node that moved more
    than ``tolerance`` since it was last drawn (:meth:`Rasterizer.update`); nodes that moved
    less keep their drawn position, so their motion adds up until it is drawn and the picture
    never lags the mesh by more than ``tolerance``.

    Parameters
    ----------
    volume : Volume
        The rest volume; also the output grid.
    nodes : array_like, shape [node_count, 3] [volume units]
        Rest node positions.
    tets : array_like, shape [tet_count, 4]
    tolerance : float [volume units]
        Node motion that does not need drawing yet.
    incremental : bool
        False: the whole volume every update.
    **options
        :class:`Rasterizer` options (``interpolation``, ``background``, ``inverted``, ``device``).

    Attributes
    ----------
    deformed : Volume
        The volume as drawn now.
    drawn_nodes : ndarray, shape [node_count, 3] [volume units]
        The node positions it is drawn for.

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.volume import DeformedVolume, Volume, grid_tet_mesh
    >>> ct = Volume(np.arange(6 * 6 * 6, dtype=np.float32).reshape(6, 6, 6))
    >>> nodes, tets = grid_tet_mesh(ct, 2)
    >>> shown = DeformedVolume(ct, nodes, tets, tolerance=0.01, device="cpu")
    >>> moved = nodes.copy(); moved[0] += (0.5, 0.0, 0.0)
    >>> shown.update(moved)["raster_voxels"] > 0, shown.update(moved)["raster_voxels"]
    (True, 0)
    """

    def __init__(self, volume: Volume, nodes, tets, *, tolerance: float = 0.0, incremental: bool = True, **options):
        self.rasterizer = Rasterizer(volume, nodes, tets, **options)
        self.drawn_nodes = np.array(nodes, float)
        self.deformed = self.rasterizer.deform(self.drawn_nodes, out_grid=volume)
        self.tolerance, self.incremental = float(tolerance), bool(incremental)

    def update(self, nodes) -> dict:
        """Draw the volume for ``nodes`` [node_count, 3] [volume units]; returns
        ``raster_ms`` (time taken), ``raster_voxels`` (voxels rewritten) and ``box``: the
        rewritten index box ``(lo, hi)`` (inclusive, [3] each) or None, which a renderer can
        take as the only region that changed (:meth:`softvr.render.VolumeRenderer.render`)."""
        t0 = time.perf_counter()
        nodes = np.asarray(nodes, float)
        if self.incremental:
            if nodes.shape != self.drawn_nodes.shape:
                raise InputError("nodes", f"an array of the rest nodes' shape {self.drawn_nodes.shape}",
                                 f"shape {nodes.shape}")
            moved = _moved_nodes(nodes, self.drawn_nodes, self.tolerance)
            box = self.rasterizer._update_moved(self.deformed, nodes, self.drawn_nodes, moved)  # noqa: SLF001
            box = None if box is None else (np.asarray(box[0]), np.asarray(box[1]))
            voxels = 0 if box is None else int(np.prod(box[1] - box[0] + 1))
            self.drawn_nodes[moved] = nodes[moved]
        else:
            self.rasterizer.deform(nodes, out=self.deformed)
            self.drawn_nodes[:] = nodes
            voxels = int(np.prod(self.deformed.shape))
            box = (np.zeros(3, int), np.asarray(self.deformed.shape) - 1)
        return {"raster_ms": 1e3 * (time.perf_counter() - t0), "raster_voxels": voxels, "box": box}
