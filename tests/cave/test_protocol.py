"""The wire format against its schema, and a node against 100 000 fuzzed packets.

Truths: what the master sends decodes to the same values; each way a packet can be wrong
(another magic, version or session, a non-rigid user pose, a non-unit head quaternion,
NaN, a bool where an integer belongs, too many events) is refused with its reason; a node fed
100 000 fuzzed packets between valid frames raises nothing, counts every one of them as
dropped, and still holds, bit for bit, the state of a reference that saw only the valid frames.
"""

import math

import numpy as np
import pytest

from softvr.cave.cluster import ClusterConfig, Node
from softvr.cave.protocol import MAX_EVENTS, VERSION, PacketError, decode, encode

from cave_packets import fuzzed_packets

_FRAME = {"n": 3, "t": 0.05, "user": np.eye(4).ravel().tolist(), "head": [0, 0, 1.7, 1, 0, 0, 0],
          "events": [["toggle", ["grid"]]], "meshes": [[1, "pose", [0, 0, 0, 1, 0, 0, 0]]]}


def test_a_frame_round_trips():
    p = decode(encode("frame", 7, _FRAME), session=7)
    assert p.kind == "frame" and p.session == 7 and p.payload["n"] == 3
    assert p.payload["events"] == [("toggle", ("grid",))]
    assert p.payload["meshes"] == [(1, "pose", [0, 0, 0, 1, 0, 0, 0])]


def _broken(**changes):
    return {**_FRAME, **changes}


@pytest.mark.parametrize("packet, reason", [
    (b"\x93\x01\x02\x03", "foreign"),
    (b"not msgpack at all \xc1", "foreign"),
    (encode("frame", 7, _FRAME).replace(b"softvr-cave", b"softvr-cavf"), "foreign"),
    (encode("frame", 8, _FRAME), "session"),
    (encode("hello", 7, _FRAME), "malformed"),
    (encode("frame", 7, _broken(user=(np.eye(4) * 2).ravel().tolist())), "malformed"),
    (encode("frame", 7, _broken(head=[0, 0, 1.7, 0, 0, 0, 0])), "malformed"),
    (encode("frame", 7, _broken(t=math.nan)), "malformed"),
    (encode("frame", 7, _broken(n=True)), "malformed"),
    (encode("frame", 7, _broken(events=[["toggle", []]] * (MAX_EVENTS + 1))), "malformed"),
    (encode("frame", 7, _broken(meshes=[[1, "delta", 3, b""]])), "malformed"),
])
def test_bad_packets_are_refused_with_their_reason(packet, reason):
    with pytest.raises(PacketError) as info:
        decode(packet, session=7)
    assert info.value.reason == reason


def test_another_protocol_version_is_named():
    import msgpack

    packet = msgpack.packb(["softvr-cave", VERSION + 1, "frame", 7, _FRAME])
    with pytest.raises(PacketError, match=f"version {VERSION + 1}") as info:
        decode(packet, session=7)
    assert info.value.reason == "version"


def test_a_node_survives_100k_fuzzed_packets_and_keeps_its_state(frame_maker):
    # Endpoints nobody binds: the node's sockets connect in the background and stay idle.
    node = Node("front", ClusterConfig(publish="tcp://127.0.0.1:9", control="tcp://127.0.0.1:9", curve=False))
    try:
        node._control(frame_maker.snapshot_for(node.nonce))
        valid = [frame_maker.next() for _ in range(3)]
        for packet in valid:
            node.receive(packet)
        assert node.state.n == 2
        before = sum(node.log.counters.values())
        count = 100_000
        for i, packet in enumerate(fuzzed_packets(valid + [frame_maker.snapshot], count, seed=5, stale_n=1)):
            node.receive(packet)
            if i % 10_000 == 0:  # valid frames keep arriving in between
                node.receive(frame_maker.next())
        dropped = sum(node.log.counters.values()) - before
        assert dropped == count, node.log.counters
        assert not node.log.resyncs and node.state is not None
        for _ in range(3):
            node.receive(frame_maker.next())
        assert node.state.n == frame_maker.n
        assert node.state.digest() == frame_maker.reference.digest()
        counters = node.log.counters
        assert min(counters["foreign"], counters["version"], counters["malformed"]) > 1000, counters
    finally:
        node.close()
