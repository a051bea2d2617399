"""The import graph obeys DESIGN.md's layering: a module imports only its own package and the tiers
below it, private modules and names stay inside their package (``softvr.x``), and the lower layers
import softvr at module top.

The graph is read from the source (``ast``), so an import inside a function counts as much as one at
module top. Violations that files still being rewritten carry (issue 19) are listed in :data:`ALLOWED`;
an entry that no longer happens fails too, so the list shrinks as the rewrites land.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"

#: DESIGN.md's data flow read as an import order, lowest first. A package imports its own modules and any tier below its
#: own; packages in one tier are independent of each other. ``softvr`` is the package root (the
#: public API: ``softvr.Scene`` and the errors). The base is ``errors``, ``files`` (every file read,
#: TOML / JSON, atomic writes), ``device`` and ``geometry`` (tet-mesh checks); on it ``gltf`` (a
#: glTF file's structure, checked through ``files``, for the model's mesh reader and the scene
#: reader alike). Where DESIGN.md's drawing is ambiguous the code decides: ``model`` is above ``sim``
#: because the builder returns a ``softvr.Scene``; ``render`` is below ``app``, which draws through
#: it; ``app`` is below ``scene`` because the player takes built objects and never reads a scene
#: file, while ``softvr run`` reads one and hands it to the player; ``cave`` plays scenes on a
#: cluster, above both.
TIERS = (
    ("softvr.errors",),
    ("softvr.files", "softvr.device", "softvr.geometry"),
    ("softvr.gltf",),
    ("softvr.collision", "softvr.dynamics", "softvr.volume"),
    ("softvr.contact", "softvr.datasets"),
    ("softvr.sim",),
    ("softvr",),
    ("softvr.model", "softvr.render", "softvr.haptics"),
    ("softvr.app",),
    ("softvr.scene",),
    ("softvr.cave",),
    ("softvr.examples",),
    ("softvr.bench", "softvr.blender"),
    ("softvr.cli",),
    ("softvr.__main__",),
)

#: Layers whose modules import softvr at module top only: an import inside a function hides an
#: edge of the graph. Every layer but ``softvr.cli``, which imports each subcommand's layer when
#: it runs, so that ``softvr --help`` loads neither numpy nor Warp (tests/test_cli_conventions.py),
#: and ``softvr.__main__``, which only calls it.
TOP_LEVEL_ONLY = TIERS[: TIERS.index(("softvr.cli",))]

#: (importer, imported) -> why it is still there. Each is a violation in a file being rewritten.
ALLOWED: dict[tuple[str, str], str] = {}


def _layer_of(module: str) -> str:
    """The tier entry a module belongs to: its second-level package (``softvr.x``), or the root."""
    parts = module.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 else module


_RANK = {layer: rank for rank, tier in enumerate(TIERS) for layer in tier}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _exists(module: str) -> bool:
    base = SRC.joinpath(*module.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _imports(path: Path) -> list[tuple[str, int, bool]]:
    """``(imported softvr module, line, inside a function)`` for every softvr import of a file.
    ``from softvr.x import name`` imports ``softvr.x.name`` when that is a module or a private name
    (``_name``, checked like a private module), else ``softvr.x``."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    local = {id(node) for fn in ast.walk(tree) if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef))
             for node in ast.walk(fn) if isinstance(node, (ast.Import, ast.ImportFrom))}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module
            targets = [f"{source}.{a.name}" if _exists(f"{source}.{a.name}") or _private(a.name) else source
                       for a in node.names]
        else:
            continue
        for target in dict.fromkeys(targets):
            if target == "softvr" or target.startswith("softvr."):
                found.append((target, node.lineno, id(node) in local))
    return found


@functools.cache
def _graph() -> tuple[tuple[str, str, int, bool], ...]:
    """``(importer, imported, line, inside a function)`` for every softvr import in src/softvr."""
    return tuple((_module_name(path), target, line, local)
                 for path in sorted((SRC / "softvr").rglob("*.py"))
                 for target, line, local in _imports(path))


def _violations(graph) -> dict[tuple[str, str], str]:
    """(importer, imported) -> what is wrong, for each upward, sideways or private import."""
    found = {}
    for importer, target, line, _ in graph:
        here, there = _layer_of(importer), _layer_of(target)
        if here not in _RANK or there not in _RANK:
            continue  # test_every_package_has_a_layer names it
        if here != there and _RANK[there] >= _RANK[here]:
            how = "above" if _RANK[there] > _RANK[here] else "in the tier of"
            found[(importer, target)] = f"line {line}: {importer} imports {target}: {there} is {how} {here}"
        elif here != there and any(_private(part) for part in target.split(".")):
            found[(importer, target)] = f"line {line}: {importer} imports the private {target} from outside {there}"
    return found


def test_every_package_has_a_layer():
    """A new package is placed in TIERS (and DESIGN.md) before it is imported."""
    modules = {_module_name(path) for path in (SRC / "softvr").rglob("*.py")}
    missing = sorted({_layer_of(m) for m in modules} - set(_RANK))
    assert not missing, f"not in TIERS (tests/test_layering.py) nor DESIGN.md's layer order: {missing}"


def test_no_upward_sideways_or_private_import():
    found = _violations(_graph())
    new = [why for key, why in sorted(found.items()) if key not in ALLOWED]
    gone = [f"{a} -> {b}" for a, b in sorted(ALLOWED) if (a, b) not in found]
    assert not new and not gone, "\n".join(
        (["imports against DESIGN.md's layer order (tests/test_layering.py):", *new] if new else [])
        + (["allowed violations that no longer happen (delete them from ALLOWED):", *gone] if gone else []))


@pytest.mark.parametrize("key", sorted(ALLOWED))
def test_allowed_violations_name_their_issue(key):
    assert "issue 19" in ALLOWED[key], f"{key}: say why, and under which issue it goes"


def test_lower_layers_import_softvr_at_module_top():
    """Up to the runtime every softvr import is at module top, where the graph can be seen."""
    lower = {layer for tier in TOP_LEVEL_ONLY for layer in tier}
    inside = [f"{importer}:{line} imports {target} inside a function"
              for importer, target, line, local in _graph() if local and _layer_of(importer) in lower]
    assert not inside, "\n".join(inside)
