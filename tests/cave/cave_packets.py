"""Packets for the cluster tests: valid frames of an analytic scene, and a fuzzer (imported by
the tests and by this folder's conftest)."""

import math
import random

import msgpack
import numpy as np

from softvr.cave.app import ClusterState, WavingSheet, user_pose_facing
from softvr.cave.protocol import encode
from softvr.cave.stream import MeshEncoder


class FrameMaker:
    """Valid frames of a small :class:`WavingSheet` in one session, with the state a correct
    node must hold after each (the reference, built by the same rules but without sockets)."""

    def __init__(self, session: int = 1234, vertices: int = 400):
        self.session = session
        self.sheet = WavingSheet(vertices)
        self.reference = ClusterState(self.sheet.items)
        self.snapshot = self.snapshot_for(0)
        self.encoders = {h: MeshEncoder(i["rest"]) for h, i in enumerate(self.sheet.items) if i["kind"] == "mesh"}
        self.n = -1

    def snapshot_for(self, nonce: int) -> bytes:
        """The snapshot of the state before the first frame, answering a join with ``nonce``."""
        return encode("snapshot", self.session, {"n": -1, "nonce": nonce, "state": ClusterState(self.sheet.items).snapshot()})

    def next(self) -> bytes:
        self.n += 1
        vertices = self.sheet.advance()
        meshes = [[h, *u] for h, e in self.encoders.items() if (u := e.encode(vertices[h])) is not None]
        t = self.n / 60
        payload = {"n": self.n, "t": t, "user": user_pose_facing((0, 0, 0.4), 0.2 * t).ravel().tolist(),
                   "head": [0.1 * math.sin(t), 0.0, 1.7, 1.0, 0.0, 0.0, 0.0],
                   "events": [["toggle", ["grid"]]] if self.n % 7 == 0 else [], "meshes": meshes}
        self.reference.apply_frame({**payload, "meshes": [tuple(m) for m in meshes],
                                    "events": [(e, tuple(a)) for e, a in payload["events"]]})
        return encode("frame", self.session, payload)


def _random_value(rng: random.Random, depth: int = 0):
    choice = rng.randrange(10 if depth < 3 else 7)
    return [lambda: rng.randrange(-2**63, 2**64), lambda: rng.random() * 10 ** rng.randrange(-300, 300),
            lambda: float("nan"), lambda: rng.choice([True, False, None]),
            lambda: "x" * rng.randrange(0, 100), lambda: rng.randbytes(rng.randrange(0, 64)),
            lambda: rng.choice([-1, 0, 1, 2, 7, 2**62 + 1]),
            lambda: [_random_value(rng, depth + 1) for _ in range(rng.randrange(0, 20))],
            lambda: {rng.choice(["n", "t", "user", "head", "events", "meshes", "node", "hash", "state", "zz"]):
                     _random_value(rng, depth + 1) for _ in range(rng.randrange(0, 6))},
            lambda: [[rng.randrange(0, 4), rng.choice(["pose", "delta", "key", "?"]), rng.choice([1, 2, 4, 3]),
                      rng.randbytes(rng.randrange(0, 40))]]][choice]()


def _mutate(rng: random.Random, obj):
    """A random change deep inside a decoded packet (a field replaced, dropped or added)."""
    if isinstance(obj, dict) and obj:
        key = rng.choice(list(obj))
        action = rng.randrange(3)
        if action == 0:
            obj[key] = _random_value(rng)
        elif action == 1:
            del obj[key]
        else:
            obj[key] = _mutate(rng, obj[key])
        return obj
    if isinstance(obj, list) and obj:
        i = rng.randrange(len(obj))
        obj[i] = _mutate(rng, obj[i]) if rng.random() < 0.6 else _random_value(rng)
        return obj
    return _random_value(rng)


def fuzzed_packets(valid: list, count: int, seed: int = 0, stale_n: int = 0):
    """``count`` packets that a node must drop: random bytes, truncated, bit-flipped, another
    version or magic, deep field mutations (frame numbers kept stale so that a mutation that
    stays valid is still not applied), msgpack bombs, and a few megabyte-sized ones."""
    rng = random.Random(seed)
    for i in range(count):
        base = rng.choice(valid)
        kind = i % 9
        if kind == 0:
            yield rng.randbytes(rng.randrange(0, 300))
        elif kind == 1:
            yield base[:rng.randrange(0, len(base))]
        elif kind == 2:
            # Flips in the header (magic, version, kind, session): a flip in a payload value can
            # make another valid packet, which only CURVE's authentication can tell apart.
            b = bytearray(base)
            for _ in range(rng.randrange(1, 8)):
                b[rng.randrange(min(len(b), 24))] ^= 1 << rng.randrange(8)
            yield bytes(b)
        elif kind == 3:
            raw = msgpack.unpackb(base, raw=False)
            raw[1] = rng.choice([0, 2, 99, "1", None, 1.0])
            yield msgpack.packb(raw, use_bin_type=True)
        elif kind == 4:
            raw = msgpack.unpackb(base, raw=False)
            raw[0] = rng.choice(["softvr-cav", "", "SOFTVR-CAVE", 5])
            yield msgpack.packb(raw, use_bin_type=True)
        elif kind in (5, 6):
            raw = msgpack.unpackb(base, raw=False)
            if isinstance(raw[4], dict) and "n" in raw[4]:
                raw[4]["n"] = stale_n
            raw[4] = _mutate(rng, raw[4])
            if rng.random() < 0.1:
                raw[2] = rng.choice(["frame", "beat", "go", "ready", "join", "snapshot", "bye", "hello", 3])
            if isinstance(raw[4], dict) and raw[2] in ("frame", "beat", "bye", "go") and "n" in raw[4]:
                raw[4]["n"] = stale_n  # a still-valid mutation must not move the node on
            if raw[2] == "bye":
                raw[2] = "go"
            yield msgpack.packb(raw, use_bin_type=True)
        elif kind == 7:
            yield rng.choice([b"\xdd\xff\xff\xff\xff", b"\xdf\xff\xff\xff\xff", b"\xc6\xff\xff\xff\xff",
                              b"\x91" * 100_000, b"\xc7\x05\x01abc", b"\xd4\xff" + b"\0", b"\xc1"])
        else:
            size = rng.choice([0, 1, 16, 1 << 20, 4 << 20]) if i % 997 == 8 else rng.randrange(0, 64)
            yield np.random.default_rng(i).bytes(size)
