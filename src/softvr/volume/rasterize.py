"""Deform a volume by rasterizing its deformed embedding tetrahedral mesh (thesis 3.1-3.2).

Three rasterization strategies write identical voxels (the inside test is exact integer
arithmetic, shared by all three) and differ only in how many candidate voxels they test:

``"bbox"``  (``culling=False``)
    Thesis Algorithm 1: every voxel of each deformed tet's axis-aligned bounding box.
``"cells"``
    Thesis 3.2 hierarchical culling: coarse grid-point 8-bit half-space masks per tet,
    cells culled when the AND of their 8 corner masks is non-zero; surviving cells are
    scanned voxel by voxel.
``"spans"`` (``culling=True``, the default)
    softvr's exact row spans: per row of a tet's box, the interval of voxels inside the
    tet is solved exactly from the 4 face equations, so only written voxels are visited.

Voxels on a face shared by two tets are written by exactly one of them: node positions
are snapped to 1/S of a voxel (S a power of two, up to 256) and each face's plane is
evaluated in exact int64 arithmetic, with ties broken by the sign of the face normal in
(z, y, x) lexicographic order, i.e. by an infinitesimal displacement of the voxel centre.
"""

from __future__ import annotations

import threading
import time
from typing import cast
from dataclasses import asdict, dataclass

import numpy as np
import warp as wp

from softvr.device import launch, load_kernels, resolve_device
from softvr.errors import InputError
from softvr.geometry import check_tets, tet_signed_volumes
from softvr.volume import _raster_kernels as K
from softvr.volume._volume import SUPPORTED_DTYPES, Volume

__all__ = ["OutputGrid", "RasterStats", "Rasterizer", "deform", "fit_output_grid"]

_METHODS = {False: "bbox", True: "spans", "bbox": "bbox", "none": "bbox", "cells": "cells", "spans": "spans"}
# Snapped coordinates stay below 2**17 so that plane values (|n| < 2**37) fit in int64.
_COORD_LIMIT = 2**17
_MAX_SUBVOXEL = 256
# CPU exact spans: x-slabs per work item, small enough to balance a few huge tets over the cores.
# Not 16: a tet of a 16-voxel grid cube spans 17 slabs, and its second item (one slab) cost a
# whole item's set-up and flush (4 480 of 14 720 items in place on the head CT, ~1 ms a frame).
_SLABS_PER_ITEM = 32
# Output type codes of the vectorized CPU row writer (see _raster_kernels._ROW_SNIPPET).
_OUT_CODES = {np.dtype(np.uint8): 1, np.dtype(np.int16): 2, np.dtype(np.uint16): 3, np.dtype(np.float32): 4}
# Inputs the CPU exact spans read directly, as z-neighbour pairs (see _raster_kernels._cpp_trilinear).
_SRC_CODES = {np.dtype(np.int16): 2, np.dtype(np.uint16): 3}


@dataclass
class RasterStats:
    """Statistics of one rasterization.

    Attributes
    ----------
    method : str
        ``"bbox"``, ``"cells"`` or ``"spans"``.
    device : str
        Warp device it ran on.
    tet_count : int
    output_voxels : int
        Voxels in the output grid.
    voxels_tested : int
        Candidate voxels whose inside test ran (for ``"spans"``: voxels visited).
    voxels_written : int
        Voxels found inside a deformed tet (each counted once).
    efficiency : float
        ``voxels_written / voxels_tested`` (thesis: 14.3 % without culling, 51 % with).
    cells_total, cells_kept : int
        Coarse cells considered and kept by culling (``"cells"`` only, else 0).
    time_setup_s, time_cull_s, time_raster_s, time_total_s : float
        Wall time [s] of per-tet set-up on the host, culling, voxel rasterization, and all.
    """

    method: str
    device: str
    tet_count: int
    output_voxels: int
    voxels_tested: int
    voxels_written: int
    efficiency: float
    cells_total: int
    cells_kept: int
    time_setup_s: float
    time_cull_s: float
    time_raster_s: float
    time_total_s: float

    @property
    def voxels_per_second(self) -> float:
        """Output voxels produced per second of total time."""
        return self.output_voxels / self.time_total_s if self.time_total_s > 0 else float("inf")

    def as_dict(self) -> dict:
        return asdict(self) | {"voxels_per_second": self.voxels_per_second}


@dataclass(frozen=True)
class OutputGrid:
    """A regular output grid without data: voxel (i, j, k) at origin + direction @ (spacing * ijk).

    Attributes
    ----------
    shape : tuple of 3 int
    spacing : ndarray, shape [3] [volume units]
    origin : ndarray, shape [3] [volume units]
    direction : ndarray, shape [3, 3]
    """

    shape: tuple
    spacing: np.ndarray
    origin: np.ndarray
    direction: np.ndarray

    @classmethod
    def of(cls, volume: Volume) -> "OutputGrid":
        return cls(volume.shape, volume.spacing, volume.origin, volume.direction)

    def world_to_index(self, xyz: np.ndarray) -> np.ndarray:
        """Continuous voxel indices [..., 3] of world positions [..., 3]."""
        return ((np.asarray(xyz, dtype=np.float64) - self.origin) @ self.direction) / self.spacing


def fit_output_grid(volume: Volume, deformed_nodes: np.ndarray) -> OutputGrid:
    """The output grid fitted to deformed node bounds.

    Keeps the input's spacing and direction. The deformed nodes' bounding box (in the
    input's frame) is tiled with whole voxels whose footprints lie inside it, the first
    voxel centre half a voxel from the lower corner: a mesh covering the input's
    footprint (:func:`grid_tet_mesh`) moved by whole voxels yields the input's grid.

    Parameters
    ----------
    volume : Volume
        The input volume (spacing and direction are kept).
    deformed_nodes : ndarray, shape [node_count, 3] [volume units]
    """
    local = np.asarray(deformed_nodes, dtype=np.float64) @ volume.direction  # world -> grid frame
    lo, hi = local.min(axis=0), local.max(axis=0)
    shape = np.maximum(np.floor((hi - lo) / volume.spacing + 1e-6).astype(np.int64), 1)
    origin = volume.direction @ (lo + 0.5 * volume.spacing)
    return OutputGrid(tuple(int(n) for n in shape), volume.spacing.copy(), origin, volume.direction.copy())


class Rasterizer:
    """Deforms one volume by one embedding tet mesh, frame after frame.

    The input volume is uploaded once; each :meth:`deform` call takes new deformed node
    positions. Implements thesis eqs. 3.1-3.2 (barycentric mappings), Algorithm 1
    (bounding-box rasterization) and 3.2 (hierarchical culling), plus exact row spans.

    Parameters
    ----------
    volume : Volume
        Input volume; dtype uint8, int16, uint16 or float32.
    nodes : array_like, shape [node_count, 3]
        Rest positions of the mesh nodes [volume spacing units, world frame].
    tets : array_like, shape [tet_count, 4]
        Positively oriented tetrahedra (node indices).
    culling : bool or {"bbox", "cells", "spans"}
        ``True`` = ``"spans"`` (fastest), ``False`` = ``"bbox"`` (thesis Algorithm 1),
        ``"cells"`` = thesis 3.2 grid-point / cell-mask culling.
    interpolation : {"linear", "nearest"}, optional
        Fetch from the rest volume; default ``"nearest"`` for label volumes
        (``volume.is_label``) so the label set is kept, else ``"linear"`` (trilinear).
    background : float, optional
        Value of output voxels outside the deformed mesh; default the input's minimum.
    device : {"cpu", "cuda", None}
        Warp device; ``None`` = CUDA when present.
    cell_size : int
        Coarse cell edge in voxels for ``"cells"`` culling (thesis: 8).
    vectorized_rows : bool
        CPU only: write each row with the vectorized C++ loop (default) instead of the
        Warp reference loop; both give bit-identical voxels.
    inverted : {"error", "skip"}
        What a deformed tet turned inside out (or flat) does: raise an
        :class:`~softvr.errors.InputError` naming it (default), or write nothing this frame
        (interactive simulations, where an embedding tet in air may fold for a moment;
        ``skipped_tets`` counts them; after :meth:`update`, those among the tets that reach
        its box). Where a fold makes drawn tets overlap, a voxel they share takes the one
        with the highest index on any number of threads (CPU exact spans).

    Examples
    --------
    >>> import numpy as np
    >>> from softvr.volume import Volume, Rasterizer, grid_tet_mesh
    >>> vol = Volume(np.random.default_rng(0).random((16, 16, 16), dtype=np.float32))
    >>> nodes, tets = grid_tet_mesh(vol, cells=4)
    >>> r = Rasterizer(vol, nodes, tets, device="cpu")
    >>> out = r.deform(nodes)
    >>> bool(np.allclose(out.data, vol.data, atol=1e-5)), r.stats.voxels_written == vol.data.size
    (True, True)
    """

    def __init__(
        self,
        volume: Volume,
        nodes,
        tets,
        *,
        culling=True,
        interpolation: str | None = None,
        background: float | None = None,
        device: str | None = None,
        cell_size: int = 8,
        vectorized_rows: bool = True,
        inverted: str = "error",
    ):
        if not isinstance(volume, Volume):
            raise InputError("volume", "a softvr.volume.Volume", type(volume).__name__)
        if volume.dtype not in SUPPORTED_DTYPES:
            raise InputError("volume.data", f"dtype in {[str(d) for d in SUPPORTED_DTYPES]}", str(volume.dtype))
        if volume.dtype.kind == "f" and not np.isfinite(volume.data).all():
            raise InputError("volume.data", "finite voxel values", "NaN or infinite values")
        key = culling if isinstance(culling, bool) else str(culling)
        if key not in _METHODS:
            raise InputError("culling", "True, False, 'bbox', 'cells' or 'spans'", repr(culling))
        self.method = _METHODS[key]
        if inverted not in ("error", "skip"):
            raise InputError("inverted", "'error' or 'skip'", repr(inverted))
        self.inverted = inverted
        self.skipped_tets = 0
        interp = interpolation or ("nearest" if volume.is_label else "linear")
        if interp not in ("linear", "nearest"):
            raise InputError("interpolation", "'linear' or 'nearest'", repr(interpolation))
        if int(cell_size) < 1:
            raise InputError("cell_size", "an int >= 1", repr(cell_size))
        self.volume = volume
        self.interpolation = interp
        self.cell_size = int(cell_size)
        self.device = resolve_device(device)
        self.nodes, self.tets = check_tets(nodes, tets)
        self.background = float(volume.data.min()) if background is None else float(background)
        if not np.isfinite(self.background):
            raise InputError("background", "a finite value", repr(background))
        info = np.iinfo(volume.dtype) if volume.dtype.kind in "iu" else None
        self._params = wp.vec4f(
            1.0 if interp == "nearest" else 0.0,
            1.0 if info else 0.0,
            float(info.min) if info else 0.0,
            float(info.max) if info else 0.0,
        )
        self._rest_index = volume.world_to_index(self.nodes)
        data = np.ascontiguousarray(volume.data)
        # Kernels only read the input: on the CPU Warp shares numpy's memory.
        self._vol: wp.array = wp.array(data.reshape(-1), device=self.device, copy=self.device != "cpu")
        self._out_code = _OUT_CODES[data.dtype] if self.device == "cpu" and vectorized_rows else 0
        self._dims = wp.vec3i(*data.shape)
        strides = [0 if n == 1 else s // data.itemsize for n, s in zip(data.shape, data.strides)]
        self._strides = wp.vec3i(*strides)
        # The CPU exact spans read trilinear corners straight from the input as z-neighbour
        # pairs (one 32- or 64-bit gather per pair) where rows are contiguous; the other CPU
        # paths gather from a float32 copy (AVX gathers are 32-bit), made on first use.
        self._src_code = (
            _SRC_CODES.get(data.dtype, 0)
            if self._out_code and strides[2] == 1 and interp == "linear" and self.method == "spans"
            else 0
        )
        self._volf_w: wp.array | None = None
        self._no_volf = wp.empty(0, dtype=wp.float32, device=self.device)
        self._rest_w: wp.array = wp.array(self._rest_index, dtype=wp.vec3d, device=self.device)
        self._tets_w: wp.array = wp.array(self.tets, dtype=wp.int32, device=self.device)
        self._tets_t = np.ascontiguousarray(self.tets.T)  # [4, tet_count] for reductions over a tet's nodes
        self.stats: RasterStats | None = None
        self._scratch: _Scratch | None = None
        # Compile (first use only, then cached on disk) now rather than inside the first frame.
        load_kernels(K.raster_slabs, self.device)

    @property
    def _volf(self) -> wp.array:
        """The input as float32 for the vectorized CPU rows (empty when they are off)."""
        if self._volf_w is None:
            if self._out_code == 0:
                self._volf_w = wp.empty(0, dtype=wp.float32, device=self.device)
            elif self._vol.dtype == wp.float32:
                self._volf_w = self._vol
            else:
                data = np.ascontiguousarray(self.volume.data).reshape(-1)
                self._volf_w = wp.array(data.astype(np.float32), device=self.device)
        return self._volf_w

    def _refresh_input(self, default_background: bool) -> None:
        """Re-read ``volume.data`` (edited in place since construction) where a copy of it is
        held, and its minimum where that is the background."""
        data = self.volume.data
        if data.dtype.kind == "f" and not np.isfinite(data).all():
            raise InputError("volume.data", "finite voxel values", "NaN or infinite values")
        shared = self.device == "cpu" and data.flags.c_contiguous and self._vol.ptr == data.ctypes.data
        if not shared:
            self._vol = wp.array(np.ascontiguousarray(data).reshape(-1), device=self.device, copy=self.device != "cpu")
            self._volf_w = None
        elif self._volf_w is not None and self._volf_w is not self._vol:
            self._volf_w = None  # a float32 copy: made again on first use
        if default_background:
            self.background = float(data.min())

    # ------------------------------------------------------------------ public
    def deform(self, deformed_nodes, out_grid: Volume | None = None, *, out: Volume | None = None) -> Volume:
        """Rasterize the volume deformed by ``deformed_nodes``.

        Parameters
        ----------
        deformed_nodes : array_like, shape [node_count, 3]
            Deformed node positions [volume spacing units, world frame].
        out_grid : Volume or OutputGrid, optional
            Output grid (shape, spacing, origin, direction are used; a Volume's data is
            not). ``None`` fits the grid to the deformed bounds (:func:`fit_output_grid`).
        out : Volume, optional
            Write into this volume's data (its grid is the output grid) instead of a new
            array: frame after frame on one grid this saves allocating and first-touching
            the output. Must have the input's dtype and C-contiguous data.

        Returns
        -------
        Volume
            The deformed volume (``out`` itself when given), same dtype as the input;
            ``stats`` holds its statistics.
        """
        if out is not None:
            if out_grid is not None:
                raise InputError("out_grid", "None when out is given (out is the grid)", "both")
            if not isinstance(out, Volume) or out.dtype != self.volume.dtype or not out.data.flags.c_contiguous:
                found = type(out).__name__ if not isinstance(out, Volume) else f"dtype {out.dtype}, C-contiguous {out.data.flags.c_contiguous}"
                raise InputError("out", f"a Volume with dtype {self.volume.dtype} and C-contiguous data", found)
            if not out.data.flags.writeable:
                raise InputError("out", "a Volume with writeable data", "read-only data")
        return cast(Volume, self._run(deformed_nodes, out_grid, count_writes=False, into=out))  # not a window

    def update(self, out: Volume, deformed_nodes, previous_nodes, *, tolerance: float = 0.0):
        """Bring ``out`` (a volume this rasterizer wrote for ``previous_nodes``) to
        ``deformed_nodes``, rasterizing only where the mesh moved.

        Voxels can change only inside the old and new footprints of the tets with a node that
        moved by more than ``tolerance`` [volume units]; the box around those footprints (one
        voxel of margin) is rasterized anew, with every tet that reaches into it, and copied
        into ``out`` (the rest of ``out`` is already right). Written in place (CPU exact spans),
        only the 8-voxel bricks of the box that those footprints reach are redrawn (per slab of
        8 x-planes, the rectangle around them), each tet cut to them. Equal to a full
        :meth:`deform` onto ``out``'s grid (up to the round-off of the sub-grid's origin) for
        ``tolerance`` 0; otherwise voxels outside the redrawn part keep tets drawn at node
        positions within ``2 tolerance`` of the present ones (``tolerance`` since their last
        draw, ``tolerance`` from ``previous_nodes``).

        Parameters
        ----------
        out : Volume
            Output volume, updated in place (its data C-contiguous, the input's dtype).
        deformed_nodes, previous_nodes : array_like, shape [node_count, 3]
            Node positions now and when ``out`` was written [volume units, world frame].
        tolerance : float
            Node motion [volume units] below which a node counts as still.

        Returns
        -------
        tuple of 2 ndarray (int) or None
            The rewritten index box of ``out`` (lower and upper corner, inclusive), or None
            when nothing moved. ``stats`` describes the partial run.
        """
        x1 = np.asarray(deformed_nodes, float)
        x0 = np.asarray(previous_nodes, float)
        if x1.shape != self.nodes.shape or x0.shape != self.nodes.shape:
            raise InputError("deformed_nodes / previous_nodes", f"arrays of the rest nodes' shape {self.nodes.shape}",
                             f"shapes {x1.shape}, {x0.shape}")
        return self._update_moved(out, x1, x0, _moved_nodes(x1, x0, tolerance))

    def _update_moved(self, out: Volume, x1: np.ndarray, x0: np.ndarray, moved: np.ndarray):
        """:meth:`update` (``x1``, ``x0`` float64 [node_count, 3], checked) where the nodes that
        moved are ``moved`` [node_count] bool."""
        if not moved.any():
            return None
        # Reductions run along contiguous rows here: numpy's reduce over axis 0 of an [n, 3]
        # (or over the 4 nodes of [tet_count, 4]) array is 10-20x slower (~1 ms a palpation frame).
        node_moved = moved[self._tets_t]  # [4, tet_count]
        tets = self.tets[node_moved[0] | node_moved[1] | node_moved[2] | node_moved[3]]
        corners = out.world_to_index(np.concatenate([x0[tets], x1[tets]], axis=1).reshape(-1, 3))
        per_tet = np.ascontiguousarray(corners.reshape(len(tets), 8, 3).transpose(2, 1, 0))  # [3, 8, t]
        tet_min, tet_max = per_tet.min(axis=1), per_tet.max(axis=1)  # [3, t]
        low, high = tet_min.min(axis=1), tet_max.max(axis=1)  # [3]
        shape = np.asarray(out.shape)
        lo = np.clip(np.floor(low).astype(int) - 1, 0, shape - 1)
        hi = np.clip(np.ceil(high).astype(int) + 1, 0, shape - 1)
        if np.any(high < -1) or np.any(low > shape):
            return None  # moved entirely outside the output grid
        window = tuple(slice(a, b + 1) for a, b in zip(lo, hi))
        origin = out.index_to_world(lo)
        if self._writes_in_place(out):
            grid = OutputGrid(tuple(int(n) for n in hi - lo + 1), out.spacing.copy(), origin, out.direction.copy())
            tet_lo = np.floor(tet_min.T).astype(int) - 1 - lo
            tet_hi = np.ceil(tet_max.T).astype(int) + 1 - lo
            region = _moved_region(tet_lo, tet_hi, hi - lo + 1)
            self._run(x1, grid, count_writes=False, window=(out.data, lo, region))
        else:
            sub = Volume(np.empty(tuple(hi - lo + 1), out.dtype), out.spacing.copy(), origin, out.direction.copy())
            self.deform(x1, out=sub)
            out.data[window] = sub.data
        return lo, hi

    def _writes_in_place(self, out: Volume) -> bool:
        """Whether :meth:`update` writes straight into ``out``'s box (the CPU exact spans, which
        take the output's row pitch): no sub-volume to fill and copy back. Not where ``out``
        may be the input itself (it would read voxels it has just written)."""
        data = out.data
        return (self.method == "spans" and self._out_code != 0 and data.dtype == self.volume.dtype
                and _span_item_slabs(data.shape) > 0 and data.flags.c_contiguous and data.flags.writeable
                and not np.may_share_memory(data, self.volume.data))

    def write_counts(self, deformed_nodes, out_grid: Volume | None = None) -> Volume:
        """How many tets claim each output voxel (0 outside the mesh, 1 inside).

        Runs the same traversal and inside test as :meth:`deform`, counting instead of
        writing; a conforming mesh must give 1 for every voxel strictly inside its hull.

        Returns
        -------
        Volume
            int32 counts on the output grid.
        """
        return cast(Volume, self._run(deformed_nodes, out_grid, count_writes=True))  # not a window

    # ---------------------------------------------------------------- internals
    def _run(self, deformed_nodes, out_grid, count_writes: bool, into: Volume | None = None,
             window: tuple | None = None) -> Volume | None:
        """Rasterize onto ``out_grid`` (or ``into``'s grid), or, with ``window = (data, lo, region)``,
        onto the box of the C-order array ``data`` [nx, ny, nz] from index ``lo`` [3] whose grid
        ``out_grid`` is, only its :class:`_Region` ``region`` (CPU exact spans only; returns None)."""
        t_start = time.perf_counter()
        x1 = np.asarray(deformed_nodes)
        if x1.shape != self.nodes.shape:
            raise InputError(
                "deformed_nodes", f"an array of the rest nodes' shape {self.nodes.shape}", f"shape {x1.shape}"
            )
        x1 = np.asarray(x1, dtype=np.float64)
        if not np.isfinite(x1).all():
            if self.inverted == "skip":
                n = int(np.argmax(~np.isfinite(x1).all(axis=1)))
                raise InputError(f"deformed_nodes[{n}]", "finite coordinates", str(x1[n].tolist()))
            check_tets(x1, self.tets, nodes_name="deformed_nodes")
        if into is not None:
            grid = OutputGrid.of(into)
        elif out_grid is None:
            grid = fit_output_grid(self.volume, x1)
        elif isinstance(out_grid, Volume):
            grid = OutputGrid.of(out_grid)
        elif isinstance(out_grid, OutputGrid):
            grid = out_grid
        else:
            raise InputError("out_grid", "None, a softvr.volume.Volume or an OutputGrid", type(out_grid).__name__)
        shape = grid.shape
        u1 = grid.world_to_index(x1)
        tets, tets_w = self.tets, self._tets_w
        # The in-place window runs every frame of an interactive update(): its arrays are reused.
        scratch = None if window is None else self._window_scratch()
        if scratch is not None and self.inverted == "skip":
            # Only the tets whose voxel box can meet the window's grid: a box is empty unless
            # the snapped corners reach [-0.5, n - 0.5] (a voxel of margin here), i.e. unless all
            # 4 corners lie beyond one side of [-1, n]: one bit a side per node, ANDed over the
            # tet's nodes (per-tet corner min / max in numpy took ~1 ms of a palpation frame). In
            # "error" mode every tet is set up, so that a folded one anywhere is still found.
            lim = np.asarray(shape, dtype=np.float64)
            side = (u1 < -1.0).astype(np.uint8) @ np.array([1, 2, 4], np.uint8) | \
                (u1 > lim).astype(np.uint8) @ np.array([8, 16, 32], np.uint8)
            c = side[self._tets_t]
            meets = (c[0] & c[1] & c[2] & c[3]) == 0
            tets = np.compress(meets, tets, axis=0, out=scratch.tets[:int(np.count_nonzero(meets))])
            tets_w = scratch.tets_w
        face_w, affine_w, box_w, det_w = self._setup_det(u1, shape, tets_w, len(tets), scratch)
        # World volume = det(index edges) * prod(spacing) / det(direction) / 6; a margin of 2
        # over check_tets' degeneracy bound covers the two ways of rounding the determinant, so
        # only the tets within it need their world volume (in "skip" mode, the folded ones).
        world = (det_w.numpy() if scratch is None else scratch.det[:len(tets)]) * (float(np.prod(grid.spacing)) / float(np.linalg.det(grid.direction)) / 6.0)
        scale = float(np.prod(np.maximum(np.ptp(np.ascontiguousarray(x1.T), axis=1), 1e-300)))  # (see update())
        near = np.flatnonzero(world <= 2e-12 * scale)
        folded = None
        if self.inverted == "skip":
            folded = np.zeros(len(tets), dtype=bool)
            folded[near] = tet_signed_volumes(x1, tets[near]) <= 1e-12 * scale
            self.skipped_tets = int(folded.sum())
        elif len(near):
            check_tets(x1, self.tets, nodes_name="deformed_nodes")
        box = box_w.numpy() if scratch is None else scratch.box[:len(tets)]
        if window is not None:
            # Only the region update() redraws: what tets cover outside it is already drawn.
            box = window[2].clip(box)
        serial = None
        if folded is not None and folded.any():
            box = box.copy() if window is None else box
            serial = _fold_redraw(box, folded)
            box[folded, 1] = box[folded, 0] - 1  # an empty range: no voxel is visited
        if scratch is not None:
            scratch.clipped[:len(box)] = box
            box_w = scratch.clipped_w
        elif folded is not None and folded.any():
            box_w = wp.array(box, dtype=wp.int32, device=self.device)

        dev = self.device
        if count_writes:
            counts = wp.zeros(shape, dtype=wp.int32, device=dev)
            out = wp.empty((1, 1, 1), dtype=self._vol.dtype, device=dev)
        elif window is not None:
            target, lo, region = window
            box_view = target[tuple(slice(a, a + n) for a, n in zip(lo, shape))]
            for i, rows, cols in region.slabs:
                box_view[i, rows, cols] = self.background
        else:
            counts = wp.empty((0, 0, 0), dtype=wp.int32, device=dev)
            out = _background(shape, self.background, self.volume.dtype, dev, None if into is None else into.data)
        if window is None:
            out_ptr, pitch = out.ptr, shape
        else:
            out_ptr = target.ctypes.data + target.itemsize * int(np.ravel_multi_index(tuple(lo), target.shape))
            pitch = (shape[0], *target.shape[1:])
        m = len(box)
        t_setup = time.perf_counter()

        cells_total = cells_kept = 0
        if self.method == "cells":
            cell_dims, cell_offsets, kept = self._cull(face_w, box, box_w)
            cells_total, cells_kept = int(cell_offsets[-1]), len(kept)
            t_cull = time.perf_counter()
            threads = cells_kept * self.cell_size
            tested = wp.zeros(max(threads, 1), dtype=wp.int32, device=dev)
            written = wp.zeros(max(threads, 1), dtype=wp.int32, device=dev)
            launch(
                K.raster_cells,
                threads,
                [
                    self._vol, self._volf, wp.uint64(out.ptr), self._out_code,
                    self._dims, self._strides, out, counts, face_w, affine_w, box_w,
                    wp.array(cell_dims, dtype=wp.int32, device=dev),
                    wp.array(cell_offsets, dtype=wp.int32, device=dev),
                    wp.array(kept if len(kept) else np.zeros(1, np.int32), dtype=wp.int32, device=dev),
                    m, self.cell_size, self._params, tested, written,
                ],
                dev,
                min_chunk=64,
                split=not count_writes,  # counting writes adds into shared counts (atomics)
            )
        elif self.method == "spans" and self._out_code and not count_writes and _span_item_slabs(pitch) > 0:
            t_cull = time.perf_counter()
            per_item = _span_item_slabs(pitch)
            # Drawn tets overlap only inside folded ones (below): that box is drawn again after the
            # split launch, on one thread in tet order, so that its voxels get the last tet that
            # covers them on any number of threads (split, two threads' writes there were a race).
            passes = [(box, box_w, True)]
            if serial is not None:
                passes.append((serial, wp.array(serial, dtype=wp.int32, device=dev), False))
            counts_w = []
            for pass_box, pass_box_w, split in passes:
                slabs = np.where(pass_box[:, 1] >= pass_box[:, 0], pass_box[:, 1] - pass_box[:, 0] + 1, 0)
                offsets = _exclusive_cumsum(-(-slabs // per_item))
                items = int(offsets[-1])
                counts_w.append(wp.zeros(max(items, 1), dtype=wp.int32, device=dev))
                if split and scratch is not None:
                    scratch.offsets[:len(offsets)] = offsets
                    offsets_w = scratch.offsets_w
                else:
                    offsets_w = wp.array(offsets, dtype=wp.int32, device=dev)
                launch(
                    K.raster_tets_cpu,
                    items,
                    [
                        self._volf if self._src_code == 0 else self._no_volf, wp.uint64(self._vol.ptr), self._src_code,
                        self._dims, self._strides, wp.uint64(out_ptr), self._out_code,
                        wp.vec3i(*pitch), face_w, affine_w, pass_box_w, offsets_w,
                        m, per_item, self._params, counts_w[-1],
                    ],
                    dev,
                    min_chunk=16,
                    split=split,
                )
            written = tested = counts_w[0]  # the redraw rewrites voxels counted here
        else:
            t_cull = time.perf_counter()
            slabs = np.where(box[:, 1] >= box[:, 0], box[:, 1] - box[:, 0] + 1, 0)
            offsets = _exclusive_cumsum(slabs)
            threads = int(offsets[-1])
            tested = wp.zeros(max(threads, 1), dtype=wp.int32, device=dev)
            written = wp.zeros(max(threads, 1), dtype=wp.int32, device=dev)
            mode = K.MODE_SPANS if self.method == "spans" else K.MODE_BBOX
            launch(
                K.raster_slabs,
                threads,
                [
                    self._vol, self._volf, wp.uint64(out.ptr), self._out_code,
                    self._dims, self._strides, out, counts, face_w, affine_w, box_w,
                    wp.array(offsets, dtype=wp.int32, device=dev),
                    m, int(mode), self._params, tested, written,
                ],
                dev,
                min_chunk=64,
                split=not count_writes,  # counting writes adds into shared counts (atomics)
            )
        n_tested = int(tested.numpy().sum(dtype=np.int64))
        n_written = n_tested if written is tested else int(written.numpy().sum(dtype=np.int64))
        if window is not None:
            data = None
        elif count_writes:
            data = counts.numpy()
        elif into is not None:
            data = into.data
            if dev != "cpu":
                data[...] = out.numpy()
        else:
            data = out.numpy()
        t_end = time.perf_counter()
        self.stats = RasterStats(
            method=self.method,
            device=dev,
            tet_count=m,
            output_voxels=int(np.prod(shape)),
            voxels_tested=n_tested,
            voxels_written=n_written,
            efficiency=n_written / n_tested if n_tested else 1.0,
            cells_total=cells_total,
            cells_kept=cells_kept,
            time_setup_s=t_setup - t_start,
            time_cull_s=t_cull - t_setup,
            time_raster_s=t_end - t_cull,
            time_total_s=t_end - t_start,
        )
        if into is not None:
            return into
        if data is None:
            return None  # update() reads the window in place
        return Volume(
            data,
            grid.spacing.copy(),
            grid.origin.copy(),
            grid.direction.copy(),
            is_label=self.volume.is_label and not count_writes,
        )

    def _setup(self, u1: np.ndarray, shape):
        """Per-tet exact face planes, output->input affine maps and clipped voxel boxes.

        Returns Warp arrays ``face`` [4 tet_count, 5] int64, ``affine`` [tet_count, 16]
        float64 and ``box`` [tet_count, 6] int32 (see :func:`_raster_kernels.tet_setup`).
        """
        return self._setup_det(u1, shape)[:3]

    def _setup_det(self, u1: np.ndarray, shape, tets_w: wp.array | None = None, m: int | None = None,
                   scratch: "_Scratch | None" = None):
        """:meth:`_setup` plus ``det`` [tet_count] float64, each deformed tet's edge-matrix
        determinant in output voxel indices; of the first ``m`` (default all) tets of ``tets_w``
        [>= m, 4] (default all). With ``scratch``, written into its arrays (their first rows)."""
        sub = subvoxel_factor(u1, shape)
        tets_w = self._tets_w if tets_w is None else tets_w
        dev, m = self.device, tets_w.shape[0] if m is None else m
        if scratch is None:
            face = wp.empty((4 * m, 5), dtype=wp.int64, device=dev)
            affine = wp.empty((m, 16), dtype=wp.float64, device=dev)
            box = wp.empty((m, 6), dtype=wp.int32, device=dev)
            det = wp.empty(m, dtype=wp.float64, device=dev)
            moved: wp.array = wp.array(u1, dtype=wp.vec3d, device=dev)
        else:
            face, affine, box, det = scratch.face_w, scratch.affine_w, scratch.box_w, scratch.det_w
            scratch.moved[:] = u1
            moved = scratch.moved_w
        launch(
            K.tet_setup,
            m,
            [self._rest_w, moved, tets_w, sub, wp.vec3i(*shape), self._dims, face, affine, box, det],
            dev,
            min_chunk=512,
        )
        return face, affine, box, det

    def _window_scratch(self) -> "_Scratch":
        """The arrays of :meth:`update`'s in-place runs (made on first use)."""
        if self._scratch is None:
            self._scratch = _Scratch(len(self.tets), len(self.nodes), self.device)
        return self._scratch

    def _cull(self, face_w, box: np.ndarray, box_w):
        """Thesis 3.2: grid-point masks, cell AND-masks, and the list of kept cells."""
        dev, n = self.device, self.cell_size
        ext = np.maximum(box[:, 1::2] - box[:, 0::2] + 1, 0)
        cell_dims = (-(-ext // n)).astype(np.int32)  # ceil
        empty = (ext == 0).any(axis=1)
        cell_dims[empty] = 0
        points = np.where(empty, 0, np.prod(cell_dims + 1, axis=1))
        point_offsets = _exclusive_cumsum(points)
        cell_offsets = _exclusive_cumsum(np.prod(cell_dims, axis=1))
        m = len(box)
        dims_w: wp.array = wp.array(cell_dims, dtype=wp.int32, device=dev)
        poff_w: wp.array = wp.array(point_offsets, dtype=wp.int32, device=dev)
        masks = wp.zeros(max(int(point_offsets[-1]), 1), dtype=wp.uint8, device=dev)
        launch(K.point_masks, int(point_offsets[-1]), [face_w, box_w, dims_w, poff_w, m, n, masks], dev)
        n_cells = int(cell_offsets[-1])
        keep = wp.zeros(max(n_cells, 1), dtype=wp.uint8, device=dev)
        launch(
            K.cell_masks,
            n_cells,
            [dims_w, poff_w, wp.array(cell_offsets, dtype=wp.int32, device=dev), m, masks, keep],
            dev,
        )
        kept = np.flatnonzero(keep.numpy()[:n_cells]).astype(np.int32)
        return cell_dims, cell_offsets, kept


def _moved_nodes(x1: np.ndarray, x0: np.ndarray, tolerance: float) -> np.ndarray:
    """bool [n]: whether each node moved by more than ``tolerance`` from ``x0`` to ``x1``
    ([n, 3] float64 each, same units): ``np.linalg.norm(x1 - x0, axis=1) > tolerance`` with the
    same sum of squares in the same order, without numpy's slow reduce over 3 columns."""
    d = x1 - x0
    d *= d
    return np.sqrt(d[:, 0] + d[:, 1] + d[:, 2]) > tolerance


def subvoxel_factor(u1: np.ndarray, shape) -> int:
    """Snapping resolution S (a power of two <= 256): nodes snap to 1/S voxel.

    Chosen so that snapped coordinates stay below 2**17, which keeps every plane value of
    the exact inside test (|n| < 2**37, |n . p| < 2**56) within int64.

    Parameters
    ----------
    u1 : ndarray, shape [node_count, 3]
        Deformed nodes in output voxel indices.
    shape : tuple of 3 int
        Output grid shape.
    """
    extent = max(float(np.abs(u1).max()), float(max(shape)), 1.0)
    if extent >= _COORD_LIMIT:
        raise InputError(
            "deformed_nodes", f"positions within {_COORD_LIMIT} voxels of the output grid", f"a node {extent:.3g} voxels away"
        )
    return int(min(_MAX_SUBVOXEL, 2 ** np.floor(np.log2(_COORD_LIMIT / extent))))


def _background(shape, value: float, dtype: np.dtype, device: str, host: np.ndarray | None) -> wp.array:
    """The output array, every voxel set to the background ``value``.

    On the CPU it is ``host`` (or a new numpy array), filled by numpy at memory speed and
    shared with Warp without a copy.
    """
    if device == "cpu":
        arr = np.empty(shape, dtype=dtype) if host is None else host
        arr.fill(value)
        return wp.array(arr, device=device, copy=False)
    out = wp.empty(tuple(shape), dtype=wp.dtype_from_numpy(dtype), device=device)
    out.fill_(value)
    return out


class _Scratch:
    """Arrays that :meth:`Rasterizer.update`'s in-place runs (CPU only) fill anew every frame,
    each a numpy array and a Warp array over the same memory, with a row for every tet of the
    mesh (a run uses the first ``m``): making and wrapping them each frame took ~0.3 ms of a
    palpation frame. ``tets`` [T, 4] int32 (the tets set up), ``moved`` [N, 3] float64 (deformed
    nodes, output voxel indices), ``face`` [4 T, 5] int64, ``affine`` [T, 16] float64, ``box`` and
    ``clipped`` [T, 6] int32 (as set up; as drawn), ``det`` [T] float64, ``offsets`` [T + 1] int32
    (:func:`_raster_kernels.tet_setup`, :func:`_raster_kernels.raster_tets_cpu`)."""

    def __init__(self, tet_count: int, node_count: int, device: str):
        def pair(shape, dtype, wp_dtype) -> tuple[np.ndarray, wp.array]:
            host = np.zeros(shape, dtype)
            return host, wp.array(host, dtype=wp_dtype, device=device, copy=False)

        self.tets, self.tets_w = pair((tet_count, 4), np.int32, wp.int32)
        self.moved, self.moved_w = pair((node_count, 3), np.float64, wp.vec3d)
        self.face, self.face_w = pair((4 * tet_count, 5), np.int64, wp.int64)
        self.affine, self.affine_w = pair((tet_count, 16), np.float64, wp.float64)
        self.box, self.box_w = pair((tet_count, 6), np.int32, wp.int32)
        self.clipped, self.clipped_w = pair((tet_count, 6), np.int32, wp.int32)
        self.det, self.det_w = pair(tet_count, np.float64, wp.float64)
        self.offsets, self.offsets_w = pair(tet_count + 1, np.int32, wp.int32)


_REGION_BRICK = 8  # [voxels] the side of the bricks that update()'s redrawn region is made of


class _Region:
    """The voxels of :meth:`Rasterizer.update`'s window that it redraws: in each slab of
    ``_REGION_BRICK`` x-planes, the y-z rectangle around the bricks marked in that slab.

    Parameters
    ----------
    marked : ndarray, shape [gx, gy, gz] bool
        The window's bricks (brick ``(a, b, c)``: voxels ``[8 a, 8 a + 7] x ...``) a moved
        tet's footprint reaches.

    Attributes
    ----------
    slabs : list of 3 slices
        Each slab's rectangle, in window voxel indices (slices may run past the window).
    """

    def __init__(self, marked: np.ndarray):
        b, g, far = _REGION_BRICK, marked.shape[0], 2**30
        rows, cols = np.any(marked, axis=2), np.any(marked, axis=1)  # [gx, gy], [gx, gz]
        used = np.any(rows, axis=1)
        # [gx, 4] voxel bounds of each slab's rectangle (y0, y1, z0, z1; y1, z1 past the end).
        ny, nz = rows.shape[1], cols.shape[1]
        rect = np.empty((g, 4), dtype=np.int64)
        rect[:, 0], rect[:, 1] = rows.argmax(axis=1), ny - rows[:, ::-1].argmax(axis=1)
        rect[:, 2], rect[:, 3] = cols.argmax(axis=1), nz - cols[:, ::-1].argmax(axis=1)
        rect *= b
        rect[~used] = (far, 0, far, 0)
        # Python ints: slices of numpy scalars cost ~10 us a slab when the caller indexes with them.
        self.slabs = [(slice(a * b, (a + 1) * b), slice(r[0], r[1]), slice(r[2], r[3]))
                      for a, r in zip(np.flatnonzero(used).tolist(), rect[used].tolist())]
        # For every slab range [a0, a1]: the x-range of its used slabs and the rectangle
        # around theirs (lower bounds in _low, upper ones past the end in _high, [a0 g + a1, 3]),
        # so that a tet's box is clipped in two look-ups.
        slab = np.arange(g)
        lows, highs = np.empty((g, 3), dtype=np.int64), np.empty((g, 3), dtype=np.int64)
        lows[:, 0], highs[:, 0] = np.where(used, slab * b, far), np.where(used, (slab + 1) * b, 0)
        lows[:, 1:], highs[:, 1:] = rect[:, 0::2], rect[:, 1::2]
        later = (slab[None, :] >= slab[:, None])[..., None]  # [a0, a, 1]: slab a is in a range from a0
        self._g = g
        self._low = np.minimum.accumulate(np.where(later, lows, far), axis=1).reshape(g * g, 3)
        self._high = np.maximum.accumulate(np.where(later, highs, 0), axis=1).reshape(g * g, 3) - 1

    def clip(self, box: np.ndarray) -> np.ndarray:
        """int32 [m, 6]: each voxel box ``box`` [m, 6] (inclusive i, j, k ranges, window
        indices, inside the window or empty) cut to the region's rectangles over its slabs;
        empty (an upper bound under its lower) where it misses the region."""
        g = self._g
        a0 = np.minimum(np.maximum(box[:, 0] // _REGION_BRICK, 0), g - 1)
        a1 = np.minimum(np.maximum(box[:, 1] // _REGION_BRICK, a0), g - 1)
        a1 += g * a0
        out = np.empty_like(box)
        np.maximum(box[:, 0::2], self._low.take(a1, axis=0), out=out[:, 0::2])
        np.minimum(box[:, 1::2], self._high.take(a1, axis=0), out=out[:, 1::2])
        empty = (out[:, 1] < out[:, 0]) | (out[:, 3] < out[:, 2]) | (out[:, 5] < out[:, 4])
        out[empty, 1] = out[empty, 0] - 1
        return out


def _moved_region(tet_lo: np.ndarray, tet_hi: np.ndarray, shape) -> _Region:
    """The :class:`_Region` of a window of ``shape`` [3] voxels covering the moved tets' voxel
    boxes ``tet_lo``, ``tet_hi`` [t, 3] int (inclusive, window indices, may reach outside)."""
    shape = np.asarray(shape)
    tet_lo, tet_hi = np.maximum(tet_lo, 0), np.minimum(tet_hi, shape - 1)
    inside = (tet_lo <= tet_hi).all(axis=1)
    a, b = tet_lo[inside] // _REGION_BRICK, tet_hi[inside] // _REGION_BRICK + 1
    # Each box of bricks added as +-1 at its 8 corners; the prefix sums count the boxes on a brick.
    dims = -(-shape // _REGION_BRICK) + 1
    step = (dims[1] * dims[2], dims[2], 1)
    ends = [np.stack([a[:, k], b[:, k]]) * step[k] for k in range(3)]  # [2, t] flat offsets a side
    corner = ends[0][:, None, None, :] + ends[1][None, :, None, :] + ends[2][None, None, :, :]  # [2, 2, 2, t]
    sign = np.broadcast_to(_CORNER_SIGN, corner.shape)
    marks = np.bincount(corner.ravel(), sign.ravel(), minlength=int(np.prod(dims))).reshape(dims)
    return _Region(marks.cumsum(axis=0).cumsum(axis=1).cumsum(axis=2)[:-1, :-1, :-1] > 0.5)


# [2, 2, 2, 1] the sign of a box's corner (lower or upper end on each axis) in _moved_region's sums.
_CORNER_SIGN = np.array([1.0, -1.0])[:, None, None, None] * np.array([1.0, -1.0])[:, None, None] * np.array([1.0, -1.0])[:, None]


def _fold_redraw(box: np.ndarray, folded: np.ndarray) -> np.ndarray | None:
    """The voxel boxes [m, 6] (inclusive ranges) cut to the box around the ``folded`` tets' boxes,
    or None when those are empty. A mesh whose boundary does not cross itself covers each point
    inside it once, counting each tet with its orientation's sign: a point inside k folded
    (negative) tets lies in k + 1 drawn ones, every other point in one. So two drawn tets overlap
    only inside folded ones."""
    fold = box[folded]
    fold = fold[np.all(fold[:, 1::2] >= fold[:, 0::2], axis=1)]
    if not len(fold):
        return None
    cut = box.copy()
    cut[:, 0::2] = np.maximum(box[:, 0::2], fold[:, 0::2].min(axis=0))
    cut[:, 1::2] = np.minimum(box[:, 1::2], fold[:, 1::2].max(axis=0))
    empty = np.any(cut[:, 1::2] < cut[:, 0::2], axis=1) | folded
    cut[empty, 1] = cut[empty, 0] - 1
    return cut


def _span_item_slabs(pitch) -> int:
    """x-slabs per work item of the CPU exact spans on an output of row pitch ``pitch`` (its
    shape [3], or a window's): at most ``_SLABS_PER_ITEM``, and few enough that every output
    offset within an item, counted from its first slab (+ 7 for a queue block run past a row),
    fits the kernel's int32 voxel queue; 0 where not even one slab does (then the generic
    kernel runs)."""
    return min(_SLABS_PER_ITEM, (2**31 - 256) // max(int(pitch[1]) * int(pitch[2]), 1))


def _exclusive_cumsum(counts: np.ndarray) -> np.ndarray:
    out = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=out[1:])
    if out[-1] >= 2**31:
        raise InputError("mesh", "fewer than 2**31 rasterization work items", f"{int(out[-1])}")
    return out.astype(np.int32)


def deform(
    volume: Volume,
    nodes,
    tets,
    deformed_nodes,
    *,
    culling=True,
    device: str | None = None,
    out_grid: Volume | None = None,
    interpolation: str | None = None,
    background: float | None = None,
) -> Volume:
    """Deform ``volume`` by moving its embedding tet mesh from ``nodes`` to ``deformed_nodes``.

    Each output voxel at position x1 inside deformed tet T takes the input value at
    x0 = beta0^-1(beta1(x1)) (thesis eqs. 3.1-3.2), fetched trilinearly (nearest for label
    volumes). One-shot form of :class:`Rasterizer`; see it for the parameters. A call on the
    same ``volume`` object (same data array and grid) with equal ``nodes``, ``tets`` and
    options as the previous call reuses that call's set-up (validated mesh, uploaded input),
    so a loop of calls runs as fast as :meth:`Rasterizer.deform`; edits of ``volume.data`` in
    place are seen.

    Parameters
    ----------
    volume : Volume
    nodes, deformed_nodes : array_like, shape [node_count, 3]
        Rest and deformed node positions [volume spacing units, world frame].
    tets : array_like, shape [tet_count, 4]
    culling : bool or {"bbox", "cells", "spans"}
    device : {"cpu", "cuda", None}
    out_grid : Volume, optional
        Output grid; ``None`` fits it to the deformed bounds.
    interpolation : {"linear", "nearest"}, optional
    background : float, optional

    Returns
    -------
    Volume
        Deformed volume with the input's dtype.
    """
    r = _one_shot_rasterizer(volume, nodes, tets, culling, device, interpolation, background)
    return r.deform(deformed_nodes, out_grid)


# deform()'s set-up, kept for the next call on the same volume and mesh: (key, rest nodes,
# tets, Rasterizer). One entry, so at most one volume is kept alive by it.
_ONE_SHOT: list = []
_ONE_SHOT_LOCK = threading.Lock()


def _one_shot_rasterizer(volume, nodes, tets, culling, device, interpolation, background) -> "Rasterizer":
    """The Rasterizer :func:`deform` runs: its last one when volume (the same object, with
    the same data array and grid) and mesh (equal values) are those of the last call, with the
    input re-read where the Rasterizer holds a copy of it; else a new one."""
    if not isinstance(volume, Volume) or not isinstance(volume.data, np.ndarray):
        return Rasterizer(volume, nodes, tets, culling=culling, interpolation=interpolation, background=background,
                          device=device)
    key = (id(volume), id(volume.data), volume.data.shape, volume.data.dtype, volume.data.strides,
           tuple(volume.spacing), tuple(volume.origin), tuple(volume.direction.ravel()), volume.is_label,
           culling if isinstance(culling, bool) else str(culling), interpolation, background, resolve_device(device))
    x0, t = np.asarray(nodes), np.asarray(tets)
    with _ONE_SHOT_LOCK:
        hit = _ONE_SHOT[0] if _ONE_SHOT else None
    if (hit is not None and hit[0] == key and hit[1].shape == x0.shape and hit[2].shape == t.shape
            and np.array_equal(hit[1], x0) and np.array_equal(hit[2], t)):
        r = hit[3]
        r._refresh_input(background is None)
        return r
    r = Rasterizer(volume, nodes, tets, culling=culling, interpolation=interpolation, background=background,
                   device=device)
    with _ONE_SHOT_LOCK:
        _ONE_SHOT[:] = [(key, np.array(x0, copy=True), np.array(t, copy=True), r)]
    return r
