"""Palpation: the head CT pressed by a probe, its FEM built from the voxels (thesis 3.3.2).

The head CT is embedded in 16 x 16 x 8 cubes over its tissue, each tet's E, nu and rho integrated
from the voxels' Hounsfield units, bone clamped; a 12 mm probe presses 5 mm into the cheek and
withdraws, and every frame the CT is rasterized through the deformed tets and volume-rendered.
Each frame is drawn while the next frame's FEM step runs on a worker thread (the player's
``overlap``, on for a volume scene): the same pictures as one after the other, a shorter frame
period where the render leaves a core idle, one render more latency.

The scene is the bundled scene file ``palpation.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_palpation`` opens a window;
``--headless`` writes ``softvr-out/palpation/palpation.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run palpation`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "palpation.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
