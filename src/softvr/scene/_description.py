"""The scene description: every table of a scene file as one pydantic model, its defaults written once.

A TOML scene file (:mod:`softvr.scene.schema`) and a glTF scene's extras (:mod:`softvr.scene.gltf`)
are both validated by these models. Each field's type checks its value and words what was
expected as the rest of softvr does (:class:`softvr.errors.Problems`: SI units, a number written
with a unit told its SI value, counts bounded by :data:`LIMITS`); every model refuses keys it does
not know, naming the nearest known one. :func:`read_table` validates one table and turns
pydantic's errors into softvr's ``(field path, expected, found)`` problems, all at once; a bad
field then takes its default, so that the valid rest of a file can still be built
(``softvr check``). Rules between the fields of a table (a body's shape allowed for its type, a
tool's required stiffness) are the models' ``problems`` methods; references between tables
(material names, body names) are checked by the readers, which see the whole file.
"""

import copy
import dataclasses
import typing
from pathlib import Path
from typing import Annotated, Any, ClassVar

from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, PrivateAttr, ValidationError, ValidationInfo,
                      model_validator)
from pydantic_core import PydanticCustomError

from softvr.errors import InputError, Problems, known_key
from softvr.files import checked_file, file_name
from softvr.render import PRESETS, VIEWS
from softvr.sim import Scene
from softvr.volume import LOAD_SUFFIXES
from softvr.volume.tetmesh import TET_MESH_SUFFIXES

__all__ = ["BODY_KEYS", "BODY_TYPES", "BOX_CELLS", "CLOTH", "DATASETS", "GLTF_CELLS", "LIMITS", "MATERIAL_KEYS",
           "MESH_SUFFIXES", "PLAUSIBLE", "SENSOR_KINDS", "SHAPES", "STATIC", "TOOL", "VOLUME_MAPPERS", "Adhesion", "Body", "Coupling",
           "DisplayTable", "Document", "Drive", "Filter", "Light", "Material", "ModelTable", "Motion", "Plane",
           "Render", "Sensor", "Simulation", "Sphere", "Variant", "Volume", "existing_file", "read_table"]

BODY_TYPES = ("rigid", "fem", "cloth", "fixed", "kinematic", "tool")
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".gltf", ".glb", ".off")
#: ``[volume] file`` names of the volumes in :mod:`softvr.datasets`.
DATASETS = {"head-ct": "head_ct", "mri-ch2": "mri_ch2", "mri-ch2better": "mri_ch2better"}
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
#: The contact settings a scene file leaves out are softvr.Scene's own.
_SCENE: dict[str, Any] = {f.name: f.default for f in dataclasses.fields(Scene)}


# --- field types: each checks its value with softvr's wording ------------------------------------------------------

def _problem(expected: str, found, field: str | None = None) -> PydanticCustomError:
    """A pydantic error carrying softvr's ``expected`` and ``found`` (and a ``field`` below the
    one validated, for rules between fields); :func:`read_table` reads them back."""
    context = {"expected": expected, "found": found if isinstance(found, str) else repr(found)[:200]}
    return PydanticCustomError("softvr", "{expected}", {**context, **({"field": field} if field else {})})


def _check(read, *, required: bool = False) -> BeforeValidator:
    """A field check: ``read(problems, table)`` reads key ``"v"`` of ``table`` with a
    :class:`~softvr.errors.Problems` getter, so the wording is the one every softvr file gets.
    ``required``: a missing value (the field's default None, validated) is "nothing", except
    when :func:`read_table` validates again without the bad fields (context ``partial``)."""

    def check(value, info: ValidationInfo):
        if value is None and (not required or (info.context or {}).get("partial")):
            return None
        problems = Problems(None, "")
        out = read(problems, {} if value is None else {"v": value})
        if problems.items:
            raise _problem(problems.items[0][1], problems.items[0][2])
        return out

    return BeforeValidator(check)


def _required():
    """A field with no default: missing, it is reported as "nothing" (:func:`_check`)."""
    return Field(None, validate_default=True)


def number(unit: str = "", *, required: bool = False, **bounds) -> BeforeValidator:
    """A finite number [unit]: ``positive``, ``minimum``, ``maximum``, ``plausible`` as
    :meth:`softvr.errors.Problems.number`."""
    return _check(lambda p, t: p.number(t, "v", "", unit=unit, **bounds), required=required)


def vector(size: int = 3, unit: str = "", *, plausible: tuple | None = None, positive: str | None = None,
           required: bool = False) -> BeforeValidator:
    """``size`` finite numbers [unit] as a tuple; ``positive``: each > 0, else this is expected."""

    def read(p: Problems, t: dict):
        value = p.vector(t, "v", "", size, unit=unit, plausible=plausible)
        if value is not None and positive and min(value) <= 0:
            p.add("", positive, list(value))
            return None
        return value

    return _check(read, required=required)


def count(limit: str | None = None, minimum: int = 0) -> BeforeValidator:
    """An integer >= ``minimum``, and <= :data:`LIMITS` ``[limit]`` when given."""

    def read(p: Problems, t: dict):
        value = p.integer(t, "v", "", minimum=minimum)
        if value is not None and limit is not None and value > LIMITS[limit]:
            p.add("", f"an integer in {minimum} .. {LIMITS[limit]} (softvr's limit for a scene)", value)
            return None
        return value

    return _check(read)


def integers(size: int, top: int, expected: str, default: tuple) -> BeforeValidator:
    """``size`` integers in 1 .. ``top`` (cubes per axis, quads per side), ``default`` when absent."""

    def read(p: Problems, t: dict):
        value = t.get("v", list(default))
        if not (isinstance(value, list) and len(value) == size and all(
                type(c) is int and 1 <= c <= top for c in value)):
            p.add("", expected, value)
            return None
        return tuple(value)

    return _check(read)


def _read_color(p: Problems, t: dict):
    color = p.vector(t, "v", "")
    if color is not None and not all(0 <= c <= 1 for c in color):
        p.add("", "r, g, b in [0, 1]", list(color))
        return None
    return color


Color = Annotated[tuple[float, ...] | None, _check(_read_color)]
Boolean = Annotated[bool | None, _check(lambda p, t: p.boolean(t, "v", "", default=None))]


def choice(choices, *, required: bool = False) -> BeforeValidator:
    """One of ``choices``."""
    return _check(lambda p, t: p.choice(t, "v", "", choices), required=required)


def _read_name(p: Problems, t: dict):
    name = t.get("v")
    if not isinstance(name, str) or not name:
        p.add("", "a non-empty string", name if name is not None else "nothing")
        return None
    return name


Name = Annotated[str | None, _check(_read_name)]
RequiredName = Annotated[str | None, _check(_read_name, required=True)]


def _table_of(expected: str) -> BeforeValidator:
    """A nested table (``[body.motion]``): anything else is reported as not ``expected``."""

    def check(value):
        if value is not None and not isinstance(value, dict):
            raise _problem(expected, type(value).__name__ if not isinstance(value, (int, float, str)) else value)
        return value

    return BeforeValidator(check)


def existing_file(folder: Path, name, field: str, suffixes: tuple, what: str) -> Path:
    """The existing regular file ``name`` (relative to ``folder``) of one of ``suffixes``, read
    later through :mod:`softvr.files`; else an :class:`InputError` naming ``field``, ``what``
    was expected."""
    try:
        path = file_name(folder, name, field)
    except InputError as exc:
        raise InputError(field, f"{what} name ({exc.expected})", exc.found) from None
    if path.suffix.lower() not in suffixes:
        raise InputError(field, f"{what} ({', '.join(suffixes)})", repr(name)[:200])
    try:
        checked_file(path, field)
    except InputError as exc:
        raise InputError(field, exc.expected, f"{exc.found}: {path}" if exc.found != "no such file"
                         else f"no file {path}") from None
    return path


def file_field(suffixes: tuple, what: str) -> BeforeValidator:
    """An :func:`existing_file` named relative to the scene's folder (validation context ``folder``)."""

    def check(value, info: ValidationInfo):
        if value is None:
            return None
        try:
            return existing_file((info.context or {}).get("folder", Path(".")), value, str(info.field_name), suffixes,
                                 what)
        except InputError as exc:
            raise _problem(exc.expected, exc.found) from None

    return BeforeValidator(check)


class _Table(BaseModel):
    """A table of a scene file: unknown keys refused (named with the nearest known one)."""

    model_config = ConfigDict(extra="forbid")
    #: How a value that is not this table is described ("a [simulation] table").
    WHAT: ClassVar[str] = "a table"
    #: The keys the table was written with, bad ones too (:func:`read_table`): the rules
    #: between fields judge what was written, not what was left after a bad value.
    _given: set = PrivateAttr(default_factory=set)

    @property
    def given(self) -> set:
        return self._given or set(self.model_fields_set)

    def problems(self) -> list:
        """(field, expected, found) of what its fields get wrong together (none by default)."""
        return []

    @classmethod
    def keys_of(cls, table: dict) -> tuple[set, str, dict]:
        """The keys ``table`` may have, how its own keys are named, and what takes each known key
        it may not have: every field here (a body's keys depend on its type)."""
        return set(cls.model_fields), "a known key", {}


# --- keyframes ----------------------------------------------------------------------------------------------------

def _number_in_place(x) -> bool:  # times [s], positions [m], angles [deg] alike: within 10 km / 1e4
    low, high = PLAUSIBLE["place"]
    return isinstance(x, (int, float)) and not isinstance(x, bool) and low <= x <= high


def _read_times(p: Problems, t: dict):
    times = t.get("v")
    if not (isinstance(times, list) and times and all(map(_number_in_place, times))
            and all(b > a for a, b in zip(times, times[1:]))):
        p.add("", "increasing times [s], at least one", times if times is not None else "nothing")
        return None
    return times


def _triples(expected: str):
    def read(p: Problems, t: dict):
        value = t.get("v")
        if not (isinstance(value, list) and all(isinstance(v, list) and len(v) == 3 and all(map(_number_in_place, v))
                                                for v in value)):
            p.add("", expected, value if value is not None else "nothing")
            return None
        return value

    return read


Times = Annotated[list | None, _check(_read_times, required=True)]
_POSITIONS = "one [x, y, z] [m] per time"
_ROTATIONS = "one [rx, ry, rz] [deg] per time (about x, then y, then z)"


class Motion(_Table):
    """``[body.motion]``: a kinematic body's or a tool handle's keyframes, linear between."""

    times: Times = _required()                     # [s]
    positions: Annotated[list | None, _check(_triples(_POSITIONS), required=True)] = _required()   # [m]
    rotations: Annotated[list | None, _check(_triples(_ROTATIONS))] = None                          # [deg]

    @model_validator(mode="after")
    def _one_per_time(self):
        if self.positions is not None and self.times is not None and len(self.positions) != len(self.times):
            raise _problem(_POSITIONS, self.positions, "positions")
        if self.rotations is not None and self.times is not None and len(self.rotations) != len(self.times):
            raise _problem(_ROTATIONS, self.rotations, "rotations")
        return self


class Drive(_Table):
    """``[body.drive]``: offsets [m] of a fem or cloth body's held nodes at times [s]."""

    times: Times = _required()
    offsets: Annotated[list | None, _check(_triples(_POSITIONS), required=True)] = _required()

    @model_validator(mode="after")
    def _one_per_time(self):
        if self.offsets is not None and self.times is not None and len(self.offsets) != len(self.times):
            raise _problem(_POSITIONS, self.offsets, "offsets")
        return self


# --- the tables -----------------------------------------------------------------------------------------------------

class Simulation(_Table):
    """``[simulation]`` (a glTF scene's extras): the time step and the contact solver."""

    WHAT: ClassVar[str] = "a [simulation] table"
    dt: Annotated[float | None, number("s", positive=True, plausible=PLAUSIBLE["dt"])] = 0.005    # [s]
    steps_per_frame: Annotated[int | None, count("steps_per_frame", 1)] = 4
    frames: Annotated[int | None, count("frames", 1)] = 100
    gravity: Annotated[tuple | None, vector(3, "m/s^2", plausible=PLAUSIBLE["speed"])] = _SCENE["gravity"]   # [m/s^2]
    friction: Annotated[float | None, number(minimum=0.0)] = _SCENE["friction"]
    pgs_iterations: Annotated[int | None, count("pgs_iterations", 1)] = _SCENE["pgs_iterations"]
    pgs_tolerance: Annotated[float | None, number("m/s", positive=True)] = _SCENE["pgs_tolerance"]          # [m/s]
    contact_margin: Annotated[float | None, number("m", minimum=0.0)] = _SCENE["contact_margin"]            # [m]
    rotation_lag: Annotated[float | None, number("rad", positive=True)] = _SCENE["rotation_lag"]            # [rad]
    collision_free_start: Boolean = False
    adhesion: Boolean = True  # false: every adhesion of the file off, the same scene dry (thesis Fig. 4.4)
    edge_contacts: Boolean = _SCENE["edge_contacts"]  # false: vertex-triangle contacts only (thesis 5.2.1)


def _read_views(p: Problems, t: dict):
    camera = t.get("v")
    if not isinstance(camera, str) or camera not in VIEWS:
        p.add("", f"a view name ({', '.join(VIEWS)})", camera)
        return None
    return camera


class Render(_Table):
    """``[render]`` (a glTF scene's extras): the camera, the image and its light."""

    WHAT: ClassVar[str] = "a [render] table"
    size: Annotated[tuple | None, integers(2, 16384, "[width, height] in pixels, 1..16384", (640, 480))] = (
        640, 480)  # [pixels]
    camera: Annotated[str | None, _check(_read_views)] = "iso"
    azimuth: Annotated[float | None, number("deg")] = 0.0
    elevation: Annotated[float | None, number("deg")] = 0.0
    zoom: Annotated[float | None, number(positive=True)] = 1.0
    bounds: Annotated[tuple | None, vector(6, "m", plausible=PLAUSIBLE["place"])] = None  # [m] None: fitted
    background: Color = (0.10, 0.11, 0.13)
    background_top: Color = (0.32, 0.36, 0.43)
    light_kit: Boolean = True
    antialias: Boolean = True  # FXAA on the surfaces (~40 ms a 512 x 512 frame on a software OpenGL)
    fps: Annotated[float | None, number("frames/s", positive=True)] = None  # [1/s] None: 1 / (dt steps_per_frame)


class Light(_Table):
    """``[[light]]``: a directional light."""

    position: Annotated[tuple | None, vector(3, "m", plausible=PLAUSIBLE["place"], required=True)] = _required()
    focal_point: Annotated[tuple | None, vector(3, "m", plausible=PLAUSIBLE["place"])] = (0.0, 0.0, 0.0)
    color: Color = (1.0, 1.0, 1.0)
    intensity: Annotated[float | None, number(minimum=0.0)] = 1.0


class Material(_Table):
    """``[material.NAME]`` (a glTF node's extras): an isotropic linear-elastic material."""

    young: Annotated[float | None, number("Pa", positive=True, plausible=PLAUSIBLE["young"])] = 1e5          # [Pa]
    poisson: Annotated[float | None, number(minimum=-0.99, maximum=0.5)] = 0.3
    # [kg/m^3]
    density: Annotated[float | None, number("kg/m^3", positive=True, plausible=PLAUSIBLE["density"])] = 1000.0
    alpha: Annotated[float | None, number("1/s", minimum=0.0)] = 0.0                                          # [1/s]
    beta: Annotated[float | None, number("s", minimum=0.0)] = 0.0                                             # [s]


_PARAMETER = Annotated[float | None, number(minimum=0.0)]
_REQUIRED_PARAMETER = Annotated[float | None, number(minimum=0.0, required=True)]


class Adhesion(_Table):
    """``[adhesion.NAME]`` (a glTF node's ``softvr_adhesion_*``): :class:`softvr.contact.Adhesion`'s
    parameters; the three without a default there are required."""

    stiffness: _REQUIRED_PARAMETER = _required()      # [N/m^3]
    max_energy: _REQUIRED_PARAMETER = _required()     # [J/m^2]
    viscosity: _REQUIRED_PARAMETER = _required()      # [J s/m^2]
    bonding_rate: _PARAMETER = None                   # [1/(Pa s)]
    saturation: _PARAMETER = None                     # [Pa]
    initial: _PARAMETER = None
    debond_gap: _PARAMETER = None                     # [m]

    def parameters(self) -> dict:
        """The keyword arguments of :class:`softvr.contact.Adhesion` (its defaults for the rest)."""
        return {k: v for k, v in self.model_dump().items() if v is not None or k in ("stiffness", "max_energy",
                                                                                     "viscosity")}


def _read_normal(p: Problems, t: dict):
    normal = p.vector(t, "v", "", plausible=PLAUSIBLE["place"])
    if normal is not None and sum(c * c for c in normal) < 1e-12:
        p.add("", "a direction: 3 numbers, not all zero", list(normal))
        return None
    return normal


class Plane(_Table):
    """``[[plane]]``: a static half-space (``friction`` None: the simulation's)."""

    point: Annotated[tuple | None, vector(3, "m", plausible=PLAUSIBLE["place"])] = (0.0, 0.0, 0.0)           # [m]
    normal: Annotated[tuple[float, ...] | None, _check(_read_normal)] = (0.0, 0.0, 1.0)
    friction: Annotated[float | None, number(minimum=0.0)] = None
    size: Annotated[float | None, number("m", positive=True, maximum=PLAUSIBLE["place"][1])] = 3.0  # [m] drawn square
    adhesion: Any = None                                                            # an [adhesion.NAME]


class Sphere(_Table):
    """``[[sphere]]``: a static sphere (``friction`` None: the simulation's)."""

    center: Annotated[tuple | None, vector(3, "m", plausible=PLAUSIBLE["place"], required=True)] = _required()     # [m]
    # [m]
    radius: Annotated[float | None, number("m", positive=True, plausible=PLAUSIBLE["size"],
                                           required=True)] = _required()
    friction: Annotated[float | None, number(minimum=0.0)] = None
    adhesion: Any = None


class Filter(_Table):
    """``[[filter]]``: two bodies that never collide (names checked by the reader)."""

    a: Any = None
    b: Any = None


def _read_points(p: Problems, t: dict):
    points = t.get("v")
    if not (isinstance(points, list) and points and all(
            isinstance(q, list) and len(q) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                        for x in q) for q in points)):
        p.add("", "a list of [x, y, z] [m]", points)
        return None
    return points


class Coupling(_Table):
    """``[[coupling]]``: zero-length springs (thesis 5.3.2) from ``a``'s nodes within ``radius``
    of ``b``'s surface, or at world ``points`` (names checked by the reader)."""

    a: Any = None
    b: Any = None
    radius: Annotated[float | None, number("m", minimum=0.0)] = None                                         # [m]
    points: Annotated[list | None, _check(_read_points)] = None                     # [m]
    stiffness: Annotated[float | None, number("N/m", positive=True, required=True)] = _required()  # [N/m] per spring
    damping: Annotated[float | None, number("N s/m", minimum=0.0)] = 0.0                                     # [N s/m]
    collide: Boolean = False

    def problems(self) -> list:
        out = []
        if "points" in self.given and "radius" in self.given:
            out.append(("points", "radius or points, not both", "both"))
        elif "points" not in self.given and "radius" not in self.given:
            out.append(("radius", "a number [m]", "nothing"))
        return out


class ModelTable(_Table):
    """``[[model]]``: a parts file (.toml) or a built model (.npz) and its parts' looks (parts
    checked by the reader, which loads the file)."""

    file: Any = None
    colors: Annotated[dict | None, _table_of("a table: part name = value")] = None
    opacity: Annotated[dict | None, _table_of("a table: part name = value")] = None


def _read_cells(p: Problems, t: dict):
    """A fem body's cells: cubes per axis (1 or 3 integers) or a cube size [m]; which one its
    shape takes is :meth:`Body.problems`'."""
    cells = t.get("v")
    if isinstance(cells, list):
        top = LIMITS["cells"]
        if not (len(cells) == 3 and all(type(c) is int and 1 <= c <= top for c in cells)):
            p.add("", f"cubes per axis: an integer in 1 .. {top} or 3 of them", cells)
            return None
        return tuple(cells)
    if type(cells) is int and cells >= 1:  # cubes per axis of a box, or a mesh's cube size [m]
        return cells
    return p.number(t, "v", "", positive=True, unit="m")


def _read_body_names(p: Problems, t: dict):
    names = t.get("v")
    if not (isinstance(names, list) and all(isinstance(o, str) for o in names)):
        p.add("", "a list of body names", names)
        return None
    return tuple(names)


#: A body's shape keys (exactly one) and the shapes each body type takes (looked up with the
#: type as given, None when it is missing).
SHAPES: dict[str | None, tuple[str, ...]] = {
    "rigid": ("box", "sphere", "mesh"), "fem": ("box", "sphere", "mesh", "tets"), "cloth": ("cloth",),
    "fixed": ("box", "mesh"), "kinematic": ("box", "sphere", "mesh"), "tool": ("box", "sphere", "mesh")}
SHAPE_KEYS = ("box", "sphere", "mesh", "tets", "cloth")
#: The keys each body type takes, its shapes' (:data:`SHAPES`) among them: a key of another type
#: is refused, named with the nearest of its own (a key that would be ignored, as ``material`` on
#: a cloth or ``spin_centre`` on a rigid body, whose spin is about its centre of mass), except
#: those with rules of their own (:data:`_RULED`, :meth:`Body.problems`).
_EVERY_BODY = ("name", "type", "position", "rotation", "color", "collides_with", "adhesion")
_SOLID = ("scale", "subdivisions", "render_mesh")  # every type with a sphere, mesh or tets shape
_MOVING = ("surface_quads", "collision_triangles")  # a moving box's surface, a moving mesh's or sphere's budget
_DEFORMING = ("velocity", "angular_velocity", "spin_centre", "fixed_below", "fixed_above", "drive")
BODY_KEYS: dict[str, tuple[str, ...]] = {kind: (*SHAPES[kind], *_EVERY_BODY, *keys) for kind, keys in {
    "rigid": (*_SOLID, *_MOVING, "material", "velocity", "angular_velocity"),
    "fem": (*_SOLID, *_MOVING, *_DEFORMING, "material", "cells"),
    "cloth": (*_DEFORMING, "quads", "area_density", "stretch", "shear", "bend", "damping", "alpha"),
    "fixed": ("scale", "render_mesh"),  # a box or a mesh: no sphere to subdivide
    "kinematic": (*_SOLID, *_MOVING, "motion"),
    "tool": (*_SOLID, *_MOVING, "material", "stiffness", "angular_stiffness", "damping", "haptics", "max_force",
             "motion")}.items()}
#: Keys a rule of :meth:`Body.problems` names on a type that does not take them: the shape (which
#: ones the type takes), the drive (of held nodes), the motion (of kinematic bodies and tools).
_RULED = (*SHAPE_KEYS, "drive", "motion")
#: The material fields each body type uses (a glTF object's own properties; a TOML body names a
#: shared ``[material.NAME]``): a rigid body or a tool weighs its density, a fem body takes all.
MATERIAL_KEYS: dict[str, tuple[str, ...]] = {"rigid": ("density",), "tool": ("density",),
                                             "fem": tuple(Material.model_fields)}
#: Defaults of a cloth body's and a tool's own fields (``damping`` and ``alpha`` are both's).
CLOTH = {"quads": (16, 16), "area_density": 0.2, "stretch": 200.0, "shear": 20.0, "bend": 1.0, "damping": 0.05,
         "alpha": 0.1}
TOOL = {"angular_stiffness": 0.0, "damping": 0.0, "haptics": False, "max_force": 10.0}
#: A FEM box's cubes per axis (a TOML mesh or sphere body states its cube size [m]) and a FEM
#: glTF object's cube size [m].
BOX_CELLS = 4
GLTF_CELLS = 0.02


_LOW, _HIGH = PLAUSIBLE["place"]  # [m] a held-nodes height


class Body(_Table):
    """``[[body]]`` (a glTF node's extras, without the shape): a body, its shape, its start and
    its type's own fields (module docstring of :mod:`softvr.scene.schema`). Fields that
    another type takes a default from :data:`CLOTH` or :data:`TOOL` (None here: not given)."""

    name: RequiredName = _required()
    type: Annotated[str | None, choice(BODY_TYPES, required=True)] = _required()
    box: Annotated[tuple | None, vector(3, "m", plausible=PLAUSIBLE["size"], positive="3 edge lengths > 0 [m]")] = None
    sphere: Annotated[float | None, number("m", positive=True, plausible=PLAUSIBLE["size"])] = None  # [m] radius
    mesh: Annotated[Path | None, file_field(MESH_SUFFIXES, "a mesh file")] = None
    tets: Annotated[Path | None, file_field(TET_MESH_SUFFIXES, "a tet mesh file")] = None
    cloth: Annotated[tuple | None, vector(2, "m", plausible=PLAUSIBLE["size"])] = None  # [m] w, h
    cells: Annotated[Any, _check(_read_cells)] = None
    # sphere / mesh / tets: along its axes
    scale: Annotated[tuple | None, vector(3, positive="3 factors > 0")] = (1.0, 1.0, 1.0)
    surface_quads: Annotated[int | None, count("surface_quads", 1)] = 1                     # box
    subdivisions: Annotated[int | None, count()] = 3  # sphere: icosphere subdivisions
    render_mesh: Annotated[Path | None, file_field(MESH_SUFFIXES, "a mesh file")] = None
    collision_triangles: Annotated[int | None, count("collision_triangles", 4)] = None
    collides_with: Annotated[tuple | None, _check(_read_body_names)] = None
    material: Any = None
    adhesion: Any = None
    position: Annotated[tuple | None, vector(3, "m", plausible=PLAUSIBLE["place"])] = (0.0, 0.0, 0.0)        # [m]
    # [deg] x, then y, then z
    rotation: Annotated[tuple | None, vector(3, "deg", plausible=PLAUSIBLE["place"])] = (0.0, 0.0, 0.0)
    velocity: Annotated[tuple | None, vector(3, "m/s", plausible=PLAUSIBLE["speed"])] = (0.0, 0.0, 0.0)      # [m/s]
    # [rad/s]
    angular_velocity: Annotated[tuple | None, vector(3, "rad/s", plausible=PLAUSIBLE["speed"])] = (0.0, 0.0, 0.0)
    spin_centre: Annotated[tuple | None, vector(3, "m", plausible=PLAUSIBLE["place"])] = None                # [m]
    # [m]
    fixed_below: Annotated[float | None, number("m", minimum=_LOW, maximum=_HIGH)] = None
    # [m]
    fixed_above: Annotated[float | None, number("m", minimum=_LOW, maximum=_HIGH)] = None
    color: Color = (0.8, 0.6, 0.5)
    drive: Annotated[Drive | None, _table_of("a table: times [s] and offsets [m]")] = None
    motion: Annotated[Motion | None, _table_of("a table: times [s] and positions [m]")] = None
    quads: Annotated[tuple | None, integers(2, LIMITS["quads"], f"[nu, nv] quads, integers in 1 .. {LIMITS['quads']}",
                                            CLOTH["quads"])] = None
    area_density: Annotated[float | None, number("kg/m^2", positive=True)] = None          # [kg/m^2]
    stretch: Annotated[float | None, number("N/m", minimum=0.0)] = None                    # [N/m]
    shear: Annotated[float | None, number("N/m", minimum=0.0)] = None                      # [N/m]
    bend: Annotated[float | None, number("N/m", minimum=0.0)] = None                       # [N/m]
    damping: Annotated[float | None, number("N s/m", minimum=0.0)] = None  # [N s/m] cloth, or the tool's coupling
    alpha: Annotated[float | None, number("1/s", minimum=0.0)] = None                      # [1/s] cloth
    stiffness: Annotated[float | None, number("N/m", positive=True)] = None  # [N/m] tool: hand - tool coupling
    # [N m/rad] tool: the coupling's hold on the tool's orientation (0: free to turn)
    angular_stiffness: Annotated[float | None, number("N m/rad", minimum=0.0)] = None
    haptics: Boolean = None
    max_force: Annotated[float | None, number("N", positive=True)] = None                  # [N]

    @classmethod
    def keys_of(cls, table: dict) -> tuple[set, str, dict]:
        """A typed body's keys are its type's (:data:`BODY_KEYS`); the other types' keys are named
        with the types that take them (but for :data:`_RULED`, named by :meth:`problems`), and a
        material's (``poisson``) as the ``[material.NAME]`` key it is."""
        kind = table.get("type")
        if not isinstance(kind, str) or kind not in BODY_KEYS:
            return super().keys_of(table)
        valid = set(BODY_KEYS[kind])
        owners = {key: [f"{' | '.join(t for t, keys in BODY_KEYS.items() if key in keys)} bodies"]
                  for key in cls.model_fields if key not in valid and key not in _RULED}
        for key in Material.model_fields:
            if key not in valid:
                owners.setdefault(key, []).append("[material.NAME] tables, which a body names with material = NAME")
        return valid, f"a key of a {kind} body", {k: f"a key of {' and of '.join(v)}" for k, v in owners.items()}

    def shape(self) -> str | None:
        """The one shape key given, when it is one the body's type takes."""
        given = [s for s in SHAPE_KEYS if s in self.given]
        return given[0] if len(given) == 1 and given[0] in SHAPES.get(self.type, SHAPE_KEYS) else None

    def problems(self) -> list:
        """The rules between a body's fields (module docstring of :mod:`softvr.scene.schema`)."""
        given, kind = self.given, self.type
        out: list[tuple[str, str, Any]] = []  # (field, expected, found)
        allowed = SHAPES.get(kind, ("box", "sphere", "mesh", "cloth"))
        shapes = [s for s in SHAPE_KEYS if s in given]
        shape = self.shape()
        if shape is None:
            out.append(("", f"one shape of {' | '.join(allowed)} for a {kind or 'body'}",
                        ", ".join(shapes) if shapes else "no shape"))
        if "scale" in given and shape not in ("sphere", "mesh", "tets"):
            out.append(("scale", "a scale only on a sphere, mesh or tets shape", f"a {shape} shape"))
        if "surface_quads" in given and shape != "box":
            out.append(("surface_quads", "surface quads only on a moving box", f"a {kind} {shape}"))
        if "subdivisions" in given and shape != "sphere":
            out.append(("subdivisions", "subdivisions only on a sphere", f"a {shape} shape"))
        if "collision_triangles" in given and shape not in ("mesh", "sphere"):
            out.append(("collision_triangles", "a triangle budget only on a moving mesh or sphere",
                        f"a {kind} {shape}"))
        top = LIMITS["cells"]
        if kind == "fem" and shape in ("mesh", "sphere"):
            if "cells" not in given:
                out.append(("cells", "a number [m]", "nothing"))
            elif isinstance(self.cells, tuple):
                out.append(("cells", "a number > 0 [m]", list(self.cells)))
        elif kind == "fem" and shape == "box" and isinstance(self.cells, float):
            out.append(("cells", f"cubes per axis: an integer in 1 .. {top} or 3 of them", self.cells))
        elif kind == "fem" and shape == "box" and isinstance(self.cells, int) and self.cells > top:
            out.append(("cells", f"an integer in 1 .. {top} (softvr's limit for a scene)", self.cells))
        if "drive" in given:
            if kind not in ("fem", "cloth"):
                out.append(("drive", "a drive only on a fem or cloth body (it moves the held nodes)", f"a {kind} body"))
            elif "fixed_below" not in given and "fixed_above" not in given:
                out.append(("drive", "held nodes to drive: fixed_below or fixed_above", "neither"))
        if kind in ("kinematic", "tool") and "motion" not in given:
            out.append(("motion", "a table: times [s] and positions [m]", "nothing"))
        elif "motion" in given and kind not in ("kinematic", "tool"):
            out.append(("motion", "a motion only on a kinematic body or a tool", f"a {kind} body"))
        if kind == "tool" and self.motion is not None and self.motion.rotations is not None:
            out.append(("motion.rotations", "positions only on a tool (its handle is a point; a kinematic body may "
                        "rotate)", "rotations"))
        if kind == "tool" and "stiffness" not in given:
            out.append(("stiffness", "a number [N/m]", "nothing"))
        return out

    def cloth_parameters(self) -> dict:
        """A cloth body's quads and material (:data:`CLOTH` for what it does not give)."""
        return {k: d if getattr(self, k) is None else getattr(self, k) for k, d in CLOTH.items()}

    def tool_parameters(self) -> dict:
        """A tool's coupling to its handle (:data:`TOOL` for what it does not give)."""
        return {"stiffness": self.stiffness, **{k: d if getattr(self, k) is None else getattr(self, k)
                                                for k, d in TOOL.items()}}


def _read_volume_file(p: Problems, t: dict):
    file = t.get("v")
    if not isinstance(file, str):
        p.add("", f"a volume file or folder, or a dataset ({', '.join(DATASETS)})", file if file is not None else
              "nothing")
        return None
    return file


def _read_preset(p: Problems, t: dict):
    preset = t.get("v")
    if not isinstance(preset, str) or preset not in PRESETS:
        p.add("", f"one of {', '.join(sorted(PRESETS))}", preset)
        return None
    return preset


_VOLUME_CELLS = f"3 integers in 1 .. {LIMITS['cells']} (mesh cubes per axis)"
#: A label volume's file kinds: those :func:`softvr.volume.load` reads whose name has one suffix.
_LABEL_SUFFIXES = tuple(s for s in LOAD_SUFFIXES if s.count(".") == 1)
#: ``[volume] mapper``: how the volume is drawn (:meth:`softvr.render.SurfaceRenderer.add_volume`).
VOLUME_MAPPERS = ("auto", "warp", "cpu")


class Volume(_Table):
    """``[volume]`` (a glTF volume node's extras): a CT / MRI embedded in a FEM body built from
    its voxels (thesis 3.3.2); ``file`` (a dataset name, or a file the reader resolves)."""

    WHAT: ClassVar[str] = "a [volume] table"
    file: Annotated[str | None, _check(_read_volume_file, required=True)] = _required()
    name: Name = "volume"
    unit: Annotated[float | None, number("m per volume unit", positive=True)] = 0.001  # [m] per volume unit
    cells: Annotated[tuple | None, integers(3, LIMITS["cells"], _VOLUME_CELLS, (16, 16, 8))] = (16, 16, 8)
    threshold: Annotated[float | None, number()] = -300.0
    skin_triangles: Annotated[int | None, count("skin_triangles", 4)] = 4000
    fix_denser_than: Annotated[float | None, number("kg/m^3", positive=True)] = 1150.0                        # [kg/m^3]
    alpha: Annotated[float | None, number("1/s", minimum=0.0)] = 2.0                                          # [1/s]
    beta: Annotated[float | None, number("s", minimum=0.0)] = 0.01                                            # [s]
    preset: Annotated[str | None, _check(_read_preset)] = "ct-skin"
    render_step: Annotated[int | None, count("render_step", 1)] = 2
    mapper: Annotated[str | None, choice(VOLUME_MAPPERS)] = "auto"
    sample_distance: Annotated[float | None, number("voxels", positive=True)] = None  # [voxels] None: the mapper's
    incremental: Boolean = True
    mask: Boolean = True
    animation: Annotated[Path | None, file_field((".npz",), "a node animation")] = None
    labels: Annotated[Path | None, file_field(_LABEL_SUFFIXES, "a label volume")] = None


#: What a ``[[sensor]]`` reads every frame, and its unit: the contact force on its body (the last
#: step's contact impulses / dt, thesis eq. 5.5), the force of the couplings on it (thesis eq.
#: 5.4: spring and damper), its centre (a rigid body's centre of mass, a node body's
#: mass-weighted mean node), and on a tool the force its haptic device renders on the hand (the
#: virtual coupling's spring k (x_tool - x_handle), thesis 5.4), each an [x, y, z] vector.
SENSOR_KINDS = {"contact_force": "N", "coupling_force": "N", "position": "m", "hand_force": "N"}
#: A contact sensor's ``other`` naming every static geometry (planes, static spheres, fixed meshes).
STATIC = "static"


class Sensor(_Table):
    """``[[sensor]]``: a quantity sampled every frame into the metrics and plotted against time
    (:data:`SENSOR_KINDS`); ``body`` and ``other`` are checked by the reader, which knows the bodies."""

    name: RequiredName = _required()
    kind: Annotated[str | None, choice(tuple(SENSOR_KINDS), required=True)] = _required()
    body: RequiredName = _required()
    other: Name = None  # contact_force: only the contacts with this body, or STATIC (None: all)

    def problems(self) -> list:
        if "other" in self.given and self.kind in SENSOR_KINDS and self.kind != "contact_force":
            return [("other", "other only on a contact_force sensor", f"a {self.kind} sensor")]
        return []


class DisplayTable(_Table):
    """``[display]``: a display preset or a display file (checked by the reader)."""

    preset: Any = None
    file: Any = None


def _read_strings(p: Problems, t: dict):
    names = t.get("v")
    if not (isinstance(names, list) and all(isinstance(n, str) and n for n in names)):
        p.add("", "a list of body names", names)
        return None
    return tuple(names)


class Variant(_Table):
    """``[variant.NAME]``: the scene changed (a coarser resolution, fewer bodies, adhesion off):
    ``remove`` these bodies, replace keys of ``[simulation]``, ``[render]`` and of bodies by
    name (``[variant.NAME.body."jello"]``); what it names is checked by the reader, which
    applies it to the file and validates the result."""

    WHAT: ClassVar[str] = "a [variant.NAME] table"
    remove: Annotated[tuple | None, _check(_read_strings)] = ()
    simulation: Annotated[dict | None, _table_of("a table: [simulation] keys")] = None
    render: Annotated[dict | None, _table_of("a table: [render] keys")] = None
    body: Annotated[dict | None, _table_of('a table of body name = table of its keys')] = None


class Document(_Table):
    """A scene file's top-level keys (each table validated by its own model)."""

    format: Any = None
    simulation: Any = None
    render: Any = None
    material: Any = None
    adhesion: Any = None
    plane: Any = None
    sphere: Any = None
    body: Any = None
    filter: Any = None
    coupling: Any = None
    model: Any = None
    volume: Any = None
    display: Any = None
    light: Any = None
    sensor: Any = None
    variant: Any = None


# --- validation -----------------------------------------------------------------------------------------------------

def _model_of(annotation) -> type[BaseModel] | None:
    """The model class inside a field's annotation (``Annotated[Motion | None, ...]``)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    return next((m for a in typing.get_args(annotation) if (m := _model_of(a)) is not None), None)


def _path(loc) -> str:
    return "".join(f"[{x}]" if isinstance(x, int) else f".{x}" for x in loc)


def _problems(exc: ValidationError, model: type[BaseModel], where: str, keys: set) -> list:
    """softvr's ``(field path, expected, found)`` of each of pydantic's errors; ``keys``: those
    the table itself may have (:meth:`_Table.keys_of`)."""
    out = []
    for e in exc.errors(include_url=False):
        loc = e["loc"]
        if e["type"] == "extra_forbidden":
            owner: Any = model  # a model at each step of an extra key's path (pydantic forbids extras only there)
            for step in loc[:-1]:
                owner = _model_of(owner.model_fields[step].annotation) if isinstance(step, str) else owner
            valid = keys if len(loc) == 1 else owner.model_fields
            out.append((f"{where}{_path(loc)}".lstrip("."), known_key(valid, loc[-1]), repr(loc[-1])))
        elif e["type"] == "softvr":
            field = e["ctx"].get("field")
            out.append((f"{where}{_path(loc)}{'.' + field if field else ''}".lstrip("."), e["ctx"]["expected"],
                        e["ctx"]["found"]))
        else:  # a check of pydantic's own (none is expected: every field has a softvr check)
            out.append((f"{where}{_path(loc)}".lstrip("."), e["msg"], repr(e.get("input"))[:200]))
    return out


def _drop(data: dict, loc: tuple) -> bool:
    """Remove the bad value at ``loc`` from ``data``: a key of a nested table, not the whole
    table, so that its other fields are judged on. Whether there was one to remove."""
    if not loc:
        return False
    *parents, key = loc
    table = data
    for step in parents:
        nested = table.get(step) if isinstance(table, dict) else None
        if not isinstance(nested, dict):  # inside a list: the field is dropped whole
            return data.pop(loc[0], _MISSING) is not _MISSING
        table = nested
    return table.pop(key, _MISSING) is not _MISSING


_MISSING = object()


def read_table(model: type[_Table], table, where: str, errors: Problems, *, folder: Path | None = None,
               rules: bool = True):
    """``table`` validated as ``model``, its problems added to ``errors`` named under ``where``
    (``body[2]``, ``node 'cube'``): the model, its bad fields taking their defaults (None when
    a required one is bad, or ``table`` is no table), and whether it had a problem.

    ``folder``: where file names are relative to; ``rules``: with the model's rules between
    fields (``problems``; a glTF node has its own).
    """
    if not isinstance(table, dict):
        errors.add(where, model.WHAT, table if isinstance(table, (int, float, str)) else type(table).__name__)
        return None, True
    keys, what, others = model.keys_of(table)
    # Another type's keys: refused here, named with the nearest of this one's.
    misplaced = Problems(errors.source, errors.kind)
    misplaced.unknown_keys([k for k in table if k in others], keys, where, others=others, what=what)
    found: list = misplaced.items
    data = copy.deepcopy({k: v for k, v in table.items() if k not in others})
    context: dict[str, Any] = {"folder": folder or Path(".")}
    out: _Table | None = None
    while True:  # ends: every round drops a bad value or turns partial (once), else stops
        try:
            valid = model.model_validate(data, context=context)
        except ValidationError as exc:
            new = [p for p in _problems(exc, model, where, keys) if p not in found]
            found += new
            dropped = [_drop(data, e["loc"]) for e in exc.errors()]  # every one, not the first only
            if not new or not any(dropped) and context.get("partial"):
                out = None
                break
            # Again without the bad fields: they take their defaults, the rest is judged on.
            context = {**context, "partial": True}
            continue
        valid._given = set(table) - set(others)
        found += [(f"{where}.{f}" if f else where, e, v if isinstance(v, str) else repr(v))
                  for f, e, v in (valid.problems() if rules else [])]
        out = valid
        break
    errors.items.extend(found)
    return out, bool(found)

