"""Soft cube: a co-rotational FEM cube dropped, tilted, onto the ground (thesis 5.1.1, 5.3).

A 0.3 m cube of 4 x 4 x 4 five-tet cubes (E = 150 kPa, nu = 0.28, 1000 kg/m^3, Rayleigh
damping) falls, lands on an edge, squashes and settles on a plane with friction 0.5 (dt 5 ms).

The scene is the bundled scene file ``soft-cube.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_soft_cube`` opens a window;
``--headless`` writes ``softvr-out/soft-cube/soft-cube.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run soft-cube`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "soft-cube.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
