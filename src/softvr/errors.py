"""Error types raised by softvr.

Every error a user can cause by bad input is an :class:`InputError` whose message names
the file (when there is one), the field or element, what was expected and what was found.
:func:`raise_all` reports a file's problems together; :func:`read_toml` reads a TOML input
file with those errors for a missing file or bad syntax.
"""

from __future__ import annotations

__all__ = ["InputError", "SimulationError", "SoftvrError", "raise_all", "read_toml"]


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
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{what}: expected {expected}, found {found}")


class SimulationError(SoftvrError, RuntimeError):
    """A simulation diverged; the message names the body and the step."""


def raise_all(problems: list, source: str | None, kind: str) -> None:
    """Raise one :class:`InputError` for every ``(what, expected, found)`` in ``problems`` (a
    file's problems reported at once, not the first only); nothing when there are none.
    ``kind`` names what a valid input is ("parts file", "display")."""
    if not problems:
        return
    if len(problems) == 1:
        raise InputError(*problems[0], source=source)
    lines = "; ".join(f"{w}: expected {e}, found {f}" for w, e, f in problems)
    raise InputError(f"{len(problems)} problems", f"a valid {kind}", lines, source=source)


def read_toml(path, kind: str) -> dict:
    """The table of a TOML file; a missing file or bad TOML is an :class:`InputError` naming it."""
    import tomllib
    from pathlib import Path

    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(kind, "an existing TOML file", "no such file", source=str(path)) from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError("TOML", "valid TOML", str(exc), source=str(path)) from None


class Problems:
    """Every problem of an input file, collected while reading it and raised together
    (:func:`raise_all`). Getters read one field of a TOML table, check it and record what
    is wrong under its field path (``body[2].young``); they return None for a bad value."""

    def __init__(self, source: str | None, kind: str):
        self.source, self.kind, self.items = source, kind, []

    def add(self, what: str, expected: str, found) -> None:
        self.items.append((what, expected, found if isinstance(found, str) else repr(found)))

    def raise_if_any(self) -> None:
        raise_all(self.items, self.source, self.kind)

    def number(self, table: dict, key: str, where: str, *, default=None, positive=False, minimum=None,
               maximum=None, unit: str = "") -> float | None:
        """A finite number (``> 0`` with ``positive``, in ``[minimum, maximum)``)."""
        import math

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
            self.add(f"{where}.{key}", f"a number {bounds} [{unit}]".replace(" []", ""), value)
            return None
        return float(value)

    def integer(self, table: dict, key: str, where: str, *, default=None, minimum: int = 0) -> int | None:
        value = table.get(key, default)
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= minimum):
            self.add(f"{where}.{key}", f"an integer >= {minimum}", value if value is not None else "nothing")
            return None
        return value

    def vector(self, table: dict, key: str, where: str, size: int = 3, *, default=None, unit: str = ""):
        """A list of ``size`` finite numbers, as a tuple of floats."""
        import math

        value = table.get(key, default)
        ok = isinstance(value, (list, tuple)) and len(value) == size and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
        if not ok:
            self.add(f"{where}.{key}", f"{size} numbers [{unit}]".replace(" []", ""),
                     value if value is not None else "nothing")
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
