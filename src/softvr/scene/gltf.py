"""glTF scenes with softvr parameters in their extras: what stock Blender exports.

Blender's glTF exporter writes an object's *custom properties* as the node's ``extras`` and the
scene's as the scene's ``extras`` (Include > Custom Properties, on by default), so a scene
authored in Blender needs no add-on: give objects properties named after the scene file's
fields, prefixed ``softvr_``:

==========================  ==================================================================
node extras                 meaning (as in the TOML scene file, :mod:`softvr.scene.schema`)
==========================  ==================================================================
``softvr_type``             rigid | fem | cloth | fixed (nodes without it are not simulated)
``softvr_density``          [kg/m^3] (rigid, fem)
``softvr_young``            [Pa] (fem)
``softvr_poisson``          (fem)
``softvr_alpha``            [1/s], ``softvr_beta`` [s]: Rayleigh damping (fem)
``softvr_cells``            [m] tet cube size (fem)
``softvr_fixed_below``      [m] clamp nodes below this height (fem, cloth)
``softvr_area_density``     [kg/m^2], ``softvr_stretch``, ``softvr_shear``, ``softvr_bend`` (cloth)
==========================  ==================================================================

Scene extras: ``softvr_dt`` [s], ``softvr_steps_per_frame``, ``softvr_frames``,
``softvr_friction``, ``softvr_ground`` (true: a ground plane at z = 0). Each node's mesh is
taken in world coordinates (its node transform applied) and turned from glTF's y-up to
softvr's z-up; its material's base colour is its colour. Every bad property is reported at once,
named by the node.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from softvr.errors import InputError, Problems
from softvr.scene.schema import BodySpec, SceneFile

__all__ = ["has_softvr_bodies", "read_gltf_scene"]

_PREFIX = "softvr_"
_GLTF_TYPES = ("rigid", "fem", "cloth", "fixed")


def _gltf_json(path: Path) -> dict:
    """The JSON of a .gltf file or of a .glb's first chunk."""
    data = path.read_bytes()
    if path.suffix.lower() == ".glb":
        if len(data) < 20 or data[:4] != b"glTF":
            raise InputError("glb", "a binary glTF file (magic 'glTF')", repr(data[:4]), source=str(path))
        length, kind = struct.unpack("<I4s", data[12:20])
        if kind != b"JSON":
            raise InputError("glb", "a JSON chunk first", repr(kind), source=str(path))
        data = data[20:20 + length]
    try:
        return json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError("glTF JSON", "valid JSON", str(exc), source=str(path)) from None


def _properties(extras) -> dict:
    return {k[len(_PREFIX):]: v for k, v in (extras or {}).items() if isinstance(k, str) and k.startswith(_PREFIX)}


def has_softvr_bodies(path) -> bool:
    """Whether a glTF / GLB file has nodes with softvr custom properties (a physics scene, not
    only scenery); False for a missing file."""
    path = Path(path)
    if not path.is_file():
        return False
    return any(_properties(node.get("extras")) for node in _gltf_json(path).get("nodes", []))


def read_gltf_scene(path) -> SceneFile:
    """A :class:`~softvr.scene.SceneFile` from a glTF / GLB scene whose nodes carry softvr
    properties as extras (module docstring)."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise InputError("scene", "an existing glTF / GLB file", "no such file", source=str(path))
    doc = _gltf_json(path)
    errors = Problems(str(path), "glTF scene")
    scenes = doc.get("scenes") or [{}]
    scene_props = _properties(scenes[doc.get("scene", 0)].get("extras"))
    simulation = {"dt": errors.number(scene_props, "dt", "scene", default=0.005, positive=True, unit="s"),
                  "steps_per_frame": errors.integer(scene_props, "steps_per_frame", "scene", default=4, minimum=1),
                  "frames": errors.integer(scene_props, "frames", "scene", default=100, minimum=1),
                  "gravity": (0.0, 0.0, -9.81),
                  "friction": errors.number(scene_props, "friction", "scene", default=0.5, minimum=0.0),
                  "pgs_iterations": 500, "contact_margin": 0.005}
    loaded = trimesh.load(path, force="scene")
    materials, bodies = {}, []
    for i, node in enumerate(doc.get("nodes", [])):
        props = _properties(node.get("extras"))
        if not props:
            continue
        name = node.get("name") or f"node {i}"
        where = f"node {name!r}"
        kind = errors.choice(props, "type", where, _GLTF_TYPES)
        if name not in loaded.graph.nodes_geometry:
            errors.add(where, "a node with a triangle mesh", "no mesh")
            continue
        transform, geometry = loaded.graph[name]
        mesh = loaded.geometry[geometry]
        v = trimesh.transformations.transform_points(np.asarray(mesh.vertices, float), transform)
        v = np.c_[v[:, 0], -v[:, 2], v[:, 1]]  # glTF y-up -> softvr z-up
        color = tuple(float(c) for c in np.asarray(getattr(mesh.visual, "main_color", (204, 153, 128, 255)))[:3] / 255)
        spec = BodySpec(name=name, type=kind, shape="cloth" if kind == "cloth" else "mesh", color=color)
        spec.mesh_data = (v, np.asarray(mesh.faces, np.int32))
        if kind in ("rigid", "fem"):
            materials[name] = {
                "young": errors.number(props, "young", where, default=1e5, positive=True, unit="Pa"),
                "poisson": errors.number(props, "poisson", where, default=0.3, minimum=-0.99, maximum=0.5),
                "density": errors.number(props, "density", where, default=1000.0, positive=True, unit="kg/m^3"),
                "alpha": errors.number(props, "alpha", where, default=0.0, minimum=0.0, unit="1/s"),
                "beta": errors.number(props, "beta", where, default=0.0, minimum=0.0, unit="s")}
            spec.material = name
        if kind == "fem":
            spec.cells = errors.number(props, "cells", where, default=0.02, positive=True, unit="m")
        if "fixed_below" in props:
            spec.fixed_below = errors.number(props, "fixed_below", where, unit="m")
        if kind == "cloth":
            spec.cloth = {"area_density": errors.number(props, "area_density", where, default=0.2, positive=True),
                          **{k: errors.number(props, k, where, default=d, minimum=0.0) for k, d in (
                              ("stretch", 200.0), ("shear", 20.0), ("bend", 1.0), ("damping", 0.05),
                              ("alpha", 0.1))}}
        bodies.append(spec)
    if not bodies:
        errors.add("nodes", "at least one node with a softvr_type custom property", "none")
    errors.raise_if_any()
    ground = scene_props.get("ground", True)
    planes = [{"point": (0.0, 0.0, 0.0), "normal": (0.0, 0.0, 1.0), "friction": simulation["friction"],
               "size": 3.0, "adhesion": None}] if ground else []
    return SceneFile(path=path, simulation=simulation,
                     render={"size": (640, 480), "camera": "iso", "bounds": None, "azimuth": 0.0, "elevation": 0.0,
                             "zoom": 1.0},
                     materials=materials, adhesions={}, planes=planes, spheres=[], bodies=bodies, filters=[])
