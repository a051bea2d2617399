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
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0


def test_readme_python_block_runs(capsys):
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    assert blocks, "the README shows how to use softvr from Python"
    for block in blocks:
        exec(compile(block, "README.md", "exec"), {})
    assert "(" in capsys.readouterr().out
