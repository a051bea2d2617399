"""Oranges: soft FEM spheres bouncing and rolling on the ground (thesis Fig. 3.7 flavour).

Four soft spheres (r 8 cm, E = 120 kPa) are thrown, spinning as if rolling, onto the ground in
four lanes; the last one crosses towards its neighbour's (friction 0.6, dt 5 ms).

The scene is the bundled scene file ``oranges.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_oranges`` opens a window;
``--headless`` writes ``softvr-out/oranges/oranges.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run oranges`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "oranges.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
