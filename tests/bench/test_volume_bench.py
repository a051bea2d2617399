"""The volume benchmark's peers are correct, and ``softvr bench volume --quick`` runs."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from scipy import ndimage

from softvr.bench import _volume_peers as P
from softvr.volume import Volume, grid_tet_mesh


def _smooth_volume() -> Volume:
    n = (20, 16, 12)
    spacing = np.array([0.8, 1.1, 1.7])
    origin = np.array([5.0, -3.0, 12.0])
    i, j, k = np.meshgrid(*(np.arange(m, dtype=np.float64) for m in n), indexing="ij")
    data = (
        100.0 * np.sin(0.35 * i + 0.2) * np.cos(0.3 * j - 0.1)
        + 40.0 * np.cos(0.45 * k) * np.sin(0.25 * i + 0.3 * j)
        + 0.5 * i * j
    ).astype(np.float32)
    return Volume(data, spacing, origin)


def _affine_case():
    """Rotation + anisotropic scale about a point, the fitted output grid, and the truth."""
    vol = _smooth_volume()
    nodes, tets = grid_tet_mesh(vol, (3, 3, 2))
    c, s = np.cos(0.5), np.sin(0.5)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    c2, s2 = np.cos(-0.3), np.sin(-0.3)
    rx = np.array([[1, 0, 0], [0, c2, -s2], [0, s2, c2]])
    a = rx @ rz @ np.diag([1.3, 0.8, 1.15])
    centre = vol.origin + vol.extent / 2 + np.array([0.7, -0.4, 0.2])
    shift = np.array([2.0, -1.5, 3.0])
    deformed = (nodes - centre) @ a.T + centre + shift

    out_spacing = np.array([0.9, 0.75, 1.3])
    lo, hi = deformed.min(0), deformed.max(0)
    out_origin = lo - 0.37 * out_spacing  # a grid not aligned with anything
    shape = tuple(int(v) for v in np.floor((hi - out_origin) / out_spacing) + 1)
    grid = P.grid_volume(shape, out_spacing, out_origin)

    # Output index o -> world x1 -> rest x0 = A^-1 (x1 - centre - shift) + centre -> input index.
    ainv = np.linalg.inv(a)
    matrix = np.diag(1 / vol.spacing) @ ainv @ np.diag(out_spacing)
    offset = (ainv @ (out_origin - centre - shift) + centre - vol.origin) / vol.spacing
    truth = ndimage.affine_transform(vol.data, matrix, offset, output_shape=shape, order=1, mode="nearest")
    # Input index of every output voxel, to keep voxels >= 1 voxel inside the input.
    o = np.stack(np.meshgrid(*(np.arange(m) for m in shape), indexing="ij"), axis=-1).astype(np.float64)
    u = o @ matrix.T + offset
    inner = np.all((u >= 1.0) & (u <= np.asarray(vol.shape) - 2.0), axis=-1)
    return vol, nodes, tets, deformed, grid, truth, inner


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("peer", ["vtk+scipy", "sitk"])
def test_peers_match_affine_transform(peer, threads):
    vol, nodes, tets, deformed, grid, truth, inner = _affine_case()
    assert inner.sum() > 500  # the comparison covers a real part of the volume
    fn = P.warp_vtk_scipy if peer == "vtk+scipy" else P.warp_sitk
    bg = -999.0
    out, tim = fn(vol, nodes, tets, deformed, grid, background=bg, threads=threads)
    assert out.shape == grid.shape and out.dtype == vol.dtype
    np.testing.assert_allclose(out.spacing, grid.spacing)
    np.testing.assert_allclose(out.origin, grid.origin)
    # Every voxel well inside the input lies inside the deformed mesh (the mesh spans the
    # voxel-centre box), so the peer must write it, with the trilinear value of the truth.
    assert np.all(out.data[inner] != bg)
    err = np.abs(out.data[inner].astype(np.float64) - truth[inner])
    scale = float(np.abs(vol.data).max())
    assert err.max() < 1e-4 * scale, f"{peer}: max error {err.max():.3g} (values up to {scale:.3g})"
    # Far outside the deformed mesh: background.
    assert (out.data == bg).sum() > 100
    assert all(tim[k] >= 0 for k in ("probe_s", "total_s"))
    assert ("fetch_s" in tim) if peer == "vtk+scipy" else ("resample_s" in tim and "field_s" in tim)


def test_peers_label_volume_keeps_labels():
    vol = _smooth_volume()
    labels = Volume((vol.data > 20).astype(np.uint8) * 3 + (vol.data > 80).astype(np.uint8) * 4,
                    vol.spacing, vol.origin, is_label=True)
    _, nodes, tets, deformed, grid, _, _ = _affine_case()
    for fn in (P.warp_vtk_scipy, P.warp_sitk):
        out, _ = fn(labels, nodes, tets, deformed, grid, background=0)
        assert set(np.unique(out.data)) <= {0, 3, 7}


def test_peers_agree_with_softvr_on_affine_case():
    from softvr.volume import Rasterizer

    vol, nodes, tets, deformed, grid, truth, inner = _affine_case()
    r = Rasterizer(vol, nodes, tets, device="cpu", background=-999.0)
    mine = r.deform(deformed, grid)
    peer, _ = P.warp_vtk_scipy(vol, nodes, tets, deformed, grid, background=-999.0)
    both = (mine.data != -999.0) & (peer.data != -999.0)
    assert both[inner].all()
    assert np.abs(mine.data[both] - peer.data[both]).max() < 1e-3 * float(np.abs(vol.data).max())


def test_quick_bench_writes_json_and_png(tmp_path, capsys):
    from softvr.bench.volume import main

    js, png = tmp_path / "out" / "volume.json", tmp_path / "volume.png"
    t0 = time.perf_counter()
    assert main(["--quick", "--json", str(js), "--plot", str(png), "--no-progress"]) == 0
    assert time.perf_counter() - t0 < 60.0
    res = json.loads(js.read_text())
    assert {"schema", "machine", "config", "cases", "targets", "wall_s"} <= set(res)
    m = res["machine"]
    assert {"cpu_model", "cores", "ram_bytes", "device", "versions", "date"} <= set(m)
    assert "warp" in m["versions"] and m["cores"] >= 1
    sections = {c["section"] for c in res["cases"]}
    assert sections == {"peers", "fig35", "fig36"}
    routes = {c["route"] for c in res["cases"]}
    assert {"softvr", "vtk+scipy", "sitk"} <= routes
    modes = {c["mode"] for c in res["cases"] if c["route"] == "softvr"}
    assert modes == {"bbox", "cells", "spans"}
    for c in res["cases"]:
        if c.get("skipped"):
            continue
        assert c["time_s"] > 0 and c["rate_voxels_per_s"] > 0
        if c["route"] == "softvr":
            assert 0 < c["efficiency"] <= 1 and c["voxels_written"] > 0
            assert c["mode"] != "spans" or c["efficiency"] == 1.0
        if c["route"] in ("vtk+scipy", "sitk"):
            # The peers write what softvr writes, to within rounding of int16 CT values.
            assert c["compared_voxels"] > 0 and c["max_abs_diff"] is not None
    # Every mode writes the same voxels on a given case.
    for sec in ("peers", "fig35", "fig36"):
        by_case = {}
        for c in res["cases"]:
            if c["section"] == sec and c["route"] == "softvr":
                by_case.setdefault(c["case"], set()).add(c["voxels_written"])
        assert all(len(v) == 1 for v in by_case.values()), by_case
    assert {"cpu_rotated", "cpu_in_place"} <= set(res["targets"])
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob("**/*.tmp"))
    out = capsys.readouterr().out
    assert "Fig 3.5" in out and "Fig 3.6" in out and "Targets" in out


def test_timed_runs_take_repeat_runs_and_more_until_the_minimum_time(monkeypatch):
    """``_timed_runs`` on a clock that advances 0.04 s per call of ``fn``: 3 runs (``repeat``)
    take 0.12 s; a minimum of 0.5 s needs ceil(0.5 / 0.04) = 13 runs; a maximum of 0.2 s stops
    after 5 (0.2 s reached), whatever the minimum."""
    from softvr.bench import volume as V  # noqa: PLC0415

    clock = [0.0]

    def fn():
        clock[0] += 0.04

    monkeypatch.setattr(V.time, "perf_counter", lambda: clock[0])
    assert len(V._timed_runs(fn, 3, 4.0)[0]) == 3
    times, _ = V._timed_runs(fn, 3, 4.0, min_case_s=0.5)
    assert len(times) == 13 and np.allclose(times, 0.04)
    assert len(V._timed_runs(fn, 3, 0.2, min_case_s=0.5)[0]) == 5
