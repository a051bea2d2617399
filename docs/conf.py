"""Sphinx configuration of softvr's docs site.

Build (warnings are errors): ``bash scripts/setup.sh docs``, or
``.venv/bin/sphinx-build -W --keep-going -b html docs docs/_build/html``.

Two kinds of pages are written here at build time (git-ignored, never edited by hand):

* ``docs/cli.md``: every ``softvr`` subcommand's ``--help``;
* ``docs/api/*.rst``: one page per public softvr module, listing exactly the names in its
  ``__all__`` (so the reference is the code's public surface, nothing more);
* ``docs/gallery/*.md``: one page per demo from ``docs/gallery/manifest.json``, which
  ``scripts/gallery.py`` writes while it runs the demos. An image whose SHA-256 is not the
  manifest's, or a demo of the script without an entry, stops the build: every gallery image is
  one the script produced by running its demo.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import json
import os
import pkgutil
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from importlib import metadata
from pathlib import Path

from sphinx.errors import ConfigError

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT / "src"))  # a clean clone builds without installing softvr first
sys.path.insert(0, str(ROOT / "scripts"))

project = "softvr"
author = "the softvr developers"
copyright = "2026, the softvr developers"
try:
    release = metadata.version("softvr")
except metadata.PackageNotFoundError:
    release = "0+unknown"
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
root_doc = "index"

# The docstrings are numpydoc-style; napoleon reads them without numpydoc's stricter checks.
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
# Parameter types as plain text (numpydoc types such as "(N, 3) float array" are prose, not names to
# cross-reference: as references, words like "shape" match several attributes and warn).
napoleon_use_param = False
# "Attributes" sections as fields of the class, not attribute directives that clash with autodoc's members.
napoleon_use_ivar = True
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": True}

myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

html_theme = "furo"
html_title = f"softvr {release}"
# The gallery's sheets and MP4s, at _static/NAME.png and _static/NAME.mp4 (the index's thumbnail grid is
# HTML, whose images Sphinx would not copy otherwise).
html_static_path = ["gallery/img", "gallery/clips"]

# Warnings excluded on purpose, each with why (everything else fails the -W build).
suppress_warnings = [
    # "more than one target found for cross-reference 'shape'": numpydoc parameter types are prose
    # ("ndarray, shape [N, 3]"), and Sphinx looks each word up as a class; a word that names attributes
    # of several classes (shape, block_size) is ambiguous. Harmless: the text is shown either way.
    "ref.python",
]

# ---------------------------------------------------------------------------------------------
# API reference from __all__

#: public modules that have no Python API of their own (command-line entry points). ``softvr.cli``'s only
#: name is ``main``, the ``softvr`` command; its module docstring is usage text that is not reStructuredText
#: (indented lines without ``::``), left as is while cli.py is rewritten (issue 19/16 in progress).
NO_API = {"bench", "cli", "examples", "__main__"}


def public_modules() -> list[str]:
    import softvr

    names = ["softvr"]
    for info in sorted(pkgutil.iter_modules(softvr.__path__), key=lambda m: m.name):
        if not info.name.startswith("_") and info.name not in NO_API:
            names.append(f"softvr.{info.name}")
    return names


def _is_code(obj) -> bool:
    return inspect.isclass(obj) or inspect.isfunction(obj) or inspect.isbuiltin(obj) or hasattr(obj, "__wrapped__")


def _exports() -> dict[str, list[str]]:
    exports = {}
    for modname in public_modules():
        module = importlib.import_module(modname)  # an import error here is a broken package: fail
        exports[modname] = [n for n in getattr(module, "__all__", []) if n != "__version__"]
    return exports


def _owners(exports: dict[str, list[str]]) -> dict[int, str]:
    """Class or function (by id) -> the one module page that documents it in full.

    A name re-exported by several modules (``softvr.Scene`` is ``softvr.sim.Scene``) is described
    once, on the deepest module's page, and linked from the others: two descriptions of one object
    are a duplicate-description warning.
    """
    owners: dict[int, tuple[str, int]] = {}
    for modname, names in exports.items():
        module = importlib.import_module(modname)
        depth = modname.count(".")
        for n in names:
            obj = getattr(module, n)
            if _is_code(obj) and (id(obj) not in owners or depth > owners[id(obj)][1]):
                owners[id(obj)] = (f"{modname}.{n}", depth)
    return {key: full for key, (full, _) in owners.items()}


def _summary(obj) -> str:
    """The first sentence of ``obj``'s docstring, for the module page's table.

    Split by hand rather than by autosummary, whose split at ". " also cuts inside literals
    (````0 .. limit````, ````n . x````) and leaves broken markup.
    """
    para = " ".join((inspect.getdoc(obj) or "").split("\n\n")[0].split())
    out = ""
    for piece in re.split(r"(``.+?``)", para):  # odd pieces are literals
        end = -1 if piece.startswith("``") else (piece + " ").find(". ")
        if end >= 0:
            return out + piece[: end + 1]
        out += piece
    return out


def write_api_pages() -> None:
    out = DOCS / "api"
    out.mkdir(exist_ok=True)
    exports = _exports()
    owners = _owners(exports)
    for stale in out.glob("*.rst"):  # a module that left the public API leaves no orphan page
        if stale.stem != "index" and stale.stem not in exports:
            stale.unlink()
    pages, skipped = [], []
    for modname, names in exports.items():
        if not names:
            skipped.append(modname)
            continue
        module = importlib.import_module(modname)
        title = f"``{modname}``"
        lines = [title, "=" * len(title), "", f".. automodule:: {modname}", "   :no-members:", "",
                 ".. list-table::", "   :widths: 30 70", ""]
        body = []
        for n in names:
            obj = getattr(module, n)
            full = f"{modname}.{n}"
            target = owners.get(id(obj), full) if _is_code(obj) else full
            lines += [f"   * - :py:obj:`{n} <{target}>`", f"     - {_summary(obj) if _is_code(obj) else ''}"]
            if not _is_code(obj):
                body.append(f".. autodata:: {full}\n   :no-value:\n")
            elif target == full:  # else described on its owner's page, which the table links to
                kind = "autoclass" if inspect.isclass(obj) else "autofunction"
                body.append(f".. {kind}:: {full}\n")
        lines.append("")
        _write_if_changed(out / f"{modname}.rst", "\n".join(lines + body))
        pages.append(modname)
    index = ["API reference", "=============", "",
             "One page per public module, listing the names in its ``__all__``.", ""]
    if skipped:
        index += ["Modules without a public API of their own: "
                  + ", ".join(f"``{m}``" for m in sorted(skipped)) + ".", ""]
    index += [".. toctree::", "   :maxdepth: 1", ""] + [f"   {m}" for m in pages] + [""]
    _write_if_changed(out / "index.rst", "\n".join(index))


# ---------------------------------------------------------------------------------------------
# Gallery from scripts/gallery.py's manifest

def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_gallery_pages() -> None:
    from gallery import GALLERY  # scripts/gallery.py: the demos the gallery must show

    gdir = DOCS / "gallery"
    manifest_path = gdir / "manifest.json"
    if not manifest_path.exists():
        raise ConfigError(f"{manifest_path} is missing: run `.venv/bin/python scripts/gallery.py` first")
    entries = json.loads(manifest_path.read_text())["entries"]
    missing = [n for n in GALLERY if n not in entries]
    if missing:
        raise ConfigError(f"gallery: no image for {', '.join(missing)}: run scripts/gallery.py {' '.join(missing)}")
    for name in GALLERY:
        e = entries[name]
        for key in ("image", "clip"):
            if key not in e:
                continue
            path = gdir / e[key]
            if not path.exists() or _sha256(path) != e[f"{key}_sha256"]:
                raise ConfigError(f"gallery: {path} is not the file scripts/gallery.py made for {name}: "
                                  f"run scripts/gallery.py {name}")
    cards = ["# Gallery", "",
             "Every demo scene bundled with softvr, run for a few frames by `scripts/gallery.py` "
             "(`softvr run SCENE.toml --frames N`); each image is the contact sheet that run wrote.", "",
             "```{toctree}", ":hidden:", ""] + list(GALLERY) + ["```", ""]
    grid = ['<div style="display: flex; flex-wrap: wrap; gap: 12px;">']
    for name in GALLERY:
        grid += [f'<a href="{name}.html" style="width: 31%; text-align: center;">'
                 f'<img src="../_static/{name}.png" alt="{name}" style="width: 100%;"><br>{name}</a>']
    cards += ["```{raw} html", *grid, "</div>", "```", ""]
    for name in GALLERY:
        e = entries[name]
        page = [f"# {name}", "", e["description"], "", f"```{{image}} {e['image']}", f":alt: {name} contact sheet",
                "```", ""]
        if "clip" in e:
            clip = Path(e["clip"]).name
            page += ["```{raw} html", f'<video controls loop muted width="640" src="../_static/{clip}"></video>',
                     "```", ""]
        page += ["Made by running:", "", "```sh", e["command"], "```", "",
                 f"({e['frames']} frames, {e['seconds']} s, softvr {e['softvr']} at commit `{e['commit']}`; "
                 f"the scene file is `src/softvr/scenes/{e['scene']}`, its full run is "
                 f"`softvr run {e['scene']}`.)", ""]
        _write_if_changed(gdir / f"{name}.md", "\n".join(page))
    _write_if_changed(gdir / "index.md", "\n".join(cards))


# ---------------------------------------------------------------------------------------------
# Command-line reference from the command's own --help

def _help(args: list[str]) -> str:
    # The installed command's text as a user sees it (not parsed from cli.py, which may change shape).
    path = os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")]))  # this tree's softvr
    proc = subprocess.run([sys.executable, "-m", "softvr", *args, "--help"], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "COLUMNS": "100", "PYTHONPATH": path})
    return (proc.stdout or proc.stderr).rstrip()


def write_cli_page() -> None:
    top = _help([])
    found = re.search(r"\{([a-z0-9,-]+)\}", top)
    commands = found.group(1).split(",") if found else []
    with ThreadPoolExecutor(max_workers=4) as pool:  # each --help is a process start: run them side by side
        texts = list(pool.map(lambda c: _help([c]), commands))
    page = ["# Command line", "", "Every subcommand of `softvr` (also `python -m softvr`), as its `--help` prints it.",
            "", "```text", top, "```", ""]
    for command, text in zip(commands, texts):
        page += [f"## softvr {command}", "", "```text", text, "```", ""]
    _write_if_changed(DOCS / "cli.md", "\n".join(page))


def _write_if_changed(path: Path, text: str) -> None:
    # Unchanged sources keep their mtime, so an incremental build rereads only what changed.
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


def _generate(app) -> None:
    write_api_pages()
    write_gallery_pages()
    write_cli_page()


def _drop_type_docstring(app, what, name, obj, options, lines) -> None:
    # A module constant without a doc comment (#:) would show its type's docstring (dict's, ndarray's):
    # not softvr's text, and not reStructuredText either.
    if what in ("data", "attribute") and lines:
        text = [line.rstrip() for line in lines if line.strip()]
        for doc in {getattr(obj, "__doc__", None), type(obj).__doc__} - {None}:
            if text == [line.rstrip() for line in inspect.cleandoc(doc).splitlines() if line.strip()]:
                lines.clear()
                return


def setup(app):
    app.connect("builder-inited", _generate)
    # Before napoleon (priority 500) rewrites the numpy-style sections of, say, ndarray's docstring.
    app.connect("autodoc-process-docstring", _drop_type_docstring, priority=100)
    return {"parallel_read_safe": True}
