"""Cloth on a sphere: a mass-spring cloth dropped over a static sphere, draping onto the ground.

A 1 m square cloth of 20 x 20 quads (stretch, shear and bend springs, 0.2 kg/m^2) falls onto a
sphere of radius 0.25 m resting on the ground and wraps around it (friction 0.5, dt 1/60 s).

The scene is the bundled scene file ``cloth-sphere.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_cloth_sphere`` opens a window;
``--headless`` writes ``softvr-out/cloth-sphere/cloth-sphere.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run cloth-sphere`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "cloth-sphere.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
