"""How a volume is warped by a tetrahedral mesh without softvr: VTK + SciPy, and SimpleITK.

Both peers take the same input as :func:`softvr.volume.deform` (a :class:`Volume`, rest
``nodes``, ``tets``, ``deformed_nodes``) and fill the same output grid. They are written the
way a competent user of those libraries would write them, on every core:

1. **Probe** (:func:`probe_rest_positions`): a ``vtkUnstructuredGrid`` of the *deformed* tets
   carries the *rest* node positions as point data; ``vtkProbeFilter`` samples it at every
   output voxel, giving the rest position (linear inside each tet, i.e. the barycentric
   mapping of thesis eqs. 3.1-3.2) and a valid mask. With image-data input, ``vtkProbeFilter``
   walks the source cells and the image points in each cell's bounds (a per-tet bounding-box
   scan, like thesis Algorithm 1) inside ``vtkSMPTools``; the SMP backend of the VTK wheel is
   ``Sequential``, so one filter uses one core. The VTK Python wrappers release the GIL,
   so the output grid is cut into z slabs probed from a thread pool (1.5-1.7x on 2 cores).
   Alternatives that were tried: ``vtkmProbe`` (VTK-m, serial in the wheel) is about 2x
   slower; ``vtkStaticCellLocator`` as locator does not change the image-input path;
   ``vtkPointInterpolator`` / ``vtkResampleToImage`` are kernel interpolators over points
   (or wrap the same probe) and do not reproduce the piecewise-linear tet mapping.
2. **VTK + SciPy** (:func:`warp_vtk_scipy`): ``scipy.ndimage.map_coordinates`` (order 1, order 0
   for label volumes) fetches the input at the valid rest positions, in chunks from a thread
   pool (SciPy releases the GIL there); background elsewhere.
3. **SimpleITK** (:func:`warp_sitk`): the probe's rest positions become a displacement field on
   the output grid (``rest - x`` at valid voxels, a point outside the input elsewhere), given to
   ``sitk.DisplacementFieldTransform``, and ``sitk.Resample`` (linear, or nearest for labels)
   with ``default`` = background, ITK threads = core count. Building the field and resampling
   are timed apart (``field_s``, ``resample_s``) as ``/work/shared/peers.md`` did.

All positions are world positions; volumes must have the identity direction (as softvr's
deformation assumes).
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from softvr.errors import InputError
from softvr.volume import Volume

__all__ = ["ProbeResult", "default_threads", "grid_volume", "probe_rest_positions", "warp_sitk", "warp_vtk_scipy"]


def default_threads() -> int:
    """Cores available to this process."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def grid_volume(shape, spacing, origin, dtype=np.uint8) -> Volume:
    """A :class:`Volume` that only describes a grid (its data is a zero-byte broadcast view)."""
    shape = tuple(int(n) for n in shape)
    return Volume(np.broadcast_to(np.zeros(1, dtype=dtype).reshape(1, 1, 1), shape), spacing, origin)


@dataclass
class ProbeResult:
    """Rest positions of the output voxels, as ``vtkProbeFilter`` found them.

    Attributes
    ----------
    shape : tuple[int, int, int]
        Output grid ``(nx, ny, nz)``.
    rest : ndarray, shape [nz, ny, nx, 3], float64
        Rest (undeformed) world position of each output voxel; meaningless where not ``valid``.
        VTK point order, i.e. the transpose of ``Volume.data`` indexing.
    valid : ndarray of bool, shape [nz, ny, nx]
        Voxel lies in a deformed tet.
    time_s : float
        Wall time of building the VTK grid and probing [s].
    """

    shape: tuple[int, int, int]
    rest: np.ndarray
    valid: np.ndarray
    time_s: float


def _check_identity(vol: Volume, name: str) -> None:
    if not np.allclose(vol.direction, np.eye(3)):
        raise InputError(f"{name}.direction", "the identity (peers assume axis-aligned grids)", str(vol.direction.tolist()))


def _unstructured_grid(deformed_nodes: np.ndarray, tets: np.ndarray, rest_nodes: np.ndarray):
    import vtk
    from vtk.util import numpy_support as ns

    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetData(ns.numpy_to_vtk(np.ascontiguousarray(deformed_nodes, dtype=np.float64), deep=1))
    ug.SetPoints(pts)
    m = len(tets)
    offsets = ns.numpy_to_vtkIdTypeArray(np.arange(0, 4 * m + 1, 4, dtype=np.int64), deep=1)
    conn = ns.numpy_to_vtkIdTypeArray(np.ascontiguousarray(tets, dtype=np.int64).ravel(), deep=1)
    cells = vtk.vtkCellArray()
    cells.SetData(offsets, conn)
    ug.SetCells(vtk.VTK_TETRA, cells)
    rest = ns.numpy_to_vtk(np.ascontiguousarray(rest_nodes, dtype=np.float64), deep=1)
    rest.SetName("rest")
    ug.GetPointData().AddArray(rest)
    return ug


def probe_rest_positions(
    nodes: np.ndarray,
    tets: np.ndarray,
    deformed_nodes: np.ndarray,
    out_grid: Volume,
    *,
    threads: int | None = None,
) -> ProbeResult:
    """Rest position of every output voxel, by ``vtkProbeFilter`` over the deformed tets.

    Parameters
    ----------
    nodes, deformed_nodes : ndarray, shape [node_count, 3]
        Rest and deformed node positions (world).
    tets : ndarray, shape [tet_count, 4]
        Node indices per tet.
    out_grid : Volume
        Output grid (shape, spacing, origin; its data is not read).
    threads : int, optional
        Slab-parallel probes at once; default all cores. 1 = one plain ``vtkProbeFilter``.
    """
    import vtk
    from vtk.util import numpy_support as ns

    _check_identity(out_grid, "out_grid")
    threads = default_threads() if threads is None else max(1, int(threads))
    nx, ny, nz = out_grid.shape
    t0 = time.perf_counter()
    ug = _unstructured_grid(deformed_nodes, tets, nodes)
    rest = np.empty((nz, ny, nx, 3), dtype=np.float64)
    valid = np.empty((nz, ny, nx), dtype=bool)
    # More slabs than threads: tets near the middle of a rotated mesh cover more points.
    n_slabs = 1 if threads == 1 else min(nz, 4 * threads)
    bounds = [nz * s // n_slabs for s in range(n_slabs + 1)]

    def probe(s: int) -> None:
        k0, k1 = bounds[s], bounds[s + 1]
        if k1 <= k0:
            return
        img = vtk.vtkImageData()
        img.SetDimensions(nx, ny, k1 - k0)
        img.SetSpacing(*out_grid.spacing.tolist())
        img.SetOrigin(*(out_grid.origin + np.array([0.0, 0.0, k0 * out_grid.spacing[2]])).tolist())
        pf = vtk.vtkProbeFilter()
        pf.SetInputData(img)
        pf.SetSourceData(ug)
        pf.Update()
        pd = pf.GetOutput().GetPointData()
        rest[k0:k1] = ns.vtk_to_numpy(pd.GetArray("rest")).reshape(k1 - k0, ny, nx, 3)
        valid[k0:k1] = ns.vtk_to_numpy(pd.GetArray(pf.GetValidPointMaskArrayName())).reshape(k1 - k0, ny, nx) != 0

    if n_slabs == 1:
        probe(0)
    else:
        with ThreadPoolExecutor(threads) as ex:
            list(ex.map(probe, range(n_slabs)))
    return ProbeResult((nx, ny, nz), rest, valid, time.perf_counter() - t0)


def _background(volume: Volume, background) -> float:
    return 0.0 if background is None else float(background)


def warp_vtk_scipy(
    volume: Volume,
    nodes: np.ndarray,
    tets: np.ndarray,
    deformed_nodes: np.ndarray,
    out_grid: Volume,
    *,
    background: float | None = None,
    threads: int | None = None,
    probe: ProbeResult | None = None,
) -> tuple[Volume, dict]:
    """Warp ``volume``: VTK probe for rest positions, then ``scipy.ndimage.map_coordinates``.

    Parameters
    ----------
    volume : Volume
        Input (identity direction). ``is_label`` selects nearest-neighbour fetches.
    nodes, tets, deformed_nodes : ndarray
        Rest mesh and deformed node positions (world).
    out_grid : Volume
        Output grid (shape, spacing, origin).
    background : float, optional
        Value of voxels outside every deformed tet (default 0).
    threads : int, optional
        Threads for the probe slabs and the fetch chunks (default all cores).
    probe : ProbeResult, optional
        Reuse a probe of the same mesh and grid (its time is then still reported).

    Returns
    -------
    Volume
        On ``out_grid``, dtype of ``volume``; its data is the transpose view of a
        C-ordered [nz, ny, nx] array.
    dict
        ``probe_s``, ``fetch_s``, ``total_s`` [s], ``threads``, ``valid_voxels``.
    """
    from scipy import ndimage

    _check_identity(volume, "volume")
    threads = default_threads() if threads is None else max(1, int(threads))
    if probe is None:
        probe = probe_rest_positions(nodes, tets, deformed_nodes, out_grid, threads=threads)
    t0 = time.perf_counter()
    bg = _background(volume, background)
    out = np.full(probe.valid.shape, bg, dtype=volume.dtype)
    flat_valid = np.flatnonzero(probe.valid)
    rest = probe.rest.reshape(-1, 3)
    order = 0 if volume.is_label else 1
    out_flat = out.reshape(-1)
    n = flat_valid.size
    n_chunks = 1 if threads == 1 or n < 65536 else 4 * threads
    bounds = [n * c // n_chunks for c in range(n_chunks + 1)]

    def fetch(c: int) -> None:
        sel = flat_valid[bounds[c] : bounds[c + 1]]
        if sel.size == 0:
            return
        idx = ((rest[sel] - volume.origin) / volume.spacing).T
        out_flat[sel] = ndimage.map_coordinates(volume.data, idx, order=order, mode="nearest", output=volume.dtype)

    if n_chunks == 1:
        fetch(0)
    else:
        with ThreadPoolExecutor(threads) as ex:
            list(ex.map(fetch, range(n_chunks)))
    fetch_s = time.perf_counter() - t0
    res = Volume(out.T, out_grid.spacing.copy(), out_grid.origin.copy(), is_label=volume.is_label)
    return res, {
        "probe_s": probe.time_s,
        "fetch_s": fetch_s,
        "total_s": probe.time_s + fetch_s,
        "threads": threads,
        "valid_voxels": int(n),
    }


def warp_sitk(
    volume: Volume,
    nodes: np.ndarray,
    tets: np.ndarray,
    deformed_nodes: np.ndarray,
    out_grid: Volume,
    *,
    background: float | None = None,
    threads: int | None = None,
    probe: ProbeResult | None = None,
) -> tuple[Volume, dict]:
    """Warp ``volume`` with ``sitk.Resample`` through a displacement field from the VTK probe.

    Parameters are those of :func:`warp_vtk_scipy`.

    Returns
    -------
    Volume
        On ``out_grid``, dtype of ``volume`` (ITK casts the interpolated value to it).
    dict
        ``probe_s``, ``field_s`` (displacement image + transform), ``input_s`` (input image),
        ``resample_s``, ``total_s`` [s] and ``threads``.
    """
    import SimpleITK as sitk

    _check_identity(volume, "volume")
    threads = default_threads() if threads is None else max(1, int(threads))
    if probe is None:
        probe = probe_rest_positions(nodes, tets, deformed_nodes, out_grid, threads=threads)
    sitk.ProcessObject.SetGlobalDefaultNumberOfThreads(threads)
    bg = _background(volume, background)
    nx, ny, nz = out_grid.shape

    t0 = time.perf_counter()
    # World position of every output voxel, [nz, ny, nx, 3] (x fastest, as ITK stores it).
    xs = out_grid.origin[0] + out_grid.spacing[0] * np.arange(nx)
    ys = out_grid.origin[1] + out_grid.spacing[1] * np.arange(ny)
    zs = out_grid.origin[2] + out_grid.spacing[2] * np.arange(nz)
    # Outside every tet: send the voxel to a point ten voxels before the input's first
    # corner, so that Resample writes its default value there.
    disp = probe.rest.copy()
    disp[~probe.valid] = volume.origin - 10.0 * volume.spacing
    disp[..., 0] -= xs[None, None, :]
    disp[..., 1] -= ys[None, :, None]
    disp[..., 2] -= zs[:, None, None]
    field = sitk.GetImageFromArray(disp, isVector=True)
    del disp
    field.SetSpacing(out_grid.spacing.tolist())
    field.SetOrigin(out_grid.origin.tolist())
    transform = sitk.DisplacementFieldTransform(field)  # takes the field's buffer
    field_s = time.perf_counter() - t0

    t1 = time.perf_counter()
    image = sitk.GetImageFromArray(np.ascontiguousarray(volume.data.T))
    image.SetSpacing(volume.spacing.tolist())
    image.SetOrigin(volume.origin.tolist())
    input_s = time.perf_counter() - t1

    reference = sitk.Image(nx, ny, nz, image.GetPixelID())
    reference.SetSpacing(out_grid.spacing.tolist())
    reference.SetOrigin(out_grid.origin.tolist())
    interp = sitk.sitkNearestNeighbor if volume.is_label else sitk.sitkLinear
    t2 = time.perf_counter()
    res = sitk.Resample(image, reference, transform, interp, bg)
    resample_s = time.perf_counter() - t2
    out = Volume(sitk.GetArrayFromImage(res).T, out_grid.spacing.copy(), out_grid.origin.copy(), is_label=volume.is_label)
    return out, {
        "probe_s": probe.time_s,
        "field_s": field_s,
        "input_s": input_s,
        "resample_s": resample_s,
        "total_s": probe.time_s + field_s + input_s + resample_s,
        "threads": threads,
    }
