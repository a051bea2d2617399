"""The parts file of ``softvr build-model`` (thesis 5.2): which meshes, what they are, how they
are coupled. TOML, versioned::

    format = "softvr-parts 1"

    [defaults]                  # optional, for every part
    cell_size = 0.008           # [m] tet cube size of soft parts
    collision_triangles = 300   # collision mesh budget

    [[part]]
    name = "scapula"
    mesh = "scapula.ply"        # OBJ, STL, PLY, glTF/GLB (relative to this file)
    kind = "fixed"              # fixed | kinematic | rigid | soft
    density = 1900.0            # [kg/m^3] rigid and soft parts

    [[part]]
    name = "supraspinatus"
    mesh = "supraspinatus.ply"
    kind = "soft"
    young = 3.0e4               # [Pa]
    poisson = 0.4
    density = 1050.0
    alpha = 2.0                 # [1/s] Rayleigh damping (optional)
    beta = 0.01                 # [s]

    [[coupling]]
    a = "supraspinatus"         # the coupled nodes are this part's
    b = "scapula"
    radius = 0.004              # [m] a's tet nodes within this distance of b's surface ...
    nodes = [0, 5, 9]           # ... and / or these node indices of a
    stiffness = 2.0e3           # [N/m] per spring
    damping = 0.0               # [N s/m]
    collide = false             # collision between a and b (off by default)

Every error names the file, the field path (``part[2].young``), what was expected and what
was found; all of a file's errors are reported at once, keys no table has too, at every level
(``part[2].densty``: named with the nearest known key, ``did you mean 'density'?``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

from softvr.errors import InputError, Problems
from softvr.files import checked_file, file_name, read_toml

__all__ = ["CouplingSpec", "PartSpec", "PartsFile", "read_parts"]

FORMAT = "softvr-parts 1"
KINDS = ("fixed", "kinematic", "rigid", "soft")
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".gltf", ".glb", ".off")
#: Most parts and couplings a parts file may have, most node indices a coupling may list, and
#: the largest collision triangle budget: far above an anatomical model's (tens of parts).
MAX_PARTS, MAX_NODES, MAX_TRIANGLES = 1000, 1_000_000, 200_000
_MAX_NAME = 128  # characters of a part name
#: Smallest soft-part tet cube [m]: finer is a unit mistake (a size in mm) or millions of tets.
MIN_CELL_SIZE = 1e-4


@dataclass
class PartSpec:
    """One anatomical part (thesis Table 5.1 row)."""

    name: str
    mesh: Path
    kind: str
    density: float = 1000.0
    young: float = 3e4
    poisson: float = 0.4
    alpha: float = 2.0
    beta: float = 0.01
    cell_size: float = 0.008
    collision_triangles: int = 300
    friction: float = 0.5


@dataclass
class CouplingSpec:
    """Zero-length springs from nodes of part ``a`` to part ``b``."""

    a: str
    b: str
    stiffness: float
    radius: float | None = None
    nodes: list = field(default_factory=list)
    damping: float = 0.0
    collide: bool = False


@dataclass
class PartsFile:
    """A validated parts file."""

    path: Path
    parts: list
    couplings: list

    def part(self, name: str) -> PartSpec:
        return next(p for p in self.parts if p.name == name)


#: The keys of each table of a parts file (module docstring): a part's are its spec's fields,
#: ``[defaults]`` the ones every part may share (not its name nor its mesh).
_PART_KEYS = tuple(f.name for f in fields(PartSpec))
_DEFAULT_KEYS = tuple(k for k in _PART_KEYS if k not in ("name", "mesh"))
_COUPLING_KEYS = tuple(f.name for f in fields(CouplingSpec))
_TOP_KEYS = ("format", "defaults", "part", "coupling")


def read_parts(path) -> PartsFile:
    """Read and validate a parts file (module docstring); mesh paths are resolved against its
    folder and must exist."""
    path = Path(path)
    source = str(path)
    doc = read_toml(path, "parts file")
    errors = Problems(source, "parts file")
    if doc.get("format") != FORMAT:
        errors.add("format", f'"{FORMAT}"', doc.get("format", "nothing"))
    errors.unknown_keys(doc, _TOP_KEYS, "")
    defaults = doc.get("defaults", {})
    if not isinstance(defaults, dict):
        errors.add("defaults", "a table", type(defaults).__name__)
        defaults = {}
    bad = errors.unknown_keys(defaults, _DEFAULT_KEYS, "defaults",
                              others={k: "a key of each [[part]]" for k in _PART_KEYS})
    defaults = {k: v for k, v in defaults.items() if k not in bad}  # reported once, not on every part
    parts, names = [], set()
    for i, raw in enumerate(_tables(doc, "part", errors, required=True)):
        where = f"part[{i}]"
        errors.unknown_keys(raw, _PART_KEYS, where)
        table = {**defaults, **raw}
        name = table.get("name")
        if not (isinstance(name, str) and name and len(name) <= _MAX_NAME and name.isprintable()):
            errors.add(f"{where}.name", f"a printable name of 1 .. {_MAX_NAME} characters",
                       name if name is not None else "nothing")
            name = f"part {i}"
        elif name in names:
            errors.add(f"{where}.name", "a name no other part has", name)
        names.add(name)
        kind = table.get("kind")
        if not isinstance(kind, str) or kind not in KINDS:
            errors.add(f"{where}.kind", " | ".join(KINDS), kind if kind is not None else "nothing")
        mesh_path = _mesh(table.get("mesh"), path.parent, f"{where}.mesh", errors)
        # A part with a bad mesh or kind is kept for its other checks; the file's problems raise below.
        spec = PartSpec(name=name, mesh=mesh_path, kind=kind)  # type: ignore[arg-type]
        for key, kw in (("density", dict(positive=True, unit="kg/m^3")), ("young", dict(positive=True, unit="Pa")),
                        ("poisson", dict(minimum=-0.99, maximum=0.5)), ("alpha", dict(minimum=0.0, unit="1/s")),
                        ("beta", dict(minimum=0.0, unit="s")),
                        ("cell_size", dict(minimum=MIN_CELL_SIZE, maximum=10.0, unit="m")),
                        ("friction", dict(minimum=0.0))):
            value = errors.number(table, key, where, default=getattr(spec, key), **kw)
            if value is not None:
                setattr(spec, key, value)
        budget = table.get("collision_triangles", spec.collision_triangles)
        if not (isinstance(budget, int) and not isinstance(budget, bool) and 4 <= budget <= MAX_TRIANGLES):
            errors.add(f"{where}.collision_triangles", f"an integer in 4 .. {MAX_TRIANGLES}", budget)
        else:
            spec.collision_triangles = budget
        parts.append(spec)
    couplings = []
    for i, raw in enumerate(_tables(doc, "coupling", errors, required=False)):
        where = f"coupling[{i}]"
        errors.unknown_keys(raw, _COUPLING_KEYS, where)
        ends = []
        for side in ("a", "b"):
            ref = raw.get(side)
            if not isinstance(ref, str) or ref not in names:
                errors.add(f"{where}.{side}", f"the name of a part ({', '.join(sorted(names))})",
                           ref if ref is not None else "nothing")
            ends.append(ref)
        if ends[0] == ends[1] and ends[0] is not None:
            errors.add(f"{where}.b", "another part than a", ends[1])
        stiffness = errors.number(raw, "stiffness", where, positive=True, unit="N/m")
        damping = errors.number(raw, "damping", where, default=0.0, minimum=0.0, unit="N s/m")
        radius = raw.get("radius")
        if radius is not None:
            radius = errors.number(raw, "radius", where, minimum=0.0, unit="m")
        nodes = raw.get("nodes", [])
        if not (isinstance(nodes, list) and len(nodes) <= MAX_NODES and all(
                isinstance(n, int) and not isinstance(n, bool) and 0 <= n < MAX_NODES for n in nodes)):
            errors.add(f"{where}.nodes", f"a list of node indices in 0 .. {MAX_NODES - 1}", nodes)
            nodes = []
        if radius is None and not nodes:
            errors.add(where, "radius and / or nodes (which nodes of a to couple)", "neither")
        collide = raw.get("collide", False)
        if not isinstance(collide, bool):
            errors.add(f"{where}.collide", "true or false", collide)
        couplings.append(CouplingSpec(a=ends[0], b=ends[1], stiffness=stiffness or 0.0, radius=radius, nodes=nodes,
                                      damping=damping or 0.0, collide=bool(collide)))
    errors.raise_if_any()
    return PartsFile(path=path, parts=parts, couplings=couplings)


def _tables(doc: dict, key: str, errors: Problems, *, required: bool) -> list:
    """The ``[[key]]`` tables of a parts file: at most :data:`MAX_PARTS`, at least one when
    ``required``; none (and a problem) when they are not that."""
    raw = doc.get(key, [])
    if not (isinstance(raw, list) and (raw or not required) and all(isinstance(table, dict) for table in raw)):
        errors.add(key, f"one or more [[{key}]] tables" if required else f"[[{key}]] tables",
                   type(raw).__name__ if raw or not required else "none")
        return []
    if len(raw) > MAX_PARTS:
        errors.add(key, f"at most {MAX_PARTS} [[{key}]] tables", len(raw))
        return []
    return raw


def _mesh(name, folder: Path, where: str, errors: Problems) -> Path | None:
    """The existing regular mesh file ``name`` (relative to the parts file's folder)."""
    if name is None:
        errors.add(where, "a mesh file name", "nothing")
        return None
    try:
        mesh = file_name(folder, name, where)
    except InputError as exc:
        errors.add(where, exc.expected, exc.found)
        return None
    if mesh.suffix.lower() not in MESH_SUFFIXES:
        errors.add(where, f"a mesh file ({', '.join(MESH_SUFFIXES)})", name)
        return mesh
    try:
        checked_file(mesh, where)
    except InputError as exc:
        errors.add(where, exc.expected, f"no file {mesh}" if exc.found == "no such file" else f"{exc.found}: {mesh}")
    return mesh
