"""Real CT and MRI volumes: files installed by Debian packages, or copies of them anywhere.

Each function reads its file afresh (nothing is cached) and returns a
:class:`~softvr.volume.Volume` whose ``spacing`` and ``origin`` are in **millimetres**,
the files' own units; all positions derived from these volumes (mesh nodes, contact
points) are therefore in mm too -- softvr's rule is that volume positions are in the
units of the volume's spacing.

* :func:`head_ct`: ``Cranium.inv3``, on Debian
  ``/usr/share/doc/invesalius-examples/examples/Cranium.inv3`` (package ``invesalius-examples``);
* :func:`mri_ch2`: ``ch2.nii.gz``, on Debian ``/usr/share/mricron/templates/ch2.nii.gz``
  (``mricron-data``);
* :func:`mri_ch2better`: ``ch2better.nii.gz``, on Debian
  ``/usr/share/mricron/templates/ch2better.nii.gz`` (``mricron-data``).

On other systems put the file (same name) into the folder named by the environment variable
``SOFTVR_DATA`` or into the cache folder ``$XDG_CACHE_HOME/softvr`` (default
``~/.cache/softvr``); :func:`data_file` searches those first, then the Debian path.
"""

from __future__ import annotations

__all__ = ["CH2BETTER_PATH", "CH2_PATH", "HEAD_CT_PATH", "cache_folder", "data_file", "head_ct", "mri_ch2",
           "mri_ch2better"]

import os
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
        The file is missing (install the Debian package ``invesalius-examples``, or see
        :func:`data_file`) or unreadable.
    """
    return load(data_file(HEAD_CT_PATH, "invesalius-examples"))


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
        The file is missing (install the Debian package ``mricron-data``, or see
        :func:`data_file`) or unreadable.
    """
    return load(data_file(CH2_PATH, "mricron-data"))


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
        The file is missing (install the Debian package ``mricron-data``, or see
        :func:`data_file`) or unreadable.
    """
    return load(data_file(CH2BETTER_PATH, "mricron-data"))


def cache_folder() -> Path:
    """softvr's data cache folder: ``$XDG_CACHE_HOME/softvr``, by default ``~/.cache/softvr``."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "softvr"


def data_file(debian_path: Path, package: str) -> Path:
    """Where a dataset file is: ``$SOFTVR_DATA/<name>``, else ``<cache_folder()>/<name>``,
    else ``debian_path`` (``<name>`` = ``debian_path.name``).

    Raises
    ------
    InputError
        None of them is a file; the message lists the places searched and says how to
        provide the file (the Debian package ``package``, SOFTVR_DATA or the cache folder).
    """
    name = debian_path.name
    searched = []
    if os.environ.get("SOFTVR_DATA"):
        searched.append(Path(os.environ["SOFTVR_DATA"]) / name)
    searched += [cache_folder() / name, Path(debian_path)]
    for path in searched:
        if path.is_file():
            return path
    raise InputError(
        "dataset file",
        f"{name}: install the Debian package {package!r} (apt-get install {package}), or copy {name} into a "
        f"folder and set SOFTVR_DATA to it, or into {cache_folder()}",
        "no such file at " + ", ".join(str(p) for p in searched),
        source=str(debian_path),
    )
