"""softvr: a toolkit for virtual-reality training applications with deformable anatomy.

Layers (see ``DESIGN.md``): :mod:`softvr.volume` deforms dense CT/MRI volumes by
rasterizing a deformed embedding tetrahedral mesh (thesis ch. 3); :mod:`softvr.render`
draws them with VTK. All quantities are SI unless a docstring says otherwise; volume
positions are in the units of the volume's spacing.

The names below are loaded on first use (PEP 562): ``import softvr.errors`` or
``softvr --help`` must not pay for the physics stack and Warp (~1 s), which
``softvr.Scene`` needs.
"""

from __future__ import annotations

from importlib import import_module, metadata, util
from typing import TYPE_CHECKING

try:
    # One version source: pyproject.toml's ``version``, read back from the installed metadata.
    __version__ = metadata.version("softvr")
except metadata.PackageNotFoundError:  # a source tree on sys.path that was never installed
    __version__ = "0+unknown"

__all__ = ["InputError", "Scene", "SimulationError", "SoftvrError", "__version__"]

# name -> module that defines it
_LAZY = {
    "InputError": "softvr.errors",
    "SimulationError": "softvr.errors",
    "SoftvrError": "softvr.errors",
    "Scene": "softvr.sim",
}

if TYPE_CHECKING:  # type checkers and IDEs see the names as eager imports
    from softvr.errors import InputError, SimulationError, SoftvrError
    from softvr.sim import Scene


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is not None:
        value = getattr(import_module(module), name)
    elif not name.startswith("_") and util.find_spec(f"softvr.{name}") is not None:
        # ``import softvr; softvr.volume.load(...)`` worked while this file imported the physics stack
        # (which imported most subpackages); it keeps working, importing the subpackage on first use.
        value = import_module(f"softvr.{name}")
    else:
        raise AttributeError(f"module 'softvr' has no attribute {name!r}")
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
