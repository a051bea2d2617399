"""Scene files: one versioned TOML description of a simulation (bodies and their shapes,
materials, adhesion, obstacles, collision filters, kinematic motion, render settings),
validated with every error at once, and built into a running demo.

* :func:`read_scene` -> :class:`SceneFile` (``softvr check SCENE``); :func:`read_gltf_scene`
  reads a glTF / GLB whose nodes carry softvr custom properties (Blender's exporter writes them
  as extras); :func:`read_any` picks by the file's suffix; :func:`read_any_with_problems` gives the
  problems and the valid rest (``softvr check`` builds it to find bodies that start crossing).
* :class:`SceneExample` / :func:`load_scene`: the scene as a demo (``softvr run SCENE.toml``,
  ``softvr view SCENE.toml``).
* :data:`BUNDLED`: the scene files shipped with softvr (``softvr run soft-cube.toml``).
"""

from pathlib import Path

from softvr.scene.build import SceneExample, load_scene, read_any, read_any_with_problems
from softvr.scene.gltf import has_softvr_bodies, read_gltf_scene
from softvr.scene.schema import BODY_TYPES, FORMAT, BodySpec, SceneFile, read_scene

__all__ = ["BODY_TYPES", "BUNDLED", "FORMAT", "BodySpec", "SceneExample", "SceneFile", "bundled", "has_softvr_bodies",
           "load_scene", "read_any", "read_any_with_problems", "read_gltf_scene", "read_scene"]

#: Folder of the bundled scene files.
BUNDLED = Path(__file__).resolve().parent.parent / "scenes"


def bundled(name: str) -> Path:
    """The path of a bundled scene file (``"soft-cube.toml"``), or ``name`` itself when that is
    a file."""
    path = Path(name)
    # exists(), not is_file(): a FIFO or device given by a bare name is the user's file, refused
    # as such by the reader (softvr.files.checked_file), not a missing bundled scene.
    if path.exists() or path.parent != Path("."):
        return path
    return BUNDLED / name
