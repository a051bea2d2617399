"""The cluster streams what the player shows: a node's decoded state holds the player's
drawables (:meth:`softvr.app.Player.drawables`), frame after frame."""

from __future__ import annotations

import numpy as np
import pytest

from softvr.cave.app import ClusterState, FrameBuilder, PlayerSource
from softvr.cave.protocol import decode
from softvr.cave.stream import DEFAULT_QUANTUM
from softvr.scene import bundled, load_scene


def test_a_node_holds_the_players_drawables_after_every_frame():
    """box-knock.toml streamed for 12 frames (the ram reaches the stack) to a node that starts
    from the master's snapshot and applies each packet: its planes are the drawables' (point,
    normal, size), and every mesh's vertices equal the player's drawn vertices to the stream's
    quantization (half a quantum per coordinate: the encoder rounds to the nearest step)."""
    with load_scene(bundled("box-knock.toml"), frames=12, haptics=False) as player:
        source = PlayerSource(player)
        master = FrameBuilder(source)
        node = ClusterState.from_snapshot(master.state.snapshot())
        shown = [d for d in player.drawables() if d.layer != "hidden"]
        assert [i["kind"] for i in node.items] == [d.kind for d in shown]
        for item, d in zip(node.items, shown):
            assert item["color"] == pytest.approx(d.color)
            if d.kind == "plane":
                assert (item["point"], item["normal"], item["size"]) == (pytest.approx(d.point),
                                                                          pytest.approx(d.normal), d.size)
        moved = 0.0
        for _ in range(12):
            node.apply_frame(decode(master.next_packet(7), 7).payload)
            shown = [d for d in player.drawables() if d.layer != "hidden"]
            for h, d in enumerate(shown):
                if d.kind == "mesh":
                    assert np.abs(node.mesh_vertices(h) - d.vertices).max() <= DEFAULT_QUANTUM / 2 * (1 + 1e-6)
                    moved = max(moved, float(np.abs(d.vertices - node.items[h]["rest"]).max()))
        assert moved > 0.1  # the ram has moved 0.2 m: the stream carried motion, not the rest shapes
