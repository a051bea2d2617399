"""glTF scenes with softvr parameters in their extras: what stock Blender exports.

Blender's glTF exporter writes an object's *custom properties* as the node's ``extras`` and the
scene's as the scene's ``extras`` (Include > Custom Properties, on by default), so a scene
authored in Blender needs no add-on: give objects properties named after the scene file's
fields, prefixed ``softvr_``:

============================  ================================================================
node extras                   meaning (as in the TOML scene file, :mod:`softvr.scene.schema`)
============================  ================================================================
``softvr_type``               rigid | fem | cloth | fixed | kinematic | tool (nodes without it
                              are not simulated)
``softvr_density``            [kg/m^3] (rigid, fem, tool)
``softvr_young``              [Pa] (fem)
``softvr_poisson``            (fem)
``softvr_alpha``              [1/s], ``softvr_beta`` [s]: Rayleigh damping (fem)
``softvr_cells``              [m] tet cube size (fem)
``softvr_fixed_below``        [m] clamp nodes below this height (fem, cloth)
``softvr_area_density``       [kg/m^2], ``softvr_stretch``, ``softvr_shear``, ``softvr_bend`` (cloth)
``softvr_stiffness``          [N/m] hand - tool coupling (tool, required)
``softvr_damping``            [N s/m] (tool; default 0), ``softvr_haptics`` (tool: true runs the
                              1 kHz haptic loop; default false), ``softvr_max_force`` [N] (tool)
``softvr_collides_with``      "a, b": collide with these bodies only (node names, comma-separated)
``softvr_couple_to``          another body's node name: zero-length springs to it (a coupling)
``softvr_coupling_stiffness`` [N/m] per spring (required with ``softvr_couple_to``)
``softvr_coupling_damping``   [N s/m] (default 0), ``softvr_coupling_collide`` (default false)
``softvr_coupling_radius``    [m] springs at this body's nodes within it of the other's surface
                              (fem, cloth) ...
``softvr_coupling_points``    ... or at these world points: x0, y0, z0, x1, ... [m] (any body)
``softvr_adhesion_stiffness`` [N/m^3]: the surface is adhesive (thesis ch. 4); with
                              ``softvr_adhesion_max_energy`` [J/m^2], ``..._viscosity`` (all
                              three required) and optional ``..._bonding_rate``,
                              ``..._saturation``, ``..._initial``, ``..._debond_gap`` [m]
============================  ================================================================

Scene extras: ``softvr_dt`` [s], ``softvr_steps_per_frame``, ``softvr_frames``,
``softvr_friction``, ``softvr_ground`` (true: a ground plane at z = 0; ``softvr_ground_adhesion_*``
as a node's ``softvr_adhesion_*`` make it adhesive), ``softvr_display`` (the
screens it is shown on: a :mod:`softvr.cave` preset or a display file), ``softvr_start_time``
[s] (the animation time that is the simulation's t = 0; default: the first key of the
kinematic bodies' and tools' animations). Each node's mesh is taken in world coordinates (its
node transform applied) and turned from glTF's y-up to softvr's z-up; its material's base colour
is its colour. Every bad property is reported at once, named by the node.

**Kinematic bodies and tools** move as the node's glTF *translation animation* (what Blender
writes for an object with location keyframes): the node's translation keys, turned z-up, are the
body's ``motion`` (linear in between; STEP keys are held, CUBICSPLINE keys pass through their
values, their tangents dropped). Keys are the node's *local* translation, so only an object
without a parent may be animated. The body's ``position`` (its reference point, which the motion
moves) is the node's world translation; its mesh is kept relative to it and placed at the
motion's start. Rotation and scale keys are ignored: a kinematic body or a tool keeps its rest
orientation. A kinematic body or tool without an animation holds still.

**Couplings** (zero-length springs, thesis 5.3.2) are written on one of the two bodies.
``softvr_coupling_points`` are in *Blender's* world coordinates (z up), which are softvr's:
custom properties are written verbatim, not turned to glTF's y-up like the meshes (the add-on's
*Pick coupling vertices* writes them).
"""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from softvr.errors import InputError, Problems
from softvr.scene.schema import BodySpec, SceneFile

__all__ = ["has_softvr_bodies", "read_gltf_scene"]

_PREFIX = "softvr_"
_GLTF_TYPES = ("rigid", "fem", "cloth", "fixed", "kinematic", "tool")
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_FLOAT = 5126  # accessor componentType of 32-bit floats
_COUPLING_KEYS = ("couple_to", "coupling_stiffness", "coupling_damping", "coupling_radius", "coupling_points",
                  "coupling_collide")


def _glb_chunks(path: Path) -> tuple[bytes, bytes | None]:
    """The JSON chunk and the BIN chunk (None when there is none) of a .glb file."""
    data = path.read_bytes()
    if len(data) < 20 or data[:4] != b"glTF":
        raise InputError("glb", "a binary glTF file (magic 'glTF')", repr(data[:4]), source=str(path))
    chunks, at = [], 12
    while at + 8 <= len(data):
        length, kind = struct.unpack("<I4s", data[at:at + 8])
        chunks.append((kind, data[at + 8:at + 8 + length]))
        at += 8 + length
    if not chunks or chunks[0][0] != b"JSON":
        raise InputError("glb", "a JSON chunk first", repr(chunks[0][0] if chunks else b""), source=str(path))
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == b"BIN\x00" else None
    return chunks[0][1], binary


def _gltf_json(path: Path, with_binary: bool = False):
    """The JSON of a .gltf file or of a .glb's first chunk (and the .glb's BIN chunk)."""
    binary = None
    if path.suffix.lower() == ".glb":
        data, binary = _glb_chunks(path)
    else:
        data = path.read_bytes()
    try:
        doc = json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError("glTF JSON", "valid JSON", str(exc), source=str(path)) from None
    return (doc, binary) if with_binary else doc


class _Bad(Exception):
    """One problem (what, expected, found) while reading an accessor."""


class _Buffers:
    """The buffers of a glTF file (a GLB's BIN chunk, files next to a .gltf, ``data:`` URIs) and
    float accessors read from them."""

    def __init__(self, path: Path, doc: dict, binary: bytes | None):
        self.path, self.doc, self.binary, self._cache = path, doc, binary, {}

    def buffer(self, i) -> bytes:
        buffers = self.doc.get("buffers", [])
        if not (isinstance(i, int) and 0 <= i < len(buffers)):
            raise _Bad(f"buffers[{i}]", f"one of the file's {len(buffers)} buffers", "no such buffer")
        if i not in self._cache:
            uri = buffers[i].get("uri")
            if uri is None:
                if self.binary is None:
                    raise _Bad(f"buffers[{i}]", "a .glb's BIN chunk or a uri", "neither")
                data = self.binary
            elif uri.startswith("data:"):
                head, _, payload = uri.partition(",")
                if not head.endswith(";base64"):
                    raise _Bad(f"buffers[{i}].uri", "a base64 data: URI", head)
                data = base64.b64decode(payload)
            else:
                file = self.path.parent / unquote(uri)
                if not file.is_file():
                    raise _Bad(f"buffers[{i}].uri", "an existing buffer file", f"no file {file}")
                data = file.read_bytes()
            length = buffers[i].get("byteLength", len(data))
            if len(data) < length:
                raise _Bad(f"buffers[{i}]", f"{length} bytes", f"{len(data)} bytes")
            self._cache[i] = data
        return self._cache[i]

    def floats(self, index, kinds: tuple) -> np.ndarray:
        """Accessor ``index`` of float32 components as float64 [count, components]; its type one
        of ``kinds`` ("SCALAR", "VEC3", ...)."""
        accessors = self.doc.get("accessors", [])
        if not (isinstance(index, int) and 0 <= index < len(accessors)):
            raise _Bad(f"accessors[{index}]", f"one of the file's {len(accessors)} accessors", "no such accessor")
        a, w = accessors[index], f"accessors[{index}]"
        if a.get("componentType") != _FLOAT:
            raise _Bad(f"{w}.componentType", f"{_FLOAT} (32-bit floats)", a.get("componentType"))
        if a.get("type") not in kinds:
            raise _Bad(f"{w}.type", " | ".join(kinds), a.get("type"))
        if "sparse" in a:
            raise _Bad(f"{w}.sparse", "a dense accessor", "a sparse one")
        k, count = _COMPONENTS[a["type"]], a.get("count")
        if not (isinstance(count, int) and count >= 1):
            raise _Bad(f"{w}.count", "an integer >= 1", count)
        if "bufferView" not in a:  # no data: zeros (glTF 2.0, 3.6.2)
            return np.zeros((count, k))
        views = self.doc.get("bufferViews", [])
        v = a["bufferView"]
        if not (isinstance(v, int) and 0 <= v < len(views)):
            raise _Bad(f"{w}.bufferView", f"one of the file's {len(views)} buffer views", v)
        view = views[v]
        data = self.buffer(view.get("buffer"))
        stride = view.get("byteStride") or 4 * k
        start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
        end = start + stride * (count - 1) + 4 * k
        if end > view.get("byteOffset", 0) + view.get("byteLength", 0) or end > len(data):
            raise _Bad(f"{w}", f"{count} {a['type']} within bufferViews[{v}]", f"bytes {start} .. {end} beyond it")
        out = np.ndarray((count, k), "<f4", buffer=data, offset=start, strides=(stride, 4)).astype(float)
        if not np.all(np.isfinite(out)):
            raise _Bad(w, "finite numbers", "NaN or infinity")
        return out


def _properties(extras) -> dict:
    return {k[len(_PREFIX):]: v for k, v in (extras or {}).items() if isinstance(k, str) and k.startswith(_PREFIX)}


def has_softvr_bodies(path) -> bool:
    """Whether a glTF / GLB file has nodes with softvr custom properties (a physics scene, not
    only scenery); False for a missing file."""
    path = Path(path)
    if not path.is_file():
        return False
    return any(_properties(node.get("extras")) for node in _gltf_json(path).get("nodes", []))


def _z_up(v) -> np.ndarray:
    """glTF y-up -> softvr z-up: (x, y, z) -> (x, -z, y)."""
    v = np.asarray(v, float)
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


def _translation_keys(doc: dict, buffers: _Buffers, node: int, where: str, errors: Problems):
    """Times [k] [s] and local translations [k, 3] (glTF y-up) of the node's translation
    animation; None without one (or on a problem, recorded in ``errors``)."""
    found = []
    for a, animation in enumerate(doc.get("animations", [])):
        for c, channel in enumerate(animation.get("channels", [])):
            target = channel.get("target", {})
            if target.get("node") == node and target.get("path") == "translation":
                found.append((a, c, animation, channel))
    if not found:
        return None
    if len(found) > 1:
        errors.add(f"{where} animation", "one translation animation",
                   f"{len(found)} (animations {', '.join(str(a) for a, *_ in found)})")
        return None
    a, c, animation, channel = found[0]
    samplers = animation.get("samplers", [])
    s = channel.get("sampler")
    if not (isinstance(s, int) and 0 <= s < len(samplers)):
        errors.add(f"{where} animations[{a}].channels[{c}].sampler", f"one of {len(samplers)} samplers", s)
        return None
    sampler = samplers[s]
    interpolation = sampler.get("interpolation", "LINEAR")
    try:
        times = buffers.floats(sampler.get("input"), ("SCALAR",))[:, 0]
        values = buffers.floats(sampler.get("output"), ("VEC3",))
    except _Bad as bad:
        errors.add(f"{where} animations[{a}] {bad.args[0]}", *bad.args[1:])
        return None
    if interpolation == "CUBICSPLINE":
        values = values[1::3]  # (in-tangent, value, out-tangent) per key: the key's value
    elif interpolation not in ("LINEAR", "STEP"):
        errors.add(f"{where} animations[{a}].samplers[{s}].interpolation", "LINEAR | STEP | CUBICSPLINE",
                   interpolation)
        return None
    if len(values) != len(times):
        errors.add(f"{where} animations[{a}].samplers[{s}]", f"one translation per time ({len(times)})",
                   f"{len(values)} translations")
        return None
    if np.any(np.diff(times) <= 0):
        errors.add(f"{where} animations[{a}].samplers[{s}].input", "increasing times [s]", times.tolist())
        return None
    if interpolation == "STEP" and len(times) > 1:
        # Held until the next key: each key once more just before the next one.
        gap = np.minimum(1e-6, np.diff(times) / 2)
        held = np.c_[times[1:] - gap].ravel()
        times = np.r_[times, held]
        order = np.argsort(times, kind="stable")
        times, values = times[order], np.r_[values, values[:-1]][order]
    return times, values


def _coupling(name: str, where: str, props: dict, kind: str, errors: Problems) -> dict | None:
    """The coupling written on a node (module docstring); its other body is checked later."""
    if not any(k in props for k in _COUPLING_KEYS):
        return None
    other = props.get("couple_to")
    if not isinstance(other, str) or not other:
        errors.add(f"{where}.couple_to", "the name of the object to couple to", other if other is not None else
                   "nothing (coupling properties without it)")
        other = None
    points, radius = None, None
    if "coupling_points" in props:
        flat = props["coupling_points"]
        ok = isinstance(flat, list) and len(flat) >= 3 and len(flat) % 3 == 0 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in flat)
        if not ok:
            errors.add(f"{where}.coupling_points", "a flat list x0, y0, z0, x1, ... [m] (3 numbers per point)",
                       flat)
        else:
            points = np.asarray(flat, float).reshape(-1, 3).tolist()
        if "coupling_radius" in props:
            errors.add(f"{where}.coupling_points", "coupling_radius or coupling_points, not both", "both")
    elif "coupling_radius" in props:
        radius = errors.number(props, "coupling_radius", where, minimum=0.0, unit="m")
        if kind not in ("fem", "cloth", None):
            errors.add(f"{where}.coupling_radius", "a fem or cloth body (its nodes are coupled), or coupling_points",
                       f"a {kind} body")
    else:
        errors.add(f"{where}.coupling_radius", "coupling_radius [m] or coupling_points", "neither")
    return {"a": name, "b": other, "points": points, "radius": radius,
            "stiffness": errors.number(props, "coupling_stiffness", where, positive=True, unit="N/m"),
            "damping": errors.number(props, "coupling_damping", where, default=0.0, minimum=0.0, unit="N s/m"),
            "collide": _boolean(props, "coupling_collide", where, errors)}


def _boolean(props: dict, key: str, where: str, errors: Problems) -> bool:
    """A bool property (Blender may write booleans as 0 / 1)."""
    value = props.get(key, False)
    if isinstance(value, int) and not isinstance(value, bool) and value in (0, 1):
        return bool(value)
    return errors.boolean(props, key, where, default=False)


def read_gltf_scene(path) -> SceneFile:
    """A :class:`~softvr.scene.SceneFile` from a glTF / GLB scene whose nodes carry softvr
    properties as extras (module docstring)."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise InputError("scene", "an existing glTF / GLB file", "no such file", source=str(path))
    doc, binary = _gltf_json(path, with_binary=True)
    buffers = _Buffers(path, doc, binary)
    errors = Problems(str(path), "glTF scene")
    scenes = doc.get("scenes") or [{}]
    scene_props = _properties(scenes[doc.get("scene", 0)].get("extras"))
    simulation = {"dt": errors.number(scene_props, "dt", "scene", default=0.005, positive=True, unit="s"),
                  "steps_per_frame": errors.integer(scene_props, "steps_per_frame", "scene", default=4, minimum=1),
                  "frames": errors.integer(scene_props, "frames", "scene", default=100, minimum=1),
                  "gravity": (0.0, 0.0, -9.81),
                  "friction": errors.number(scene_props, "friction", "scene", default=0.5, minimum=0.0),
                  "pgs_iterations": 500, "contact_margin": 0.005}
    start_time = errors.number(scene_props, "start_time", "scene", unit="s") if "start_time" in scene_props else None
    display = _display(scene_props, path.parent, errors) if "display" in scene_props else None
    nodes = doc.get("nodes", [])
    parent = {child: i for i, node in enumerate(nodes) for child in node.get("children", [])}
    loaded = trimesh.load(path, force="scene")
    materials, adhesions, bodies, couplings, moving, named = {}, {}, [], [], [], {}
    for i, node in enumerate(nodes):
        props = _properties(node.get("extras"))
        if not props:
            continue
        name = node.get("name") or f"node {i}"
        where = f"node {name!r}"
        kind = errors.choice(props, "type", where, _GLTF_TYPES)
        named[name] = kind
        coupling = _coupling(name, where, props, kind, errors)
        if coupling is not None:
            couplings.append((where, coupling))
        if name not in loaded.graph.nodes_geometry:
            errors.add(where, "a node with a triangle mesh", "no mesh")
            continue
        transform, geometry = loaded.graph[name]
        mesh = loaded.geometry[geometry]
        v = _z_up(trimesh.transformations.transform_points(np.asarray(mesh.vertices, float), transform))
        color = tuple(float(c) for c in np.asarray(getattr(mesh.visual, "main_color", (204, 153, 128, 255)))[:3] / 255)
        spec = BodySpec(name=name, type=kind, shape="cloth" if kind == "cloth" else "mesh", color=color)
        spec.mesh_data = (v, np.asarray(mesh.faces, np.int32))
        if "collides_with" in props:
            others = props["collides_with"]
            if not isinstance(others, str):
                errors.add(f"{where}.collides_with", "node names, comma-separated", others)
            else:
                spec.collides_with = tuple(o.strip() for o in others.split(",") if o.strip())
        if kind in ("rigid", "fem", "tool"):
            materials[name] = {
                "young": errors.number(props, "young", where, default=1e5, positive=True, unit="Pa"),
                "poisson": errors.number(props, "poisson", where, default=0.3, minimum=-0.99, maximum=0.5),
                "density": errors.number(props, "density", where, default=1000.0, positive=True, unit="kg/m^3"),
                "alpha": errors.number(props, "alpha", where, default=0.0, minimum=0.0, unit="1/s"),
                "beta": errors.number(props, "beta", where, default=0.0, minimum=0.0, unit="s")}
            spec.material = name
        sticky = _adhesion(props, "adhesion_", where, errors)
        if sticky is not None:
            adhesions[name] = sticky
            spec.adhesion = name
        if kind == "fem":
            spec.cells = errors.number(props, "cells", where, default=0.02, positive=True, unit="m")
        if "fixed_below" in props:
            spec.fixed_below = errors.number(props, "fixed_below", where, unit="m")
        if kind == "cloth":
            spec.cloth = {"area_density": errors.number(props, "area_density", where, default=0.2, positive=True),
                          **{k: errors.number(props, k, where, default=d, minimum=0.0) for k, d in (
                              ("stretch", 200.0), ("shear", 20.0), ("bend", 1.0), ("damping", 0.05),
                              ("alpha", 0.1))}}
        if kind == "tool":
            spec.tool = {"stiffness": errors.number(props, "stiffness", where, positive=True, unit="N/m"),
                         "damping": errors.number(props, "damping", where, default=0.0, minimum=0.0, unit="N s/m"),
                         "haptics": _boolean(props, "haptics", where, errors),
                         "max_force": errors.number(props, "max_force", where, default=10.0, positive=True,
                                                    unit="N")}
        if kind in ("kinematic", "tool"):
            # The reference point: the node's world translation; the mesh is kept relative to it.
            origin = _z_up(np.asarray(transform, float)[:3, 3])
            spec.mesh_data = (v - origin, spec.mesh_data[1])
            spec.position = tuple(float(x) for x in origin)
            keys = _translation_keys(doc, buffers, i, where, errors)
            if keys is not None and i in parent:
                errors.add(f"{where} animation", "an animated object without a parent (its keys are its local "
                           "translation)", f"a child of node {nodes[parent[i]].get('name') or parent[i]!r}")
                keys = None
            moving.append((spec, keys))
        bodies.append(spec)
    # Simulation time 0: the scene's start time, else the first key of any motion.
    starts = [keys[0][0] for _, keys in moving if keys is not None]
    t0 = start_time if start_time is not None else (min(starts) if starts else 0.0)
    for spec, keys in moving:
        if keys is None:  # holds still
            spec.motion = {"times": [0.0], "positions": [list(spec.position)]}
        else:
            times, translations = keys
            positions = _z_up(translations)
            spec.motion = {"times": (times - t0).tolist(), "positions": positions.tolist()}
            # It starts where its motion starts (whatever frame Blender was on at export).
            spec.position = tuple(float(x) for x in _linear_at(times - t0, positions, 0.0))
    names = {b.name for b in bodies}
    for spec in bodies:
        for other in spec.collides_with or ():
            if other not in names:
                errors.add(f"node {spec.name!r}.collides_with", f"names of softvr objects ({', '.join(sorted(names))})",
                           repr(other))
    for where, c in couplings:
        other = c["b"]
        if named.get(c["a"]) == "fixed":
            errors.add(f"{where}.couple_to", "couplings on a body (a fixed glTF object is an obstacle, not a body)",
                       "a fixed object")
        if other is None:
            continue
        if other not in named:
            errors.add(f"{where}.couple_to", f"the name of a softvr object ({', '.join(sorted(named))})", repr(other))
        elif other == c["a"]:
            errors.add(f"{where}.couple_to", "another object than itself", repr(other))
        elif named[other] == "fixed":
            errors.add(f"{where}.couple_to", "a body (a fixed glTF object is an obstacle, not a body: mark it "
                       "kinematic to hold it still)", f"{other!r}, a fixed object")
    if not bodies:
        errors.add("nodes", "at least one node with a softvr_type custom property", "none")
    ground = scene_props.get("ground", True)
    ground_adhesion = _adhesion(scene_props, "ground_adhesion_", "scene", errors)
    errors.raise_if_any()
    if ground_adhesion is not None:
        adhesions["ground"] = ground_adhesion
    planes = [{"point": (0.0, 0.0, 0.0), "normal": (0.0, 0.0, 1.0), "friction": simulation["friction"],
               "size": 3.0, "adhesion": None if ground_adhesion is None else "ground"}] if ground else []
    return SceneFile(path=path, simulation=simulation,
                     render={"size": (640, 480), "camera": "iso", "bounds": None, "azimuth": 0.0, "elevation": 0.0,
                             "zoom": 1.0},
                     materials=materials, adhesions=adhesions, planes=planes, spheres=[], bodies=bodies, filters=[],
                     couplings=[c for _, c in couplings], display=display)


def _adhesion(props: dict, prefix: str, where: str, errors: Problems) -> dict | None:
    """The :class:`softvr.contact.Adhesion` parameters of the ``softvr_<prefix>*`` extras, or
    None when there are none."""
    from softvr.scene.schema import adhesion_parameters

    table = {k[len(prefix):]: v for k, v in props.items() if k.startswith(prefix)}
    return adhesion_parameters(table, f"{where}.{prefix.rstrip('_')}", errors) if table else None


def _display(scene_props: dict, folder: Path, errors: Problems) -> str | None:
    """``softvr_display``: a :mod:`softvr.cave` display preset, or a display file (relative to
    the scene's folder)."""
    from softvr.cave.display import PRESETS

    value = scene_props["display"]
    if isinstance(value, str) and value in PRESETS:
        return value
    if isinstance(value, str) and value.lower().endswith(".toml") and (folder / value).is_file():
        return str((folder / value).resolve())
    errors.add("scene.display", f"a display preset ({', '.join(PRESETS)}) or an existing display file (.toml)",
               repr(value))
    return None


def _linear_at(times, values, t: float) -> np.ndarray:
    """Keys ``values`` [k, 3] at ``times`` [k], linear in between, held outside, at ``t``."""
    return np.array([np.interp(t, times, values[:, j]) for j in range(values.shape[1])])
