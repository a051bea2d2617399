"""Error types raised by softvr.

Every error a user can cause by bad input is an :class:`InputError` whose message names
the file (when there is one), the field or element, what was expected and what was found.
:func:`raise_all` reports a file's problems together (:class:`Problems` collects them while a
reader walks a table; :func:`with_unit` says what to write for a number given with a unit).
Reading the files is :mod:`softvr.files`'s.
"""

from __future__ import annotations

import difflib
import math
import re

__all__ = ["InputError", "Problems", "SimulationError", "SoftvrError", "known_key", "raise_all", "with_unit"]


class SoftvrError(Exception):
    """Base class of all softvr errors."""


class InputError(SoftvrError, ValueError):
    """Bad input: a file, field or element that is not what softvr expects.

    Parameters
    ----------
    what : str
        The field or element at fault, e.g. ``"tets[12]"`` or ``"spacing"``.
    expected : str
        What softvr expected there.
    found : str
        What it found.
    source : str, optional
        The file (or argument name) the input came from.
    """

    def __init__(self, what: str, expected: str, found: str, source: str | None = None):
        self.what, self.expected, self.found, self.source = what, expected, found, source
        #: Every ``(what, expected, found)`` of a file reported at once (:func:`raise_all`).
        self.problems = [(what, expected, found)]
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{what}: expected {expected}, found {found}")


class SimulationError(SoftvrError, RuntimeError):
    """A simulation diverged; the message names the body and the step."""


_KNOWN = "a known key"


def known_key(valid, key, what: str = _KNOWN) -> str:
    """What was expected instead of the unknown ``key``: ``what``, naming the nearest of the
    ``valid`` keys when one is near (difflib's ratio >= 0.6), else all of them; the one wording
    of every file softvr reads tables from (scene, glTF extras, parts, display)."""
    valid = sorted(valid)
    near = difflib.get_close_matches(str(key), valid, n=1, cutoff=0.6)
    if near:
        return f"{what} (did you mean {near[0]!r}?)"
    return f"one of {', '.join(valid)}" if what == _KNOWN else f"{what}: one of {', '.join(valid)}"


def raise_all(problems: list, source: str | None, kind: str) -> None:
    """Raise one :class:`InputError` for every ``(what, expected, found)`` in ``problems`` (a
    file's problems reported at once, not the first only); nothing when there are none.
    ``kind`` names what a valid input is ("parts file", "display")."""
    if not problems:
        return
    if len(problems) == 1:
        what, expected, found = problems[0]
        error = InputError(what, expected, found, source=source)
    else:
        lines = "".join(f"\n  - {w}: expected {e}, found {f}" for w, e, f in problems)
        error = InputError(f"{len(problems)} problems", f"a valid {kind}", lines, source=source)
    error.problems = list(problems)
    raise error


#: Units people write in input files, as (factor to SI, the SI unit softvr reads): how a
#: number written with a unit is reported (softvr files hold bare SI numbers).
_UNITS = {
    "m": (1.0, "m"), "cm": (1e-2, "m"), "mm": (1e-3, "m"), "um": (1e-6, "m"), "µm": (1e-6, "m"), "km": (1e3, "m"),
    "in": (0.0254, "m"), "ft": (0.3048, "m"),
    "s": (1.0, "s"), "ms": (1e-3, "s"), "us": (1e-6, "s"), "µs": (1e-6, "s"), "min": (60.0, "s"),
    "kg": (1.0, "kg"), "g": (1e-3, "kg"),
    "Pa": (1.0, "Pa"), "kPa": (1e3, "Pa"), "MPa": (1e6, "Pa"), "GPa": (1e9, "Pa"), "psi": (6894.757, "Pa"),
    "N/m^2": (1.0, "Pa"), "N/mm^2": (1e6, "Pa"),
    "kg/m^3": (1.0, "kg/m^3"), "kg/m3": (1.0, "kg/m^3"), "g/cm^3": (1e3, "kg/m^3"), "g/cm3": (1e3, "kg/m^3"),
    "g/cc": (1e3, "kg/m^3"), "g/ml": (1e3, "kg/m^3"), "kg/l": (1e3, "kg/m^3"),
    "kg/m^2": (1.0, "kg/m^2"), "g/m^2": (1e-3, "kg/m^2"), "g/cm^2": (10.0, "kg/m^2"),
    "N": (1.0, "N"), "mN": (1e-3, "N"), "kN": (1e3, "N"),
    "N/m": (1.0, "N/m"), "N/mm": (1e3, "N/m"), "N/cm": (1e2, "N/m"),
    "N s/m": (1.0, "N s/m"), "Ns/m": (1.0, "N s/m"),
    "m/s": (1.0, "m/s"), "cm/s": (1e-2, "m/s"), "mm/s": (1e-3, "m/s"), "km/h": (1 / 3.6, "m/s"),
    "m/s^2": (1.0, "m/s^2"), "m/s2": (1.0, "m/s^2"),
    "rad/s": (1.0, "rad/s"), "deg/s": (0.017453292519943295, "rad/s"), "rpm": (0.10471975511965977, "rad/s"),
    "deg": (1.0, "deg"), "°": (1.0, "deg"), "rad": (57.29577951308232, "deg"),
    "1/s": (1.0, "1/s"), "Hz": (1.0, "1/s"),
    "J/m^2": (1.0, "J/m^2"), "N/m^3": (1.0, "N/m^3"),
}
_QUANTITY = {"m": "a length", "s": "a time", "kg": "a mass", "Pa": "a pressure (stress)", "kg/m^3": "a density",
             "kg/m^2": "an area density", "N": "a force", "N/m": "a stiffness", "N s/m": "a damping",
             "m/s": "a speed", "m/s^2": "an acceleration", "rad/s": "an angular speed", "deg": "an angle",
             "1/s": "a rate", "J/m^2": "an energy per area", "N/m^3": "a stiffness per area"}


def with_unit(value, unit: str) -> str | None:
    """What to tell someone who wrote ``value`` (e.g. ``"5 mm"``) where softvr reads a bare
    number in ``unit`` (e.g. ``"m"``): the SI number to write instead, or that the unit is of
    another quantity; None when ``value`` is not a number with a unit."""
    if not isinstance(value, str):
        return None
    try:
        float(value)
        return f"{value!r} (a string: write the number without quotes)"
    except ValueError:
        pass
    match = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(\S.*?)\s*", value)
    if match is None:
        return None
    number, written = float(match.group(1)), match.group(2).replace(" ", "").replace("·", "").replace("*", "")
    known = {k.replace(" ", ""): v for k, v in _UNITS.items()}
    if written not in known or not math.isfinite(number) or not unit:
        return f"{value!r} (softvr files hold bare numbers in SI units{f': [{unit}]' if unit else ''})"
    factor, si = known[written]
    if si != unit:
        what = _QUANTITY.get(si, si)
        return f"{value!r}: {what} [{si}], not [{unit}] (softvr files hold bare numbers in SI units)"
    return f"{value!r} (softvr files hold bare numbers in SI units: write {number * factor:.6g} [{unit}])"


class Problems:
    """Every problem of an input file, collected while reading it and raised together
    (:func:`raise_all`). Getters read one field of a TOML table, check it and record what
    is wrong under its field path (``body[2].young``); they return None for a bad value.

    Numbers are SI. A number written with a unit (``"5 mm"``) is reported with the SI number
    to write instead (:func:`with_unit`); ``plausible = (low, high)`` bounds a number to what
    it can be in its SI unit, so that one given in other units (a density in g/cm^3, a time
    step in ms, a size in mm) is reported, not simulated.
    """

    def __init__(self, source: str | None, kind: str):
        self.source, self.kind = source, kind
        self.items: list[tuple] = []  # (what, expected, found)

    def add(self, what: str, expected: str, found) -> None:
        self.items.append((what, expected, found if isinstance(found, str) else repr(found)))

    def raise_if_any(self) -> None:
        raise_all(self.items, self.source, self.kind)

    def unknown_keys(self, table, valid, where: str, *, others: dict | None = None, what: str = _KNOWN) -> list:
        """Record every key of ``table`` not in ``valid`` under ``where.key``, each named with the
        nearest valid one (:func:`known_key`). ``others``: the keys of other kinds of table,
        each with what takes it, which are expected as ``what`` ("a key of a rigid body") and
        found with their owner. The keys recorded."""
        others = others or {}
        bad = sorted((k for k in table if k not in valid), key=str)
        for key in bad:
            if key in others:
                self.add(f"{where}.{key}".lstrip("."), known_key(valid, key, what), f"{key!r} ({others[key]})")
            else:
                self.add(f"{where}.{key}".lstrip("."), known_key(valid, key), repr(key)[:100])
        return bad

    def number(self, table: dict, key: str, where: str, *, default=None, positive=False, minimum=None,
               maximum=None, unit: str = "", plausible: tuple | None = None) -> float | None:
        """A finite number (``> 0`` with ``positive``, in ``[minimum, maximum)``, within
        ``plausible`` (class docstring))."""
        value = table.get(key, default)
        if value is None:
            self.add(f"{where}.{key}", f"a number [{unit}]".replace(" []", ""), "nothing")
            return None
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        ok = ok and (not positive or value > 0) and (minimum is None or value >= minimum)
        ok = ok and (maximum is None or value < maximum)
        if not ok:
            bounds = "> 0" if positive else (f">= {minimum}" if minimum is not None else "finite")
            if maximum is not None:
                bounds += f" and < {maximum}"
            self.add(f"{where}.{key}", f"a number {bounds} [{unit}]".replace(" []", ""),
                     with_unit(value, unit) or value)
            return None
        if plausible is not None and not plausible[0] <= value <= plausible[1]:
            self.add(f"{where}.{key}", f"{_QUANTITY.get(unit, 'a number')} in SI units, {plausible[0]:g} .. "
                     f"{plausible[1]:g} [{unit}]", f"{value!r} (in other units?)")
            return None
        return float(value)

    def integer(self, table: dict, key: str, where: str, *, default=None, minimum: int = 0) -> int | None:
        value = table.get(key, default)
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= minimum):
            self.add(f"{where}.{key}", f"an integer >= {minimum}", value if value is not None else "nothing")
            return None
        return value

    def vector(self, table: dict, key: str, where: str, size: int = 3, *, default=None, unit: str = "",
               plausible: tuple | None = None):
        """A list of ``size`` finite numbers, as a tuple of floats; each within ``plausible``
        (class docstring)."""
        value = table.get(key, default)
        ok = isinstance(value, (list, tuple)) and len(value) == size and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
        if not ok:
            written = next((w for v in value if (w := with_unit(v, unit))), None) \
                if isinstance(value, (list, tuple)) and unit else None
            self.add(f"{where}.{key}", f"{size} numbers [{unit}]".replace(" []", ""),
                     written or (value if value is not None else "nothing"))
            return None
        if plausible is not None and not all(plausible[0] <= v <= plausible[1] for v in value):
            self.add(f"{where}.{key}", f"{size} numbers, each {_QUANTITY.get(unit, 'a number')} in SI units, "
                     f"{plausible[0]:g} .. {plausible[1]:g} [{unit}]", f"{list(value)!r} (in other units?)")
            return None
        return tuple(float(v) for v in value)

    def choice(self, table: dict, key: str, where: str, choices, *, default=None):
        value = table.get(key, default)
        if value not in choices:
            self.add(f"{where}.{key}", " | ".join(choices), value if value is not None else "nothing")
            return None
        return value

    def boolean(self, table: dict, key: str, where: str, *, default: bool = False) -> bool:
        value = table.get(key, default)
        if not isinstance(value, bool):
            self.add(f"{where}.{key}", "true or false", value)
            return default
        return value
