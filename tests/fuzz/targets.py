"""Reader entry points the fuzz suite calls in its children (harness.run_reader targets):
each reads one input file the way a softvr command does, raising what the command would."""

from __future__ import annotations

from softvr.files import native_read
from softvr.model.build import build_model
from softvr.volume import load_tet_mesh

__all__ = ["build_parts", "read_tets"]


def read_tets(path: str):
    """A scene's ``tets = PATH`` body file, read as scene/build.py reads it."""
    return native_read(load_tet_mesh, path, "tets", "a tet mesh file meshio can read")


def build_parts(path: str):
    """``softvr build-model PATH`` without writing the model."""
    return build_model(path, progress=False)
