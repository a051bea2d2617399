"""Probe: a round probe pressed into adhesive soft tissue and pulled back.

A kinematic sphere (r 1 cm) indents a clamped FEM block 5 mm, holds and withdraws; the tacky
tissue holds on to it past the rest surface until the bonds let go (thesis eqs. 4.12, 4.16).

The scene is the bundled scene file ``probe.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_probe`` opens a window;
``--headless`` writes ``softvr-out/probe/probe.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run probe`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "probe.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
