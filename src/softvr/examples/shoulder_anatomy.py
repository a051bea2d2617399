"""A procedural shoulder with the structure of thesis Table 5.1 (no anatomical meshes can ship).

Boxes, spheres and a torus stand in for the parts; what matters is the structure the
simulation sees: two bones (a fixed scapula-like plate with an acromion, a scripted
humerus-like head and shaft), three rotator-cuff-like muscles, two ligaments, a labrum ring and
its tendon (soft), the biceps tendon and the transverse humeral ligament (rigid), coupled as in
the table. Coupled parts overlap or touch their bones at rest, as modelled anatomy does; their
collision is off (thesis 5.2.1). The palpation variant adds the outer deltoid-like muscle.

The glenoid faces +x at the origin; +z is up; metres.

:func:`write_shoulder_parts` writes the meshes (PLY) and the parts file for
``softvr build-model``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softvr.errors import InputError
from softvr.model.shapes import box_surface

__all__ = ["VARIANTS", "shoulder_meshes", "write_shoulder_parts"]

VARIANTS = ("palpation", "arthroscopy")

_MUSCLE = dict(young=3.0e4, poisson=0.4, density=1050.0, alpha=3.0, beta=0.01)
_LIGAMENT = dict(young=1.0e5, poisson=0.4, density=1100.0, alpha=3.0, beta=0.01)


def _box(lo, hi, edge: float = 0.006):
    """The box [lo, hi] [m] as a closed surface of squares about ``edge`` [m] wide (contacts
    happen at vertices and edges, so a soft part's faces need more than two triangles)."""
    import trimesh  # noqa: PLC0415

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v, t = box_surface(hi - lo, max(1, int(np.ceil((hi - lo).max() / edge))))
    return trimesh.Trimesh(v + lo, t, process=False)


def _merge(*meshes):
    import trimesh  # noqa: PLC0415

    return trimesh.util.concatenate(meshes)


def shoulder_meshes(variant: str = "palpation") -> dict:
    """Part name -> trimesh.Trimesh (closed, outward) of the procedural shoulder."""
    import trimesh  # noqa: PLC0415

    if variant not in VARIANTS:
        raise InputError("variant", " | ".join(VARIANTS), repr(variant))
    head = trimesh.creation.icosphere(subdivisions=3, radius=0.026)
    head.apply_translation((0.019, 0.0, 0.0))
    labrum = trimesh.creation.torus(0.02, 0.0035, major_sections=32, minor_sections=12)
    labrum.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    labrum.apply_translation((-0.008, 0.0, 0.0))
    meshes = {
        # 1, 2: the bones
        "scapula": _merge(_box((-0.035, -0.05, -0.09), (-0.012, 0.05, 0.04)),  # blade and glenoid face x = -0.012
                          _box((-0.035, -0.014, 0.05), (0.066, 0.014, 0.062)),  # acromion, over the joint
                          _box((-0.035, 0.02, 0.036), (-0.004, 0.032, 0.046))),  # coracoid, in front
        "humerus": _merge(head, _box((0.004, -0.011, -0.16), (0.028, 0.011, -0.012)),  # head and shaft
                          _box((0.026, -0.01, -0.1), (0.055, 0.01, -0.082))),  # deltoid tuberosity
        # 3-5: rotator cuff, from the scapula over the head
        "supraspinatus": _box((-0.03, -0.022, 0.027), (0.036, 0.004, 0.045)),
        "infraspinatus": _box((-0.03, -0.045, -0.035), (0.036, -0.028, 0.02)),
        "subscapularis": _box((-0.03, 0.028, -0.035), (0.036, 0.045, 0.016)),
        # 6, 7: ligaments
        "coracoacromial": _box((-0.01, 0.014, 0.044), (0.05, 0.022, 0.05)),
        "coracohumeral": _box((-0.008, 0.006, 0.034), (0.024, 0.02, 0.043)),
        # 9, 10: labrum ring on the glenoid rim and its tendon over the head
        "labrum": labrum,
        "labrum_tendon": _box((-0.01, 0.006, 0.027), (0.046, 0.013, 0.033)),
        # 11, 8: rigid biceps tendon in front of the head, held by the transverse humeral ligament
        "biceps_tendon": _box((0.043, 0.005, -0.08), (0.05, 0.014, 0.03)),
        "transverse_humeral": _box((0.051, 0.002, -0.032), (0.055, 0.017, -0.024)),
    }
    if variant == "palpation":
        meshes["deltoid"] = _box((0.057, -0.04, -0.092), (0.07, 0.04, 0.05))
    return meshes


def _parts_toml(variant: str) -> str:
    parts = [
        ("scapula", "fixed", dict(density=1900.0)),
        ("humerus", "kinematic", dict(density=1900.0)),
        ("supraspinatus", "soft", _MUSCLE),
        ("infraspinatus", "soft", _MUSCLE),
        ("subscapularis", "soft", _MUSCLE),
        ("coracoacromial", "soft", _LIGAMENT),
        ("coracohumeral", "soft", _LIGAMENT),
        ("transverse_humeral", "rigid", dict(density=1100.0)),
        ("labrum", "soft", _LIGAMENT),
        ("labrum_tendon", "soft", _LIGAMENT),
        ("biceps_tendon", "rigid", dict(density=1100.0)),
    ]
    # Table 5.1's couplings (a's nodes near b's surface are tied to b).
    couplings = [
        ("supraspinatus", "scapula", 0.004), ("supraspinatus", "humerus", 0.003),
        ("infraspinatus", "scapula", 0.004), ("infraspinatus", "humerus", 0.003),
        ("subscapularis", "scapula", 0.004), ("subscapularis", "humerus", 0.003),
        ("coracoacromial", "scapula", 0.003),
        ("coracohumeral", "scapula", 0.004), ("coracohumeral", "humerus", 0.012),
        ("transverse_humeral", "humerus", 0.03),
        ("labrum", "scapula", 0.004), ("labrum_tendon", "labrum", 0.005),
        ("biceps_tendon", "humerus", 0.004), ("biceps_tendon", "labrum_tendon", 0.004),
    ]
    if variant == "palpation":
        parts.append(("deltoid", "soft", {**_MUSCLE, "cell_size": 0.014}))
        couplings += [("deltoid", "scapula", 0.003), ("deltoid", "humerus", 0.004)]
    lines = ['format = "softvr-parts 1"', "", "[defaults]", "cell_size = 0.01", "collision_triangles = 200", ""]
    for name, kind, props in parts:
        lines += ["[[part]]", f'name = "{name}"', f'mesh = "{name}.ply"', f'kind = "{kind}"']
        lines += [f"{k} = {v!r}" for k, v in props.items()]
        lines.append("")
    for a, b, radius in couplings:
        stiffness = 3000.0 if b in ("scapula", "humerus") else 1500.0
        lines += ["[[coupling]]", f'a = "{a}"', f'b = "{b}"', f"radius = {radius!r}", f"stiffness = {stiffness!r}",
                  "damping = 0.5", ""]
    return "\n".join(lines)


def write_shoulder_parts(folder, variant: str = "palpation") -> Path:
    """Write the procedural shoulder's meshes (PLY) and ``shoulder_<variant>.toml`` into
    ``folder``; returns the parts file's path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name, mesh in shoulder_meshes(variant).items():
        mesh.export(folder / f"{name}.ply")
    path = folder / f"shoulder_{variant}.toml"
    path.write_text(_parts_toml(variant))
    return path
