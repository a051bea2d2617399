"""``softvr bench palpation --quick``: the stages are timed on the head CT, JSON and PNG are
written, and the benchmark's own check holds: after the last frame the incrementally updated
volume equals the fully rasterized one (nodes that moved less than the 0.01 mm tolerance since
they were last drawn may differ: allowed on 0.1 % of voxels); the overlapped pass (each render
beside the next frame's step) is timed and compared with the sequential one (the exact comparison
is tests/app/test_overlap.py's: here split launches may race, see there)."""

import json

import pytest

from softvr.bench import palpation as P
from softvr.datasets import HEAD_CT_PATH

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.mark.skipif(not HEAD_CT_PATH.exists(), reason="head CT (Debian invesalius-examples) not installed")
def test_quick_bench_writes_json_and_png(tmp_path, capsys):
    js, png = tmp_path / "palpation.json", tmp_path / "palpation.png"
    assert P.main(["--quick", "--json", str(js), "--plot", str(png), "--no-progress", "--device", "cpu"]) == 0
    assert png.read_bytes()[:8] == PNG_MAGIC
    result = json.loads(js.read_text())
    assert result["schema"] == "softvr-bench-palpation/1" and len(result["trace"]["fem_ms"]) == 6
    assert result["incremental_equals_full"] > 0.999
    assert result["median"]["raster_voxels"] < 0.5 * 256 * 256 * 108
    assert len(result["trace"]["period_ms"]) == 6 and 0.0 <= result["overlap_equals_sequential"] <= 1.0
    out = capsys.readouterr().out
    assert "rasterize: incremental" in out and "overlapped (render || next step)" in out
