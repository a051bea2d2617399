"""The scene file: one versioned TOML description of a simulation, validated all at once.

::

    format = "softvr-scene 1"

    [simulation]
    dt = 0.005                  # [s]
    steps_per_frame = 8
    frames = 120
    gravity = [0.0, 0.0, -9.81] # [m/s^2]
    friction = 0.5              # Coulomb, where a contact's sides give none
    pgs_iterations = 500
    contact_margin = 0.005      # [m]
    collision_free_start = false    # true: soft bodies that start crossing another body are
                                # pushed out of it first (thesis 5.2.3; softvr.model.push_apart)

    [render]
    size = [640, 480]           # [pixels]
    camera = "iso"              # front | side | top | iso ... (softvr.render.Camera views)
    azimuth = 0.0               # [deg]
    elevation = 0.0             # [deg]
    zoom = 1.0
    bounds = [-0.5, 0.5, -0.5, 0.5, 0.0, 0.6]   # [m] (optional: fitted to the bodies)
    background = [0.10, 0.11, 0.13]             # r, g, b at the bottom ...
    background_top = [0.32, 0.36, 0.43]         # ... and the top (a vertical gradient)
    light_kit = true            # VTK's key / fill / back / head lights (false: only [[light]]s)

    [[light]]                   # directional scene lights
    position = [1.0, -1.0, 2.0] # [m] shining from here ...
    focal_point = [0.0, 0.0, 0.0]   # [m] ... towards here
    color = [1.0, 0.95, 0.9]
    intensity = 0.8

    [material.jelly]            # named materials (FEM and rigid bodies)
    young = 1.5e5               # [Pa]
    poisson = 0.28
    density = 1000.0            # [kg/m^3]
    alpha = 1.0                 # [1/s] Rayleigh damping
    beta = 0.002                # [s]

    [adhesion.tacky]            # named softvr.contact.Adhesion parameters (thesis ch. 4)
    stiffness = 1e7
    max_energy = 5.0

    [[plane]]                   # static half-spaces
    point = [0.0, 0.0, 0.0]
    normal = [0.0, 0.0, 1.0]
    friction = 0.5
    adhesion = "tacky"          # optional
    size = 3.0                  # [m] drawn square

    [[sphere]]                  # static spheres
    center = [0.0, 0.0, 0.25]
    radius = 0.25
    friction = 0.5

    [[body]]
    name = "cube"
    type = "fem"                # rigid | fem | cloth | fixed | kinematic | tool
    box = [0.3, 0.3, 0.3]       # [m] shape: box, sphere = r, mesh = "file" (OBJ, STL, PLY, glTF), cloth = [w, h]
                                # (rigid: box | sphere | mesh; fem: box | sphere | mesh; fixed: box | mesh;
                                #  kinematic, tool: box | sphere | mesh; cloth: cloth)
    cells = 4                   # fem box: cubes per axis (5 tets each); fem sphere / mesh: cube size [m]
    material = "jelly"
    position = [0.0, 0.0, 0.3]  # [m] of the shape's centre
    rotation = [0.0, 0.0, 0.0]  # [deg] about x, then y, then z
    velocity = [0.0, 0.0, 0.0]  # [m/s]
    angular_velocity = [0.0, 0.0, 0.0]  # [rad/s] about spin_centre (default: position)
    fixed_below = 0.01          # [m] fem / cloth: clamp the nodes below (fixed_above: above) a height
    color = [0.9, 0.5, 0.4]
    adhesion = "tacky"

    scale = [1.0, 1.0, 1.0]     # sphere / mesh / tets: stretch along the shape's own axes first
    surface_quads = 1           # box: quads of its drawn / collision surface along the longest edge
    subdivisions = 3            # sphere: icosphere subdivisions of its surface (1280 triangles at 3)
    collides_with = ["floor"]   # optional: collide with these bodies only
    render_mesh = "hi.obj"      # optional: the drawn surface, when it is not the shape (thesis 5.1:
                                # render, collision and dynamics representations); placed as the shape
    collision_triangles = 500   # mesh / sphere: the collision surface simplified to about this many

    # fem: tets = "lip.vtu" (a tet mesh file: VTK, Gmsh, Medit, ...; nodes in metres) is a
    #      fourth shape; box: cells = n or [nx, ny, nz]
    # fem / cloth: [body.drive] times = [...] [s], offsets = [[dx, dy, dz], ...] [m]: the held
    #      nodes (fixed_below / fixed_above) move by these offsets (linear between, held after)
    # cloth: cloth = [w, h], quads = [nu, nv], area_density [kg/m^2], stretch, shear, bend [N/m],
    #        damping [N s/m], alpha [1/s]
    # kinematic: [body.motion] times = [...] [s], positions = [[x, y, z], ...] [m] (linear between),
    #            optional rotations = [[rx, ry, rz], ...] [deg]: the body's orientation at each time
    #            (about x, then y, then z, as rotation; slerp between), turning it about its position
    # tool: a rigid sphere, box or mesh (material) on a virtual coupling (stiffness [N/m], damping
    #       [N s/m]) to a haptic handle that follows [body.motion]; haptics = true runs the
    #       1 kHz haptic loop in its own process, max_force [N] caps what the hand feels

    [[filter]]                  # bodies that never collide with each other
    a = "cube"
    b = "floor box"

    [[coupling]]                # zero-length springs (thesis 5.3.2)
    a = "cube"                  # a fem or cloth body: its nodes ...
    b = "post"                  # ... within radius of this body's surface are tied to it
    radius = 0.005              # [m]
    stiffness = 2.0e3           # [N/m] per spring
    damping = 0.0               # [N s/m]
    collide = false             # contacts between a and b (off by default)
    # points = [[x, y, z], ...] [m]: instead of radius, springs at these world points (any two
    #          bodies, rigid ones too; each point is tied to both where it is at the start)

    [volume]                    # a CT / MRI embedded in a FEM body built from its voxels (thesis
    file = "head-ct"            # 3.3.2): a volume file or DICOM folder (softvr.volume.load), or a
                                # dataset: head-ct | mri-ch2 | mri-ch2better (softvr.datasets)
    name = "head"               # the FEM body's name (for filters, couplings, collides_with)
    unit = 0.001                # [m] per volume unit (0.001: the volume is in millimetres)
    cells = [16, 16, 8]         # mesh cubes per axis over the volume (5 tets each; empty ones dropped)
    threshold = -300.0          # tissue above it; the skin (collision surface) is its iso-surface
    skin_triangles = 4000       # the skin simplified to this many triangles
    fix_denser_than = 1150.0    # [kg/m^3] nodes of denser tets (bone) are held
    alpha = 2.0                 # [1/s] Rayleigh damping
    beta = 0.01                 # [s]
    preset = "ct-skin"          # transfer function (softvr.render.PRESETS)
    render_step = 2             # render every k-th voxel per axis
    incremental = true          # rasterize only around the tets that moved
    mask = true                 # drop the cubes without tissue (false: the whole grid)
    animation = "press.npz"     # optional: every node follows this cache (times [k] [s], nodes
                                # [k, node_count, 3] [m], linear between): a scripted deformation
    # Every frame the volume is rasterized through the deformed tets (thesis ch. 3) and drawn
    # with the bodies' surfaces; E, nu, rho of each tet come from the voxels (softvr.model.CT_TISSUE).

    [display]                   # the screens it is shown on (softvr cave preview|master|local SCENE)
    preset = "cube"             # a softvr.cave preset, or file = "my-cave.toml" (softvr-display 1)

    [[model]]                   # a model of coupled parts (thesis 5.2): its parts become bodies
    file = "shoulder/parts.toml"    # named as the parts, its couplings springs; a parts file
                                    # (built when the scene loads) or a built model (.npz)
    colors = { deltoid = [0.7, 0.3, 0.3] }   # optional, per part
    opacity = { deltoid = 0.45 }             # optional, per part

Every error names the file, the field path (``body[2].material``), what was expected and what
was found, all of a file's errors at once: missing mesh files, unknown body types, numbers out
of range or of the wrong kind, references to materials, adhesions or bodies that do not exist.
Numbers are SI, bare: one written with a unit (``box = [0.2, 0.2, "20 cm"]``) is reported with
the SI number to write, and a time step, density, Young's modulus or body size outside what it
can be in SI units (:data:`PLAUSIBLE`: a step in ms, a density in g/cm^3, a size in mm) is
reported, not simulated. ``softvr check`` also builds the valid rest
(:func:`read_scene_with_problems`) and reports bodies that start crossing, with the others.
Counts (frames, cells, quads, triangle budgets) are bounded by :data:`LIMITS` before anything
is built, and the file is read through :mod:`softvr.files` (a regular UTF-8 file, nesting and
integers bounded, file names without NUL bytes and of lengths the OS accepts):
docs/input-limits.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from softvr.errors import InputError, Problems, raise_all
from softvr.files import checked_file, file_name, read_toml
from softvr.volume.tetmesh import TET_MESH_SUFFIXES

__all__ = ["BODY_TYPES", "FORMAT", "LIMITS", "PLAUSIBLE", "BodySpec", "SceneFile", "adhesion_parameters", "read_scene",
           "read_scene_with_problems"]

FORMAT = "softvr-scene 1"
BODY_TYPES = ("rigid", "fem", "cloth", "fixed", "kinematic", "tool")
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".gltf", ".glb", ".off")
_SHAPES = {"rigid": ("box", "sphere", "mesh"), "fem": ("box", "sphere", "mesh", "tets"), "cloth": ("cloth",),
           "fixed": ("box", "mesh"), "kinematic": ("box", "sphere", "mesh"), "tool": ("box", "sphere", "mesh")}
_SHAPE_KEYS = ("box", "sphere", "mesh", "tets", "cloth")
_ADHESION_KEYS = ("stiffness", "max_energy", "viscosity", "bonding_rate", "saturation", "initial", "debond_gap")
#: What a value can be in its SI unit (:class:`softvr.errors.Problems`): outside, it was most
#: likely written in other units (a step in ms, a density in g/cm^3, a stiffness in MPa, a
#: size in mm) and is reported instead of simulated.
PLAUSIBLE = {"dt": (1e-7, 0.1),            # [s] a contact simulation's step
             "density": (10.0, 30000.0),   # [kg/m^3] foams .. osmium
             "young": (1.0, 1e12),          # [Pa] hydrogels .. diamond
             "size": (0.0, 50.0),           # [m] a body's box edges, sphere radius, cloth sides
             "place": (-1e4, 1e4),          # [m] positions, points, centres: within 10 km of the origin
             "speed": (-1e4, 1e4)}          # [m/s], [rad/s], [m/s^2]: velocities, spins, gravity
#: Largest count a scene may ask for, checked before anything is built: far above what a
#: real-time scene needs (a 64^3-cube FEM box is 1.3 million tets), far below what fills a
#: machine's memory (docs/input-limits.md).
LIMITS = {"frames": 1_000_000, "steps_per_frame": 10_000, "pgs_iterations": 100_000,
          "cells": 64,                  # fem box / volume: cubes per axis
          "surface_quads": 64,          # box: quads along its longest edge (6 n^2 in all)
          "quads": 1024,                # cloth: quads per side
          "collision_triangles": 200_000, "skin_triangles": 1_000_000, "render_step": 64}


@dataclass
class BodySpec:
    """One ``[[body]]`` (module docstring); shape in ``shape`` ("box", "sphere", "mesh",
    "tets", "cloth") with its ``size`` (box [3] [m], sphere radius [m], cloth [w, h] [m]) or
    ``mesh`` path (a surface, or for "tets" a tet mesh file)."""

    name: str
    type: str
    shape: str
    size: tuple | float | None = None
    mesh: Path | None = None
    cells: float | tuple = 4
    scale: tuple = (1.0, 1.0, 1.0)
    surface_quads: int = 1
    subdivisions: int = 3
    render_mesh: Path | tuple | None = None  # a mesh file, or (vertices [n, 3] [m], triangles) in memory (glTF)
    collision_triangles: int | None = None
    collides_with: tuple | None = None
    drive: dict = field(default_factory=dict)
    tool: dict = field(default_factory=dict)
    material: str | None = None
    position: tuple = (0.0, 0.0, 0.0)
    rotation: tuple = (0.0, 0.0, 0.0)
    velocity: tuple = (0.0, 0.0, 0.0)
    angular_velocity: tuple = (0.0, 0.0, 0.0)
    spin_centre: tuple | None = None
    fixed_below: float | None = None
    fixed_above: float | None = None
    color: tuple = (0.8, 0.6, 0.5)
    adhesion: str | None = None
    cloth: dict = field(default_factory=dict)
    motion: dict = field(default_factory=dict)
    mesh_data: tuple | None = None  # (vertices [n, 3] [m], triangles [t, 3]) given in memory (glTF)


@dataclass
class SceneFile:
    """A validated scene file (module docstring)."""

    path: Path
    simulation: dict
    render: dict
    materials: dict
    adhesions: dict
    planes: list
    spheres: list
    bodies: list
    filters: list
    couplings: list = field(default_factory=list)
    models: list = field(default_factory=list)
    volume: dict | None = None
    display: str | None = None  # a softvr.cave display preset name or a display file's path

    def body(self, name: str) -> BodySpec | None:
        """The ``[[body]]`` of this name (None for a model's part)."""
        return next((b for b in self.bodies if b.name == name), None)

    def model_parts(self) -> dict:
        """Part name -> kind ("fixed", "kinematic", "rigid", "soft") of every model's parts."""
        return {name: kind for m in self.models for name, kind in m["parts"].items()}


def _table(doc: dict, key: str, errors: Problems, where: str | None = None) -> dict:
    """``doc[key]`` if it is a table (an empty one when absent); else a problem and ``{}``."""
    t = doc.get(key, {})
    if not isinstance(t, dict):
        errors.add(where or key, f"a [{key}] table", type(t).__name__)
        return {}
    return t


def _count(errors: Problems, t: dict, key: str, where: str, *, default=None, minimum: int = 0,
           limit: str | None = None) -> int | None:
    """An integer >= ``minimum`` and <= :data:`LIMITS` ``[limit or key]``."""
    value = errors.integer(t, key, where, default=default, minimum=minimum)
    top = LIMITS[limit or key]
    if value is not None and value > top:
        errors.add(f"{where}.{key}", f"an integer in {minimum} .. {top} (softvr's limit for a scene)", value)
        return None
    return value


def _named_tables(doc: dict, key: str, errors: Problems) -> dict:
    tables = doc.get(key, {})
    if not isinstance(tables, dict) or not all(isinstance(v, dict) for v in tables.values()):
        errors.add(key, f"[{key}.NAME] tables", type(tables).__name__)
        return {}
    return tables


def _list(doc: dict, key: str, errors: Problems) -> list:
    items = doc.get(key, [])
    if not isinstance(items, list) or not all(isinstance(v, dict) for v in items):
        errors.add(key, f"[[{key}]] tables", type(items).__name__)
        return []
    return items


def _simulation(doc: dict, errors: Problems) -> dict:
    t = _table(doc, "simulation", errors)
    w = "simulation"
    out = {"dt": errors.number(t, "dt", w, default=0.005, positive=True, unit="s", plausible=PLAUSIBLE["dt"]),
           "steps_per_frame": _count(errors, t, "steps_per_frame", w, default=4, minimum=1),
           "frames": _count(errors, t, "frames", w, default=100, minimum=1),
           "gravity": errors.vector(t, "gravity", w, default=[0.0, 0.0, -9.81], unit="m/s^2",
                                    plausible=PLAUSIBLE["speed"]),
           "friction": errors.number(t, "friction", w, default=0.5, minimum=0.0),
           "pgs_iterations": _count(errors, t, "pgs_iterations", w, default=500, minimum=1),
           "contact_margin": errors.number(t, "contact_margin", w, default=0.005, minimum=0.0, unit="m"),
           "collision_free_start": errors.boolean(t, "collision_free_start", w, default=False)}
    return out


def _render(doc: dict, errors: Problems, where: str = "render") -> dict:
    """The ``[render]`` table and the ``[[light]]`` list of ``doc``, problems named under
    ``where`` (a glTF scene's extras: ``"scene"``)."""
    t = _table(doc, "render", errors, where)
    w = where
    size = t.get("size", [640, 480])
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and 0 < v <= 16384 for v in size)):
        errors.add(f"{w}.size", "[width, height] in pixels, 1..16384", size)
        size = [640, 480]
    bounds = t.get("bounds")
    if bounds is not None:
        bounds = errors.vector(t, "bounds", w, 6, unit="m", plausible=PLAUSIBLE["place"])
    from softvr.render.camera import VIEWS  # noqa: PLC0415 - VTK, only when a scene is read

    camera = t.get("camera", "iso")
    if not isinstance(camera, str) or camera not in VIEWS:
        errors.add(f"{w}.camera", f"a view name ({', '.join(VIEWS)})", camera)
        camera = "iso"
    colors = {}
    for key, default in (("background", (0.10, 0.11, 0.13)), ("background_top", (0.32, 0.36, 0.43))):
        colors[key] = _color(t, key, w, default, errors)
    lights = []
    for i, light in enumerate(_list(doc, "light", errors)):
        lw = f"light[{i}]"
        lights.append({"position": errors.vector(light, "position", lw, unit="m", plausible=PLAUSIBLE["place"]),
                       "focal_point": errors.vector(light, "focal_point", lw, default=[0.0, 0.0, 0.0], unit="m",
                                                    plausible=PLAUSIBLE["place"]),
                       "color": _color(light, "color", lw, (1.0, 1.0, 1.0), errors),
                       "intensity": errors.number(light, "intensity", lw, default=1.0, minimum=0.0)})
    return {"size": tuple(size), "camera": camera, "bounds": bounds, **colors, "lights": lights,
            "light_kit": errors.boolean(t, "light_kit", w, default=True),
            "azimuth": errors.number(t, "azimuth", w, default=0.0, unit="deg"),
            "elevation": errors.number(t, "elevation", w, default=0.0, unit="deg"),
            "zoom": errors.number(t, "zoom", w, default=1.0, positive=True)}


def _color(t: dict, key: str, w: str, default, errors: Problems) -> tuple:
    color = errors.vector(t, key, w, default=list(default))
    if color is not None and not all(0 <= c <= 1 for c in color):
        errors.add(f"{w}.{key}", "r, g, b in [0, 1]", list(color))
        return tuple(default)
    return tuple(color) if color is not None else tuple(default)


def _materials(doc: dict, errors: Problems) -> dict:
    out = {}
    for name, t in _named_tables(doc, "material", errors).items():
        w = f"material.{name}"
        out[name] = {"young": errors.number(t, "young", w, default=1e5, positive=True, unit="Pa",
                                            plausible=PLAUSIBLE["young"]),
                     "poisson": errors.number(t, "poisson", w, default=0.3, minimum=-0.99, maximum=0.5),
                     "density": errors.number(t, "density", w, default=1000.0, positive=True, unit="kg/m^3",
                                              plausible=PLAUSIBLE["density"]),
                     "alpha": errors.number(t, "alpha", w, default=0.0, minimum=0.0, unit="1/s"),
                     "beta": errors.number(t, "beta", w, default=0.0, minimum=0.0, unit="s")}
    return out


def _adhesions(doc: dict, errors: Problems) -> dict:
    return {name: adhesion_parameters(t, f"adhesion.{name}", errors)
            for name, t in _named_tables(doc, "adhesion", errors).items()}


def adhesion_parameters(t: dict, w: str, errors: Problems) -> dict:
    """:class:`softvr.contact.Adhesion` keyword arguments from a table (``[adhesion.NAME]``, or
    a glTF node's ``softvr_adhesion_*`` extras), every problem named under ``w``."""
    unknown = sorted(set(t) - set(_ADHESION_KEYS))
    if unknown:
        errors.add(f"{w}.{unknown[0]}", f"one of {', '.join(_ADHESION_KEYS)}", unknown[0])
    # stiffness, max_energy and viscosity have no default (softvr.contact.Adhesion).
    required = ("stiffness", "max_energy", "viscosity")
    return {k: errors.number(t, k, w, minimum=0.0) for k in _ADHESION_KEYS if k in t or k in required}


def _ref(table: dict, key: str, where: str, known: dict | set, what: str, errors: Problems, *, required=False):
    value = table.get(key)
    if value is None and not required:
        return None
    if not isinstance(value, str) or value not in known:
        names = ", ".join(sorted(known)) or f"none defined: add a [{what}.NAME] table"
        errors.add(f"{where}.{key}", f"the name of a {what} ({names})", value if value is not None else "nothing")
        return None
    return value


def _body(i: int, t: dict, scene_dir: Path, materials: dict, adhesions: dict, errors: Problems) -> BodySpec | None:
    w = f"body[{i}]"
    name = t.get("name")
    if not isinstance(name, str) or not name:
        errors.add(f"{w}.name", "a non-empty string", name if name is not None else "nothing")
        name = f"body {i}"
    kind = errors.choice(t, "type", w, BODY_TYPES)
    allowed = _SHAPES.get(kind, ("box", "sphere", "mesh", "cloth"))
    given = [s for s in _SHAPE_KEYS if s in t]
    shape, size, mesh = None, None, None
    if len(given) != 1 or given[0] not in allowed:
        errors.add(w, f"one shape of {' | '.join(allowed)} for a {kind or 'body'}",
                   ", ".join(given) if given else "no shape")
    else:
        shape = given[0]
        if shape == "box":
            size = errors.vector(t, "box", w, unit="m", plausible=PLAUSIBLE["size"])
            if size is not None and min(size) <= 0:
                errors.add(f"{w}.box", "3 edge lengths > 0 [m]", list(size))
        elif shape == "sphere":
            size = errors.number(t, "sphere", w, positive=True, unit="m", plausible=PLAUSIBLE["size"])
        elif shape == "cloth":
            size = errors.vector(t, "cloth", w, 2, unit="m", plausible=PLAUSIBLE["size"])
        else:
            mesh = _file(t, shape, w, scene_dir, MESH_SUFFIXES if shape == "mesh" else TET_MESH_SUFFIXES,
                         "a mesh file" if shape == "mesh" else "a tet mesh file", errors)
    spec = BodySpec(name=name, type=kind, shape=shape, size=size, mesh=mesh)
    if "scale" in t:
        scale = errors.vector(t, "scale", w)
        if shape not in ("sphere", "mesh", "tets"):
            errors.add(f"{w}.scale", "a scale only on a sphere, mesh or tets shape", f"a {shape} shape")
        elif scale is not None and min(scale) <= 0:
            errors.add(f"{w}.scale", "3 factors > 0", list(scale))
        elif scale is not None:
            spec.scale = scale
    if "surface_quads" in t:
        if shape != "box" or kind == "fixed":
            errors.add(f"{w}.surface_quads", "surface quads only on a moving box", f"a {kind} {shape}")
        spec.surface_quads = _count(errors, t, "surface_quads", w, minimum=1)
    if "subdivisions" in t:
        if shape != "sphere":
            errors.add(f"{w}.subdivisions", "subdivisions only on a sphere", f"a {shape} shape")
        spec.subdivisions = min(errors.integer(t, "subdivisions", w, minimum=0) or 0, 6)
    if "render_mesh" in t:
        if kind not in ("rigid", "fem", "kinematic", "tool", "fixed"):
            errors.add(f"{w}.render_mesh", "a render mesh on a rigid, fem, kinematic, tool or fixed body",
                       f"a {kind} body")
        spec.render_mesh = _file(t, "render_mesh", w, scene_dir, MESH_SUFFIXES, "a mesh file", errors)
    if "collision_triangles" in t:
        if shape not in ("mesh", "sphere") or kind == "fixed":
            errors.add(f"{w}.collision_triangles", "a triangle budget only on a moving mesh or sphere",
                       f"a {kind} {shape}")
        spec.collision_triangles = _count(errors, t, "collision_triangles", w, minimum=4)
    if "collides_with" in t:
        others = t["collides_with"]
        if not (isinstance(others, list) and all(isinstance(o, str) for o in others)):
            errors.add(f"{w}.collides_with", "a list of body names", others)
        else:
            spec.collides_with = tuple(others)
    if kind in ("rigid", "fem", "tool"):
        spec.material = _ref(t, "material", w, materials, "material", errors, required=True)
    spec.adhesion = _ref(t, "adhesion", w, adhesions, "adhesion", errors)
    for key, unit, bound in (("position", "m", "place"), ("rotation", "deg", "place"), ("velocity", "m/s", "speed"),
                             ("angular_velocity", "rad/s", "speed")):
        value = errors.vector(t, key, w, default=list(getattr(spec, key)), unit=unit, plausible=PLAUSIBLE[bound])
        if value is not None:
            setattr(spec, key, value)
    if "spin_centre" in t:
        spec.spin_centre = errors.vector(t, "spin_centre", w, unit="m", plausible=PLAUSIBLE["place"])
    color = errors.vector(t, "color", w, default=list(spec.color))
    if color is not None and not all(0 <= c <= 1 for c in color):
        errors.add(f"{w}.color", "r, g, b in [0, 1]", list(color))
    elif color is not None:
        spec.color = color
    for key in ("fixed_below", "fixed_above"):
        if key in t:
            setattr(spec, key, errors.number(t, key, w, unit="m", minimum=PLAUSIBLE["place"][0],
                                             maximum=PLAUSIBLE["place"][1]))
    if kind == "fem" and shape in ("mesh", "sphere"):
        spec.cells = errors.number(t, "cells", w, positive=True, unit="m")
    elif kind == "fem" and shape == "box":
        cells = t.get("cells", 4)
        if isinstance(cells, list):
            top = LIMITS["cells"]
            if not (len(cells) == 3 and all(isinstance(c, int) and not isinstance(c, bool) and 1 <= c <= top
                                            for c in cells)):
                errors.add(f"{w}.cells", f"cubes per axis: an integer in 1 .. {top} or 3 of them", cells)
            spec.cells = tuple(cells)
        else:
            spec.cells = _count(errors, t, "cells", w, default=4, minimum=1)
    if "drive" in t:
        if kind not in ("fem", "cloth"):
            errors.add(f"{w}.drive", "a drive only on a fem or cloth body (it moves the held nodes)", f"a {kind} body")
        elif "fixed_below" not in t and "fixed_above" not in t:
            errors.add(f"{w}.drive", "held nodes to drive: fixed_below or fixed_above", "neither")
        spec.drive = _keyframes(t["drive"], f"{w}.drive", "offsets", errors)
    if kind == "cloth":
        spec.cloth = {"quads": t.get("quads", [16, 16]),
                      "area_density": errors.number(t, "area_density", w, default=0.2, positive=True, unit="kg/m^2"),
                      **{k: errors.number(t, k, w, default=d, minimum=0.0, unit=u) for k, d, u in (
                          ("stretch", 200.0, "N/m"), ("shear", 20.0, "N/m"), ("bend", 1.0, "N/m"),
                          ("damping", 0.05, "N s/m"), ("alpha", 0.1, "1/s"))}}
        quads = spec.cloth["quads"]
        top = LIMITS["quads"]
        if not (isinstance(quads, list) and len(quads) == 2 and all(
                isinstance(q, int) and not isinstance(q, bool) and 1 <= q <= top for q in quads)):
            errors.add(f"{w}.quads", f"[nu, nv] quads, integers in 1 .. {top}", quads)
    if kind in ("kinematic", "tool"):
        spec.motion = _keyframes(t.get("motion"), f"{w}.motion", "positions", errors, rotations=kind == "kinematic")
        if kind == "tool" and isinstance(t.get("motion"), dict) and "rotations" in t["motion"]:
            errors.add(f"{w}.motion.rotations", "positions only on a tool (its handle is a point; a kinematic "
                       "body may rotate)", "rotations")
    elif "motion" in t:
        errors.add(f"{w}.motion", "a motion only on a kinematic body or a tool", f"a {kind} body")
    if kind == "tool":
        spec.tool = {"stiffness": errors.number(t, "stiffness", w, positive=True, unit="N/m"),
                     "damping": errors.number(t, "damping", w, default=0.0, minimum=0.0, unit="N s/m"),
                     "haptics": errors.boolean(t, "haptics", w, default=False),
                     "max_force": errors.number(t, "max_force", w, default=10.0, positive=True, unit="N")}
    return spec


def _file(t: dict, key: str, w: str, scene_dir: Path, suffixes: tuple, what: str, errors: Problems) -> Path | None:
    """The existing file ``t[key]`` names, relative to the scene's folder."""
    try:
        path = file_name(scene_dir, t[key], f"{w}.{key}")
    except InputError as exc:
        errors.add(exc.what, f"{what} name ({exc.expected})", exc.found)
        return None
    if path.suffix.lower() not in suffixes:
        errors.add(f"{w}.{key}", f"{what} ({', '.join(suffixes)})", repr(t[key])[:200])
        return path
    try:
        checked_file(path, f"{w}.{key}")
    except InputError as exc:
        errors.add(f"{w}.{key}", exc.expected, f"{exc.found}: {path}" if exc.found != "no such file"
                   else f"no file {path}")
    return path


def _keyframes(t, w: str, key: str, errors: Problems, *, rotations: bool = False, prefix: str = "",
               flat: bool = False) -> dict:
    """``times`` [s] and one [x, y, z] [m] of ``key`` per time (a motion or a drive); with
    ``rotations``, optionally one [rx, ry, rz] [deg] (x, then y, then z) of ``rotations`` per
    time too. A glTF node's extras read with ``prefix`` (keys ``<prefix>times`` and
    ``<prefix><key>``, named so) and ``flat`` (``key`` a flat list x0, y0, z0, x1, ... [m])."""
    if not isinstance(t, dict):
        errors.add(w, f"a table: times [s] and {key} [m]", t if t is not None else "nothing")
        return {}

    low, high = PLAUSIBLE["place"]

    def number(x) -> bool:  # times [s], positions [m], angles [deg] alike: within 1e4
        return isinstance(x, (int, float)) and not isinstance(x, bool) and low <= x <= high

    def triples(v) -> bool:
        return isinstance(v, list) and all(isinstance(p, list) and len(p) == 3 and all(map(number, p)) for p in v)

    times, given = t.get(prefix + "times"), t.get(prefix + key)
    ok_times = isinstance(times, list) and len(times) >= 1 and all(map(number, times)) and all(
        b > a for a, b in zip(times, times[1:]))
    if not ok_times:
        errors.add(f"{w}.{prefix}times", "increasing times [s], at least one",
                   times if times is not None else "nothing")
    positions = given
    if flat and isinstance(given, list) and len(given) % 3 == 0 and all(map(number, given)):
        positions = [given[j:j + 3] for j in range(0, len(given), 3)]
    ok_positions = triples(positions) and (not ok_times or len(positions) == len(times))
    if not ok_positions:
        errors.add(f"{w}.{prefix}{key}", "x0, y0, z0, x1, ... [m]: 3 numbers per time" if flat else
                   "one [x, y, z] [m] per time", given if given is not None else "nothing")
    out = {"times": times, key: positions} if ok_times and ok_positions else {}
    if rotations and "rotations" in t:
        angles = t["rotations"]
        if not triples(angles) or (ok_times and len(angles) != len(times)):
            errors.add(f"{w}.rotations", "one [rx, ry, rz] [deg] per time (about x, then y, then z)", angles)
        elif out:
            out["rotations"] = angles
    return out


def read_scene(path) -> SceneFile:
    """Read and validate a scene file (module docstring); mesh paths are resolved against its
    folder and must exist. Raises one :class:`~softvr.errors.InputError` listing every problem."""
    scene, problems = read_scene_with_problems(path)
    raise_all(problems, str(path), "scene file")
    return scene


def _normal(t: dict, w: str, errors: Problems) -> tuple | None:
    """A plane's ``normal``: 3 numbers, not all zero (any length; the plane normalizes it)."""
    normal = errors.vector(t, "normal", w, default=[0.0, 0.0, 1.0], plausible=PLAUSIBLE["place"])
    if normal is not None and sum(c * c for c in normal) < 1e-12:
        errors.add(f"{w}.normal", "a direction: 3 numbers, not all zero", list(normal))
        return None
    return normal


def _complete(table: dict, defaults: dict) -> dict:
    """``table`` with its bad (None) values replaced by ``defaults``'."""
    return {k: defaults[k] if v is None and k in defaults else v for k, v in table.items()}


def read_scene_with_problems(path) -> tuple[SceneFile, list]:
    """A scene file's problems, and the scene without the parts that have one.

    Returns the :class:`SceneFile` with every body, plane, sphere, model, volume, filter and
    coupling that has a problem left out (bad simulation, render and material numbers take
    their defaults, bodies keep their geometry), and the ``(what, expected, found)`` problems
    of the whole file: so that ``softvr check`` can also build what is valid and report
    bodies that start crossing, together with everything else. A coupling with a problem
    still excuses its two bodies from colliding (as a filter), as it would when mended.
    A missing file or bad TOML raises :class:`~softvr.errors.InputError` (nothing to check).
    """
    path = Path(path)
    doc = read_toml(path, "scene file")
    errors = Problems(str(path), "scene file")
    if doc.get("format") != FORMAT:
        errors.add("format", f'"{FORMAT}"', doc.get("format", "nothing"))
    known = {"format", "simulation", "render", "material", "adhesion", "plane", "sphere", "body", "filter", "coupling",
             "model", "volume", "display", "light"}
    for key in sorted(set(doc) - known):
        errors.add(key, f"one of {', '.join(sorted(known))}", key)
    defaults = Problems(None, "defaults")
    simulation = _complete(_simulation(doc, errors), _simulation({}, defaults))
    render = _complete(_render(doc, errors), _render({}, defaults))
    material_default = _materials({"material": {"_": {}}}, defaults)["_"]
    materials = {k: _complete(v, material_default) for k, v in _materials(doc, errors).items()}
    adhesions = {k: v for k, v in _adhesions(doc, errors).items() if None not in v.values()}

    def counted(read, *args):
        """``read(*args)`` and whether it found a problem."""
        before = len(errors.items)
        out = read(*args)
        return out, len(errors.items) > before

    planes = []
    for i, t in enumerate(_list(doc, "plane", errors)):
        w = f"plane[{i}]"
        plane, bad = counted(lambda: {
            "point": errors.vector(t, "point", w, default=[0.0, 0.0, 0.0], unit="m", plausible=PLAUSIBLE["place"]),
            "normal": _normal(t, w, errors),
            "friction": errors.number(t, "friction", w, default=simulation["friction"], minimum=0.0),
            "size": errors.number(t, "size", w, default=3.0, positive=True, unit="m", maximum=PLAUSIBLE["place"][1]),
            "adhesion": _ref(t, "adhesion", w, adhesions, "adhesion", errors)})
        planes += [] if bad else [plane]
    spheres = []
    for i, t in enumerate(_list(doc, "sphere", errors)):
        w = f"sphere[{i}]"
        sphere, bad = counted(lambda: {
            "center": errors.vector(t, "center", w, unit="m", plausible=PLAUSIBLE["place"]),
            "radius": errors.number(t, "radius", w, positive=True, unit="m", plausible=PLAUSIBLE["size"]),
            "friction": errors.number(t, "friction", w, default=simulation["friction"], minimum=0.0),
            "adhesion": _ref(t, "adhesion", w, adhesions, "adhesion", errors)})
        spheres += [] if bad else [sphere]
    raw_models = [counted(_model, i, t, path.parent, errors) for i, t in enumerate(_list(doc, "model", errors))]
    models = [m for m, bad in raw_models if not bad]
    names = {name for m, _ in raw_models for name in m["parts"]}
    volume, bad_volume = counted(_volume, doc["volume"], path.parent, errors) if "volume" in doc else (None, False)
    display = _display(doc["display"], path.parent, errors) if "display" in doc else None
    if volume is not None:
        names.add(volume["name"])
    bodies, bad_bodies = [], set()
    raw_bodies = _list(doc, "body", errors)
    for i, t in enumerate(raw_bodies):
        spec, bad = counted(_body, i, t, path.parent, materials, adhesions, errors)
        if spec.name in names:
            errors.add(f"body[{i}].name", "a name no other body has", spec.name)
            bad = True
        names.add(spec.name)
        bodies.append(spec)
        if bad:
            bad_bodies.add(i)
    if not raw_bodies and not planes and not spheres and not raw_models and volume is None:
        errors.add("body", "at least one [[body]]", "none")
    for i, spec in enumerate(bodies):
        for other in spec.collides_with or ():
            if other not in names:
                errors.add(f"body[{i}].collides_with", f"names of bodies ({', '.join(sorted(names))})", repr(other))
                bad_bodies.add(i)
    filters = []
    for i, t in enumerate(_list(doc, "filter", errors)):
        ends = [_ref(t, side, f"filter[{i}]", names, "body", errors, required=True) for side in ("a", "b")]
        filters.append(tuple(ends))
    parts = {name: kind for m in models for name, kind in m["parts"].items()}
    if volume is not None:
        parts[volume["name"]] = "soft"
    couplings = [counted(_coupling, i, t, bodies, parts, errors) for i, t in enumerate(_list(doc, "coupling", errors))]
    # What is left to build: the parts without problems, and what refers only to them.
    kept = [b for i, b in enumerate(bodies) if i not in bad_bodies]
    present = {b.name for b in kept} | {name for m in models for name in m["parts"]}
    if volume is not None and not bad_volume:
        present.add(volume["name"])
    filters += [(c["a"], c["b"]) for c, bad in couplings if bad and not c["collide"]]
    scene = SceneFile(path=path, simulation=simulation, render=render, materials=materials, adhesions=adhesions,
                      planes=planes, spheres=spheres, bodies=kept,
                      filters=[f for f in filters if set(f) <= present],
                      couplings=[c for c, bad in couplings if not bad and {c["a"], c["b"]} <= present],
                      models=models, volume=None if bad_volume else volume, display=display)
    return scene, errors.items


def _display(t, scene_dir: Path, errors: Problems) -> str | None:
    """The ``[display]`` table: a preset name, or a display file (loaded now, to check it)."""
    from softvr.cave.display import PRESETS, load_display  # noqa: PLC0415
    from softvr.errors import InputError  # noqa: PLC0415

    if not isinstance(t, dict) or len(set(t) & {"preset", "file"}) != 1 or set(t) - {"preset", "file"}:
        errors.add("display", "a table with preset = NAME or file = PATH", t)
        return None
    if "preset" in t:
        if not isinstance(t["preset"], str) or t["preset"] not in PRESETS:
            errors.add("display.preset", f"one of {', '.join(PRESETS)}", t["preset"])
            return None
        return t["preset"]
    path = _file(t, "file", "display", scene_dir, (".toml",), "a display file", errors)
    if path is None or not path.is_file():
        return None
    try:
        load_display(path)
    except InputError as exc:
        errors.add("display.file", "a valid display file", str(exc))
        return None
    return str(path)


#: ``[volume] file`` names of the volumes in :mod:`softvr.datasets`.
DATASETS = {"head-ct": "head_ct", "mri-ch2": "mri_ch2", "mri-ch2better": "mri_ch2better"}


def _volume(t, scene_dir: Path, errors: Problems, where: str = "volume") -> dict | None:
    """The ``[volume]`` table (module docstring), problems named under ``where`` (a glTF
    volume node: ``node 'NAME'``)."""
    w = where
    if not isinstance(t, dict):
        errors.add(w, "a [volume] table", type(t).__name__)
        return None
    from softvr.render import PRESETS  # noqa: PLC0415

    known = {"file", "name", "unit", "cells", "threshold", "skin_triangles", "fix_denser_than", "alpha", "beta",
             "preset", "render_step", "incremental", "mask", "animation"}
    for key in sorted(set(t) - known):
        errors.add(f"{w}.{key}", f"one of {', '.join(sorted(known))}", key)
    file = t.get("file")
    source = None
    if not isinstance(file, str):
        errors.add(f"{w}.file", f"a volume file or folder, or a dataset ({', '.join(DATASETS)})",
                   file if file is not None else "nothing")
    elif file in DATASETS:
        source = file
    else:
        try:
            source = file_name(scene_dir, file, f"{w}.file")
        except InputError as exc:
            errors.add(exc.what, f"a volume file or folder name ({exc.expected})", exc.found)
        else:
            if not source.exists():
                errors.add(f"{w}.file", f"an existing volume file or folder, or a dataset ({', '.join(DATASETS)})",
                           f"no file {source}")
                source = None
    cells = t.get("cells", [16, 16, 8])
    top = LIMITS["cells"]
    if not (isinstance(cells, list) and len(cells) == 3 and all(
            isinstance(c, int) and not isinstance(c, bool) and 1 <= c <= top for c in cells)):
        errors.add(f"{w}.cells", f"3 integers in 1 .. {top} (mesh cubes per axis)", cells)
        cells = [16, 16, 8]
    name = t.get("name", "volume")
    if not isinstance(name, str) or not name:
        errors.add(f"{w}.name", "a non-empty string", name)
        name = "volume"
    preset = t.get("preset", "ct-skin")
    if not isinstance(preset, str) or preset not in PRESETS:
        errors.add(f"{w}.preset", f"one of {', '.join(sorted(PRESETS))}", preset)
    animation = _file(t, "animation", w, scene_dir, (".npz",), "a node animation", errors) if "animation" in t else None
    return {"file": source, "name": name, "cells": tuple(cells), "preset": preset, "animation": animation,
            "mask": errors.boolean(t, "mask", w, default=True),
            "unit": errors.number(t, "unit", w, default=0.001, positive=True, unit="m per volume unit"),
            "threshold": errors.number(t, "threshold", w, default=-300.0),
            "skin_triangles": _count(errors, t, "skin_triangles", w, default=4000, minimum=4),
            "fix_denser_than": errors.number(t, "fix_denser_than", w, default=1150.0, positive=True, unit="kg/m^3"),
            "alpha": errors.number(t, "alpha", w, default=2.0, minimum=0.0, unit="1/s"),
            "beta": errors.number(t, "beta", w, default=0.01, minimum=0.0, unit="s"),
            "render_step": _count(errors, t, "render_step", w, default=2, minimum=1),
            "incremental": errors.boolean(t, "incremental", w, default=True)}


def _model(i: int, t: dict, scene_dir: Path, errors: Problems, where: str | None = None) -> dict:
    """A ``[[model]]``: its file and part name -> kind (a parts file is validated now);
    problems named under ``where`` (a glTF model node: ``node 'NAME'``), else ``model[i]``."""
    w = where or f"model[{i}]"
    empty = {"parts": {}, "colors": {}, "opacity": {}}
    if "file" not in t:
        errors.add(f"{w}.file", "a parts file (.toml) or a built model (.npz)", "nothing")
        return {"file": None, **empty}
    path = _file(t, "file", w, scene_dir, (".toml", ".npz"), "a parts file or a built model", errors)
    if path is None or not path.is_file() or path.suffix.lower() not in (".toml", ".npz"):
        return {"file": path, **empty}
    from softvr.errors import InputError  # noqa: PLC0415
    from softvr.model import load_model, read_parts  # noqa: PLC0415

    try:
        specs = read_parts(path).parts if path.suffix.lower() == ".toml" else [p.spec for p in load_model(path).parts]
    except InputError as exc:
        errors.add(f"{w}.file", "a valid parts file or model", str(exc))
        return {"file": path, **empty}
    parts = {p.name: p.kind for p in specs}
    looks = {}
    for key, check in (("colors", lambda v: isinstance(v, list) and len(v) == 3 and all(
            isinstance(c, (int, float)) and 0 <= c <= 1 for c in v)), ("opacity", lambda v: isinstance(
            v, (int, float)) and 0 < v <= 1)):
        table = t.get(key, {})
        if not isinstance(table, dict):
            errors.add(f"{w}.{key}", "a table: part name = value", table)
            table = {}
        for name, value in table.items():
            if name not in parts:
                errors.add(f"{w}.{key}.{name}", f"a part of the model ({', '.join(parts)})", repr(name))
            elif not check(value):
                errors.add(f"{w}.{key}.{name}", "r, g, b in [0, 1]" if key == "colors" else "a number in (0, 1]", value)
        looks[key] = {k: v for k, v in table.items() if k in parts}
    return {"file": path, "parts": parts, **looks}


def _coupling(i: int, t: dict, bodies: list, parts: dict, errors: Problems) -> dict:
    """A ``[[coupling]]``: zero-length springs (thesis 5.3.2) from the nodes of ``a`` (fem or
    cloth) within ``radius`` of ``b``'s surface at the start to ``b``, or at given world
    ``points`` between any two bodies."""
    w = f"coupling[{i}]"
    kinds = {**{name: ("fem" if kind == "soft" else kind) for name, kind in parts.items()},
             **{b.name: b.type for b in bodies}}
    meshes = {b.name for b in bodies if b.type == "fixed" and b.shape == "mesh"}
    a = _ref(t, "a", w, kinds, "body", errors, required=True)
    b = _ref(t, "b", w, kinds, "body", errors, required=True)
    points = None
    if "points" in t:
        points = t["points"]
        if "radius" in t:
            errors.add(f"{w}.points", "radius or points, not both", "both")
        if not (isinstance(points, list) and points and all(
                isinstance(p, list) and len(p) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                             for x in p) for p in points)):
            errors.add(f"{w}.points", "a list of [x, y, z] [m]", points)
            points = None
    elif a is not None and kinds[a] not in ("fem", "cloth"):
        errors.add(f"{w}.a", "a fem or cloth body (its nodes are coupled), or points", f"{a!r}, a {kinds[a]} body")
    for side, name in (("a", a), ("b", b)):
        if name in meshes:
            errors.add(f"{w}.{side}", "a body (a fixed mesh is an obstacle, not a body: use a fixed box or a "
                       "kinematic body)", repr(name))
    if a is not None and a == b:
        errors.add(f"{w}.b", "another body than a", repr(b))
    return {"a": a, "b": b, "points": points,
            "radius": None if points is not None else errors.number(t, "radius", w, minimum=0.0, unit="m"),
            "stiffness": errors.number(t, "stiffness", w, positive=True, unit="N/m"),
            "damping": errors.number(t, "damping", w, default=0.0, minimum=0.0, unit="N s/m"),
            "collide": errors.boolean(t, "collide", w, default=False)}
