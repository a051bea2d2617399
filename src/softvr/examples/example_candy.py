"""Candy: soft and hard candies fall on a block of Jell-O (the scene of thesis Fig. 4.1).

At the thesis' scale: about 10 K tetrahedra in the deformable bodies and 25 K collision
triangles, 8 ms steps, Coulomb friction 0.3 everywhere (thesis 4.4). The Jell-O is a
co-rotational FEM box standing on a plate (its bottom nodes held), its collision surface a finer
triangulation embedded in its tets (thesis 5.1); the even candies are soft (FEM balls and
beans), the odd ones hard (spinning boxes and balls). They rain down, bounce, squash the block
and pile up on it.

The scene is the bundled scene file ``candy.toml`` (:data:`softvr.scene.BUNDLED`); this script
plays it through the public API. ``python -m softvr.examples.example_candy`` opens a window;
``--headless`` writes ``softvr-out/candy/candy.mp4``, ``_sheet.png`` and ``_metrics.json``;
``--variant quick`` plays the file's small scale (four candies, coarser meshes: the candy
bench's ``--quick``). ``candy-adhesive.toml`` is the same drop with adhesive surfaces.
"""

from __future__ import annotations

from softvr.examples._leaf import play_leaf
from softvr.scene import BUNDLED

__all__ = ["SCENE", "main"]

#: The demo: its one definition.
SCENE = BUNDLED / "candy.toml"


def main(argv: list[str] | None = None):
    """Play the scene (a window, or ``--headless`` to files); returns the played player."""
    return play_leaf(SCENE, __doc__, argv)


if __name__ == "__main__":
    main()
