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
