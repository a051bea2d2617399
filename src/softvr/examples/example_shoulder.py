"""Shoulder: coupled anatomy palpated through a 1 kHz haptic loop (thesis ch. 5, Fig. 5.6).

The procedural shoulder (the structure of thesis Table 5.1) goes through the model pipeline as the
scene loads (its bundled parts file); a finger on a virtual coupling to a scripted haptic handle,
its force rendered by a 1 kHz loop in its own process, presses and slides over the deltoid while
a second finger behind the skin meets the anatomy under it.

The scene is the bundled scene file ``shoulder.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_shoulder`` opens a window;
``--headless`` writes ``softvr-out/shoulder/shoulder.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run shoulder`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "shoulder.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
