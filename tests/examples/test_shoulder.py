"""The shoulder demo (thesis ch. 5): the model pipeline on the procedural anatomy, and 60 s of
scripted palpation through the haptic loop without penetration or explosion.

Truths: barycentric reconstruction of every embedded vertex; the independent crossing test for
the collision-free start; the contact solver's own end gaps bound the overlap (the issue's
1 mm); energies and forces stay finite and bounded by the coupling's reach (the hand never
gets more than k times the distance between hand and tool, the force limit clips the rest).
"""

import json

import numpy as np
import pytest

from softvr.errors import InputError
from softvr.examples import example_shoulder
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


def test_palpation_runs_60_seconds_without_penetration_or_explosion(tmp_path):
    """The issue's run: 60 s of scripted palpation, the haptic thread rendering at 1 kHz."""
    ex = example_shoulder.Example(frames=1500, width=64, height=48, dt=0.02, steps_per_frame=2)
    try:
        while ex.frame < ex.frames:
            ex.step()
        stats = ex.loop.period_stats()
    finally:
        ex.close()
    m = ex.metrics
    forces = np.array([r["hand_force_n"] for r in m])
    summary = (f"penetration {max(r['max_penetration_m'] for r in m):.3g} m, kinetic energy max "
               f"{max(r['kinetic_energy_j'] for r in m):.3g} J, hand force max {forces.max():.3g} N, haptic {stats}")
    assert m[-1]["sim_time_s"] == pytest.approx(60.0)
    assert max(r["max_penetration_m"] for r in m) < 1e-3, summary
    assert all(np.isfinite(r["energy_j"]) and np.isfinite(r["kinetic_energy_j"]) for r in m), summary
    assert max(r["kinetic_energy_j"] for r in m) < 0.05, summary  # palpation is slow: no explosion
    assert forces.max() <= ex.loop.max_force and forces.max() > 0.3, summary  # the hand felt the tissue
    assert stats["count"] > 1000 and stats["p50_ms"] == pytest.approx(1.0, abs=0.1), summary
    for body in ex.bodies.values():
        assert np.isfinite(getattr(body, "q", getattr(body, "position", None))).all()
    json.dumps(m)  # the metrics are valid JSON (no inf / NaN)


def test_arthroscopy_variant_runs_and_main_writes_its_files(tmp_path):
    assert example_shoulder.main(["--variant", "arthroscopy", "--frames", "3", "--size", "32", "24", "--out",
                                  str(tmp_path), "--quiet", "--no-haptics"]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["shoulder.mp4", "shoulder_force.png", "shoulder_metrics.json", "shoulder_sheet.png"]
    doc = json.loads((tmp_path / "shoulder_metrics.json").read_text())
    assert doc["variant"] == "arthroscopy" and doc["soft_parts"] == 7 and doc["coupling_islands"] >= 5
