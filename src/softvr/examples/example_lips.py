"""Lips: two soft lips pressed together stick briefly as they open (thesis Fig. 4.3).

Two FEM lips are held and driven by their outer faces (the jaws): pressed 1.5 mm together over
0.2 s, held while the wet contacts bond, then opened at 2 cm/s; the adhesion holds the inner faces
together for a few millimetres before they snap apart.

The scene is the bundled scene file ``lips.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_lips`` opens a window;
``--headless`` writes ``softvr-out/lips/lips.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run lips`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "lips.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
