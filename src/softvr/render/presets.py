"""Transfer-function presets: how voxel values map to colour and opacity.

Opacities are per voxel length: softvr sets VTK's scalar-opacity unit distance to the
smallest voxel spacing, so a preset looks the same whatever the units of the volume.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softvr.errors import InputError

__all__ = ["PRESETS", "Preset", "label_colors", "resolve_preset"]

# Categorical palette (Tableau 20, reordered so that neighbouring labels contrast).
_PALETTE = np.array(
    [
        (0.839, 0.153, 0.157), (0.122, 0.467, 0.706), (0.173, 0.627, 0.173), (1.000, 0.498, 0.055),
        (0.580, 0.404, 0.741), (0.090, 0.745, 0.812), (0.890, 0.467, 0.761), (0.737, 0.741, 0.133),
        (0.549, 0.337, 0.294), (0.498, 0.498, 0.498), (1.000, 0.596, 0.588), (0.682, 0.780, 0.910),
        (0.596, 0.875, 0.541), (1.000, 0.733, 0.471), (0.773, 0.690, 0.835), (0.620, 0.855, 0.898),
        (0.969, 0.714, 0.824), (0.859, 0.859, 0.553), (0.769, 0.612, 0.580), (0.780, 0.780, 0.780),
    ]
)


def label_colors(labels) -> np.ndarray:
    """RGB colours in [0, 1], shape [n, 3], of integer ``labels`` [n]; label ``L`` gets
    palette entry ``(L - 1) mod 20`` so a label keeps its colour from frame to frame."""
    labels = np.asarray(labels, dtype=np.int64)
    return _PALETTE[(labels - 1) % len(_PALETTE)]


@dataclass(frozen=True)
class Preset:
    """A transfer function.

    Parameters
    ----------
    name : str
    colors : tuple of (value, r, g, b)
        Colour transfer function points; r, g, b in [0, 1]; linear in between.
    opacities : tuple of (value, opacity)
        Scalar opacity per voxel length, in [0, 1]; linear in between, constant outside.
    gradient_opacities : tuple of (gradient magnitude [value units per voxel], factor), optional
        Multiplies the opacity: low factors at small gradients hide homogeneous regions.
    interpolation : {"linear", "nearest"}
        Sampling between voxel centres; label volumes need ``"nearest"``.
    shade : bool
        Gradient (Phong) shading.
    ambient, diffuse, specular : float
        Lighting coefficients when shading.
    categorical : bool
        Colour each integer value by :func:`label_colors`; value 0 is transparent and
        every other value has opacity ``label_opacity``. ``colors``/``opacities`` are ignored.
    label_opacity : float
        Opacity per voxel length of non-zero labels.

    Examples
    --------
    >>> from softvr.render import PRESETS, Preset
    >>> PRESETS["ct"].interpolation
    'linear'
    >>> bones = Preset("bones", colors=((300, 1, 1, 1),), opacities=((200, 0), (500, 1)))
    >>> bones.shade
    True
    """

    name: str
    colors: tuple = ()
    opacities: tuple = ()
    gradient_opacities: tuple | None = None
    interpolation: str = "linear"
    shade: bool = True
    ambient: float = 0.2
    diffuse: float = 0.8
    specular: float = 0.15
    categorical: bool = False
    label_opacity: float = 0.5

    def __post_init__(self) -> None:
        if self.interpolation not in ("linear", "nearest"):
            raise InputError(f"Preset({self.name!r}).interpolation", "'linear' or 'nearest'", repr(self.interpolation))
        if not self.categorical and (not self.colors or not self.opacities):
            raise InputError(f"Preset({self.name!r})", "colors and opacities (or categorical=True)", "an empty table")
        for v, *rgb in self.colors:
            if len(rgb) != 3 or not all(0 <= c <= 1 for c in rgb):
                raise InputError(f"Preset({self.name!r}).colors", "(value, r, g, b) with r, g, b in [0, 1]", repr((v, *rgb)))
        for point in self.opacities:
            if len(point) != 2 or not 0 <= point[1] <= 1:
                raise InputError(f"Preset({self.name!r}).opacities", "(value, opacity in [0, 1])", repr(point))


#: Built-in presets.
#:
#: ``"ct"``
#:     Hounsfield units: air (< -500) transparent; skin and soft tissue (-500..200)
#:     skin-coloured and faint, shown mainly at boundaries via gradient opacity, so the
#:     skin surface reads as a semi-transparent shell; bone (> 250) white and opaque.
#: ``"ct-skin"``
#:     Hounsfield units: the skin as an opaque shaded surface (everything above -300 HU),
#:     for seeing the body's outside deform (palpation).
#: ``"mri"``
#:     T1-weighted uint8 (0..255) brain: background (< 20) transparent, grey levels with
#:     opacity rising towards white matter.
#: ``"labels"``
#:     Segmentations: nearest-neighbour sampling, categorical colours, 0 transparent.
PRESETS: dict[str, Preset] = {
    "ct": Preset(
        "ct",
        colors=(
            (-1000, 0.0, 0.0, 0.0),
            (-500, 0.55, 0.25, 0.15),
            (-100, 0.88, 0.60, 0.50),
            (100, 0.93, 0.70, 0.60),
            (250, 0.95, 0.90, 0.80),
            (600, 1.0, 1.0, 0.95),
            (3000, 1.0, 1.0, 1.0),
        ),
        opacities=((-1000, 0.0), (-500, 0.0), (-300, 0.05), (200, 0.08), (250, 0.2), (600, 0.85), (3000, 0.95)),
        gradient_opacities=((0, 0.15), (80, 1.0)),
        specular=0.2,
    ),
    "ct-skin": Preset(
        "ct-skin",
        colors=((-1000, 0.0, 0.0, 0.0), (-400, 0.80, 0.55, 0.45), (-100, 0.90, 0.68, 0.58), (200, 0.92, 0.72, 0.62),
                (3000, 0.92, 0.72, 0.62)),
        opacities=((-1000, 0.0), (-500, 0.0), (-300, 0.9), (3000, 0.95)),
        specular=0.25,
    ),
    "mri": Preset(
        "mri",
        colors=((0, 0.0, 0.0, 0.0), (40, 0.35, 0.3, 0.3), (120, 0.75, 0.72, 0.7), (255, 1.0, 1.0, 1.0)),
        opacities=((0, 0.0), (20, 0.0), (60, 0.03), (140, 0.12), (255, 0.4)),
        gradient_opacities=((0, 0.3), (15, 1.0)),
        specular=0.1,
    ),
    "labels": Preset("labels", interpolation="nearest", categorical=True, label_opacity=0.5),
}


def resolve_preset(preset: "str | Preset", volume=None) -> Preset:
    """The :class:`Preset` named by ``preset``.

    ``"auto"`` picks ``"labels"`` for ``volume.is_label``, ``"mri"`` for unsigned 8-bit
    data and ``"ct"`` otherwise.
    """
    if isinstance(preset, Preset):
        return preset
    if preset == "auto":
        if volume is None:
            return PRESETS["ct"]
        if getattr(volume, "is_label", False):
            return PRESETS["labels"]
        return PRESETS["mri"] if np.asarray(volume.data).dtype == np.uint8 else PRESETS["ct"]
    if isinstance(preset, str) and preset in PRESETS:
        return PRESETS[preset]
    raise InputError("preset", f"one of {sorted(PRESETS) + ['auto']} or a Preset", repr(preset))
