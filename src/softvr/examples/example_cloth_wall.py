"""Cloth on a wall: a swinging cloth sticks to an adhesive wall and peels off (thesis Fig. 4.2).

A 0.5 m cloth pinned at its top edge is swung against the wall x = 0, whose surface bonds
(thesis eq. 4.11) and debonds (eq. 4.12) as the cloth hangs off it under its weight.

The scene is the bundled scene file ``cloth-wall.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_cloth_wall`` opens a window;
``--headless`` writes ``softvr-out/cloth-wall/cloth-wall.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run cloth-wall`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "cloth-wall.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
