"""Real CT and MRI volumes installed by Debian packages.

Each function reads its file afresh (nothing is cached) and returns a
:class:`~softvr.volume.Volume` whose ``spacing`` and ``origin`` are in **millimetres**,
the files' own units; all positions derived from these volumes (mesh nodes, contact
points) are therefore in mm too -- softvr's rule is that volume positions are in the
units of the volume's spacing.

* :func:`head_ct`: ``/usr/share/doc/invesalius-examples/examples/Cranium.inv3``
  (Debian package ``invesalius-examples``);
* :func:`mri_ch2`: ``/usr/share/mricron/templates/ch2.nii.gz`` (``mricron-data``);
* :func:`mri_ch2better`: ``/usr/share/mricron/templates/ch2better.nii.gz`` (``mricron-data``).
"""

from __future__ import annotations

__all__ = ["CH2BETTER_PATH", "CH2_PATH", "HEAD_CT_PATH", "head_ct", "mri_ch2", "mri_ch2better"]

from pathlib import Path

from softvr.errors import InputError
from softvr.volume import Volume, load

#: InVesalius sample project "Cranium" (a head CT), from the ``invesalius-examples`` package.
HEAD_CT_PATH = Path("/usr/share/doc/invesalius-examples/examples/Cranium.inv3")
#: Colin27 ("ch2") T1 MRI template, 1 mm, from the ``mricron-data`` package.
CH2_PATH = Path("/usr/share/mricron/templates/ch2.nii.gz")
#: Colin27 high-resolution T1 MRI template, 0.5 mm, from the ``mricron-data`` package.
CH2BETTER_PATH = Path("/usr/share/mricron/templates/ch2better.nii.gz")


def head_ct() -> Volume:
    """The InVesalius "Cranium" head CT.

    Returns
    -------
    Volume
        ``data`` int16 Hounsfield units, shape [256, 256, 108] ([x, y, z]; the project
        stores it [z, y, x] = (108, 256, 256)); ``spacing`` (0.957, 0.957, 1.5) [mm] as
        read from the project's ``main.plist``; ``origin`` 0 and identity ``direction``
        (the project stores no patient geometry). Air is about -1000, bone above 1000.
        Axes: z runs from the neck to the top of the skull, the face is towards +y.

    Raises
    ------
    InputError
        The file is missing (install the Debian package ``invesalius-examples``) or
        unreadable.
    """
    return load(_require(HEAD_CT_PATH, "invesalius-examples"))


def mri_ch2() -> Volume:
    """The Colin27 "ch2" T1-weighted MRI template at 1 mm.

    Returns
    -------
    Volume
        ``data`` uint8, shape [181, 217, 181]; ``spacing`` (1, 1, 1) [mm]; ``origin`` and
        ``direction`` from the NIfTI affine (MNI / RAS+ space, kept as-is).

    Raises
    ------
    InputError
        The file is missing (install the Debian package ``mricron-data``) or unreadable.
    """
    return load(_require(CH2_PATH, "mricron-data"))


def mri_ch2better() -> Volume:
    """The Colin27 "ch2better" T1-weighted MRI template at 0.5 mm (35 M voxels).

    Returns
    -------
    Volume
        ``data`` uint8, shape [301, 370, 316] (about 35 MB); ``spacing`` (0.5, 0.5, 0.5)
        [mm]; ``origin`` and ``direction`` from the NIfTI affine (RAS+, kept as-is).

    Raises
    ------
    InputError
        The file is missing (install the Debian package ``mricron-data``) or unreadable.
    """
    return load(_require(CH2BETTER_PATH, "mricron-data"))


def _require(path: Path, package: str) -> Path:
    if not path.is_file():
        raise InputError(
            "dataset file",
            f"the file installed by the Debian package {package!r} (apt-get install {package})",
            "no such file",
            source=str(path),
        )
    return path
