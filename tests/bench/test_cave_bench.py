"""``softvr bench cave --quick``: runs master and node processes, writes JSON and a PNG.

Checked against the run's own independent quantities: every node held the master's state
(no digest mismatches), the streamed 10 K-vertex frames are far smaller than the pickled
whole state (the thesis' way) and under the issue's 100 kB, events-only frames are tiny.
"""

import json

from softvr.bench import cave as C

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_quick_bench_writes_json_and_png(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SOFTVR_CAVE_KEYS", str(tmp_path / "keys"))  # CURVE keys made here, not in ~/.config
    js, png = tmp_path / "cave.json", tmp_path / "cave.png"
    assert C.main(["--quick", "--json", str(js), "--plot", str(png), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert png.read_bytes()[:8] == PNG_MAGIC
    result = json.loads(js.read_text())
    assert result["schema"] == "softvr-bench-cave/1"
    assert {(r["nodes"], r["load"]) for r in result["runs"]} == {(2, "events"), (2, "streamed"), (4, "events"),
                                                                  (4, "streamed")}
    for r in result["runs"]:
        assert r["mismatches"] == 0 and r["sync_ms"]["count"] == 60
        assert 0 < r["sync_ms"]["p50"] <= r["sync_ms"]["p99"]
    streamed = [r["frame_bytes"]["mean"] for r in result["runs"] if r["load"] == "streamed"]
    events = [r["frame_bytes"]["max"] for r in result["runs"] if r["load"] == "events"]
    assert max(events) < 1000 and max(streamed) < 100_000
    assert result["peers"]["pickled_state_bytes"] > 120_000 > 2 * max(streamed)  # 10 K x 3 float32 = 120 kB
    assert all(f["p50"] > 0 for f in result["peers"]["zmq_alone"])
    assert "ZeroMQ alone" not in out and "zmq alone" in out and "targets:" in out and "CURVE on" in out
    assert result["config"]["curve"] is True
    secrets = list((tmp_path / "keys").rglob("*.key_secret"))
    assert len(secrets) == 5 and {p.stat().st_mode & 0o777 for p in secrets} == {0o600}  # master + 4 nodes
