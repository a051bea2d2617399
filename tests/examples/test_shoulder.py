"""The shoulder demo (thesis ch. 5): the model pipeline on the procedural anatomy, and the
bundled shoulder.toml's scripted palpation through the haptic loop without penetration or explosion.

Truths: barycentric reconstruction of every embedded vertex; the independent crossing test for
the collision-free start; the contact solver's own end gaps bound the overlap (the issue's
1 mm); energies and forces stay finite and bounded by the coupling's reach (the hand never
gets more than k times the distance between hand and tool, the force limit clips the rest).
"""

import json

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.examples.shoulder_anatomy import write_shoulder_parts
from softvr.model import build_model, intersecting_triangle_pairs, load_model, read_parts


@pytest.fixture(scope="module")
def palpation_model(tmp_path_factory):
    folder = tmp_path_factory.mktemp("shoulder")
    return build_model(write_shoulder_parts(folder, "palpation"), progress=False), folder


def test_model_has_table_5_1s_structure_and_a_collision_free_start(palpation_model):
    model, _ = palpation_model
    kinds = {p.spec.name: p.spec.kind for p in model.parts}
    assert kinds["scapula"] == "fixed" and kinds["humerus"] == "kinematic"
    assert kinds["biceps_tendon"] == kinds["transverse_humeral"] == "rigid"
    assert sum(k == "soft" for k in kinds.values()) == 8  # 7 of Table 5.1 + the deltoid
    pairs = {frozenset((c.a, c.b)) for c, _ in model.couplings}
    for a, b in (("supraspinatus", "scapula"), ("supraspinatus", "humerus"), ("labrum", "scapula"),
                 ("labrum_tendon", "labrum"), ("biceps_tendon", "labrum_tendon"), ("transverse_humeral", "humerus")):
        assert frozenset((a, b)) in pairs
    # Every render and collision vertex of a soft part is bound to one tet that reproduces it.
    for part in model.parts:
        if not part.soft:
            continue
        for vertices, (index, weights) in ((part.render_vertices, part.render_embedding),
                                           (part.collision_vertices, part.collision_embedding)):
            assert index.shape == (len(vertices),) and (weights >= -1e-9).all()
            np.testing.assert_allclose(np.einsum("pk,pkc->pc", weights, part.rest_nodes[part.tets[index]]), vertices,
                                       atol=1e-12)
    # Parts that may collide start apart (the independent crossing test agrees with the report).
    coupled = {frozenset((c.a, c.b)) for c, _ in model.couplings if not c.collide}
    assert model.crossings == {}
    for i, a in enumerate(model.parts):
        for b in model.parts[i + 1:]:
            if frozenset((a.spec.name, b.spec.name)) in coupled:
                continue
            assert len(intersecting_triangle_pairs(a.collision_now(), a.collision_triangles, b.collision_now(),
                                                   b.collision_triangles)) == 0, (a.spec.name, b.spec.name)


def test_build_model_command_writes_a_model_that_loads_back(palpation_model, tmp_path, capsys):
    from softvr.cli import main

    _, folder = palpation_model
    out = tmp_path / "shoulder.model.npz"
    assert main(["build-model", str(folder / "shoulder_palpation.toml"), "-o", str(out), "--quiet"]) == 0
    assert "collision-free start: no crossing triangles" in capsys.readouterr().out
    model = load_model(out)
    again = build_model(folder / "shoulder_palpation.toml", progress=False)
    assert [p.spec.name for p in model.parts] == [p.spec.name for p in again.parts]
    for p, q in zip(model.parts, again.parts):
        np.testing.assert_array_equal(p.collision_triangles, q.collision_triangles)
        if p.soft:
            np.testing.assert_allclose(p.start_nodes, q.start_nodes)
    assert sum(len(s) for _, s in model.couplings) == sum(len(s) for _, s in again.couplings)


def test_bad_parts_files_report_every_problem_at_once(tmp_path):
    (tmp_path / "ok.ply").write_text("not a mesh")
    parts = tmp_path / "parts.toml"
    parts.write_text('format = "softvr-parts 1"\n'
                     '[[part]]\nname = "bone"\nmesh = "missing.ply"\nkind = "rigid"\n'
                     '[[part]]\nname = "muscle"\nmesh = "ok.ply"\nkind = "squishy"\nyoung = -5.0\n'
                     '[[coupling]]\na = "muscle"\nb = "tendon"\nstiffness = 100.0\nradius = 0.01\n')
    with pytest.raises(InputError) as info:
        read_parts(parts)
    message = str(info.value)
    for fragment in ("parts.toml", "part[0].mesh", "missing.ply", "part[1].kind", "squishy", "part[1].young",
                     "coupling[0].b", "found tendon"):
        assert fragment in message
    with pytest.raises(InputError, match="no such file"):
        read_parts(tmp_path / "nope.toml")


def test_palpation_scene_plays_its_whole_path_without_penetration_or_explosion(capsys):
    """shoulder.toml played over its whole scripted path (12 s: the approach, six 2 s presses
    sliding along the 6 s and 9 s sweeps), the haptic process rendering at 1 kHz. (The Python
    twin's 60 s run repeated that path five times; the scene's keys end at 12 s, after which the
    handle holds, and one pass is a fifth of the time.)"""
    from softvr.cli import main
    from softvr.scene import BUNDLED, load_scene

    assert main(["check", "shoulder.toml"]) == 0
    assert "12 model parts (8 soft)" in capsys.readouterr().out
    with load_scene(BUNDLED / "shoulder.toml", width=64, height=48) as player:
        tool = player.tools[0]
        forces, overlap = [], []
        while player.frame < player.frames:
            player.step()
            forces.append(float(np.linalg.norm(tool.force())))
            # The contact solver's own end gaps (the scene has no plane for the drawn-vertex measure).
            gaps = [g.min() for g in player.scene.last_solution.gaps_after if len(g)]
            overlap.append(max(0.0, -min(gaps, default=0.0)))
        stats = tool.loop.period_stats()
        m = player.metrics
        forces = np.array(forces)
        summary = (f"overlap {max(overlap):.3g} m, kinetic energy max "
                   f"{max(r['kinetic_energy_j'] for r in m):.3g} J, hand force max {forces.max():.3g} N, haptic {stats}")
        assert m[-1]["sim_time_s"] == pytest.approx(12.0)
        assert max(overlap) < 1e-3 and max(len(g) for g in player.scene.last_solution.gaps_after) > 0, summary
        assert all(np.isfinite(r["energy_j"]) and np.isfinite(r["kinetic_energy_j"]) for r in m), summary
        assert max(r["kinetic_energy_j"] for r in m) < 0.05, summary  # palpation is slow: no explosion
        # The hand never gets more than the device's force limit, and it felt the tissue.
        assert forces.max() <= tool.loop.max_force and forces.max() > 0.3, summary
        assert stats["count"] > 1000 and stats["p50_ms"] == pytest.approx(1.0, abs=0.1), summary
        for body in player.bodies.values():
            assert np.isfinite(getattr(body, "q", getattr(body, "position", None))).all()
        json.dumps(m)  # the metrics are valid JSON (no inf / NaN)


def test_arthroscopy_variant_runs_and_writes_its_files(tmp_path, capsys):
    from softvr.cli import main

    assert main(["demo", "shoulder", "--variant", "arthroscopy", "--frames", "3", "--size", "32", "24", "--out",
                 str(tmp_path), "--quiet", "--no-haptics"]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["shoulder-arthroscopy.mp4", "shoulder-arthroscopy_metrics.json", "shoulder-arthroscopy_sheet.png"]
    doc = json.loads((tmp_path / "shoulder-arthroscopy_metrics.json").read_text())
    assert doc["body_types"]["probe"] == "tool" and len(doc["frames"]) == 3
    assert doc["summary"]["max_penetration_m"] < 1e-3
