"""Fuzz suite (issue 17): seeded mutants of scene TOML, glTF, display, parts and mesh files
through the readers and the commands that read them (``softvr check``, ``cave preview``,
``build-model``). Every input must be read or refused with a softvr InputError that names the
file and the field: no traceback, no ``sys.exit``, no crash, no hang, no allocation that
pushes a reader past the memory limit (harness.RSS_LIMIT). The volume readers have their
own suite (test_fuzz_volumes.py).

Reproduce one input: the corpus is a function of SEED; a failure lists the file, and
``harness.run_reader(target, [path])`` runs it alone.
"""

from __future__ import annotations

import json
import os
import random
import shutil
from pathlib import Path

import meshio
import numpy as np
import pytest
import trimesh
from harness import RSS_LIMIT, run_cli, run_reader, summary
from mutate import MILD, byte_mutants, field_mutants, glb_bytes, gltf_seed, load_toml, mutate_tree, toml_text

SEED = 17
SCENES = Path(__file__).resolve().parents[2] / "src" / "softvr" / "scenes"
#: Scenes mutated for the readers (all bundled TOML scenes but the volume-heavy ones) and the
#: few small ones built by ``softvr check`` (a build takes ~0.1 s).
READ_SCENES = ("soft-cube", "box-stack", "cloth-wall", "cloth-sphere", "oranges", "candy", "probe", "lips",
               "shoulder", "volume", "candy-adhesive")
BUILD_SCENES = ("soft-cube", "box-stack", "cloth-wall", "probe")
#: File names a mutant may point at: FIFOs (reading one blocks forever), a symlink to a device.
SPECIAL = ("fifo.obj", "fifo.toml", "fifo.bin", "fifo.vtu")


def _folder(root: Path, name: str) -> Path:
    folder = root / name
    folder.mkdir()
    for special in SPECIAL:
        os.mkfifo(folder / special)
    (folder / "zero.toml").symlink_to("/dev/zero")
    return folder


def _toml_mutants(seeds: list, folder: Path, rng: random.Random, n: int, prefix: str, *,
                  mild: bool = False) -> list[str]:
    """``n`` mutants of the TOML ``seeds``: a quarter byte-level, the rest 1-3 hostile values;
    ``mild``: one value each, of the right type at the edge of its range (to be built)."""
    paths = []
    for i in range(n):
        seed = rng.choice(seeds)
        if mild:
            data = toml_text(mutate_tree(load_toml(seed), rng, pool=MILD)).encode()
        elif rng.random() < 0.25:
            data = byte_mutants(Path(seed).read_bytes(), rng, 1)[0]
        else:
            data = toml_text(mutate_tree(load_toml(seed), rng, count=rng.choice([1, 1, 2, 3]))).encode()
        path = folder / f"{prefix}{i:04d}.toml"
        path.write_bytes(data)
        paths.append(str(path))
    return paths


def _field_mutants(seeds: list, folder: Path, rng: random.Random, per_field: int, prefix: str,
                   pool=None) -> list[str]:
    """Every field of the TOML ``seeds`` set to ``per_field`` hostile values (``pool``: see
    mutate.field_mutants)."""
    paths = []
    for i, tree in enumerate(field_mutants([load_toml(s) for s in seeds], rng, per_field, pool)):
        path = folder / f"{prefix}{i:04d}.toml"
        path.write_text(toml_text(tree))
        paths.append(str(path))
    return paths


def _check(outcomes, paths, what: str) -> dict:
    report = summary(outcomes, paths)
    peak = max(o.rss_bytes for o in outcomes)
    print(f"\nfuzz {what}: {report['inputs']} inputs, {report['counts']}, peak RSS {peak >> 20} MiB, "
          f"{report['seconds']:.1f} s in readers")
    assert report["n_bad"] == 0, report["bad"]
    assert report["n_unnamed"] == 0, report["unnamed"]
    assert peak <= RSS_LIMIT
    return report


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def test_scene_toml_mutants_are_read_or_refused_naming_file_and_field(root):
    folder = _folder(root, "scenes")
    shutil.copytree(SCENES / "lips", folder / "lips")
    shutil.copytree(SCENES / "shoulder", folder / "shoulder")
    rng = random.Random(SEED)
    paths = _toml_mutants([SCENES / f"{n}.toml" for n in READ_SCENES], folder, rng, 600, "s")
    paths += _field_mutants(sorted(SCENES.glob("*.toml")), folder, rng, 6, "f")
    paths += [str(folder / "zero.toml"), str(folder / "fifo.toml")]
    outcomes = run_reader("softvr.scene.schema:read_scene", paths)
    report = _check(outcomes, paths, "scene TOML (read_scene)")
    assert report["counts"].get("ok", 0) >= 20  # the mutants are not all refused for one reason


def test_softvr_check_builds_or_refuses_scene_mutants(root):
    folder = _folder(root, "check")
    rng = random.Random(SEED + 1)
    paths = _toml_mutants([SCENES / f"{n}.toml" for n in BUILD_SCENES], folder, rng, 60, "c")
    seeds = [load_toml(SCENES / f"{n}.toml") for n in BUILD_SCENES]
    for i, tree in enumerate(field_mutants(seeds, rng, 3, pool=MILD)):  # every field at 3 edges of its range
        path = folder / f"m{i:04d}.toml"
        path.write_text(toml_text(tree))
        paths.append(str(path))
    outcomes = run_reader("softvr.scene.command:check_main", [[p] for p in paths], labels=paths)
    _check(outcomes, paths, "softvr check (scene TOML, built)")


def _gltf_mutants(folder: Path, rng: random.Random, n: int) -> list[str]:
    doc, binary = gltf_seed()
    (folder / "scene.bin").write_bytes(binary)
    external = json.loads(json.dumps(doc))
    external["buffers"][0]["uri"] = "scene.bin"
    extra = [{"softvr_type": "fem"}, {"softvr_type": 5}, "scene.bin", "fifo.bin", "%2e%2e/%2e%2e/etc/passwd",
             10 ** 12, -(2 ** 40), [[0, 1], [1, 0]]]
    paths = []
    for i in range(n):
        r = rng.random()
        if r < 0.45:
            data, ext = glb_bytes(mutate_tree(doc, rng, extra=extra, count=rng.choice([1, 1, 2])), binary), ".glb"
        elif r < 0.8:
            data, ext = json.dumps(mutate_tree(external, rng, extra=extra, count=rng.choice([1, 1, 2]))).encode(), ".gltf"
        elif r < 0.9:
            data, ext = byte_mutants(glb_bytes(doc, binary), rng, 1)[0], ".glb"
        else:
            data, ext = byte_mutants(json.dumps(external).encode(), rng, 1)[0], ".gltf"
        path = folder / f"g{i:04d}{ext}"
        path.write_bytes(data)
        paths.append(str(path))
    return paths


def test_gltf_mutants_are_read_or_refused_naming_file_and_field(root):
    folder = _folder(root, "gltf")
    rng = random.Random(SEED + 2)
    paths = _gltf_mutants(folder, rng, 400)
    doc, binary = gltf_seed()
    for i, tree in enumerate(field_mutants([doc], rng, 4)):  # every field of the document, 4 hostile values
        path = folder / f"f{i:04d}.glb"
        path.write_bytes(glb_bytes(tree, binary))
        paths.append(str(path))
    outcomes = run_reader("softvr.scene.gltf:read_gltf_scene", paths)
    report = _check(outcomes, paths, "glTF scenes (read_gltf_scene)")
    assert report["counts"].get("ok", 0) >= 20


def test_softvr_check_builds_or_refuses_gltf_mutants(root):
    folder = _folder(root, "gltf-check")
    rng = random.Random(SEED + 3)
    paths = _gltf_mutants(folder, rng, 60)
    doc, binary = gltf_seed()
    for i, tree in enumerate(field_mutants([doc], rng, 1, pool=MILD)):  # every field at an edge of its range
        path = folder / f"m{i:04d}.glb"
        path.write_bytes(glb_bytes(tree, binary))
        paths.append(str(path))
    outcomes = run_reader("softvr.scene.command:check_main", [[p] for p in paths], labels=paths)
    _check(outcomes, paths, "softvr check (glTF, built)")


def _display_seeds(folder: Path) -> list[Path]:
    from softvr.cave.display import PRESETS, save_display

    seeds = []
    for name, make in PRESETS.items():
        seeds.append(save_display(make(), folder / f"seed-{name}.toml"))
    return seeds


def test_display_mutants_are_read_or_refused_naming_file_and_field(root):
    folder = _folder(root, "display")
    rng = random.Random(SEED + 4)
    paths = _toml_mutants(_display_seeds(folder), folder, rng, 300, "d")
    paths += _field_mutants(_display_seeds(folder), folder, rng, 20, "f")
    outcomes = run_reader("softvr.cave.display:load_display", paths)
    _check(outcomes, paths, "display files (load_display)")


def test_cave_preview_renders_or_refuses_display_mutants(root):
    folder = _folder(root, "preview")
    rng = random.Random(SEED + 5)
    paths = _toml_mutants(_display_seeds(folder), folder, rng, 6, "p", mild=True)
    paths += _field_mutants([folder / "seed-single-wall.toml"], folder, rng, 2, "f", pool=MILD)
    out = folder / "out"
    argv = [["preview", p, "soft-cube", "--frames", "1", "--scale", "0.05", "--out", str(out)] for p in paths]
    outcomes = run_reader("softvr.cave.command:main", argv, labels=paths)
    # A screen whose plane holds the scripted viewer's eye is refused when it is rendered
    # (softvr.cave.rig.world_view), naming the file and the screen ("wall eye") like the rest.
    _check(outcomes, paths, "softvr cave preview (display files)")


def _parts_seed(folder: Path) -> Path:
    """A small parts file: a soft sphere coupled to a fixed box under it (~0.2 s to build)."""
    trimesh.creation.icosphere(2, radius=0.02).export(folder / "ball.ply")
    box = trimesh.creation.box((0.08, 0.08, 0.01))
    box.apply_translation((0.0, 0.0, -0.025))
    box.export(folder / "base.ply")
    seed = folder / "seed-parts.toml"
    seed.write_text('format = "softvr-parts 1"\n[defaults]\ncell_size = 0.01\ncollision_triangles = 80\n'
                    '[[part]]\nname = "ball"\nmesh = "ball.ply"\nkind = "soft"\nyoung = 3e4\ndensity = 1000.0\n'
                    '[[part]]\nname = "base"\nmesh = "base.ply"\nkind = "fixed"\n'
                    '[[coupling]]\na = "ball"\nb = "base"\nradius = 0.01\nstiffness = 100.0\n')
    return seed


def test_parts_mutants_are_read_or_refused_naming_file_and_field(root):
    folder = _folder(root, "parts")
    for mesh in (SCENES / "shoulder").glob("*.ply"):
        shutil.copy(mesh, folder / mesh.name)
    seeds = [SCENES / "shoulder" / "shoulder_palpation.toml", SCENES / "shoulder" / "shoulder_arthroscopy.toml",
             _parts_seed(folder)]
    rng = random.Random(SEED + 6)
    paths = _toml_mutants(seeds, folder, rng, 300, "p")
    paths += _field_mutants(seeds, folder, rng, 12, "f")
    outcomes = run_reader("softvr.model.parts:read_parts", paths)
    _check(outcomes, paths, "parts files (read_parts)")


def test_build_model_builds_or_refuses_parts_mutants(root):
    folder = _folder(root, "build")
    rng = random.Random(SEED + 7)
    paths = _toml_mutants([_parts_seed(folder)], folder, rng, 10, "b", mild=True)
    paths += _field_mutants([folder / "seed-parts.toml"], folder, rng, 2, "f", pool=MILD)
    outcomes = run_reader("targets:build_parts", paths)
    _check(outcomes, paths, "softvr build-model (parts files, built)")


def _count_edit(data: bytes, rng: random.Random) -> bytes:
    """One number of a file's first 3000 characters (a header's counts) made hostile."""
    text = data.decode("latin-1")
    spans = [(i, j) for i, j in _numbers(text[:3000])]
    if not spans:
        return data
    i, j = rng.choice(spans)
    value = rng.choice(["1000000000000000000", "-5", "4294967295", "99999999", "0", "1e308", "nan"])
    return (text[:i] + value + text[j:]).encode("latin-1")


def _numbers(text: str):
    i = 0
    while i < len(text):
        if text[i].isdigit():
            j = i
            while j < len(text) and text[j].isdigit():
                j += 1
            yield i, j
            i = j
        else:
            i += 1


def test_mesh_file_mutants_are_read_or_refused_naming_the_file(root):
    folder = _folder(root, "meshes")
    rng = random.Random(SEED + 8)
    sphere = trimesh.creation.icosphere(1, radius=0.05)
    seeds = {".obj": sphere.export(file_type="obj").encode(), ".stl": sphere.export(file_type="stl"),
             ".ply": sphere.export(file_type="ply"), ".off": sphere.export(file_type="off").encode(),
             ".glb": sphere.export(file_type="glb"), ".ply-ascii": sphere.export(file_type="ply", encoding="ascii"),
             ".stl-ascii": sphere.export(file_type="stl_ascii").encode()}
    paths = []
    for i in range(500):
        kind = rng.choice(sorted(seeds))
        data = _count_edit(seeds[kind], rng) if rng.random() < 0.5 else byte_mutants(seeds[kind], rng, 1)[0]
        path = folder / f"m{i:04d}{kind.split('-')[0]}"
        path.write_bytes(data)
        paths.append(str(path))
    paths += [str(folder / "fifo.obj")]
    outcomes = run_reader("softvr.model.build:load_mesh", paths)
    _check(outcomes, paths, "surface meshes (load_mesh, trimesh)")


def test_tet_mesh_mutants_are_read_or_refused_naming_the_file(root):
    folder = _folder(root, "tets")
    rng = random.Random(SEED + 9)
    points = np.random.default_rng(SEED).random((12, 3))
    cells = [("tetra", np.array([[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]]))]
    seeds = {}
    for kind, options in ((".vtu", {"binary": False}), (".vtu-binary", {}), (".vtk", {"binary": False}),
                          (".msh", {"file_format": "gmsh22", "binary": False})):
        seed = folder / f"seed{kind.split('-')[0]}"
        meshio.write(seed, meshio.Mesh(points, cells), **options)
        seeds[kind] = seed.read_bytes()
    paths = []
    for i in range(250):
        kind = rng.choice(sorted(seeds))
        data = _count_edit(seeds[kind], rng) if rng.random() < 0.5 else byte_mutants(seeds[kind], rng, 1)[0]
        path = folder / f"t{i:04d}{kind.split('-')[0]}"
        path.write_bytes(data)
        paths.append(str(path))
    paths += [str(folder / "fifo.vtu")]
    outcomes = run_reader("targets:read_tets", paths)
    _check(outcomes, paths, "tet meshes (a scene's tets = FILE, meshio)")


def test_commands_refuse_the_issues_files_with_exit_2_naming_file_and_field(root):
    """The inputs issue 17 lists, through the real commands in their own processes: exit
    status 2, no traceback, the file and the field named."""
    folder = _folder(root, "cli")
    base = (SCENES / "soft-cube.toml").read_text()
    bad_vtu = folder / "bad.vtu"
    bad_vtu.write_text("<VTKFile>garbage")  # meshio calls sys.exit(1) on it
    cases = {
        "latin1.toml": ("check", base.replace("soft cube", "soft cub\xe9").encode("latin-1"), "UTF-8"),
        "deep.toml": ("check", (base + "x = " + "[" * 3000 + "]" * 3000 + "\n").encode(), "nested"),
        "huge.toml": ("check", base.replace("frames = 60", "frames = " + "9" * 5000).encode(), "TOML"),
        "cells.toml": ("check", base.replace("cells = 4", "cells = 4096").encode(), "cells"),
        "fifo-mesh.toml": ("check", base.replace('name = "soft cube"', 'name = "soft cube"\nmesh = "fifo.obj"')
                           .replace('box = [0.3, 0.3, 0.3]\n', "").encode(), "mesh"),
        "exit.toml": ("check", base.replace('box = [0.3, 0.3, 0.3]', 'tets = "bad.vtu"').encode(), "tets"),
        "zero.toml": ("check", None, "scene"),
        "fifo.toml": ("check", None, "scene"),
        "parts.toml": ("build-model", b'format = "softvr-parts 1"\n[[part]]\nname = "a"\nmesh = "fifo.obj"\n'
                       b'kind = "fixed"\n', "part[0].mesh"),
        "display.toml": ("cave preview", b'format = "softvr-display 1"\n[[screen]]\nname = "x"\n'
                         b'pixels = [16384, 16384]\nlower_left = [0, 0, 0]\nlower_right = [1, 0, 0]\n'
                         b'upper_left = [0, 0, 1]\n[[screen]]\nname = "y"\npixels = [16384, 16384]\n'
                         b'lower_left = [0, 0, 0]\nlower_right = [1, 0, 0]\nupper_left = [0, 0, 1]\n', "pixels"),
    }
    outcomes, paths = [], []
    for name, (command, data, field) in cases.items():
        path = folder / name
        if data is not None:
            path.write_bytes(data)
        args = [*command.split(), path] + (["soft-cube", "--out", str(folder / "out")] if "cave" in command else [])
        outcome = run_cli(args, label=name, timeout_s=60)
        outcomes.append(outcome)
        paths.append(path)
        assert outcome.kind == "clean", (name, outcome.kind, outcome.detail)
        assert field in outcome.detail, (name, outcome.detail)
    _check(outcomes, paths, "softvr check on the issue's files (subprocesses)")


def _model_mutants(folder: Path, rng: random.Random, n: int) -> list[str]:
    """Mutants of a built model (.npz): its JSON manifest mutated, an array replaced by one of
    another shape, dtype or range, the archive's bytes mutated, or an .npy header claiming
    more elements than its entry holds."""
    from softvr.model.build import build_model

    model = build_model(_parts_seed(folder), progress=False)
    seed = model.save(folder / "seed.model.npz")
    arrays = dict(np.load(seed))
    manifest = json.loads(str(arrays["manifest"]))
    odd = [np.zeros((0, 3)), np.full((4, 3), np.nan), np.arange(12).reshape(4, 3) * 10 ** 6, np.zeros((5, 4)),
           np.array([-1, 0, 1]), np.zeros(3, np.float16), np.array("text")]
    paths = []
    for i in range(n):
        path = folder / f"model{i:04d}.npz"
        kind = rng.randrange(4)
        if kind == 0:
            changed = {**arrays, "manifest": np.array(json.dumps(mutate_tree(manifest, rng, pool=MILD + [[], {}, "x"])))}
            np.savez(path, **changed)
        elif kind == 1:
            key = rng.choice(sorted(k for k in arrays if k != "manifest"))
            np.savez(path, **{**arrays, key: odd[rng.randrange(len(odd))]})
        elif kind == 2:
            path.write_bytes(byte_mutants(seed.read_bytes(), rng, 1)[0])
        else:
            np.savez(path, **arrays)  # stored, not deflated: the .npy headers are in the bytes
            data = path.read_bytes()
            at = data.find(b"'shape': (", rng.randrange(len(data) // 2))
            if at >= 0:
                start = at + len(b"'shape': (")
                end = data.index(b",", start)
                data = data[:start] + rng.choice([b"1000000000000", b"99999", b"0"]).ljust(end - start)[:max(
                    end - start, 1)] + data[end:]
            path.write_bytes(data)
        paths.append(str(path))
    return paths


def test_model_file_mutants_are_loaded_or_refused_naming_the_file(root):
    folder = _folder(root, "models")
    paths = _model_mutants(folder, random.Random(SEED + 10), 250)
    outcomes = run_reader("softvr.model.build:load_model", paths)
    _check(outcomes, paths, "built models (load_model, .npz)")
