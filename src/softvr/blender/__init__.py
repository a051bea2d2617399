"""The Blender add-on (``softvr_blender``, for Blender >= 4.2), shipped with softvr.

:func:`build_addon` zips it for Blender's *Install from Disk* (``softvr blender-addon``). The
add-on itself runs inside Blender and imports ``bpy``; softvr never imports it.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

from softvr.files import atomic_output

__all__ = ["ADDON_SOURCE", "build_addon"]

ADDON_SOURCE = Path(__file__).resolve().parent / "softvr_blender"


def build_addon(folder) -> Path:
    """Write ``softvr-blender.zip`` (the add-on folder ``softvr_blender/``) into ``folder``,
    atomically; returns its path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / "softvr-blender.zip"
    with atomic_output(target, ".zip") as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
            for path in sorted(ADDON_SOURCE.rglob("*.py")):
                z.write(path, Path("softvr_blender") / path.relative_to(ADDON_SOURCE))
    return target
