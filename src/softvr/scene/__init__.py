"""Scene files: one versioned TOML description of a simulation (bodies and their shapes,
materials, adhesion, obstacles, collision filters, kinematic motion, render settings),
validated with every error at once, and built into a running demo.

* :func:`read_scene` -> :class:`SceneFile` (``softvr check SCENE``); :func:`read_gltf_scene`
  reads a glTF / GLB whose nodes carry softvr custom properties (Blender's exporter writes them
  as extras); both validate with one description (:mod:`softvr.scene._description`, a pydantic
  model per table, its defaults written once). :func:`read_any` picks by the file's suffix;
  :func:`read_any_with_problems` gives the problems and the valid rest (``softvr check`` builds
  it to find bodies that start crossing).
* :mod:`softvr.scene.display`: the display files a scene's ``[display]`` names (the screens;
  :mod:`softvr.cave` adds their cameras).
* :class:`SceneExample` / :func:`load_scene`: the scene as a demo (``softvr run SCENE.toml``,
  ``softvr view SCENE.toml``).
* :data:`BUNDLED`: the scene files shipped with softvr (``softvr run soft-cube.toml``).
"""

import importlib
from pathlib import Path

from softvr.scene.gltf import has_softvr_bodies, read_gltf_scene
from softvr.scene.schema import BODY_TYPES, FORMAT, BodySpec, SceneFile, read_scene

__all__ = ["BODY_TYPES", "BUNDLED", "FORMAT", "BodySpec", "SceneExample", "SceneFile", "bundled", "has_softvr_bodies",
           "load_scene", "read_any", "read_any_with_problems", "read_gltf_scene", "read_scene"]

#: Folder of the bundled scene files.
BUNDLED = Path(__file__).resolve().parent.parent / "scenes"
#: Names of softvr.scene.build, imported when first used: building loads the runtime (softvr.app,
#: VTK), which reading a scene file, or a display file (softvr.cave), does not need.
_BUILD = ("SceneExample", "load_scene", "read_any", "read_any_with_problems")


def __getattr__(name: str):
    if name in _BUILD:
        return getattr(importlib.import_module("softvr.scene.build"), name)
    raise AttributeError(f"module 'softvr.scene' has no attribute {name!r}")


def bundled(name: str) -> Path:
    """The path of a bundled scene file (``"soft-cube.toml"``), or ``name`` itself when that is
    a file."""
    path = Path(name)
    # exists(), not is_file(): a FIFO or device given by a bare name is the user's file, refused
    # as such by the reader (softvr.files.checked_file), not a missing bundled scene.
    if path.exists() or path.parent != Path("."):
        return path
    return BUNDLED / name
