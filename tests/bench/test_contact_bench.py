"""``softvr bench contact --quick`` runs, writes its JSON and PNG, and softvr's cube rests on the plane.

The peers (MuJoCo, PyBullet, Newton) are optional: the quick run includes whichever are
installed, and a missing one must show up as a "skipped: not installed" row, not vanish.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from softvr.bench import _contact_peers as P
from softvr.bench import contact as C

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_full_scene_is_the_peers_md_cube():
    nodes, tets = C.cube_mesh(C.FULL_SCENE)
    assert nodes.shape == (729, 3) and tets.shape == (2560, 4)
    np.testing.assert_allclose(nodes.min(axis=0), [-0.4, -0.4, 0.5])
    np.testing.assert_allclose(nodes.max(axis=0), [0.4, 0.4, 1.3])
    lam, mu = C.FULL_SCENE.lame
    assert lam == pytest.approx(1e5) and mu == pytest.approx(1e5)
    assert C.FULL_SCENE.steps == 60 and C.FULL_SCENE.mass == pytest.approx(512.0)
    assert C.QUICK_SCENE.steps == 15


def test_quick_bench_writes_json_and_png(tmp_path, capsys):
    js, png = tmp_path / "contact.json", tmp_path / "contact.png"
    assert C.main(["--quick", "--json", str(js), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert png.read_bytes()[:8] == PNG_MAGIC
    result = json.loads(js.read_text())
    assert result["schema"] == "softvr-bench-contact/1"
    for key in ("machine", "config", "engines", "targets", "wall_s"):
        assert key in result
    assert result["config"]["quick"] is True
    assert set(result["machine"]["versions"]) >= {"softvr", "numpy", "scipy", "mujoco", "pybullet", "newton"}
    assert [r["engine"] for r in result["engines"]] == list(C.ENGINES)

    keys = ("steps_per_s", "real_time_factor", "max_penetration_m", "bottom_end_m", "centre_end_m", "contacts_end",
            "tets", "nodes", "mass_kg", "trace")
    for r in result["engines"]:
        assert r["status"] in ("ok", "skipped", "failed"), r
        if r["engine"] != "softvr" and not P.installed(r["engine"]):
            assert r["status"] == "skipped" and r["reason"] == P.NOT_INSTALLED
        if r["status"] == "ok":
            for key in keys:
                assert key in r, (r["engine"], key)
            assert len(r["trace"]["min_z"]) == result["config"]["steps"] == 15
            assert r["mass_kg"] == pytest.approx(8.0, rel=1e-5)  # same density in every engine
        else:
            assert r["engine"] in out and r["reason"] in out  # the row says why

    sv = result["engines"][0]
    assert sv["engine"] == "softvr" and sv["status"] == "ok"
    assert sv["steps_per_s"] > 0
    # Contact without penetration, and the cube comes to rest on the plane.
    assert sv["max_penetration_m"] < 1e-3
    assert abs(sv["bottom_end_m"]) < 2e-3
    assert sv["centre_end_m"] == pytest.approx(0.1, abs=2e-3)  # half the 0.2 m edge, a little sag
    assert abs(sv["centre_speed_end_m_s"]) < 0.05
    assert sv["contacts_end"] == 16  # the bottom face's 4 x 4 nodes
    assert sv["active_contacts_end"] > 0 and sv["pgs_iterations_end"] > 0
    assert result["targets"]["penetration_met"] is True
    assert "targets:" in out and "softvr" in out
    # The candy scene ran at its quick scale: candies reached the block (contacts between
    # bodies) and the solver kept the normal constraints to its tolerance.
    candy = result["candy"]
    assert candy["quick"] is True and candy["steps"] == 20 and len(candy["trace"]["step_s"]) == 20
    assert candy["contacts_max"] > 0 and candy["residual_max_m_s"] < 1e-3
    assert "Candy scene" in out and "candy scale real time:" in out


def test_missing_and_failing_peers_get_a_row(monkeypatch, tmp_path, capsys):
    """A peer that is not installed, or whose process dies, is reported in its row."""
    monkeypatch.setattr(P, "installed", lambda name: name != "mujoco")
    monkeypatch.setattr(P, "run_peer_process", lambda name, scene, repeat, timeout_s: {"failed": "failed: exit status -11"})
    js = tmp_path / "c.json"
    assert C.main(["--quick", "--engines", "softvr,mujoco,pybullet", "--json", str(js), "--no-progress",
                   "--no-candy"]) == 0
    out = capsys.readouterr().out
    assert "skipped: not installed (pip install softvr[peers])" in out
    assert "failed: exit status -11" in out
    rows = {r["engine"]: r for r in json.loads(js.read_text())["engines"]}
    assert rows["mujoco"]["status"] == "skipped" and rows["pybullet"]["status"] == "failed"
    assert rows["softvr"]["vs_fastest_peer"] is None  # no peer ran: no ratio, and the targets say so
    assert "no peer ran" in out
    assert "candy scale real time: not measured (--no-candy)" in out


def test_unknown_engine_is_an_argument_error():
    with pytest.raises(SystemExit) as exc:
        C.main(["--quick", "--engines", "softvr,havok"])
    assert exc.value.code == 2


def test_vtk_file_for_pybullet_round_trips(tmp_path):
    """The tet mesh handed to PyBullet is the softvr mesh (read back with meshio)."""
    meshio = pytest.importorskip("meshio", reason="meshio is a softvr dependency; needed to read the file back")
    nodes, tets = C.cube_mesh(C.QUICK_SCENE)
    path = tmp_path / "cube.vtk"
    P.write_vtk_tets(path, nodes, tets)
    mesh = meshio.read(path)
    np.testing.assert_allclose(mesh.points, nodes, atol=1e-6)
    np.testing.assert_array_equal(mesh.cells_dict["tetra"], tets)


def test_cubes_in_one_scene_land_and_rest_like_the_single_cube():
    # Four quick-scene cubes (0.2 m, bottom 5 cm up) in one scene, 0.25 s: each falls the 5 cm in
    # sqrt(2 * 0.05 / g) = 0.10 s and rests on the plane by the end, within the 1 mm target, as
    # the single cube of the bench does.
    result = C.run_contact_bench(quick=True, engines=("softvr",), candy=False, cubes=4, progress=False)
    cubes = result["cubes"]
    assert (cubes["cubes"], cubes["device"]) == (4, "cpu") and cubes["path"].startswith("node arrays on cpu")
    assert cubes["tets"] == 4 * 135 and cubes["steps"] == 15
    assert cubes["max_penetration_m"] < 1e-3
    np.testing.assert_allclose(cubes["bottom_end_m"], 0.0, atol=1e-3)
    assert "4 cubes in one scene" in C.format_table(result)
