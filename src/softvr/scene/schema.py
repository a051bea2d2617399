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
    pgs_tolerance = 1e-5        # [m/s] velocity error at which the contact solve stops (optional)
    contact_margin = 0.005      # [m]
    rotation_lag = 1e-4         # [rad] how far a tet's co-rotation and forces may lag its nodes
                                # (optional; softvr.Scene.rotation_lag)
    collision_free_start = false    # true: soft bodies that start crossing another body are
                                # pushed out of it first (thesis 5.2.3; softvr.model.push_apart)
    adhesion = true             # false: every adhesion of the file off (the same scene dry)
    edge_contacts = true        # false: no edge-edge contacts, vertex-triangle both ways only
                                # (where no edge can touch without a vertex: a smooth probe on skin)

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
    antialias = true            # FXAA on the surfaces' edges (a post-process: ~40 ms a 512 x 512
                                # frame on a software OpenGL; a volume is cast after it)
    fps = 12.0                  # [frames/s] optional: the video's rate (default 1 / (dt steps_per_frame):
                                # real time; fewer plays a short event slowed down)

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
    #       [N s/m]; angular_stiffness [N m/rad]: the hand holds its orientation, default 0: free
    #       to turn) to a haptic handle that follows [body.motion]; haptics = true runs the
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
    mapper = "auto"             # warp (softvr's ray caster, off-screen) | cpu (VTK's) | auto (warp
                                # off-screen, cpu in a window: SurfaceRenderer.add_volume)
    sample_distance = 1.0       # [voxels] optional: the ray step (default: the mapper's, 0.5 warp, 1 cpu)
    incremental = true          # rasterize only around the tets that moved
    mask = true                 # drop the cubes without tissue (false: the whole grid)
    animation = "press.npz"     # optional: every node follows this cache (times [k] [s], nodes
                                # [k, node_count, 3] [m], linear between): a scripted deformation
    labels = "labels.nrrd"      # optional: a segmentation on the volume's grid, deformed with it
                                # (nearest voxel; the player's volume.label_surface(label))
    # Every frame the volume is rasterized through the deformed tets (thesis ch. 3) and drawn
    # with the bodies' surfaces; E, nu, rho of each tet come from the voxels (softvr.model.CT_TISSUE).

    [[sensor]]                  # a quantity sampled every frame into the metrics and plotted
    name = "press"              # against time (NAME_sensors.png); each an [x, y, z] vector
    kind = "contact_force"      # contact_force [N] (the step's contact impulses / dt on body) |
                                # coupling_force [N] (its couplings' springs) | position [m] (its centre)
                                # | hand_force [N] (a tool: the force its haptic device renders)
    body = "cube"
    other = "floor box"         # contact_force only: the contacts with this body, or "static"
                                # (planes, static spheres, fixed meshes); default: all of them

    [display]                   # the screens it is shown on (softvr cave preview|master|local SCENE)
    preset = "cube"             # a softvr.cave preset, or file = "my-cave.toml" (softvr-display 1)

    [variant.quick]             # the scene changed, played on request (softvr run SCENE --variant
    remove = ["candy 7"]        # quick; load_scene(path, ["quick"])): these bodies left out (and
                                # the couplings, filters and sensors that name them), ...
    [variant.quick.simulation]  # ... these [simulation] / [render] keys replaced, ...
    frames = 20
    [variant.quick.body."jello"]    # ... and these keys of a body (not its name or type)
    cells = [6, 6, 3]
    # Variants apply in the order asked, a later one's keys winning. Each is checked with the
    # file: its keys, the bodies it names, and the file with it applied (a problem named where
    # the variant writes it, variant.quick.body.jello.cells, or below it, variant.empty body,
    # where it breaks what it does not write: no body left).

    [[model]]                   # a model of coupled parts (thesis 5.2): its parts become bodies
    file = "shoulder/parts.toml"    # named as the parts, its couplings springs; a parts file
                                    # (built when the scene loads) or a built model (.npz)
    colors = { deltoid = [0.7, 0.3, 0.3] }   # optional, per part
    opacity = { deltoid = 0.45 }             # optional, per part

Every error names the file, the field path (``body[2].material``), what was expected and what
was found, all of a file's errors at once: missing mesh files, unknown body types, numbers out
of range or of the wrong kind, references to materials, adhesions or bodies that do not exist,
and keys no table has (``poison = 0.35`` in ``[material.jelly]``: named with the nearest known
key, ``did you mean 'poisson'?``; a ``[[body]]``'s keys are its type's,
:data:`~softvr.scene._description.BODY_KEYS`, another type's named with the nearest of its
own; a ``[[model]]``'s parts file's problems are named below it, ``model[0].file part[2].densty``).
Each table is one pydantic model of
:mod:`softvr.scene._description`, where its defaults are written, the glTF reader's too.
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
from typing import Any

from softvr.errors import InputError, Problems, known_key, raise_all
from softvr.files import file_name, read_toml
from softvr.model import load_model, read_parts
from softvr.scene._description import (BODY_TYPES, BOX_CELLS, DATASETS, LIMITS, MESH_SUFFIXES, PLAUSIBLE, STATIC,
                                       Adhesion, Body, Coupling, DisplayTable, Document, Filter, Light, Material,
                                       ModelTable, Plane, Render, Sensor, Simulation, Sphere, Variant, Volume,
                                       existing_file, read_table)
from softvr.scene.display import PRESETS as DISPLAY_PRESETS
from softvr.scene.display import read_display

__all__ = ["BODY_TYPES", "DATASETS", "FORMAT", "LIMITS", "MESH_SUFFIXES", "PLAUSIBLE", "BodySpec", "SceneFile",
           "adhesion_parameters", "read_scene", "read_scene_with_problems", "render_settings", "sensor_tables",
           "simulation_settings"]

FORMAT = "softvr-scene 1"
_BODY = Body.model_fields  # the defaults of a [[body]]'s fields


@dataclass
class BodySpec:
    """One ``[[body]]`` (module docstring) as the builder takes it; shape in ``shape`` ("box",
    "sphere", "mesh", "tets", "cloth") with its ``size`` (box [3] [m], sphere radius [m], cloth
    [w, h] [m]) or ``mesh`` path (a surface, or for "tets" a tet mesh file). Defaults are the
    description's (:class:`softvr.scene._description.Body`)."""

    name: str
    type: str
    shape: str
    size: Any = None  # by shape (validated): box (x, y, z), sphere radius, cloth (w, h); None for meshes
    mesh: Path | None = None
    cells: Any = BOX_CELLS  # by shape (validated): one number, or three (one per axis)
    scale: tuple = _BODY["scale"].default
    surface_quads: int = _BODY["surface_quads"].default
    subdivisions: int = _BODY["subdivisions"].default
    render_mesh: Path | tuple | None = None  # a mesh file, or (vertices [n, 3] [m], triangles) in memory (glTF)
    collision_triangles: int | None = None
    collides_with: tuple | None = None
    drive: dict = field(default_factory=dict)
    tool: dict = field(default_factory=dict)
    material: str | None = None
    position: tuple = _BODY["position"].default
    rotation: tuple = _BODY["rotation"].default
    velocity: tuple = _BODY["velocity"].default
    angular_velocity: tuple = _BODY["angular_velocity"].default
    spin_centre: tuple | None = None
    fixed_below: float | None = None
    fixed_above: float | None = None
    color: tuple = _BODY["color"].default
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
    display: str | None = None  # a display preset name or a display file's path
    sensors: list = field(default_factory=list)  # [[sensor]] tables: name, kind, body, other
    variants: tuple = ()  # the names of the [variant.NAME] tables applied, in order

    def body(self, name: str) -> BodySpec | None:
        """The ``[[body]]`` of this name (None for a model's part)."""
        return next((b for b in self.bodies if b.name == name), None)

    def model_parts(self) -> dict:
        """Part name -> kind ("fixed", "kinematic", "rigid", "soft") of every model's parts."""
        return {name: kind for m in self.models for name, kind in m["parts"].items()}


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


def simulation_settings(table, where: str, errors: Problems) -> dict:
    """The ``[simulation]`` settings of ``table`` (a glTF scene's extras too), a bad value
    taking its default (:class:`~softvr.scene._description.Simulation`)."""
    settings, _ = read_table(Simulation, table, where, errors)
    return (settings or Simulation()).model_dump()


def render_settings(table, lights: list, where: str, errors: Problems) -> dict:
    """The ``[render]`` settings of ``table`` (a glTF scene's extras too), a bad value taking
    its default, and the ``[[light]]`` tables of ``lights`` (those without a problem)."""
    settings, _ = read_table(Render, table, where, errors)
    out = (settings or Render()).model_dump()
    out["lights"] = []
    for i, t in enumerate(lights):
        light, bad = read_table(Light, t, f"light[{i}]", errors)
        if not bad:
            out["lights"].append(light.model_dump())
    return out


def adhesion_parameters(t: dict, w: str, errors: Problems) -> dict | None:
    """:class:`softvr.contact.Adhesion` keyword arguments from a table (``[adhesion.NAME]``, or
    a glTF node's ``softvr_adhesion_*`` extras), every problem named under ``w``; None when it
    has one."""
    adhesion, bad = read_table(Adhesion, t, w, errors)
    return None if bad else adhesion.parameters()


def _ref(table: dict, key: str, where: str, known: dict | set, what: str, errors: Problems, *, required=False):
    value = table.get(key)
    if value is None and not required:
        return None
    if not isinstance(value, str) or value not in known:
        names = ", ".join(sorted(known)) or f"none defined: add a [{what}.NAME] table"
        errors.add(f"{where}.{key}", f"the name of a {what} ({names})", value if value is not None else "nothing")
        return None
    return value


def _body(i: int, t: dict, scene_dir: Path, materials: dict, adhesions: dict, errors: Problems) -> BodySpec:
    """A ``[[body]]`` as the builder takes it (bad fields as their defaults: it is left out)."""
    w = f"body[{i}]"
    body, _ = read_table(Body, t, w, errors, folder=scene_dir)
    kind, shape = body.type, body.shape()
    size = {"box": body.box, "sphere": body.sphere, "cloth": body.cloth}.get(shape)
    spec = BodySpec(name=body.name or f"body {i}", type=kind, shape=shape, size=size,
                    mesh=body.mesh if shape == "mesh" else body.tets if shape == "tets" else None,
                    scale=body.scale, surface_quads=body.surface_quads, subdivisions=min(body.subdivisions or 0, 6),
                    render_mesh=body.render_mesh, collision_triangles=body.collision_triangles,
                    collides_with=body.collides_with, position=body.position, rotation=body.rotation,
                    velocity=body.velocity, angular_velocity=body.angular_velocity, spin_centre=body.spin_centre,
                    fixed_below=body.fixed_below, fixed_above=body.fixed_above, color=body.color)
    if kind in ("rigid", "fem", "tool"):
        spec.material = _ref(t, "material", w, materials, "material", errors, required=True)
    spec.adhesion = _ref(t, "adhesion", w, adhesions, "adhesion", errors)
    if kind == "fem" and shape in ("mesh", "sphere"):
        spec.cells = float(body.cells) if isinstance(body.cells, (int, float)) else None
    elif kind == "fem" and shape == "box" and body.cells is not None:
        spec.cells = body.cells
    if body.drive is not None:
        spec.drive = {"times": body.drive.times, "offsets": body.drive.offsets}
    if kind in ("kinematic", "tool") and body.motion is not None:
        spec.motion = {"times": body.motion.times, "positions": body.motion.positions}
        if kind == "kinematic" and body.motion.rotations is not None:
            spec.motion["rotations"] = body.motion.rotations
    if kind == "cloth":
        spec.cloth = body.cloth_parameters()
    if kind == "tool":
        spec.tool = body.tool_parameters()
    return spec


def _file(t: dict, key: str, w: str, scene_dir: Path, suffixes: tuple, what: str, errors: Problems) -> Path | None:
    """The existing file ``t[key]`` names, relative to the scene's folder (None, and a problem,
    when it is not one)."""
    try:
        return existing_file(scene_dir, t[key], f"{w}.{key}", suffixes, what)
    except InputError as exc:
        errors.add(exc.what, exc.expected, exc.found)
        return None


def read_scene(path, variants=()) -> SceneFile:
    """Read and validate a scene file (module docstring) with its ``variants`` applied in turn
    (names of its ``[variant.NAME]`` tables); mesh paths are resolved against its folder and
    must exist. Raises one :class:`~softvr.errors.InputError` listing every problem."""
    scene, problems = read_scene_with_problems(path, variants)
    raise_all(problems, str(path), "scene file")
    return scene


def read_scene_with_problems(path, variants=()) -> tuple[SceneFile, list]:
    """A scene file's problems, and the scene without the parts that have one.

    Returns the :class:`SceneFile` with every body, plane, sphere, model, volume, filter and
    coupling that has a problem left out (bad simulation, render and material numbers take
    their defaults, bodies keep their geometry), and the ``(what, expected, found)`` problems
    of the whole file: so that ``softvr check`` can also build what is valid and report
    bodies that start crossing, together with everything else. A coupling with a problem
    still excuses its two bodies from colliding (as a filter), as it would when mended.
    A missing file or bad TOML raises :class:`~softvr.errors.InputError` (nothing to check).

    Every ``[variant.NAME]`` is checked, applied to the file (:func:`_variant_problems`); the
    scene returned has ``variants`` (their names, applied in this order) applied.
    """
    path = Path(path)
    doc = read_toml(path, "scene file")
    scene, problems = _read_document(path, doc)
    errors = Problems(str(path), "scene file")
    tables = _named_tables(doc, "variant", errors)
    for name in variants:
        if name not in tables:
            errors.add("variant", known_key(tables, name, "the name of one of its [variant.NAME] tables") if tables
                       else "a [variant.NAME] table of this name (the file has none)", repr(name))
    chosen = {}
    for name, table in tables.items():
        variant, bad = _variant_problems(path, doc, name, table, problems, errors)
        if not bad:
            chosen[name] = variant
    if variants and all(name in chosen for name in variants):
        scene, _ = _read_document(path, _patched(doc, [chosen[name] for name in variants]))
        scene.variants = tuple(variants)
    return scene, problems + errors.items


#: The tables that name bodies, and the keys they name them with: a variant that removes a body
#: removes those of them that name it.
_NAMING = {"coupling": ("a", "b"), "filter": ("a", "b"), "sensor": ("body", "other")}


def _patched(doc: dict, variants: list) -> dict:
    """The document ``doc`` with each :class:`~softvr.scene._description.Variant` applied in turn:
    its bodies removed (with the couplings, filters and sensors that name one, and their names in
    other bodies' ``collides_with``), its ``[simulation]``, ``[render]`` and body keys replacing
    the file's."""
    out = {k: v for k, v in doc.items() if k != "variant"}
    for v in variants:
        gone = set(v.remove or ())
        for key in ("simulation", "render"):
            if getattr(v, key) and isinstance(out.get(key, {}), dict):
                out[key] = {**out.get(key, {}), **getattr(v, key)}
        if isinstance(out.get("body"), list):
            out["body"] = [{**b, **(v.body or {}).get(_name(b.get("name")), {})} if isinstance(b, dict) else b
                           for b in out["body"] if not (isinstance(b, dict) and _name(b.get("name")) in gone)]
            for b in out["body"]:
                if isinstance(b, dict) and isinstance(b.get("collides_with"), list):
                    b["collides_with"] = [n for n in b["collides_with"] if _name(n) not in gone]
        for table, keys in _NAMING.items():
            if isinstance(out.get(table), list):
                out[table] = [t for t in out[table]
                              if not (isinstance(t, dict) and {_name(t.get(k)) for k in keys} & gone)]
    return out


def _name(value) -> str | None:
    """A body's name as a variant matches it: the string, or None for a value of another type
    (the file's own check reports that body's name)."""
    return value if isinstance(value, str) else None


def _variant_problems(path: Path, doc: dict, name: str, table, base: list, errors: Problems):
    """``[variant.NAME]`` checked: its keys, the bodies it names, and the file with it applied.
    A problem of a key the variant writes is named where it writes it
    (``variant.quick.body.jello.cells``); another that only the applied file has (no body left)
    is named below the variant (``variant.empty body``). Returns the
    :class:`~softvr.scene._description.Variant` (None when it is no table) and whether it had a
    problem."""
    w = f"variant.{name}"
    before = len(errors.items)
    variant, _ = read_table(Variant, table, w, errors)
    if variant is None:
        return None, True
    bodies = [b for b in doc.get("body", []) if isinstance(b, dict)] if isinstance(doc.get("body"), list) else []
    names = {_name(b.get("name")) for b in bodies} - {None}
    for k, gone in enumerate(variant.remove or ()):
        if gone not in names:
            errors.add(f"{w}.remove[{k}]", known_key(names, gone, "the name of a [[body]]"), repr(gone))
    patches = {}
    for body, patch in (variant.body or {}).items():
        if body not in names:
            errors.add(f"{w}.body.{body}", known_key(names, body, "the name of a [[body]]"), repr(body))
        elif not isinstance(patch, dict):
            errors.add(f"{w}.body.{body}", "a table of the body's keys", patch)
        else:
            for key in sorted({"name", "type"} & set(patch)):
                errors.add(f"{w}.body.{body}.{key}", "another key of the body (a variant keeps its name and type)",
                           repr(patch[key]))
            patches[body] = {k: v for k, v in patch.items() if k not in ("name", "type")}
    # The rest judged on as the file with it applied: what it names that is not there left out.
    variant = variant.model_copy(update={"remove": tuple(n for n in variant.remove or () if n in names),
                                         "body": patches})
    applied = _patched(doc, [variant])
    kept = [b for b in bodies if _name(b.get("name")) not in variant.remove]
    index = {f"body[{j}]": (f"body[{bodies.index(b)}]", _name(b.get("name"))) for j, b in enumerate(kept)}
    _, problems = _read_document(path, applied)
    for what, expected, found in problems:
        head, dot, rest = what.partition(".")
        key = rest.split(".")[0].split("[")[0]
        original, body = index.get(head, (head, None))
        written = ((variant.body or {}).get(body, {}) if body is not None else
                   (getattr(variant, head, None) or {}) if head in ("simulation", "render") else {})
        if key in written or (body is not None and not dot and set(written) & {"box", "sphere", "mesh", "tets",
                                                                                  "cloth", "cells"}):
            where = f"{w}.body.{body}" if body is not None else f"{w}.{head}"
            errors.add(f"{where}{dot}{rest}", expected, found)
        elif (f"{original}{dot}{rest}", expected, found) not in base:
            errors.add(f"{w} {original}{dot}{rest}", expected, found)
    return variant, len(errors.items) > before


def _read_document(path: Path, doc: dict) -> tuple[SceneFile, list]:
    """The scene of a scene file's TOML document ``doc`` (:func:`read_scene_with_problems`)."""
    errors = Problems(str(path), "scene file")
    if doc.get("format") != FORMAT:
        errors.add("format", f'"{FORMAT}"', doc.get("format", "nothing"))
    read_table(Document, doc, "", errors)  # its unknown keys
    simulation = simulation_settings(doc.get("simulation", {}), "simulation", errors)
    render = render_settings(doc.get("render", {}), _list(doc, "light", errors), "render", errors)
    materials = {}
    for name, t in _named_tables(doc, "material", errors).items():
        material, _ = read_table(Material, t, f"material.{name}", errors)
        materials[name] = material.model_dump()
    adhesions = {name: adhesion_parameters(t, f"adhesion.{name}", errors)
                 for name, t in _named_tables(doc, "adhesion", errors).items()}
    adhesions = {k: v for k, v in adhesions.items() if v is not None}

    def counted(read, *args):
        """``read(*args)`` and whether it found a problem."""
        before = len(errors.items)
        out = read(*args)
        return out, len(errors.items) > before

    planes = []
    for i, t in enumerate(_list(doc, "plane", errors)):
        w = f"plane[{i}]"
        plane, bad = read_table(Plane, t, w, errors)
        adhesion, bad_ref = counted(_ref, t, "adhesion", w, adhesions, "adhesion", errors)
        if not (bad or bad_ref):
            planes.append({**plane.model_dump(), "adhesion": adhesion,
                           "friction": simulation["friction"] if plane.friction is None else plane.friction})
    spheres = []
    for i, t in enumerate(_list(doc, "sphere", errors)):
        w = f"sphere[{i}]"
        sphere, bad = read_table(Sphere, t, w, errors)
        adhesion, bad_ref = counted(_ref, t, "adhesion", w, adhesions, "adhesion", errors)
        if not (bad or bad_ref):
            spheres.append({**sphere.model_dump(), "adhesion": adhesion,
                            "friction": simulation["friction"] if sphere.friction is None else sphere.friction})
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
        read_table(Filter, t, f"filter[{i}]", errors)  # its unknown keys
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
    # A fixed mesh is an obstacle, not a body: its contacts are the static geometry's.
    bodies_named = names - {b.name for b in bodies if b.type == "fixed" and b.shape == "mesh"}
    coupled = {c[side] for c, _ in couplings for side in "ab"} | {name for m in models for name in m["parts"]}
    sensors = sensor_tables([(f"sensor[{i}]", t) for i, t in enumerate(_list(doc, "sensor", errors))], bodies_named,
                            coupled, {b.name for b in bodies if b.type == "tool"}, errors)
    scene = SceneFile(path=path, simulation=simulation, render=render, materials=materials, adhesions=adhesions,
                      planes=planes, spheres=spheres, bodies=kept,
                      filters=[f for f in filters if set(f) <= present],
                      couplings=[c for c, bad in couplings if not bad and {c["a"], c["b"]} <= present],
                      models=models, volume=None if bad_volume else volume, display=display,
                      sensors=[s for s in sensors if {s["body"], s["other"]} - {None, STATIC} <= present])
    return scene, errors.items


def sensor_tables(tables: list, names: set, coupled: set, tools: set, errors: Problems) -> list:
    """The ``[[sensor]]`` tables (``(where, table)`` pairs: a TOML file's ``sensor[i]``, a glTF
    node's properties) without a problem: each names a body of the scene (``names``), a
    coupling_force sensor one with couplings (``coupled``), a hand_force sensor a tool
    (``tools``), a contact sensor's ``other`` another body or
    :data:`~softvr.scene._description.STATIC`; no two share a name."""
    out, seen = [], set()
    for w, t in tables:
        sensor, bad = read_table(Sensor, t, w, errors)
        if sensor is None:
            continue
        bodies = ", ".join(sorted(names)) or "none"
        if sensor.body is not None and sensor.body not in names:
            errors.add(f"{w}.body", f"the name of a body ({bodies})", repr(sensor.body))
            bad = True
        elif sensor.kind == "coupling_force" and sensor.body is not None and sensor.body not in coupled:
            errors.add(f"{w}.body", f"a body with couplings ({', '.join(sorted(coupled)) or 'none in this scene'})",
                       repr(sensor.body))
            bad = True
        elif sensor.kind == "hand_force" and sensor.body is not None and sensor.body not in tools:
            errors.add(f"{w}.body", f"a tool (its handle's force) ({', '.join(sorted(tools)) or 'none in this scene'})",
                       repr(sensor.body))
            bad = True
        if sensor.other is not None and (sensor.other not in names | {STATIC} or sensor.other == sensor.body):
            errors.add(f"{w}.other", f'the name of another body ({bodies}) or "{STATIC}"', repr(sensor.other))
            bad = True
        if sensor.name in seen:
            errors.add(f"{w}.name", "a name no other sensor has", repr(sensor.name))
            bad = True
        seen.add(sensor.name)
        if not bad:
            out.append(sensor.model_dump())
    return out


def _display(t, scene_dir: Path, errors: Problems) -> str | None:
    """The ``[display]`` table: a preset name, or a display file (read now, to check it)."""
    table, bad = read_table(DisplayTable, t, "display", errors)
    if table is None or bad:
        return None
    if len(table.given) != 1:
        errors.add("display", "a table with preset = NAME or file = PATH", t)
        return None
    if table.preset is not None:
        if not isinstance(table.preset, str) or table.preset not in DISPLAY_PRESETS:
            errors.add("display.preset", f"one of {', '.join(DISPLAY_PRESETS)}", table.preset)
            return None
        return table.preset
    path = _file(t, "file", "display", scene_dir, (".toml",), "a display file", errors)
    if path is None:
        return None
    try:
        read_display(path)
    except InputError as exc:
        errors.add("display.file", "a valid display file", str(exc))
        return None
    return str(path)


def _volume(t, scene_dir: Path, errors: Problems, where: str = "volume") -> dict | None:
    """The ``[volume]`` table (module docstring), problems named under ``where`` (a glTF
    volume node: ``node 'NAME'``); its file a dataset's name or resolved to an existing file
    or folder."""
    volume, _ = read_table(Volume, t, where, errors, folder=scene_dir)
    if volume is None:
        return None
    source = volume.file
    if source is not None and source not in DATASETS:
        try:
            source = file_name(scene_dir, source, f"{where}.file")
        except InputError as exc:
            errors.add(exc.what, f"a volume file or folder name ({exc.expected})", exc.found)
            source = None
        else:
            if not source.exists():
                errors.add(f"{where}.file", "an existing volume file or folder, or a dataset "
                           f"({', '.join(DATASETS)})", f"no file {source}")
                source = None
    return {**volume.model_dump(), "file": source}


def _model(i: int, t: dict, scene_dir: Path, errors: Problems, where: str | None = None) -> dict:
    """A ``[[model]]``: its file and part name -> kind (a parts file is validated now);
    problems named under ``where`` (a glTF model node: ``node 'NAME'``), else ``model[i]``."""
    w = where or f"model[{i}]"
    empty: dict[str, dict] = {"parts": {}, "colors": {}, "opacity": {}}
    read_table(ModelTable, t, w, errors)  # its unknown keys
    if "file" not in t:
        errors.add(f"{w}.file", "a parts file (.toml) or a built model (.npz)", "nothing")
        return {"file": None, **empty}
    path = _file(t, "file", w, scene_dir, (".toml", ".npz"), "a parts file or a built model", errors)
    if path is None:
        return {"file": path, **empty}
    try:
        specs = read_parts(path).parts if path.suffix.lower() == ".toml" else [p.spec for p in load_model(path).parts]
    except InputError as exc:
        if exc.source == str(path):  # each of the parts file's problems, named below the field that names it
            errors.items += [(f"{w}.file {what}", expected, found) for what, expected, found in exc.problems]
        else:
            errors.add(f"{w}.file", "a valid parts file or model", str(exc))
        return {"file": path, **empty}
    parts = {p.name: p.kind for p in specs}
    looks = {}
    for key, check in (("colors", lambda v: isinstance(v, list) and len(v) == 3 and all(
            isinstance(c, (int, float)) and 0 <= c <= 1 for c in v)), ("opacity", lambda v: isinstance(
            v, (int, float)) and 0 < v <= 1)):
        table = t.get(key, {})
        if not isinstance(table, dict):
            table = {}  # reported by read_table
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
    coupling, _ = read_table(Coupling, t, w, errors)
    kinds = {**{name: ("fem" if kind == "soft" else kind) for name, kind in parts.items()},
             **{b.name: b.type for b in bodies}}
    meshes = {b.name for b in bodies if b.type == "fixed" and b.shape == "mesh"}
    a = _ref(t, "a", w, kinds, "body", errors, required=True)
    b = _ref(t, "b", w, kinds, "body", errors, required=True)
    if "points" not in t and a is not None and kinds[a] not in ("fem", "cloth"):
        errors.add(f"{w}.a", "a fem or cloth body (its nodes are coupled), or points", f"{a!r}, a {kinds[a]} body")
    for side, name in (("a", a), ("b", b)):
        if name in meshes:
            errors.add(f"{w}.{side}", "a body (a fixed mesh is an obstacle, not a body: use a fixed box or a "
                       "kinematic body)", repr(name))
    if a is not None and a == b:
        errors.add(f"{w}.b", "another body than a", repr(b))
    return {**coupling.model_dump(), "a": a, "b": b, "radius": None if "points" in t else coupling.radius}
