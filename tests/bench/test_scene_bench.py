"""``softvr bench scene --quick`` times the three quick scenes, glTF vs TOML and MuJoCo, and
writes its JSON and PNG.

Truths, from outside the benchmark: each scene's dt and steps per frame are the TOML file's
(read here with tomllib); the bundled scenes start collision-free (``softvr check`` passes
them); the real-time factor is its definition; the glTF and the TOML twin of soft-cube build
the same body; MuJoCo's model of box-stack has the file's five boxes and their mass
(5 x 0.2 x 0.2 x 0.1 m^3 x 500 kg/m^3 = 10 kg).
"""

import json
import math
import statistics
import sys
import tomllib

import pytest

from softvr.bench import scene as S
from softvr.scene import bundled

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _positive(x) -> bool:
    return isinstance(x, float) and math.isfinite(x) and x > 0


def test_quick_bench_writes_json_and_png(tmp_path, capsys):
    js, png = tmp_path / "scene.json", tmp_path / "scene.png"
    assert S.main(["--quick", "--no-progress", "--json", str(js), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert png.read_bytes()[:8] == PNG_MAGIC
    result = json.loads(js.read_text())
    assert result["schema"] == "softvr-bench-scene/1" and result["machine"]["cores"] >= 1
    frames, repeat = result["config"]["frames"], result["config"]["repeat"]
    assert [r["scene"] for r in result["scenes"]] == list(S.QUICK_SCENES)
    for r in result["scenes"]:
        assert r["status"] == "ok", r
        assert r["scene"] in out
        sim = tomllib.loads(bundled(r["scene"]).read_text())["simulation"]
        assert r["dt_s"] == sim["dt"] and r["steps_per_frame"] == sim["steps_per_frame"]
        assert r["start_problems"] == 0
        for key in ("read_ms", "build_ms", "check_ms", "first_frame_ms", "step_ms", "render_ms", "frame_ms",
                    "real_time_factor"):
            assert _positive(r[key]), (r["scene"], key, r[key])
        assert len(r["samples"]["read_ms"]) == len(r["samples"]["build_ms"]) == repeat
        assert r["read_ms"] == statistics.median(r["samples"]["read_ms"])
        trace = r["trace"]
        assert len(trace["step_ms"]) == len(trace["render_ms"]) == len(trace["frame_ms"]) == frames
        assert all(_positive(v) for values in trace.values() for v in values)
        assert r["step_ms"] == statistics.median(trace["step_ms"][1:]) and r["first_frame_ms"] == trace["frame_ms"][0]
        # A frame's wall time holds its physics and its render.
        assert all(f >= s + d for f, s, d in zip(trace["frame_ms"], trace["step_ms"], trace["render_ms"]))
        # The stages of a frame's steps are parts of its physics time (Scene.stage_ms).
        assert len(r["stage_trace"]) == frames
        assert all(sum(st.values()) <= s for st, s in zip(r["stage_trace"], trace["step_ms"]))
        assert set(r["stage_ms"]) == {"dynamics", "collision", "contact", "integrate"}
        assert r["real_time_factor"] == pytest.approx(sim["dt"] * sim["steps_per_frame"] * 1e3 / r["step_ms"])
    cube = result["scenes"][0]
    assert (cube["bodies"], cube["tets"], cube["nodes"]) == (1, 4 ** 3 * 5, 5 ** 3)  # a box of 4^3 cubes
    g = result["gltf_vs_toml"]
    assert g["gltf"]["file"].endswith(".glb") and g["toml"]["file"].endswith(".toml")
    for key in ("bodies", "nodes", "tets"):
        assert g["gltf"][key] == g["toml"][key] > 0
    assert all(_positive(g[k][t]) for k in ("gltf", "toml") for t in ("read_ms", "build_ms"))
    assert "glTF / TOML" in out
    peer = result["peer"]
    m = peer["mujoco"]
    if m["status"] != "ok":
        assert m["status"] == S.NOT_INSTALLED and peer["softvr_over_mujoco"] is None
        assert "not installed" in out
        return
    boxes = tomllib.loads(bundled("box-stack.toml").read_text())["body"]
    assert m["bodies"] == len(boxes) == 5
    assert m["mass_kg"] == pytest.approx(sum(500.0 * math.prod(b["box"]) for b in boxes)) == pytest.approx(10.0)
    assert all(_positive(m[k]) for k in ("load_ms", "first_frame_ms", "frame_ms", "real_time_factor"))
    stack = next(r for r in result["scenes"] if r["scene"] == "box-stack.toml")
    ratios = peer["softvr_over_mujoco"]
    assert ratios["load"] == pytest.approx((stack["read_ms"] + stack["build_ms"]) / m["load_ms"])
    assert ratios["frame"] == pytest.approx(stack["step_ms"] / m["frame_ms"])
    assert "softvr / MuJoCo" in out


def test_a_bad_scene_name_is_refused_with_the_choices(capsys):
    with pytest.raises(SystemExit) as info:
        S.main(["--scenes", "soft-cube.toml", "teapot.toml"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "teapot.toml" in err and "box-stack.toml" in err


def test_the_mjcf_refuses_what_it_cannot_write():
    from softvr.scene import read_scene

    with pytest.raises(ValueError, match="soft cube"):
        S.box_stack_mjcf(read_scene(bundled("soft-cube.toml")))


def test_without_mujoco_the_peer_is_recorded_as_missing(monkeypatch):
    from softvr.scene import read_scene

    monkeypatch.setitem(sys.modules, "mujoco", None)  # import mujoco raises ImportError
    assert S.run_mujoco(read_scene(bundled("box-stack.toml")), frames=2, repeat=1) == {"status": S.NOT_INSTALLED}
