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
