"""Error types raised by softvr.

Every error a user can cause by bad input is an :class:`InputError` whose message names
the file (when there is one), the field or element, what was expected and what was found.
"""

from __future__ import annotations

__all__ = ["InputError", "SimulationError", "SoftvrError"]


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
