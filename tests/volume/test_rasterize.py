"""Rasterizer checks against independent truths (thesis eqs. 3.1-3.2, Algorithm 1, 3.2).

Truths used: the input itself (identity, whole-voxel shifts), ``scipy.ndimage.affine_transform``
(affine maps), an analytic hull (rigid rotation) and a brute-force float64 barycentric point
location in numpy (which tet holds each voxel).
"""

import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial.transform import Rotation

from softvr.errors import InputError
from softvr.volume import Rasterizer, Volume, deform, grid_tet_mesh, rasterize
from softvr.volume.tetmesh import tet_signed_volumes

METHODS = ["bbox", "cells", "spans"]


def _volume(dtype, shape=(23, 19, 17), spacing=(0.9, 1.3, 0.7), origin=(-3.0, 5.0, 11.0), seed=0):
    rng = np.random.default_rng(seed)
    if np.dtype(dtype).kind == "f":
        data = rng.random(shape, dtype=np.float32)
    else:
        info = np.iinfo(dtype)
        data = rng.integers(info.min, info.max, size=shape, endpoint=True).astype(dtype)
    return Volume(data, spacing=spacing, origin=origin)


def _rotate(nodes, degrees=(45.0, 45.0), axes="xy"):
    c = nodes.mean(axis=0)
    return (nodes - c) @ Rotation.from_euler(axes, degrees, degrees=True).as_matrix().T + c


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.uint16, np.float32])
@pytest.mark.parametrize("method", METHODS)
def test_identity_reproduces_input_exactly(device, dtype, method):
    vol = _volume(dtype)
    nodes, tets = grid_tet_mesh(vol, (4, 3, 5))
    out = deform(vol, nodes, tets, nodes, culling=method, device=device)
    assert out.shape == vol.shape and out.dtype == vol.dtype
    assert np.allclose(out.origin, vol.origin) and np.allclose(out.spacing, vol.spacing)
    np.testing.assert_array_equal(out.data, vol.data)


@pytest.mark.parametrize("shift", [(1, 0, 0), (0, -2, 3), (4, 5, -1)])
def test_whole_voxel_translation_shifts_exactly(device, shift):
    vol = _volume(np.int16)
    nodes, tets = grid_tet_mesh(vol, 3)
    moved = nodes + np.asarray(shift) * vol.spacing
    # Fitted grid: same data, origin moved.
    out = deform(vol, nodes, tets, moved, device=device)
    np.testing.assert_array_equal(out.data, vol.data)
    assert np.allclose(out.origin, vol.origin + np.asarray(shift) * vol.spacing)
    # On the input's own grid the data moves by `shift` voxels; uncovered voxels get the background.
    out = deform(vol, nodes, tets, moved, device=device, out_grid=vol, background=-7)
    expect = np.full_like(vol.data, -7)
    src = tuple(slice(max(0, -s), n - max(0, s)) for s, n in zip(shift, vol.shape))
    dst = tuple(slice(max(0, s), n - max(0, -s)) for s, n in zip(shift, vol.shape))
    expect[dst] = vol.data[src]
    np.testing.assert_array_equal(out.data, expect)


def _affine_cases():
    rot = Rotation.from_euler("zyx", [30, -20, 55], degrees=True).as_matrix()
    scale = np.diag([1.3, 0.8, 1.1])
    shear = np.array([[1.0, 0.35, 0.0], [0.0, 1.0, -0.2], [0.15, 0.0, 1.0]])
    return {"rotation": rot, "anisotropic scale": scale, "shear": shear, "all": rot @ shear @ scale}


@pytest.mark.parametrize("name", list(_affine_cases()))
def test_affine_deformation_matches_scipy(device, name):
    """x1 = L x0 + c for every node, so the deformation is affine in every tet and the
    output must equal c0(u0) with u0 = S0^-1 (L^-1 (o1 + S1 u1 - c) - o0):
    ``scipy.ndimage.affine_transform`` with order 1 computes exactly that."""
    lin = _affine_cases()[name]
    vol = _volume(np.float32, shape=(26, 22, 18))
    nodes, tets = grid_tet_mesh(vol, (5, 4, 3))
    c = np.array([2.0, -1.0, 0.5])
    out = deform(vol, nodes, tets, nodes @ lin.T + c, device=device, culling=True, background=-1.0)

    truth, inner, lo = _affine_truth(vol, out, lin, c)
    assert inner.mean() > 0.1
    # Rest positions are carried in float32 per row: |du0| <= ~4 ulp(64) = 3e-5 voxel, and
    # random data has |grad c0| <= 1 per voxel, so values agree to 1e-4 (plus float32 lerp).
    np.testing.assert_allclose(out.data[inner], truth[inner], atol=1e-4)
    # Outside the deformed footprint the background is kept.
    assert (out.data[lo] == -1.0).all()


def _affine_truth(vol, out, lin, c):
    """SciPy's trilinear value of ``vol`` at each voxel of ``out`` moved back by x1 = L x0 + c;
    masks of the voxels whose rest position lies inside the input (``inner``) and outside its
    footprint by a margin (``outside``)."""
    s0, s1 = np.diag(vol.spacing), np.diag(out.spacing)
    m = np.linalg.inv(s0) @ np.linalg.inv(lin) @ s1
    off = np.linalg.inv(s0) @ (np.linalg.inv(lin) @ (out.origin - c) - vol.origin)
    truth = ndimage.affine_transform(vol.data, m, off, output_shape=out.shape, order=1, mode="nearest")
    u1 = np.stack(np.meshgrid(*map(np.arange, out.shape), indexing="ij"), -1).reshape(-1, 3)
    u0 = u1 @ m.T + off
    inner = np.all((u0 >= 0) & (u0 <= np.array(vol.shape) - 1), axis=1).reshape(out.shape)
    outside = np.all((u0 < -0.6) | (u0 > np.array(vol.shape) - 0.4), axis=1).reshape(out.shape)
    return truth, inner, outside


def _deform_matches_affine_truth(vol, cells, lin, c, device, min_inner):
    """``deform`` of ``vol`` by x1 = L x0 + c on a ``grid_tet_mesh`` of ``cells``, checked as in
    test_affine_deformation_matches_scipy (SciPy's value within 1e-4 on the voxels whose rest
    position is inside, at least ``min_inner`` of them; the background outside); returns it."""
    nodes, tets = grid_tet_mesh(vol, cells)
    out = deform(vol, nodes, tets, nodes @ lin.T + c, device=device, background=-1.0)
    truth, inner, outside = _affine_truth(vol, out, lin, c)
    assert inner.mean() > min_inner
    np.testing.assert_allclose(out.data[inner], truth[inner], atol=1e-4)
    assert (out.data[outside] == -1.0).all()
    return out


def test_tets_taller_than_a_row_chunk_match_scipy(device):
    """Tets spanning ~150 rows: the CPU spans walk a slab's rows in chunks of 64, so these cross
    chunk boundaries (the other tests' tets span < 64 rows). Affine deformation, truth and
    tolerance as in test_affine_deformation_matches_scipy."""
    lin = Rotation.from_euler("x", 4, degrees=True).as_matrix() @ np.array(
        [[1.0, 0.1, 0.0], [0.0, 1.05, 0.0], [0.0, 0.0, 1.0]])
    vol = _volume(np.float32, shape=(14, 150, 12), spacing=(1.0, 0.8, 1.2))
    out = _deform_matches_affine_truth(vol, (2, 1, 2), lin, np.array([0.5, 3.0, -1.0]), device, 0.2)
    assert out.shape[1] > 140


def test_tets_with_more_voxels_per_row_chunk_than_the_cpu_queue_match_scipy(device):
    """Five tets over a 12 x 90 x 60 volume: a 64-row chunk of one slab holds up to ~3800
    voxels, more than the CPU spans' 1024-voxel queue, so the queue is flushed inside the chunk
    (the other tests' chunks fit in it and are queued with no flush in between). Truth and
    tolerance as in test_affine_deformation_matches_scipy."""
    lin = Rotation.from_euler("z", 3, degrees=True).as_matrix() @ np.array(
        [[1.0, 0.0, 0.0], [0.05, 1.0, 0.0], [0.0, 0.08, 1.02]])
    vol = _volume(np.float32, shape=(12, 90, 60), spacing=(1.0, 0.8, 0.7))
    _deform_matches_affine_truth(vol, (1, 1, 1), lin, np.array([0.3, -1.0, 0.6]), device, 0.3)


def test_tets_wider_than_a_cpu_work_item_match_scipy(device):
    """Five tets over a 75 x 9 x 10 volume, each ~75 x-slabs wide: the CPU spans split a tet into
    work items of 32 slabs, so each tet is three items, the later ones starting inside its box
    (the other tests' tets are one item). Truth and tolerance as in
    test_affine_deformation_matches_scipy."""
    lin = Rotation.from_euler("y", 2, degrees=True).as_matrix() @ np.array(
        [[1.02, 0.0, 0.0], [0.06, 1.0, 0.0], [0.0, -0.05, 1.0]])
    vol = _volume(np.float32, shape=(75, 9, 10), spacing=(0.6, 1.0, 0.9))
    out = _deform_matches_affine_truth(vol, (1, 1, 1), lin, np.array([-0.4, 0.7, 0.2]), device, 0.3)
    assert out.shape[0] > 64


@pytest.mark.parametrize("ny, nz", [(256, 108), (1024, 1024), (8192, 8192), (8192, 8193), (40000, 40000), (46341, 46341)])
def test_cpu_span_work_items_keep_every_output_offset_within_int32(ny, nz):
    """The CPU spans queue an item's output offsets as int32, counted from the item's first
    slab: an item of ``s`` slabs reaches offset s ny nz - 1, and a queue block may run 7 past a
    row's end. So s ny nz + 6 must not exceed int32's maximum (numpy's), s stays at most 32
    (load balance), and is 0 (the generic kernel) only where a single slab does not fit."""
    s = rasterize._span_item_slabs((1, ny, nz))
    top = int(np.iinfo(np.int32).max)
    assert 0 <= s <= 32
    assert s * ny * nz + 6 <= top
    assert (s == 0) == (ny * nz + 6 > top)
    assert s == 32 or (s + 1) * ny * nz + 6 > top - 256


def test_all_methods_write_identical_voxels(device):
    vol = _volume(np.int16, shape=(40, 36, 30))
    nodes, tets = grid_tet_mesh(vol, (6, 5, 4))
    rng = np.random.default_rng(3)
    moved = _rotate(nodes) + rng.normal(scale=0.3, size=nodes.shape)
    assert (tet_signed_volumes(moved, tets) > 0).all()
    outs, stats = {}, {}
    for method in METHODS:
        r = Rasterizer(vol, nodes, tets, culling=method, device=device)
        outs[method] = r.deform(moved).data
        stats[method] = r.stats
    np.testing.assert_array_equal(outs["bbox"], outs["cells"])
    np.testing.assert_array_equal(outs["bbox"], outs["spans"])
    written = {s.voxels_written for s in stats.values()}
    assert len(written) == 1
    assert stats["spans"].efficiency == 1.0
    assert stats["cells"].voxels_tested <= stats["bbox"].voxels_tested
    assert stats["cells"].cells_kept <= stats["cells"].cells_total
    assert 0.05 < stats["bbox"].efficiency < 0.4  # thesis: 14.3 % of AABB voxels are inside


def _voxel_barycentrics(shape, origin, spacing, nodes, tets):
    """Per tet t: (t, idx [n, 3], bary [n, 4]), the voxels of its bounding box on the grid and
    their float64 barycentric coordinates in it (numpy only)."""
    for t, tet in enumerate(tets):
        x = nodes[tet]
        lo = np.maximum(np.floor((x.min(0) - origin) / spacing).astype(int), 0)
        hi = np.minimum(np.ceil((x.max(0) - origin) / spacing).astype(int), np.array(shape) - 1)
        if np.any(hi < lo):
            continue
        idx = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"), -1).reshape(-1, 3)
        p = origin + idx * spacing
        yield t, idx, np.linalg.solve(np.vstack([x.T, np.ones(4)]), np.vstack([p.T, np.ones(len(p))])).T


def _brute_force_owner_counts(shape, origin, spacing, nodes, tets, margin):
    """Per voxel: tets whose float64 barycentrics are all > margin (surely inside) and
    whether any tet has all barycentrics > -margin (maybe inside)."""
    sure = np.zeros(shape, np.int32)
    maybe = np.zeros(shape, bool)
    for _, idx, bary in _voxel_barycentrics(shape, origin, spacing, nodes, tets):
        ii = tuple(idx[bary.min(1) > margin].T)
        np.add.at(sure, ii, 1)
        maybe[tuple(idx[bary.min(1) > -margin].T)] = True
    return sure, maybe


@pytest.mark.parametrize("dtype, atol", [(np.float32, 1e-4), (np.int16, 1)])
def test_twisted_thin_sheet_matches_scipy_trilinear_through_the_tets(device, dtype, atol):
    """The volume demo's case (volume.toml twists the head CT about its long axis; its
    one-voxel-thin headrest then shows diagonal stripes): a non-affine, piecewise-linear map.
    Each voxel surely inside a deformed tet must take SciPy's trilinear value (map_coordinates,
    order 1) of the rest volume at the rest point with the same float64 barycentrics in the rest
    tet (thesis eqs. 3.1-3.2); the truth shares no code with softvr. Along the twisted sheet the
    truth's peak rises and falls as the sheet crosses voxel centres: the stripes are what
    trilinear resampling does to a one-voxel sheet, and the output must show exactly them.
    Tolerance: rest positions are float32 per row (<= 3e-5 voxel, the sheet's slope <= 1000 a
    voxel for int16: 0.03) plus the int16 output's rounding to the nearest integer (0.5)."""
    shape, spacing = (28, 28, 16), np.array([0.96, 0.96, 1.5])
    i, j, _ = np.meshgrid(*map(np.arange, shape), indexing="ij")
    sheet = np.abs(j - (6.0 + 0.03 * (i - 13.5) ** 2)) < 0.5  # a curved sheet one voxel thick, along z
    vol = Volume((sheet * (1.0 if dtype == np.float32 else 1000.0)).astype(dtype), spacing=spacing)
    nodes, tets = grid_tet_mesh(vol, (4, 4, 3))
    centre = nodes.mean(axis=0)
    angle = np.radians(30.0) * (nodes[:, 2] - nodes[:, 2].min()) / np.ptp(nodes[:, 2])
    d = nodes - centre
    moved = centre + np.stack([np.cos(angle) * d[:, 0] - np.sin(angle) * d[:, 1],
                               np.sin(angle) * d[:, 0] + np.cos(angle) * d[:, 1], d[:, 2]], axis=1)
    assert (tet_signed_volumes(moved, tets) > 0).all()
    out = deform(vol, nodes, tets, moved, device=device, out_grid=vol, background=-1)

    truth = np.full(shape, np.nan)
    rest_index = (nodes - vol.origin) / spacing
    for t, idx, bary in _voxel_barycentrics(shape, vol.origin, spacing, moved, tets):
        keep = bary.min(1) > 1e-2  # surely T's: snapping nodes to 1/256 voxel moves faces (see below)
        u0 = bary[keep] @ rest_index[tets[t]]
        inner = np.all((u0 >= 0) & (u0 <= np.array(shape) - 1), axis=1)
        truth[tuple(idx[keep][inner].T)] = ndimage.map_coordinates(vol.data.astype(np.float64), u0[inner].T, order=1)
    compared = ~np.isnan(truth)
    assert compared.mean() > 0.6
    on_sheet = compared & (truth > 0.2 * vol.data.max())
    assert on_sheet.sum() > 500
    np.testing.assert_allclose(out.data[compared], truth[compared], atol=atol, rtol=0)


@pytest.mark.parametrize("method", METHODS)
def test_every_voxel_written_once_against_brute_force(device, method):
    vol = _volume(np.uint8, shape=(30, 28, 26))
    nodes, tets = grid_tet_mesh(vol, (5, 4, 4))
    rng = np.random.default_rng(1)
    moved = _rotate(nodes, (30, 60)) + rng.normal(scale=0.4, size=nodes.shape)
    assert (tet_signed_volumes(moved, tets) > 0).all()
    r = Rasterizer(vol, nodes, tets, culling=method, device=device)
    counts = r.write_counts(moved)
    # Nodes are snapped to 1/256 voxel before the exact inside test: faces move by at most
    # sqrt(3)/512 voxel, i.e. barycentrics by < 1e-2 for tets over 1 voxel high (these are ~5).
    sure, maybe = _brute_force_owner_counts(counts.shape, counts.origin, counts.spacing, moved, tets, 1e-2)
    assert counts.data.max() == 1
    assert (counts.data[sure > 0] == 1).all()  # inside some tet for sure -> written once
    assert (counts.data[~maybe] == 0).all()  # outside every tet for sure -> never written
    assert sure.sum() > 0.5 * counts.data.sum()  # the check covers most written voxels


def test_ten_thousand_tets_write_every_hull_voxel_exactly_once(device):
    """>= 10 K tets, rotated 45 deg about two axes: the hull is the rotated footprint box, so a
    voxel is inside iff its un-rotated position lies inside the box (by a margin)."""
    vol = _volume(np.int16, shape=(64, 60, 40))
    nodes, tets = grid_tet_mesh(vol, (16, 16, 8))
    assert len(tets) >= 10_000
    centre = nodes.mean(axis=0)
    rot = Rotation.from_euler("xy", [45, 45], degrees=True).as_matrix()
    moved = (nodes - centre) @ rot.T + centre
    for method in METHODS:
        r = Rasterizer(vol, nodes, tets, culling=method, device=device)
        counts = r.write_counts(moved)
        idx = np.stack(np.meshgrid(*map(np.arange, counts.shape), indexing="ij"), -1).reshape(-1, 3)
        world = counts.origin + idx * counts.spacing
        rest = (world - centre) @ rot + centre  # inverse rotation
        u = (rest - vol.origin) / vol.spacing
        # Snapping nodes to 1/256 voxel moves hull faces by < 4e-3 voxel: use a 1e-2 margin.
        hi = np.array(vol.shape) - 0.5
        inside = np.all((u > -0.5 + 1e-2) & (u < hi - 1e-2), axis=1).reshape(counts.shape)
        outside = np.any((u < -0.5 - 1e-2) | (u > hi + 1e-2), axis=1).reshape(counts.shape)
        assert counts.data.max() == 1, method
        assert (counts.data[inside] == 1).all(), method
        assert (counts.data[outside] == 0).all(), method
        assert r.stats.voxels_written == counts.data.sum()


def test_label_volumes_keep_their_label_set(device):
    rng = np.random.default_rng(2)
    labels = np.array([0, 3, 7, 200], np.uint8)
    data = ndimage.zoom(rng.integers(0, 4, size=(6, 6, 6)), 5, order=0)
    vol = Volume(labels[data], is_label=True)
    nodes, tets = grid_tet_mesh(vol, 5)
    moved = _rotate(nodes, (20, 35)) + rng.normal(scale=0.5, size=nodes.shape)
    out = deform(vol, nodes, tets, moved, device=device)
    assert out.is_label
    assert set(np.unique(out.data)) == set(labels.tolist())
    # The same volume not marked as labels is interpolated: in-between values appear.
    smooth = deform(Volume(vol.data), nodes, tets, moved, device=device)
    assert len(np.unique(smooth.data)) > len(labels)


def test_stats_report_thesis_quantities(device):
    vol = _volume(np.int16, shape=(48, 48, 48))
    nodes, tets = grid_tet_mesh(vol, 4)
    r = Rasterizer(vol, nodes, tets, culling="cells", device=device)
    r.deform(_rotate(nodes))
    s = r.stats
    assert s.method == "cells" and s.tet_count == len(tets)
    assert s.voxels_written <= s.voxels_tested and s.efficiency == pytest.approx(s.voxels_written / s.voxels_tested)
    assert s.time_total_s >= s.time_raster_s > 0 and s.voxels_per_second > 0
    assert set(s.as_dict()) >= {"voxels_tested", "voxels_written", "efficiency", "time_cull_s", "time_raster_s"}


def test_bad_input_names_the_problem():
    vol = _volume(np.int16, shape=(8, 8, 8))
    nodes, tets = grid_tet_mesh(vol, 2)
    with pytest.raises(InputError, match=r"deformed_nodes.*shape"):
        deform(vol, nodes, tets, nodes[:-1], device="cpu")
    bad = nodes.copy()
    bad[5] = np.nan
    with pytest.raises(InputError, match=r"deformed_nodes\[5\].*finite"):
        deform(vol, nodes, tets, bad, device="cpu")
    with pytest.raises(InputError, match=r"nodes\[5\].*finite"):
        deform(vol, bad, tets, nodes, device="cpu")
    flipped = nodes.copy()
    flipped[:, 0] *= -1  # a mirror inverts every tet
    with pytest.raises(InputError, match="inverted"):
        deform(vol, nodes, tets, flipped, device="cpu")
    flat = nodes.copy()
    flat[:, 2] = 0.0
    with pytest.raises(InputError, match="degenerate"):
        deform(vol, nodes, tets, flat, device="cpu")
    with pytest.raises(InputError, match="dtype"):
        deform(Volume(np.zeros((4, 4, 4), np.int64)), nodes, tets, nodes, device="cpu")
    with pytest.raises(InputError, match="non-empty"):
        Volume(np.zeros((0, 4, 4), np.int16))
    nan_volume = Volume(np.zeros((8, 8, 8), np.float32))
    nan_volume.data[3, 4, 5] = np.nan
    with pytest.raises(InputError, match="finite voxel values"):
        deform(nan_volume, nodes, tets, nodes, device="cpu")
    with pytest.raises(InputError, match="culling"):
        deform(vol, nodes, tets, nodes, culling="octree", device="cpu")
    with pytest.raises(InputError, match="interpolation"):
        deform(vol, nodes, tets, nodes, interpolation="cubic", device="cpu")
    with pytest.raises(InputError, match="voxels away"):
        deform(vol, nodes, tets, nodes * 1e6, device="cpu")
    with pytest.raises(InputError, match="device"):
        deform(vol, nodes, tets, nodes, device="tpu")


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.uint16, np.float32])
@pytest.mark.parametrize("interpolation", ["linear", "nearest"])
@pytest.mark.parametrize("motion", ["rotated", "in place"])
def test_vectorized_cpu_rows_match_the_warp_reference_bit_for_bit(dtype, interpolation, motion):
    """The CPU fast path (C++ row loop, vectorized) evaluates the reference's expressions in
    the same order without FMA contraction, so every voxel must be bit-identical. "in place" (a
    small displacement: rows run near the input's z axis) is where the exact spans' sampling of
    16-bit inputs prefetches, "rotated" where it does not."""
    vol = _volume(dtype, shape=(33, 29, 27))
    nodes, tets = grid_tet_mesh(vol, (5, 4, 4))
    rng = np.random.default_rng(5)
    if motion == "rotated":
        moved = _rotate(nodes, (25, 40)) * 1.1 + rng.normal(scale=0.3, size=nodes.shape)
    else:
        moved = nodes + rng.normal(scale=0.15, size=nodes.shape) * vol.spacing
    for method in METHODS:
        fast = Rasterizer(vol, nodes, tets, culling=method, interpolation=interpolation, device="cpu")
        ref = Rasterizer(vol, nodes, tets, culling=method, interpolation=interpolation, device="cpu",
                         vectorized_rows=False)
        np.testing.assert_array_equal(fast.deform(moved).data, ref.deform(moved).data)


def test_deform_into_an_existing_volume_reuses_its_buffer(device):
    vol = _volume(np.int16, shape=(24, 20, 18))
    nodes, tets = grid_tet_mesh(vol, 3)
    r = Rasterizer(vol, nodes, tets, device=device)
    first = r.deform(_rotate(nodes, (10, 20)))
    second_nodes = _rotate(nodes, (15, 25))
    fresh = r.deform(second_nodes, out_grid=first)
    reused = r.deform(second_nodes, out=first)
    assert reused is first
    np.testing.assert_array_equal(reused.data, fresh.data)
    with pytest.raises(InputError, match="dtype int16"):
        r.deform(nodes, out=Volume(np.zeros(first.shape, np.float32)))
    with pytest.raises(InputError, match="out_grid"):
        r.deform(nodes, out_grid=first, out=first)
