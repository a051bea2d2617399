"""Incremental rasterization against the full one.

Truth: rasterizing the whole output grid for the new node positions (:meth:`Rasterizer.deform`
with ``out``). :meth:`Rasterizer.update` rewrites only a box around the tets that moved; every
voxel must match the full result up to the round-off of the sub-grid's origin (trilinear
samples of a float volume: 1e-4 of the value range), and the box must be local.
"""

import numpy as np
import pytest

from softvr.volume import Rasterizer, Volume, grid_tet_mesh


def _dent(nodes, centre, depth):
    r2 = np.sum((nodes - centre) ** 2, axis=1) / 4.0**2
    moved = nodes.copy()
    moved[:, 2] -= depth * np.exp(-r2)
    return moved


def test_update_matches_a_full_rasterization_and_stays_local(device):
    rng = np.random.default_rng(3)
    data = rng.random((40, 36, 32)).astype(np.float32)
    vol = Volume(data, spacing=(1.0, 1.0, 1.0))
    nodes, tets = grid_tet_mesh(vol, cells=(10, 9, 8))
    r = Rasterizer(vol, nodes, tets, device=device)
    out = r.deform(nodes, out_grid=vol)
    previous = nodes
    centre = np.array([12.0, 15.0, 31.5])
    for depth in (0.5, 1.5, 3.0, 2.0, 0.0):
        moved = _dent(nodes, centre, depth)
        moved[np.linalg.norm(moved - nodes, axis=1) < 1e-3] = nodes[np.linalg.norm(moved - nodes, axis=1) < 1e-3]
        box = r.update(out, moved, previous, tolerance=0.0)
        full = r.deform(moved, out_grid=vol)
        np.testing.assert_allclose(out.data, full.data, atol=1e-4)
        lo, hi = box
        assert np.prod(hi - lo + 1) < 0.35 * data.size  # only around the dent
        previous = moved
    assert r.update(out, previous, previous) is None
    with pytest.raises(Exception, match="shape"):
        r.update(out, nodes[:-1], nodes)


@pytest.mark.parametrize("culling", ["spans", "bbox", "cells"])
def test_skipped_inverted_tets_write_nothing(culling, device):
    """Truth: the same rasterization over the mesh without the folded tets, wherever one
    tet alone covers a voxel (where the fold makes neighbours overlap, which one writes
    last depends on the tet order)."""
    data = np.random.default_rng(4).random((16, 16, 16)).astype(np.float32)
    vol = Volume(data)
    nodes, tets = grid_tet_mesh(vol, cells=4)
    moved = nodes.copy()
    interior = np.flatnonzero(np.all((nodes > 0) & (nodes < 15), axis=1))[0]
    moved[interior] += (9.0, 0.0, 0.0)  # folds some of the tets around this node
    from softvr.volume.tetmesh import tet_signed_volumes

    folded = tet_signed_volumes(moved, tets) <= 0
    assert folded.any()
    r = Rasterizer(vol, nodes, tets, culling=culling, inverted="skip", device=device)
    out = r.deform(moved, out_grid=vol)
    assert r.skipped_tets == folded.sum()
    others = Rasterizer(vol, nodes, tets[~folded], culling=culling, device=device)
    reference = others.deform(moved, out_grid=vol)
    single = others.write_counts(moved, out_grid=vol).data <= 1
    assert single.mean() > 0.95
    np.testing.assert_array_equal(out.data[single], reference.data[single])
    with pytest.raises(Exception, match="inverted"):
        Rasterizer(vol, nodes, tets, culling=culling, device=device).deform(moved, out_grid=vol)


def test_update_with_skipped_tets_matches_a_full_rasterization(device):
    """:meth:`Rasterizer.update` with ``inverted="skip"`` sets up only the tets that can reach
    the rewritten box. Truth: the full rasterization with the folded tets skipped, wherever
    one tet alone covers a voxel (as above: where folded neighbours overlap, the order decides),
    up to the round-off of the sub-grid's origin (1e-4 of the value range, as above)."""
    data = np.random.default_rng(5).random((30, 28, 26)).astype(np.float32)
    vol = Volume(data)
    nodes, tets = grid_tet_mesh(vol, cells=(6, 7, 5))
    r = Rasterizer(vol, nodes, tets, inverted="skip", device=device)
    out = r.deform(nodes, out_grid=vol)
    moved = _dent(nodes, np.array([14.0, 13.0, 25.5]), 3.0)
    node = int(np.argmin(np.linalg.norm(nodes - (15.0, 12.0, 15.0), axis=1)))
    moved[node] += (8.0, 0.0, 0.0)  # folds the tets around it
    still = np.linalg.norm(moved - nodes, axis=1) < 1e-3
    moved[still] = nodes[still]
    lo, hi = r.update(out, moved, nodes)
    assert r.skipped_tets > 0 and np.any(lo > 0) and np.prod(hi - lo + 1) < 0.7 * data.size
    full = r.deform(moved, out_grid=vol)
    single = r.write_counts(moved, out_grid=vol).data <= 1
    assert single.mean() > 0.95
    np.testing.assert_allclose(out.data[single], full.data[single], atol=1e-4)


def test_update_redraws_only_the_region_the_moved_tets_reach(device):
    """Two dents at opposite corners: the rewritten box spans both, but only the bricks their
    moved tets' footprints reach (old and new) are redrawn. Truth: the full rasterization
    (tolerance 0, every other node exactly still), up to the sub-grid round-off as above; a
    sentinel voxel inside the box but far from both dents is left as it was."""
    data = np.random.default_rng(6).random((48, 40, 36)).astype(np.float32)
    vol = Volume(data)
    nodes, tets = grid_tet_mesh(vol, cells=(12, 10, 9))
    r = Rasterizer(vol, nodes, tets, device=device)
    out = r.deform(nodes, out_grid=vol)
    moved = _dent(_dent(nodes, np.array([6.0, 6.0, 35.5]), 2.5), np.array([41.0, 33.0, 35.5]), -2.0)
    still = np.linalg.norm(moved - nodes, axis=1) < 1e-3
    moved[still] = nodes[still]
    sentinel = (20, 30, 34)
    out.data[sentinel] = -7.0
    lo, hi = r.update(out, moved, nodes)
    assert np.all(lo <= sentinel) and np.all(np.asarray(sentinel) <= hi)
    full = r.deform(moved, out_grid=vol)
    assert out.data[sentinel] == -7.0
    out.data[sentinel] = full.data[sentinel]
    np.testing.assert_allclose(out.data, full.data, atol=1e-4)


def test_node_motion_under_the_tolerance_moves_the_picture_by_at_most_twice_it():
    """DeformedVolume with ``tolerance`` tau: each drawn voxel is the sample of a tet whose
    nodes were drawn within tau of their drawn positions, which are within tau of the nodes
    now, so within 2 tau of them. With x~ those nodes, the tet's map phi~ and the true map phi
    (thesis eq. 3.1, barycentric) differ by at most 2 tau at any rest point r~ (weights >= 0
    summing to 1), so the true rest point of the voxel lies within 2 tau |F^-1| of r~ (F: a
    deformed tet's edge matrix over its rest one, thesis eq. 3.2). Truth: a linear volume
    I(x) = g . x, which trilinear interpolation reproduces, so where both the incremental and a
    full rasterization sample the mesh, |difference| <= |g| 2 tau max|F^-1| (+ float32 round-off)."""
    from softvr.volume import DeformedVolume

    n, tau = 24, 0.2
    g = np.array([1.0, 2.0, 3.0])
    data = (np.indices((n, n, n)).T @ g).T.astype(np.float32)
    vol = Volume(data)
    nodes, tets = grid_tet_mesh(vol, cells=6)
    shown = DeformedVolume(vol, nodes, tets, tolerance=tau, device="cpu")
    rng = np.random.default_rng(7)
    moved, worst, lagging = nodes.copy(), 0.0, 0
    for _ in range(12):
        # Small steps around a dent; some nodes move less than tau a step and add up.
        moved = moved + rng.normal(0.0, 0.08, nodes.shape) * np.exp(-np.sum((nodes - 12.0) ** 2, axis=1) / 60.0)[:, None]
        shown.update(moved)
        full = shown.rasterizer.deform(moved, out_grid=vol).data
        inside = (shown.deformed.data != 0) & (full != 0)
        lagging += int(np.sum(shown.deformed.data[inside] != full[inside]))
        rest_edges = nodes[tets[:, 1:]] - nodes[tets[:, :1]]
        edges = moved[tets[:, 1:]] - moved[tets[:, :1]]
        inv_f = np.linalg.inv(np.linalg.solve(rest_edges, edges).transpose(0, 2, 1))  # F^-1 per tet
        bound = np.linalg.norm(g) * 2 * tau * np.linalg.norm(inv_f, ord=2, axis=(1, 2)).max() + 1e-4 * data.max()
        worst = max(worst, float(np.abs(shown.deformed.data[inside] - full[inside]).max()) / bound)
    assert lagging > 0  # the tolerance was used
    assert worst <= 1.0


def _last_tet_wins(data, nodes, tets, moved, order):
    """NumPy / SciPy truth of a rasterization onto the rest grid (unit spacing, origin 0) that
    draws the tets ``order`` one after the other (thesis Algorithm 1), so that a voxel centre
    inside several takes the last one's value: float64 barycentric weights of the deformed tets
    (thesis eq. 3.1), the rest point sampled trilinearly (``map_coordinates``, order 1). Returns
    the values and a mask of the covered voxels no tet face passes within 1e-6 of (weights)."""
    from scipy.ndimage import map_coordinates

    shape = data.shape
    covered = np.zeros(shape, dtype=bool)
    rest = np.zeros((*shape, 3))
    clear = np.ones(shape, dtype=bool)
    for t in order:
        x = moved[tets[t]]
        lo = np.maximum(np.floor(x.min(axis=0)).astype(int) - 1, 0)
        hi = np.minimum(np.ceil(x.max(axis=0)).astype(int) + 1, np.asarray(shape) - 1)
        idx = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"), -1).reshape(-1, 3)
        w = np.linalg.solve((x[1:] - x[0]).T, (idx - x[0]).T).T
        w = np.column_stack([1.0 - w.sum(axis=1), w])
        clear[tuple(idx.T)] &= np.abs(w).min(axis=1) > 1e-6
        sel = tuple(idx[w.min(axis=1) > 0].T)
        covered[sel] = True
        rest[sel] = w[w.min(axis=1) > 0] @ nodes[tets[t]]
    values = np.zeros(shape, dtype=data.dtype)
    values[covered] = map_coordinates(data.astype(np.float64), rest[covered].T, order=1, mode="nearest")
    return values, covered & clear


@pytest.mark.parametrize("threads", ["1", "2"])
def test_overlapping_tets_at_a_fold_are_drawn_in_tet_order_on_any_thread_count(threads, monkeypatch):
    """Where a fold makes tets overlap, the voxel they share gets the value of the tet with the
    highest index (thesis Algorithm 1 in tet order), run after run (split over two threads, the
    order of two threads' writes was a race). Truth: NumPy barycentric cover + SciPy trilinear
    samples in tet order (:func:`_last_tet_wins`), within float32 round-off (1e-4 of the range)."""
    monkeypatch.setenv("SOFTVR_NUM_THREADS", threads)
    data = np.random.default_rng(8).random((48, 48, 40)).astype(np.float32)
    vol = Volume(data)
    nodes, tets = grid_tet_mesh(vol, cells=(6, 6, 5))
    moved = nodes.copy()
    for centre in ((7.5, 15.5, 15.5), (15.5, 31.5, 23.5), (23.5, 15.5, 7.5), (31.5, 31.5, 23.5)):  # apart
        node = int(np.argmin(np.linalg.norm(nodes - centre, axis=1)))
        moved[node] += (19.0, 3.0, 0.0)  # past the next nodes: a fold, its neighbours overlap
    from softvr.volume.tetmesh import tet_signed_volumes

    folded = tet_signed_volumes(moved, tets) <= 0
    truth, compare = _last_tet_wins(data, nodes, tets, moved, np.flatnonzero(~folded))
    r = Rasterizer(vol, nodes, tets, inverted="skip", device="cpu")
    assert (r.write_counts(moved, out_grid=vol).data > 1).sum() > 200  # tets do overlap
    for _ in range(30):
        out = r.deform(moved, out_grid=vol)
        assert r.skipped_tets == folded.sum()
        np.testing.assert_allclose(out.data[compare], truth[compare], atol=1e-4)


def test_moved_nodes_is_numpys_norm_test_bit_for_bit():
    """The moved-node test that update() and DeformedVolume share (a faster form of the norm).
    Truth: NumPy's ``np.linalg.norm(x1 - x0, axis=1) > tolerance``, node for node, including
    a tolerance equal to a node's motion (not moved: the test is strict) and still nodes."""
    from softvr.volume.rasterize import _moved_nodes

    rng = np.random.default_rng(5)
    x0 = rng.normal(size=(5000, 3)) * 50.0
    x1 = x0 + rng.normal(size=(5000, 3)) * rng.choice([1e-3, 1e-2, 1.0], size=(5000, 1))
    x1[:3] = x0[:3]
    norms = np.linalg.norm(x1 - x0, axis=1)
    for tolerance in (0.0, 0.01, float(np.median(norms)), float(norms[17])):
        np.testing.assert_array_equal(_moved_nodes(x1, x0, tolerance), norms > tolerance)
    assert not _moved_nodes(x1, x0, float(norms[17]))[17]
    # Each node against its own norm and the next float below it (the comparison broadcasts):
    # equal to NumPy's norm to the last bit, or one of the two fails.
    assert not _moved_nodes(x1, x0, norms).any()
    below = np.nextafter(norms, -np.inf)
    np.testing.assert_array_equal(_moved_nodes(x1, x0, below), norms > below)


def test_deformed_volume_refuses_nodes_of_another_shape():
    from softvr.volume import DeformedVolume

    vol = Volume(np.zeros((6, 6, 6), np.float32))
    nodes, tets = grid_tet_mesh(vol, 2)
    shown = DeformedVolume(vol, nodes, tets, device="cpu")
    with pytest.raises(Exception, match="nodes.*shape"):
        shown.update(nodes[:-1])
