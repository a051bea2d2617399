"""``softvr bench adhesion --quick`` runs both candy scenes and writes its JSON and PNG.

Truths: without adhesion no contact ever pulls (normal impulses are >= 0, Signorini); with
it some do, and the scene is the same (same sizes, same number of steps); the pull-off case
separates at m g + sum(A) sqrt(W C).
"""

import json

from softvr.bench import adhesion as A

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_quick_bench_writes_json_and_png(tmp_path, capsys):
    js, png = tmp_path / "adhesion.json", tmp_path / "adhesion.png"
    assert A.main(["--quick", "--json", str(js), "--plot", str(png), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert png.read_bytes()[:8] == PNG_MAGIC
    result = json.loads(js.read_text())
    assert result["schema"] == "softvr-bench-adhesion/1"
    plain, sticky = result["runs"]["plain"], result["runs"]["adhesion"]
    assert plain["adhesion"] is False and sticky["adhesion"] is True
    for key in ("tets", "collision_triangles", "steps"):
        assert plain[key] == sticky[key]
    assert max(plain["trace"]["pulling_contacts"]) == 0
    assert plain["contacts_max"] > 0 and sticky["contacts_max"] > 0
    assert result["targets"]["cost_ratio"] > 0
    assert "targets: real time" in out and "adhesion's cost at equal contact count" in out
    assert result["targets"]["candy_met"] == (plain["ms_per_step"] <= 40.0)  # issue 16: the plain candy's step
    assert f"plain candy {plain['ms_per_step']:.1f} ms per step vs <= 40" in out
    # The pull-off case separates at the force the model predicts (tests/contact/test_adhesion.py),
    # and MuJoCo's adhesion actuator, given that force as its gain, runs beside it when installed.
    pull = result["pull_off"]
    assert pull["softvr"]["status"] == "ok"
    assert pull["predicted_separation_n"] <= pull["softvr"]["separation_force_n"] <= 1.05 * pull["predicted_separation_n"]
    assert pull["mujoco"]["status"] == "ok" or pull["mujoco"]["status"].startswith("skipped: not installed")
    assert "Pull-off:" in out
