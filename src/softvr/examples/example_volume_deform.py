"""Volume deformation: the head CT pressed and twisted through its tet mesh (thesis ch. 3).

The head CT (Debian ``invesalius-examples``) is embedded in 16 x 16 x 8 cubes (10 240 tets)
whose nodes follow a keyed animation (a dent pressed into the face, then a twist of up to
35 degrees at the top); every frame the CT is rasterized through them and volume-rendered.

The scene is the bundled scene file ``volume.toml`` (:data:`softvr.scene.BUNDLED`); this script plays
it through the public API. ``python -m softvr.examples.example_volume_deform`` opens a window;
``--headless`` writes ``softvr-out/volume/volume.mp4``, ``_sheet.png`` and ``_metrics.json``
instead (as ``softvr run volume`` does).
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "volume.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
