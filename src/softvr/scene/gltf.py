"""glTF scenes with softvr parameters in their extras: what stock Blender exports.

Blender's glTF exporter writes an object's *custom properties* as the node's ``extras`` and the
scene's as the scene's ``extras`` (Include > Custom Properties, on by default), so a scene
authored in Blender needs no add-on: give objects properties named after the scene file's
fields, prefixed ``softvr_``:

============================  ================================================================
node extras                   meaning (as in the TOML scene file, :mod:`softvr.scene.schema`)
============================  ================================================================
``softvr_type``               rigid | fem | cloth | fixed | kinematic | tool, or volume | model
                              (an Empty: below); nodes without it are not simulated
``softvr_density``            [kg/m^3] (rigid, fem, tool)
``softvr_young``              [Pa] (fem)
``softvr_poisson``            (fem)
``softvr_alpha``              [1/s], ``softvr_beta`` [s]: Rayleigh damping (fem)
``softvr_cells``              [m] tet cube size (fem)
``softvr_fixed_below``        [m] clamp nodes below (``softvr_fixed_above``: above) this height
                              (fem, cloth)
``softvr_drive_times``        [s] and ``softvr_drive_offsets`` (x0, y0, z0, x1, ... [m], 3 per
                              time): the clamped nodes move by these offsets, linear between,
                              held after (fem, cloth; ``[body.drive]``)
``softvr_velocity``           [m/s] (3 numbers) start velocity, with ``softvr_angular_velocity``
                              [rad/s] about ``softvr_spin_centre`` [m] (default: the object's
                              origin; rigid bodies: their centre of mass)
``softvr_area_density``       [kg/m^2], ``softvr_stretch``, ``softvr_shear``, ``softvr_bend`` (cloth)
``softvr_stiffness``          [N/m] hand - tool coupling (tool, required)
``softvr_angular_stiffness``  [N m/rad] the coupling's hold on the tool's orientation (tool; default 0)
``softvr_damping``            [N s/m] (tool; default 0), ``softvr_haptics`` (tool: true runs the
                              1 kHz haptic loop; default false), ``softvr_max_force`` [N] (tool)
``softvr_render_mesh``        another object's name (scenery: no ``softvr_type``): its mesh is
                              drawn instead, where it is, carried by the body (thesis 5.1;
                              TOML ``render_mesh``)
``softvr_collision_triangles`` the collision surface simplified to about this many triangles
                              (rigid, fem, kinematic, tool)
``softvr_collides_with``      "a, b": collide with these bodies only (node names or model parts,
                              comma-separated)
``softvr_couple_to``          another body's node name or a model part: zero-length springs to
                              it (a coupling)
``softvr_coupling_stiffness`` [N/m] per spring (required with ``softvr_couple_to``)
``softvr_coupling_damping``   [N s/m] (default 0), ``softvr_coupling_collide`` (default false)
``softvr_coupling_radius``    [m] springs at this body's nodes within it of the other's surface
                              (fem, cloth, volume) ...
``softvr_coupling_points``    ... or at these world points: x0, y0, z0, x1, ... [m] (any body)
``softvr_sensor_position``    a sensor's name: the object's centre sampled every frame (a
                              ``[[sensor]]`` on this body; also ``softvr_sensor_coupling_force``,
                              ``softvr_sensor_contact_force``, ``softvr_sensor_hand_force`` (a
                              tool), one of each kind per object)
``softvr_sensor_contact_force_other`` the contact sensor's ``other``: an object's name or "static"
``softvr_adhesion_stiffness`` [N/m^3]: the surface is adhesive (thesis ch. 4); with
                              ``softvr_adhesion_max_energy`` [J/m^2], ``..._viscosity`` (all
                              three required) and optional ``..._bonding_rate``,
                              ``..._saturation``, ``..._initial``, ``..._debond_gap`` [m]
============================  ================================================================

Every body's ``position`` is its object's origin (the node's world translation) and its mesh,
taken in world coordinates (the node transform applied) and turned from glTF's y-up to softvr's
z-up, is kept relative to it; its material's base colour is its colour. Vectors in custom
properties (velocities, spin centre, drive offsets, coupling points, gravity) are in *Blender's*
world coordinates (z up), which are softvr's: custom properties are written verbatim, not turned
to glTF's y-up like the meshes (the add-on's *Pick coupling vertices* writes the points).

**Volumes and models** are Empties (nodes without a mesh; their transform is not used):
``softvr_type = "volume"`` is the scene's ``[volume]``, its FEM body named as the node, with the
``[volume]`` fields prefixed (``softvr_file``: a volume file or folder relative to the glTF's
folder, or a dataset; ``softvr_unit``, ``softvr_cells`` (3 integers), ``softvr_threshold``,
``softvr_skin_triangles``, ``softvr_fix_denser_than``, ``softvr_alpha``, ``softvr_beta``,
``softvr_preset``, ``softvr_render_step``, ``softvr_incremental``, ``softvr_mask``,
``softvr_animation``); it may carry coupling and sensor properties. ``softvr_type = "model"`` is a
``[[model]]``: ``softvr_file`` (a parts file .toml, or a built model .npz, relative to the
glTF's folder), optional ``softvr_colors`` / ``softvr_opacity`` (part name -> value). Its parts
are bodies named as the parts, for couplings and ``softvr_collides_with``.

Scene extras: ``softvr_dt`` [s], ``softvr_steps_per_frame``, ``softvr_frames``,
``softvr_friction``, ``softvr_gravity`` [m/s^2], ``softvr_pgs_iterations``, ``softvr_pgs_tolerance`` [m/s],
``softvr_contact_margin`` [m], ``softvr_rotation_lag`` [rad], ``softvr_edge_contacts`` (false: vertex-triangle
contacts only),
``softvr_collision_free_start`` (soft bodies that start
crossing another are pushed out of it first; the add-on sets it), ``softvr_ground`` (true: a
ground plane at z = 0;
``softvr_ground_adhesion_*`` as a node's ``softvr_adhesion_*`` make it adhesive),
``softvr_display`` (the screens it is shown on: a :mod:`softvr.cave` preset or a display file),
``softvr_start_time`` [s] (the animation time that is the simulation's t = 0; default: the first
key of the kinematic bodies' and tools' animations), and the ``[render]`` fields
``softvr_size`` [w, h], ``softvr_camera``, ``softvr_azimuth`` [deg], ``softvr_elevation``
[deg], ``softvr_zoom``, ``softvr_bounds`` [m], ``softvr_background``,
``softvr_background_top`` (r, g, b), ``softvr_light_kit``. Booleans may be 0 / 1 (as Blender
may write them). Every bad property is reported at once, named by the node; a node takes the
properties of its type only (a rigid or tool object's material is its ``softvr_density``, so
its ``softvr_poisson`` is refused as a fem object's), another type's named with the nearest
its own type takes (:data:`_NODE_KEYS`, from the TOML description's ``BODY_KEYS``).

**Lights**: the ``KHR_lights_punctual`` lights (Blender: Include > Punctual Lights) are the
scene's lights (``[[light]]``), shining from the light node's world position: a directional
(sun) or spot light towards its node's -z axis (the spot's cone is not kept), a point light
towards the scene's origin. Their intensity (1: full) undoes Blender's export in its default
lighting mode (Standard): a sun's is its strength [W/m^2] (glTF lux / 683), a point or spot
lamp's its power [W] / 1000 (glTF candela 4 pi / 683 / 1000), so Blender's default sun
(1 W/m^2) and lamp (1000 W) have intensity 1.

**Kinematic bodies and tools** move as the node's glTF *translation and rotation animations*
(what Blender writes for an object with location and rotation keyframes): the node's keys,
turned z-up and each channel sampled at the union of both channels' key times, are the body's
``motion`` (positions linear in between, rotations slerped; STEP keys are held, CUBICSPLINE
keys pass through their values, their tangents dropped). Keys are the node's *local*
transform, so only an object without a parent may be animated. The motion moves the node's
origin and turns the body about it (its mesh kept in the node's own axes); the body starts
where the motion starts (``position`` and ``rotation`` the keyed ones at t = 0, whatever frame
Blender was on at export). A tool's handle is a point: rotation keys that turn it are
refused. Scale keys are ignored. A kinematic body or tool without an animation holds still.

**Couplings** (zero-length springs, thesis 5.3.2) are written on one of the two bodies.
"""

from __future__ import annotations

import base64
import binascii
import warnings
from pathlib import Path
from urllib.parse import unquote

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from softvr.errors import InputError, Problems, raise_all
from softvr.files import checked_file, file_name, inside_folder, native_read
from softvr.gltf import COMPONENTS, gltf_json
from softvr.scene._description import (BODY_KEYS, GLTF_CELLS, MATERIAL_KEYS, SENSOR_KINDS, STATIC, Body, Coupling,
                                       Drive, Material, ModelTable, Plane, Render, Simulation, Volume, read_table)
from softvr.scene.display import PRESETS as DISPLAY_PRESETS
from softvr.scene.display import read_display
from softvr.scene.schema import (BodySpec, SceneFile, _model, _volume, adhesion_parameters, render_settings,
                                 sensor_tables, simulation_settings)

__all__ = ["has_softvr_bodies", "read_gltf_scene", "read_gltf_scene_with_problems"]

_PREFIX = "softvr_"
_GLTF_TYPES = ("rigid", "fem", "cloth", "fixed", "kinematic", "tool", "volume", "model")
_FLOAT = 5126  # accessor componentType of 32-bit floats
#: A coupling written on a node: its other body and a ``[[coupling]]``'s fields, prefixed.
_COUPLING_KEYS = ("couple_to", *(f"coupling_{k}" for k in Coupling.model_fields if k not in ("a", "b")))
#: The sensors written on a node (the sensor's body): ``sensor_<kind>`` = its name, one of each
#: kind of :data:`~softvr.scene._description.SENSOR_KINDS`, and the contact sensor's ``other``.
_SENSOR_KEYS = (*(f"sensor_{kind}" for kind in SENSOR_KINDS), "sensor_contact_force_other")
#: A body node's own custom properties: the ``[[body]]`` fields its mesh and transform do not give.
_NODE_BODY_KEYS = ("cells", "fixed_below", "fixed_above", "velocity", "angular_velocity", "spin_centre", "area_density",
                   "stretch", "shear", "bend", "damping", "alpha", "stiffness", "angular_stiffness", "haptics",
                   "max_force", "collision_triangles")
#: The custom properties of a node of each type: a body's (and ``adhesion_*``, :class:`~softvr.scene.
#: _description.Adhesion`'s) are its type's ``[[body]]`` keys (:data:`~softvr.scene._description.BODY_KEYS`)
#: that a node gives, its material's (:data:`~softvr.scene._description.MATERIAL_KEYS`), a drive's (refused
#: on other types by a rule of its own) and a coupling's; a volume's its ``[volume]`` fields (its name is the
#: node's) and a coupling's; a model's its ``[[model]]`` fields. Another type's are refused, named with the
#: nearest of these.
_NODE_KEYS = {**{kind: {"type", "drive_times", "drive_offsets", *_COUPLING_KEYS, *MATERIAL_KEYS.get(kind, ()),
                        *(k for k in keys if k in (*_NODE_BODY_KEYS, "render_mesh", "collides_with")),
                        # A fixed object is an obstacle, not a body: nothing to sense.
                        *(_SENSOR_KEYS if kind != "fixed" else ())}
                 for kind, keys in BODY_KEYS.items()},
              "volume": {"type", *_COUPLING_KEYS, *_SENSOR_KEYS, *(k for k in Volume.model_fields if k != "name")},
              "model": {"type", *ModelTable.model_fields}}
_ANY_NODE_KEY = set().union(*_NODE_KEYS.values())
#: Every custom property of the scene (and ``ground_adhesion_*``).
_SCENE_KEYS = {*Simulation.model_fields, *Render.model_fields, "start_time", "ground", "display"}
#: Properties that are booleans, which Blender may write as 0 / 1.
_BOOLEANS = ("haptics", "coupling_collide", "collision_free_start", "edge_contacts", "light_kit", "mask", "incremental",
             "ground")


class _Bad(Exception):
    """One problem (what, expected, found) while reading an accessor."""


class _Buffers:
    """The buffers of a glTF file (a GLB's BIN chunk, files next to a .gltf, ``data:`` URIs) and
    float accessors read from them."""

    def __init__(self, path: Path, doc: dict, binary: bytes | None):
        self.path, self.doc, self.binary = path, doc, binary
        self._cache: dict[int, bytes] = {}  # buffer index -> its bytes

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
                try:
                    data = base64.b64decode(payload, validate=True)
                except binascii.Error as exc:
                    raise _Bad(f"buffers[{i}].uri", "a base64 data: URI", str(exc)) from None
            else:  # inside the glTF's folder, a regular file (softvr.gltf's checks said so; again now)
                try:
                    file = checked_file(inside_folder(self.path.parent, unquote(uri), f"buffers[{i}].uri"),
                                        f"buffers[{i}].uri")
                except InputError as exc:
                    raise _Bad(exc.what, exc.expected, exc.found) from None
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
        k, count = COMPONENTS[a["type"]], a.get("count")
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
    return any(_properties(node.get("extras")) for node in gltf_json(path).get("nodes", []))


def _z_up(v) -> np.ndarray:
    """glTF y-up -> softvr z-up: (x, y, z) -> (x, -z, y)."""
    v = np.asarray(v, float)
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


def _channel_keys(doc: dict, buffers: _Buffers, node: int, path: str, where: str, errors: Problems):
    """Times [k] [s] and local values (glTF y-up) of the node's ``path`` animation:
    translations [k, 3] [m] ("translation") or unit quaternions [k, 4] (x, y, z, w)
    ("rotation"); None without one (or on a problem, recorded in ``errors``)."""
    found = []
    for a, animation in enumerate(doc.get("animations", [])):
        for c, channel in enumerate(animation.get("channels", [])):
            target = channel.get("target", {})
            if target.get("node") == node and target.get("path") == path:
                found.append((a, c, animation, channel))
    if not found:
        return None
    if len(found) > 1:
        errors.add(f"{where} animation", f"one {path} animation",
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
        values = buffers.floats(sampler.get("output"), ("VEC4",) if path == "rotation" else ("VEC3",))
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
        errors.add(f"{where} animations[{a}].samplers[{s}]", f"one {path} per time ({len(times)})",
                   f"{len(values)} {path}s")
        return None
    if path == "rotation" and np.any(np.abs(np.linalg.norm(values, axis=1) - 1.0) > 1e-3):
        errors.add(f"{where} animations[{a}].samplers[{s}].output", "unit quaternions (x, y, z, w)",
                   f"norms {np.linalg.norm(values, axis=1).round(4).tolist()}")
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


def _z_up_rotations(quaternions):
    """glTF y-up unit quaternions [k, 4] (x, y, z, w) -> the same turns in softvr's z-up frame
    (a scipy Rotation of k): R' = C R C^T for C of :func:`_z_up`, i.e. the axis turned by C."""
    q = np.asarray(quaternions, float)
    return Rotation.from_quat(np.c_[_z_up(q[:, :3]), q[:, 3]])


def _slerp_at(times, rotations, t):
    """Orientations ``rotations`` (a scipy Rotation of k) keyed at ``times`` [k] [s], slerped in
    between and held outside, at ``t`` [s] (a number, or an array for a Rotation of as many)."""
    if len(times) == 1:
        return rotations[np.zeros(np.shape(t), int)] if np.ndim(t) else rotations[0]
    return Slerp(times, rotations)(np.clip(t, times[0], times[-1]))


def _degrees(rotations) -> list:
    """x-then-y-then-z angles [deg] ([3], or [k, 3] for k orientations) of a scipy Rotation: the
    scene format's ``rotation`` and ``motion.rotations``."""
    with warnings.catch_warnings():
        # At gimbal lock scipy picks one of the many angle triples of the orientation: still exact.
        warnings.filterwarnings("ignore", "Gimbal lock", UserWarning)
        return rotations.as_euler("xyz", degrees=True).tolist()


def _node_motion(doc: dict, buffers: _Buffers, node: int, origin, where: str, errors: Problems):
    """The node's translation and rotation animations turned z-up and sampled at the union of
    their key times: times [k] [s], positions [k, 3] [m] (``origin`` [3] [m] throughout without
    translation keys) and orientations (a scipy Rotation of k; None without rotation keys).
    None without either animation (or on a problem, recorded in ``errors``)."""
    moves = _channel_keys(doc, buffers, node, "translation", where, errors)
    turns = _channel_keys(doc, buffers, node, "rotation", where, errors)
    if moves is None and turns is None:
        return None
    times = np.unique(np.concatenate([keys[0] for keys in (moves, turns) if keys is not None]))
    positions = np.tile(origin, (len(times), 1)) if moves is None else _z_up(_linear_at(moves[0], moves[1], times).T)
    rotations = None if turns is None else _slerp_at(turns[0], _z_up_rotations(turns[1]), times)
    return times, positions, rotations


def _world_matrix(nodes: list, parent: dict, i: int) -> np.ndarray:
    """Node ``i``'s world transform [4, 4] (glTF y-up): its matrix or translation, rotation
    and scale, after its parents'."""
    node = nodes[i]
    if "matrix" in node:
        local = np.asarray(node["matrix"], float).reshape(4, 4).T  # glTF matrices are column-major
    else:
        local = np.eye(4)
        local[:3, :3] = Rotation.from_quat(node.get("rotation", [0.0, 0.0, 0.0, 1.0])).as_matrix() * np.asarray(
            node.get("scale", [1.0, 1.0, 1.0]), float)
        local[:3, 3] = node.get("translation", [0.0, 0.0, 0.0])
    return local if i not in parent else _world_matrix(nodes, parent, parent[i]) @ local


#: Blender's glTF exporter (lighting mode Standard, its default) writes a sun of S [W/m^2] as
#: 683 S [lux] and a point or spot lamp of P [W] as 683 P / (4 pi) [cd]; softvr's light
#: intensity (1: full) is S, and P / 1000 for a lamp (Blender's default 1000 W lamp is 1).
_LUMENS_PER_WATT = 683.0
_LAMP_WATTS = 1000.0


def _lights(doc: dict, parent: dict, errors: Problems) -> list:
    """``[[light]]`` entries of the nodes' KHR_lights_punctual lights (module docstring)."""
    lights = doc.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    nodes, out = doc.get("nodes", []), []
    for i, node in enumerate(nodes):
        ref = node.get("extensions", {}).get("KHR_lights_punctual")
        if ref is None:
            continue
        where, k = f"node {node.get('name') or f'node {i}'!r}", ref.get("light")
        if not (isinstance(k, int) and 0 <= k < len(lights)):
            errors.add(f"{where}.extensions.KHR_lights_punctual.light", f"one of the file's {len(lights)} lights", k)
            continue
        light, w = lights[k], f"KHR_lights_punctual.lights[{k}]"
        kind = errors.choice(light, "type", w, ("directional", "point", "spot"))
        color = errors.vector(light, "color", w, default=[1.0, 1.0, 1.0])
        if color is not None and not all(0 <= c <= 1 for c in color):
            errors.add(f"{w}.color", "r, g, b in [0, 1]", list(color))
            color = None
        intensity = errors.number(light, "intensity", w, default=1.0, minimum=0.0)
        matrix = _world_matrix(nodes, parent, i)
        position = _z_up(matrix[:3, 3])
        if kind == "point":  # no direction: it shines towards the scene's origin
            focal_point = np.zeros(3)
            if np.allclose(position, focal_point):
                errors.add(where, "a point light away from the scene origin (it shines towards it)",
                           "one at the origin")
                continue
        else:  # glTF lights shine along their node's -z
            axis = matrix[:3, :3] @ [0.0, 0.0, -1.0]
            focal_point = position + _z_up(axis / np.linalg.norm(axis))
        if kind is None or intensity is None or color is None:
            continue
        scale = 1.0 if kind == "directional" else 4.0 * np.pi / _LAMP_WATTS
        out.append({"position": tuple(float(x) for x in position),
                    "focal_point": tuple(float(x) for x in focal_point), "color": color,
                    "intensity": intensity * scale / _LUMENS_PER_WATT})
    return out


def _flat_triples(flat, field: str, expected: str, where: str, errors: Problems) -> list | None:
    """A flat custom property x0, y0, z0, x1, ... [m] as [[x0, y0, z0], ...] (Blender's custom
    properties hold flat lists); else a problem named ``field``, and None."""
    if isinstance(flat, list) and flat and len(flat) % 3 == 0 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in flat):
        return np.asarray(flat, float).reshape(-1, 3).tolist()
    errors.add(f"{where}.{field}", expected, flat)
    return None


def _renamed(model, table: dict, where: str, prefix: str, errors: Problems, **options):
    """``table`` read as ``model`` (:func:`read_table`), its problems named as the custom
    properties they came from: ``<where>.<prefix><field>`` (``node 'gel'.coupling_stiffness``)."""
    found = Problems(errors.source, errors.kind)
    out, bad = read_table(model, table, where, found, **options)
    head = f"{where}."
    errors.items += [(f"{head}{prefix}{w[len(head):]}" if w.startswith(head) else w, e, f) for w, e, f in found.items]
    return out, bad


def _coupling(name: str, where: str, props: dict, kind: str, errors: Problems) -> dict | None:
    """The coupling written on a node (module docstring) as a ``[[coupling]]``
    (:class:`~softvr.scene._description.Coupling`); its other body is checked later."""
    if not any(k in props for k in _COUPLING_KEYS):
        return None
    other = props.get("couple_to")
    if not isinstance(other, str) or not other:
        errors.add(f"{where}.couple_to", "the name of the object to couple to", other if other is not None else
                   "nothing (coupling properties without it)")
        other = None
    table = {k[len("coupling_"):]: v for k, v in props.items() if k.startswith("coupling_") and k != "coupling_points"}
    if "coupling_points" in props:
        table["points"] = _flat_triples(props["coupling_points"], "coupling_points",
                                        "a flat list x0, y0, z0, x1, ... [m] (3 numbers per point)", where, errors)
    elif "coupling_radius" in props and kind not in ("fem", "cloth", None):
        errors.add(f"{where}.coupling_radius", "a fem or cloth body (its nodes are coupled), or coupling_points",
                   f"a {kind} body")
    coupling, _ = _renamed(Coupling, {k: v for k, v in table.items() if v is not None}, where, "coupling_", errors)
    return {**coupling.model_dump(), "a": name, "b": other,
            "points": table.get("points"), "radius": None if "points" in table else coupling.radius}


def _booleans(table: dict) -> dict:
    """``table`` with the values 0 / 1 of its boolean properties as false / true (Blender may
    write booleans as 0 / 1)."""
    return {k: bool(v) if k in _BOOLEANS and type(v) is int and v in (0, 1) else v for k, v in table.items()}


def _node_keys(props: dict, kind, where: str, errors: Problems) -> dict:
    """A node's custom properties its type takes (:data:`_NODE_KEYS`); the others reported, each
    named with the nearest it takes, another type's with the types that take it."""
    valid = _NODE_KEYS.get(kind, _ANY_NODE_KEY)
    others = {k: f"a key of {' | '.join(t for t, keys in _NODE_KEYS.items() if k in keys)} objects"
              for k in _ANY_NODE_KEY - valid}
    sticky = "adhesion_" if kind in BODY_KEYS else None  # a body's adhesion: Adhesion's fields, checked there
    bad = errors.unknown_keys([k for k in props if not (sticky and k.startswith(sticky))], valid, where,
                              others=others, what=f"a key of a {kind} object")
    return {k: v for k, v in props.items() if k not in bad}


def read_gltf_scene(path) -> SceneFile:
    """A :class:`~softvr.scene.SceneFile` from a glTF / GLB scene whose nodes carry softvr
    properties as extras (module docstring). Raises one :class:`~softvr.errors.InputError`
    listing every problem."""
    scene, problems = read_gltf_scene_with_problems(path)
    raise_all(problems, str(path), "glTF scene")
    return scene


def _node_body(name: str, where: str, kind: str, props: dict, errors: Problems):
    """A body node's extras as a ``[[body]]`` and its ``[material.NAME]`` (the description's
    models, without the shape: the node's mesh is it). The glTF rules between fields are here."""
    material_keys = MATERIAL_KEYS.get(kind, ())
    table = {k: v for k, v in props.items() if k in _NODE_BODY_KEYS and k not in material_keys}
    if "drive_times" in props or "drive_offsets" in props:
        if kind not in ("fem", "cloth"):
            errors.add(f"{where}.drive_offsets", "a drive only on a fem or cloth object (it moves the held nodes)",
                       f"a {kind} object")
        elif "fixed_below" not in props and "fixed_above" not in props:
            errors.add(f"{where}.drive_offsets", "held nodes to drive: softvr_fixed_below or softvr_fixed_above",
                       "neither")
        offsets = _flat_triples(props.get("drive_offsets"), "drive_offsets",
                                "x0, y0, z0, x1, ... [m]: 3 numbers per time", where, errors)
        drive, _ = _renamed(Drive, {"times": props.get("drive_times"), **({"offsets": offsets} if offsets else {})},
                            where, "drive_", errors)
        table["drive"] = None if drive is None or drive.offsets is None or drive.times is None else drive.model_dump()
    if kind == "tool" and "stiffness" not in props:
        errors.add(f"{where}.stiffness", "a number [N/m]", "nothing")
    if kind == "fem" and isinstance(props.get("cells"), list):
        errors.add(f"{where}.cells", "a number > 0 [m]", props["cells"])
        table.pop("cells")
    body, _ = read_table(Body, {"name": name, "type": kind, **{k: v for k, v in table.items() if v is not None}},
                         where, errors, rules=False)
    material = None
    if material_keys:
        read, _ = read_table(Material, {k: props[k] for k in material_keys if k in props}, where, errors)
        material = read.model_dump()
    return body, material


def _node_spec(doc: dict, loaded, buffers: _Buffers, i: int, where: str, kind: str, props: dict, parent: dict,
               errors: Problems):
    """A body node as the builder takes it: its :class:`BodySpec` (mesh in world coordinates,
    z up, relative to its origin), its material and adhesion parameters (None without), and
    the keys of its animation (:func:`_node_motion`; None without one); None when the node has
    no triangle mesh."""
    import trimesh  # noqa: PLC0415 - 0.75 s here: loaded when a glTF's meshes are read, not with softvr.scene

    node, nodes = doc["nodes"][i], doc["nodes"]
    name = node.get("name") or f"node {i}"
    keys = None
    if name not in loaded.graph.nodes_geometry:
        errors.add(where, "a node with a triangle mesh", "no mesh")
        return None
    transform, geometry = loaded.graph[name]
    mesh = loaded.geometry[geometry]
    if not isinstance(mesh, trimesh.Trimesh):  # points or lines (a primitive's mode)
        errors.add(where, "a node with a triangle mesh", f"a {type(mesh).__name__}")
        return None
    v = _z_up(trimesh.transformations.transform_points(np.asarray(mesh.vertices, float), transform))
    faces = np.asarray(mesh.faces)
    if not np.all(np.isfinite(v)) or len(faces) and (faces.min() < 0 or faces.max() >= len(v)):
        errors.add(where, "a mesh of finite vertices whose triangles index them",
                   f"{len(v)} vertices, triangle indices {faces.min() if len(faces) else 0} .. "
                   f"{faces.max() if len(faces) else 0}")
        return None
    base = getattr(mesh.visual, "main_color", None)  # the material's base colour; else a body's default
    color = Body.model_fields["color"].default if base is None else tuple(
        float(c) for c in np.asarray(base)[:3] / 255)
    # Its position is the object's origin (the node's world translation), as a TOML body's;
    # its mesh is kept relative to it.
    origin = _z_up(np.asarray(transform, float)[:3, 3])
    body, material = _node_body(name, where, kind, props, errors)
    spec = BodySpec(name=name, type=kind, shape="cloth" if kind == "cloth" else "mesh", color=color,
                    position=tuple(float(x) for x in origin), fixed_below=body.fixed_below,
                    fixed_above=body.fixed_above, collision_triangles=body.collision_triangles,
                    # Custom properties are verbatim Blender world coordinates: z up, as softvr's.
                    velocity=body.velocity, angular_velocity=body.angular_velocity, spin_centre=body.spin_centre)
    spec.mesh_data = (v - origin, np.asarray(mesh.faces, np.int32))
    unturn = None  # a rotating kinematic body's mesh is kept in the node's own axes
    if "collides_with" in props:
        others = props["collides_with"]
        if not isinstance(others, str):
            errors.add(f"{where}.collides_with", "node names, comma-separated", others)
        else:
            spec.collides_with = tuple(o.strip() for o in others.split(",") if o.strip())
    spec.material = name if material is not None else None
    sticky = _adhesion(props, "adhesion_", where, errors)
    spec.adhesion = name if sticky is not None else None
    if kind == "fem":
        spec.cells = GLTF_CELLS if body.cells is None else float(body.cells)
    if body.drive is not None:
        spec.drive = {"times": body.drive.times, "offsets": body.drive.offsets}
    if kind == "cloth":
        spec.cloth = body.cloth_parameters()
    if kind == "tool":
        spec.tool = body.tool_parameters()
    if kind in ("kinematic", "tool"):
        keys = _node_motion(doc, buffers, i, origin, where, errors)
        if keys is not None and i in parent:
            errors.add(f"{where} animation", "an animated object without a parent (its keys are its local "
                       "transform)", f"a child of node {nodes[parent[i]].get('name') or parent[i]!r}")
            keys = None
        if keys is not None and keys[2] is not None:
            if kind == "tool":
                turned = float((keys[2][0].inv() * keys[2]).magnitude().max())
                if turned > 1e-6:
                    errors.add(f"{where} animation", "location keys only on a tool (its handle is a point; a "
                               "kinematic object may rotate)",
                               f"rotation keys turning it {np.degrees(turned):.3g} deg")
                keys = (*keys[:2], None)  # a still orientation: its rest one
            elif "matrix" in node:
                errors.add(f"{where}.matrix", "translation, rotation and scale on an animated node (glTF 2.0)",
                           "a matrix")
            else:
                # Its keys turn the node's own axes: its mesh in them (its rest rotation undone).
                unturn = _z_up_rotations([node.get("rotation", [0.0, 0.0, 0.0, 1.0])])[0].inv()
                spec.mesh_data = (unturn.apply(spec.mesh_data[0]), spec.mesh_data[1])
    if "render_mesh" in props:
        # Another object's mesh drawn instead (thesis 5.1), placed as it is and carried by the body.
        other = props["render_mesh"]
        if not isinstance(other, str) or other not in loaded.graph.nodes_geometry or not isinstance(
                loaded.geometry[loaded.graph[other][1]], trimesh.Trimesh):
            errors.add(f"{where}.render_mesh", "the name of an object with a triangle mesh", repr(other))
        else:
            drawn, geometry = loaded.graph[other]
            shape = loaded.geometry[geometry]
            vertices = _z_up(trimesh.transformations.transform_points(np.asarray(shape.vertices, float),
                                                                      drawn)) - origin
            if unturn is not None:
                vertices = unturn.apply(vertices)
            spec.render_mesh = (vertices, np.asarray(shape.faces, np.int32))
    return spec, material, sticky, keys


def read_gltf_scene_with_problems(path) -> tuple[SceneFile, list]:
    """A glTF scene's problems, and the scene without the objects that have one (as
    :func:`softvr.scene.schema.read_scene_with_problems` for TOML: ``softvr check`` builds the
    rest to find bodies that start crossing). An object's bad coupling properties leave out the
    coupling, not the object; the coupled pair still does not collide. An unreadable file
    raises :class:`~softvr.errors.InputError`."""
    import trimesh  # noqa: PLC0415 - 0.75 s here: loaded when a glTF's meshes are read, not with softvr.scene

    path = checked_file(path, "scene")
    doc, binary = gltf_json(path, with_binary=True)
    buffers = _Buffers(path, doc, binary)
    errors = Problems(str(path), "glTF scene")
    scenes = doc.get("scenes") or [{}]
    scene_props = _booleans(_properties(scenes[doc.get("scene", 0)].get("extras")))
    errors.unknown_keys([k for k in scene_props if not k.startswith("ground_adhesion_")], _SCENE_KEYS, "scene")
    simulation = simulation_settings({k: v for k, v in scene_props.items() if k in Simulation.model_fields}, "scene",
                                     errors)
    render = render_settings({k: v for k, v in scene_props.items() if k in Render.model_fields}, [], "scene", errors)
    start_time = errors.number(scene_props, "start_time", "scene", unit="s") if "start_time" in scene_props else None
    display = _display(scene_props, path.parent, errors) if "display" in scene_props else None
    nodes = doc.get("nodes", [])
    parent = {child: i for i, node in enumerate(nodes) for child in node.get("children", [])}
    loaded = native_read(lambda file: trimesh.load(file, force="scene"), path, "glTF meshes",
                         "meshes trimesh can read")
    materials, adhesions, bodies, couplings, moving, named = {}, {}, [], [], [], {}
    sensors: list[tuple[str, dict]] = []  # (where, a [[sensor]] table) of the nodes' sensor_* properties
    volumes: list[dict | None] = []  # one at most (more are a problem); None: one with a problem
    models: list[dict] = []
    model_nodes = []
    for i, node in enumerate(nodes):
        props = _booleans(_properties(node.get("extras")))
        if not props:
            continue
        name = node.get("name") or f"node {i}"
        where = f"node {name!r}"
        kind = errors.choice(props, "type", where, _GLTF_TYPES)
        props = _node_keys(props, kind, where, errors)
        if kind == "model":  # an Empty: a [[model]], whose parts become bodies
            models.append(_model(len(models), {k: v for k, v in props.items() if k != "type"}, path.parent, errors,
                                 where))
            model_nodes.append(where)
            continue
        named[name] = kind
        sensors += _node_sensors(name, where, props)
        coupling = _coupling(name, where, props, "fem" if kind == "volume" else kind, errors)
        if coupling is not None:
            couplings.append((where, coupling))
        if kind == "volume":  # an Empty: the [volume], its FEM body named as the node
            table = {k: v for k, v in props.items() if k not in ("type", *_COUPLING_KEYS)}
            volumes.append(_volume({**table, "name": name}, path.parent, errors, where))
            continue
        made = _node_spec(doc, loaded, buffers, i, where, kind, props, parent, errors)
        if made is None:
            continue
        spec, material, sticky, keys = made
        if material is not None:
            materials[name] = material
        if sticky is not None:
            adhesions[name] = sticky
        if kind in ("kinematic", "tool"):
            moving.append((spec, keys))
        bodies.append(spec)
    if len(volumes) > 1:
        errors.add("nodes", "one volume node (a scene has one volume)",
                   ", ".join(repr(v["name"]) for v in volumes if v is not None))  # (None: reported already)
    volume = volumes[0] if volumes else None
    parts = {name: kind for m in models for name, kind in m["parts"].items()}
    for name in sorted(set(parts) & set(named)):
        errors.add(f"node {name!r}", "a name no model part has", repr(name))
    # Simulation time 0: the scene's start time, else the first key of any motion.
    starts = [keys[0][0] for _, keys in moving if keys is not None]
    t0 = start_time if start_time is not None else (min(starts) if starts else 0.0)
    for spec, keys in moving:
        if keys is None:  # holds still
            spec.motion = {"times": [0.0], "positions": [list(spec.position)]}
            continue
        times, positions, rotations = keys
        times = times - t0
        spec.motion = {"times": times.tolist(), "positions": positions.tolist()}
        # It starts where its motion starts (whatever frame Blender was on at export).
        spec.position = tuple(float(x) for x in _linear_at(times, positions, 0.0))
        if rotations is not None:
            spec.motion["rotations"] = _degrees(rotations)
            spec.rotation = tuple(_degrees(_slerp_at(times, rotations, 0.0)))
    names = {b.name for b in bodies} | set(parts) | ({volume["name"]} if volume is not None else set())
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
        if other not in named and other not in parts:
            errors.add(f"{where}.couple_to", f"the name of a softvr object or model part "
                       f"({', '.join(sorted({*named, *parts}))})", repr(other))
        elif other == c["a"]:
            errors.add(f"{where}.couple_to", "another object than itself", repr(other))
        elif named.get(other) == "fixed":
            errors.add(f"{where}.couple_to", "a body (a fixed glTF object is an obstacle, not a body: mark it "
                       "kinematic to hold it still)", f"{other!r}, a fixed object")
    if not bodies and volume is None and not models:
        errors.add("nodes", "at least one node with a softvr_type custom property", "none")
    render["lights"] = _lights(doc, parent, errors)
    ground = errors.boolean(scene_props, "ground", "scene", default=True)
    ground_adhesion = _adhesion(scene_props, "ground_adhesion_", "scene", errors)
    # What is left to build: the objects without problems of their own (module docstring).
    whats = [w for w, _, _ in errors.items]

    def flawed(where: str, couplings_too: bool = False) -> bool:
        return any((w == where or w.startswith((where + ".", where + " "))) and
                   (couplings_too or not w.startswith(where + ".coupl")) for w in whats)

    bodies = [b for b in bodies if not flawed(f"node {b.name!r}")]
    models = [m for m, where in zip(models, model_nodes) if not flawed(where)]
    if volume is not None and (flawed(f"node {volume['name']!r}") or len(volumes) > 1):
        volume = None
    present = {b.name for b in bodies} | {name for m in models for name in m["parts"]} | (
        {volume["name"]} if volume is not None else set())
    kept = [c for where, c in couplings if not flawed(where, couplings_too=True) and {c["a"], c["b"]} <= present]
    filters = [(c["a"], c["b"]) for where, c in couplings
               if flawed(where, couplings_too=True) and not c["collide"] and {c["a"], c["b"]} <= present]
    # A sensor with a problem is left out, not its node (as a [[sensor]] is: after what is kept).
    coupled = {c[side] for _, c in couplings for side in "ab"} | set(parts)
    found = Problems(errors.source, errors.kind)
    sensed = sensor_tables(sensors, names - {n for n, k in named.items() if k == "fixed"}, coupled,
                           {n for n, k in named.items() if k == "tool"}, found)
    _name_sensor_problems(found, errors)
    if ground_adhesion is not None:
        adhesions["ground"] = ground_adhesion
    plane = Plane().model_dump()  # the ground: a [[plane]] of the description's defaults
    planes = [{**plane, "friction": simulation["friction"], "adhesion": "ground" if "ground" in adhesions else None}
              ] if ground else []
    scene = SceneFile(path=path, simulation=simulation, render=render, materials=materials, adhesions=adhesions,
                      planes=planes, spheres=[], bodies=bodies, filters=filters, couplings=kept, models=models,
                      volume=volume, display=display,
                      sensors=[t for t in sensed if {t["body"], t["other"]} - {None, STATIC} <= present])
    return scene, errors.items


def _node_sensors(name: str, where: str, props: dict) -> list:
    """The sensors written on a node (module docstring) as ``(where, [[sensor]] table)`` pairs,
    each named by the property that holds its name (``node 'probe'.sensor_position``)."""
    out = []
    for kind in SENSOR_KINDS:
        if f"sensor_{kind}" in props:
            table = {"name": props[f"sensor_{kind}"], "kind": kind, "body": name}
            if kind == "contact_force" and "sensor_contact_force_other" in props:
                table["other"] = props["sensor_contact_force_other"]
            out.append((f"{where}.sensor_{kind}", table))
    if "sensor_contact_force_other" in props and "sensor_contact_force" not in props:
        out.append((f"{where}.sensor_contact_force", {"kind": "contact_force", "body": name,
                                                      "other": props["sensor_contact_force_other"]}))
    return out


def _name_sensor_problems(found: Problems, errors: Problems) -> None:
    """The sensors' problems in ``found`` (:func:`~softvr.scene.schema.sensor_tables`, each
    below ``node 'NAME'.sensor_<kind>``) added to ``errors`` as the node properties they came
    from: a sensor's ``name`` is ``sensor_<kind>`` itself, its ``other``
    ``sensor_contact_force_other``, its ``body`` the node's (whose couplings a coupling_force
    sensor needs)."""
    for what, expected, value in found.items:
        head, _, field = what.rpartition(".")
        if field == "other":
            what = head.rsplit(".", 1)[0] + ".sensor_contact_force_other"
        elif field in ("name", "body"):
            what = head
        errors.add(what, expected, value)


def _adhesion(props: dict, prefix: str, where: str, errors: Problems) -> dict | None:
    """The :class:`softvr.contact.Adhesion` parameters of the ``softvr_<prefix>*`` extras, or
    None when there are none (or they have a problem)."""
    table = {k[len(prefix):]: v for k, v in props.items() if k.startswith(prefix)}
    return adhesion_parameters(table, f"{where}.{prefix.rstrip('_')}", errors) if table else None


def _display(scene_props: dict, folder: Path, errors: Problems) -> str | None:
    """``softvr_display``: a display preset (:data:`softvr.scene.display.PRESETS`), or a display
    file (relative to the scene's folder)."""
    value = scene_props["display"]
    if isinstance(value, str) and value in DISPLAY_PRESETS:
        return value
    if isinstance(value, str) and value.lower().endswith(".toml"):
        try:  # read now, to check it (as a TOML scene's [display] file)
            file = file_name(folder, value, "scene.display")
            read_display(file)
            return str(file.name)
        except InputError as exc:
            errors.add("scene.display", "a valid display file", str(exc))
            return None
    errors.add("scene.display", f"a display preset ({', '.join(DISPLAY_PRESETS)}) or an existing display file "
               "(.toml)", repr(value))
    return None


def _linear_at(times, values, t: float | np.ndarray) -> np.ndarray:
    """Keys ``values`` [k, 3] at ``times`` [k], linear in between, held outside, at ``t``."""
    return np.array([np.interp(t, times, values[:, j]) for j in range(values.shape[1])])
