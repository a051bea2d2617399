"""One convention for every ``softvr`` subcommand (issue 20, "CLI").

Truths, written down here and not read from softvr: every subcommand's ``--help`` exits 0 with a
usage line that names the command as typed (``softvr run soft-cube``, never ``python -m``); the
commands that run kernels (run, view, demo, bench, cave) take ``--device cpu|cuda``; ``--out DIR``
puts a run's files into DIR, named after the scene as the command line spells it, and without it
they go to ``softvr-out/NAME/``; ``softvr --version`` prints the installed distribution's version
(importlib.metadata); a bundled scene is found by its name with or without ``.toml`` and by its
path, and a path that is no scene file is named as the user wrote it.
"""

import logging
import subprocess
import sys
from importlib.metadata import version

import pytest

from softvr import cli
from softvr.cli import main

#: Every subcommand and nested command with a --help of its own (as typed after ``softvr``).
HELPS = [
    ["demo"], ["demo", "volume"], ["demo", "shoulder"], ["demo", "palpation"],
    ["run"], *[["run", name] for name in ("soft-cube", "box-stack", "cloth-sphere", "oranges", "candy", "cloth-wall",
                                          "lips", "probe", "shoulder")],
    ["run", "soft-cube.toml"], ["view", "soft-cube"], ["view", "soft-cube.toml"], ["view", "volume"],
    ["view", "palpation"],
    ["bench"], *[["bench", area] for area in ("volume", "contact", "adhesion", "shoulder", "cave", "palpation",
                                              "scene")],
    ["cave"], *[["cave", c] for c in ("preview", "master", "node", "local", "keys")],
    ["check"], ["build-model"], ["tetmesh"], ["blender-addon"], ["info"],
]

#: Commands that run kernels, each of which must offer --device.
DEVICE = [["run", "soft-cube"], ["run", "soft-cube.toml"], ["view", "soft-cube"], ["view", "soft-cube.toml"],
          ["demo", "volume"], ["demo", "shoulder"], ["demo", "palpation"], ["bench", "volume"],
          ["bench", "palpation"], ["cave", "preview"], ["cave", "master"], ["cave", "local"]]


def _help(words, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        code = main([*words, "--help"])
        raise SystemExit(code)
    captured = capsys.readouterr()
    assert exc.value.code in (0, None), (words, captured.err[-500:])
    assert "Traceback" not in captured.err + captured.out
    return captured.out


@pytest.mark.parametrize("words", HELPS, ids=" ".join)
def test_every_help_exits_0_and_names_the_command_as_typed(words, capsys):
    out = _help(words, capsys)
    assert "usage: softvr" in out and "python -m" not in out, out[:300]
    if words[0] == "run" and len(words) == 2 and not words[1].endswith(".toml"):
        assert f"usage: softvr run {words[1]}" in out


def test_the_top_level_and_listing_helps_list_what_exists(capsys):
    assert main(["--help"]) == 0
    top = capsys.readouterr().out
    assert all(c in top for c in ("demo", "run", "view", "bench", "cave", "check", "build-model", "--version"))
    assert all(d in _help(["demo"], capsys) for d in ("volume", "shoulder", "palpation"))
    bench = _help(["bench"], capsys)
    assert all(a in bench for a in ("volume", "contact", "adhesion", "shoulder", "cave", "palpation", "scene"))


@pytest.mark.parametrize("words", DEVICE, ids=" ".join)
def test_commands_that_run_kernels_take_a_device(words, capsys):
    out = _help(words, capsys)
    assert "--device" in out and "cpu" in out and "cuda" in out


def test_version_is_the_installed_distributions():
    proc = subprocess.run([sys.executable, "-m", "softvr", "--version"], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.strip() == f"softvr {version('softvr')}"


def test_help_loads_neither_warp_nor_numpy():
    """``softvr --help`` answers before the physics stack is imported (no Warp start-up)."""
    code = ("import contextlib, io, sys\nimport softvr.cli\nwith contextlib.redirect_stdout(io.StringIO()):\n"
            "    softvr.cli.main(['--help'])\nprint(sorted(m for m in ('warp', 'numpy', 'vtk') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.strip() == "[]", proc.stdout + proc.stderr


def test_a_cuda_device_where_none_is_present_is_named(capsys):
    import warp as wp

    if wp.is_cuda_available():
        pytest.skip("a CUDA device is present")
    assert main(["run", "box-stack", "--frames", "1", "--device", "cuda", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "device" in err and "cpu" in err and "Traceback" not in err
    assert main(["bench", "scene", "--device", "cuda"]) != 0  # physics benches: cpu only, said so
    assert "--device" in capsys.readouterr().err


def test_out_and_the_one_naming_rule(tmp_path, monkeypatch):
    """A demo and its scene file, options before or after the scene, write the same file names;
    without --out, into softvr-out/NAME/."""
    small = ["--frames", "1", "--size", "32", "24", "--quiet"]
    assert main(["run", "box-stack", *small, "--out", str(tmp_path / "demo")]) == 0
    assert main(["run", *small, "--out", str(tmp_path / "file"), "box-stack.toml"]) == 0
    names = ["box-stack.mp4", "box-stack_metrics.json", "box-stack_sheet.png"]
    assert sorted(p.name for p in (tmp_path / "demo").iterdir()) == names
    assert sorted(p.name for p in (tmp_path / "file").iterdir()) == names
    monkeypatch.chdir(tmp_path)
    assert main(["run", "box-stack.toml", *small]) == 0
    assert sorted(p.name for p in (tmp_path / "softvr-out" / "box-stack").iterdir()) == names


def test_a_bundled_scene_by_name_and_by_path(capsys):
    from softvr.scene import BUNDLED

    outs = []
    for word in ("soft-cube", "soft-cube.toml", str(BUNDLED / "soft-cube.toml")):
        assert main(["check", word]) == 0, word
        outs.append(capsys.readouterr().out.split(":")[0])
    assert len(set(outs)) == 1 and outs[0].endswith("soft-cube.toml")


@pytest.mark.parametrize("word, what", [(".", "'.' (a folder)"), ("nosuch.toml", "'nosuch.toml' (no such file)"),
                                        ("some/where/else.toml", "'some/where/else.toml' (no such file)")])
def test_a_path_that_is_no_scene_is_named_as_written(word, what, capsys):
    assert main(["check", word]) == 2
    err = capsys.readouterr().err
    assert what in err and "scenes/" not in err and "Traceback" not in err


def test_a_bundled_parts_file_by_name_unless_one_is_here(tmp_path, monkeypatch):
    """docs/anatomy.md's ``softvr build-model shoulder_palpation.toml``: the bundled parts file,
    unless the user has a file of that name here."""
    from softvr import cli

    monkeypatch.chdir(tmp_path)
    assert cli._bundled_file("shoulder_palpation.toml").endswith("scenes/shoulder/shoulder_palpation.toml")
    (tmp_path / "shoulder_palpation.toml").write_text("")
    assert cli._bundled_file("shoulder_palpation.toml") == "shoulder_palpation.toml"
    assert cli._bundled_file("nosuch.toml") == "nosuch.toml"


def test_an_unknown_demo_names_the_demos(capsys):
    assert main(["demo", "teapot"]) == 2
    err = capsys.readouterr().err
    assert "'teapot'" in err and all(d in err for d in ("volume", "shoulder", "palpation"))


def test_a_bundled_scene_without_a_demo_twin_runs_by_name(tmp_path):
    """candy-adhesive exists only as a scene file: ``softvr run candy-adhesive`` finds it."""
    small = ["--frames", "1", "--size", "32", "24", "--quiet"]
    assert main(["run", "candy-adhesive", *small, "--out", str(tmp_path)]) == 0
    assert (tmp_path / "candy-adhesive.mp4").is_file()


def test_verbose_shows_softvr_info_lines_on_stderr(monkeypatch, capsys):
    """``softvr --verbose CMD`` shows what softvr's loggers say at INFO; without it nothing; and the
    option belongs to softvr, not to the command (which never sees it)."""
    seen = []

    def command(argv):
        seen.append(argv)
        logging.getLogger("softvr.some.module").info("a line at INFO")
        return 0

    monkeypatch.setitem(cli._COMMANDS, "check", command)
    monkeypatch.setattr(logging.getLogger("softvr"), "level", logging.NOTSET)  # restored after the test
    monkeypatch.setattr(logging.getLogger("softvr"), "handlers", [])
    assert main(["check", "x.toml"]) == 0
    assert "a line at INFO" not in capsys.readouterr().err
    assert main(["--verbose", "check", "x.toml"]) == 0 and main(["-v", "check", "y.toml"]) == 0
    err = capsys.readouterr().err
    assert err.count("softvr.some.module: INFO: a line at INFO") == 2, err  # one handler, however often
    assert seen == [["x.toml"], ["x.toml"], ["y.toml"]]
    assert main(["--help"]) == 0
    assert "--verbose" in capsys.readouterr().out


def test_verbose_shows_the_missing_cuda_driver_in_one_line():
    from softvr.device import cuda_driver_present

    if cuda_driver_present():
        pytest.skip("a CUDA driver is present: nothing to say about its absence")
    # --device cuda is refused after Warp starts: a command that gets that far and stops (no physics).
    words = ["run", "soft-cube", "--device", "cuda"]
    quiet = subprocess.run([sys.executable, "-m", "softvr", *words], capture_output=True, text=True)
    verbose = subprocess.run([sys.executable, "-m", "softvr", "--verbose", *words], capture_output=True, text=True)
    assert quiet.returncode == verbose.returncode == 2, verbose.stderr
    assert "CUDA driver" not in quiet.stderr, quiet.stderr
    lines = [line for line in verbose.stderr.splitlines() if "CUDA driver" in line]
    assert lines == ["softvr.device: INFO: no NVIDIA CUDA driver found: Warp runs on the CPU only"], verbose.stderr
