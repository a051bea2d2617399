"""Documentation runs: module docstring examples (doctest) and the README's Python block."""

import doctest
import importlib
import re
from pathlib import Path

import pytest

MODULES = [
    "softvr.volume",
    "softvr.volume.rasterize",
    "softvr.volume.tetmesh",
    "softvr.volume._volume",
    "softvr.render",
    "softvr.render.volume_render",
    "softvr.render.camera",
    "softvr.render.contact_sheet",
    "softvr.sim._scene",
    "softvr.dynamics.cloth",
    "softvr.render.surfaces",
    "softvr.haptics",
    "softvr.dynamics.couplings",
    "softvr.cave.tracking",
    "softvr.cave.rig",
    "softvr.volume.incremental",
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0


DOCS = ["README.md", "docs/volume.md", "docs/adhesion.md", "docs/anatomy.md", "docs/cave.md", "docs/palpation.md",
        "docs/scenes.md"]


@pytest.mark.parametrize("doc", DOCS)
def test_python_blocks_in_docs_run(doc, tmp_path, monkeypatch, capsys):
    text = (Path(__file__).parents[1] / doc).read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, f"{doc} shows how to use softvr from Python"
    monkeypatch.chdir(tmp_path)  # blocks may write files
    for block in blocks:
        exec(compile(block, doc, "exec"), {})
    assert capsys.readouterr().out
