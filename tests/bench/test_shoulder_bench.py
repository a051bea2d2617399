"""``softvr bench shoulder --quick`` runs both variants and writes its JSON and PNG.

Truths: the scene has Table 5.1's structure (8 soft parts with the deltoid, 7 without, one
coupling island per soft part tied to the bones plus the labrum chain); the haptic loop ran
beside the simulation at its rate (its tick count matches the wall time it ran, its median
period is the 1 ms it was asked for).
"""

import json

from softvr.bench import shoulder as S

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_quick_bench_writes_json_and_png(tmp_path, capsys):
    js, png = tmp_path / "shoulder.json", tmp_path / "shoulder.png"
    assert S.main(["--quick", "--json", str(js), "--plot", str(png), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert png.read_bytes()[:8] == PNG_MAGIC
    result = json.loads(js.read_text())
    assert result["schema"] == "softvr-bench-shoulder/1"
    palpation, arthroscopy = result["runs"]["palpation"], result["runs"]["arthroscopy"]
    assert palpation["soft_parts"] == 8 and arthroscopy["soft_parts"] == 7
    assert palpation["coupling_islands"] == 9 and arthroscopy["coupling_islands"] == 8
    for run in (palpation, arthroscopy):
        assert run["steps"] == 10 and run["contacts_max"] > 0
        assert abs(run["haptic"]["p50_ms"] - 1.0) < 0.1 and run["haptic"]["count"] > 100
    assert "haptic p99" in out and "thesis (2008, two cores)" in out
