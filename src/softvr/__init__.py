"""softvr: a toolkit for virtual-reality training applications with deformable anatomy.

Layers (see ``DESIGN.md``): :mod:`softvr.volume` deforms dense CT/MRI volumes by
rasterizing a deformed embedding tetrahedral mesh (thesis ch. 3); :mod:`softvr.render`
draws them with VTK. All quantities are SI unless a docstring says otherwise; volume
positions are in the units of the volume's spacing.
"""

from softvr.errors import InputError, SimulationError, SoftvrError
from softvr.sim import Scene

__version__ = "0.1.0"

__all__ = ["InputError", "Scene", "SimulationError", "SoftvrError", "__version__"]
