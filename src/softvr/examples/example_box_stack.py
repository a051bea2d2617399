"""Box stack: five rigid boxes stacked on the ground, resting through box-box contacts.

Five 0.2 x 0.2 x 0.1 m pine boxes (500 kg/m^3) start stacked 0.1 mm apart and settle onto each
other and the ground (friction 0.6, dt 10 ms, four steps a frame).

The scene is the bundled scene file ``box-stack.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_box_stack`` opens a window;
``--headless`` writes ``softvr-out/box-stack/box-stack.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run box-stack`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "box-stack.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
