"""The cluster's wire format: msgpack packets with a versioned schema, validated on receipt.

Every packet is one msgpack array ``["softvr-cave", version, kind, session, payload]``:

========  ===============  ==================================================================
kind      direction        payload (a map)
========  ===============  ==================================================================
frame     master -> all    ``n`` frame number, ``t`` [s], ``user`` [16] (world <- tracker,
                           row-major 4x4), ``head`` [7] (position [m], quaternion w x y z in
                           the tracker frame), ``events`` [[name, [args]]], ``meshes``
                           [[handle, "pose", [7]] | [handle, "delta", width, zlib bytes] |
                           [handle, "key", zlib bytes]] (see :mod:`softvr.cave.stream`)
beat      master -> all    ``n``: the last frame published (-1: none yet). A heartbeat: a node
                           behind it missed a frame and resyncs; one waiting at the barrier
                           re-sends its ``ready`` (it may have been lost); a node that hears
                           no beat nor frame for ``master_timeout_s`` calls its master lost
go        master -> all    ``n``: every node rendered frame ``n``; present it (swap barrier)
bye       master -> all    ``n``: the run ended after frame ``n``
join      node -> master   ``node``: the node's name (the one its CURVE key may use),
                           ``nonce``: a random number; asks for a snapshot
ready     node -> master   ``node``, ``n``, ``hash`` (16 bytes): frame ``n`` is rendered
snapshot  master -> node   ``n``, ``state``: the full application state after frame ``n``;
                           ``nonce``: the join's it answers (a node takes no other)
resync    master -> node   ``n``: the node's ``ready`` for frame ``n`` had the wrong digest;
                           join again
========  ===============  ==================================================================

Nothing on a socket is ever unpickled: a packet is data, decoded by msgpack with size limits
and then checked field by field (:func:`decode`). A packet that fails is dropped and counted
by reason (``foreign``: not a softvr-cave packet, ``version``: another protocol version,
``session``: another master's run, ``malformed``: anything else), so a node survives any
input — the thesis sent cPickle over multicast, which lets anyone on the LAN run code on
every node.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NoReturn

import msgpack

__all__ = ["KINDS", "MAGIC", "MAX_AHEAD", "MAX_FRAME", "VERSION", "Packet", "PacketError", "check_head", "check_mesh_update", "check_user",
           "decode", "encode"]

MAGIC = "softvr-cave"
VERSION = 2
KINDS = ("frame", "beat", "go", "bye", "join", "ready", "snapshot", "resync")

#: Limits on what a packet may hold (a node never allocates more for one packet).
MAX_EVENTS = 256
MAX_MESHES = 65536
MAX_BYTES = 256 << 20
MAX_NAME = 64
#: A frame more than this many frames ahead of a node's state is implausible: dropped and
#: counted (``ahead``), never a reason to resync (a forged frame n + 2**40 would loop).
MAX_AHEAD = 1 << 16
#: Frame numbers stay below this (far from int64's end: ``n + 1`` never overflows).
MAX_FRAME = 1 << 62


class PacketError(ValueError):
    """A packet that is not a valid softvr-cave packet; ``reason`` is the counter it goes to."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True)
class Packet:
    """A decoded, validated packet: ``kind`` (one of :data:`KINDS`), the master's ``session``
    id and the checked ``payload``."""

    kind: str
    session: int
    payload: dict


def encode(kind: str, session: int, payload: dict) -> bytes:
    """The bytes of a packet (the sender's payload is trusted; :func:`decode` checks it)."""
    return msgpack.packb([MAGIC, VERSION, kind, int(session), payload], use_bin_type=True)


def _fail(detail: str) -> NoReturn:
    raise PacketError("malformed", detail)


def _int(value, what: str, low: int = 0, high: int = MAX_FRAME) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
        _fail(f"{what}: expected an integer in [{low}, {high}], found {type(value).__name__}")
    return value


def _float(value, what: str) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        _fail(f"{what}: expected a finite number")
    return float(value)


def _floats(value, count: int, what: str) -> list:
    if not isinstance(value, list) or len(value) != count:
        _fail(f"{what}: expected {count} numbers")
    return [_float(v, what) for v in value]


def _str(value, what: str, limit: int = MAX_NAME) -> str:
    if not isinstance(value, str) or not 0 < len(value) <= limit:
        _fail(f"{what}: expected a string of 1..{limit} characters")
    return value


def _bytes(value, what: str, size: int | None = None) -> bytes:
    if not isinstance(value, bytes) or len(value) > MAX_BYTES or (size is not None and len(value) != size):
        _fail(f"{what}: expected {'' if size is None else size} bytes")
    return value


def _list(value, what: str, limit: int) -> list:
    if not isinstance(value, list) or len(value) > limit:
        _fail(f"{what}: expected a list of at most {limit}")
    return value


def _event(value) -> tuple:
    if not isinstance(value, list) or len(value) != 2:
        _fail("event: expected [name, [args]]")
    name = _str(value[0], "event name")
    args = _list(value[1], "event args", 16)
    for a in args:
        if isinstance(a, str):
            _str(a, "event argument")
        elif not isinstance(a, bool):
            _float(a, "event argument")
    return name, tuple(args)


def check_mesh_update(value) -> tuple:
    """A checked mesh update ``(handle, kind, data...)`` (module docstring)."""
    if not isinstance(value, list) or len(value) < 3:
        _fail("mesh update: expected [handle, kind, data...]")
    handle = _int(value[0], "mesh handle", 0, MAX_MESHES)
    kind = value[1]
    if kind == "pose" and len(value) == 3:
        return handle, kind, _floats(value[2], 7, "mesh pose")
    if kind == "delta" and len(value) == 4:
        width = value[2]
        if width not in (1, 2, 4) or isinstance(width, bool):
            _fail("mesh delta width: expected 1, 2 or 4")
        return handle, kind, width, _bytes(value[3], "mesh delta")
    if kind == "key" and len(value) == 3:
        return handle, kind, _bytes(value[2], "mesh key")
    _fail("mesh update: expected pose, delta or key")


def check_user(value) -> list:
    """A checked user pose: 16 numbers of a rigid row-major 4x4 transform."""
    m = _floats(value, 16, "user")
    r = [m[0:3], m[4:7], m[8:11]]
    orthonormal = all(abs(sum(a * b for a, b in zip(r[i], r[j])) - (i == j)) < 1e-6 for i in range(3) for j in range(3))
    if not orthonormal or m[12:] != [0.0, 0.0, 0.0, 1.0]:
        _fail("user: expected a rigid 4x4 transform (orthonormal rotation, last row 0 0 0 1)")
    return m


def check_head(value) -> list:
    """A checked head pose: position [m] and a unit quaternion (w, x, y, z)."""
    h = _floats(value, 7, "head")
    if abs(math.sqrt(sum(q * q for q in h[3:])) - 1.0) > 1e-3:
        _fail("head: expected a unit quaternion (w, x, y, z) after the position")
    return h


def _frame(p: dict) -> dict:
    return {"n": _int(p.get("n"), "n"), "t": _float(p.get("t"), "t"),
            "user": check_user(p.get("user")), "head": check_head(p.get("head")),
            "events": [_event(e) for e in _list(p.get("events"), "events", MAX_EVENTS)],
            "meshes": [check_mesh_update(m) for m in _list(p.get("meshes"), "meshes", MAX_MESHES)]}


_PAYLOADS = {
    "frame": _frame,
    "beat": lambda p: {"n": _int(p.get("n"), "n", -1)},
    "go": lambda p: {"n": _int(p.get("n"), "n")},
    "bye": lambda p: {"n": _int(p.get("n"), "n")},
    "join": lambda p: {"node": _str(p.get("node"), "node"), "nonce": _int(p.get("nonce"), "nonce")},
    "ready": lambda p: {"node": _str(p.get("node"), "node"), "n": _int(p.get("n"), "n", -1),
                        "hash": _bytes(p.get("hash"), "hash", 16)},
    # The state's own fields are checked where it is restored (softvr.cave.app.ClusterState).
    "snapshot": lambda p: {"n": _int(p.get("n"), "n", -1), "nonce": _int(p.get("nonce"), "nonce"),
                           "state": p["state"] if isinstance(p.get("state"), dict) else _fail("state: expected a map")},
    "resync": lambda p: {"n": _int(p.get("n"), "n", -1)},
}


def decode(data: bytes, session: int | None = None) -> Packet:
    """Unpack and check a packet; raises :class:`PacketError` (with its ``reason``) for
    anything that is not a well-formed packet of this protocol version (and, when
    ``session`` is given, of that master's run)."""
    try:
        raw = msgpack.unpackb(data, raw=False, use_list=True, strict_map_key=True,
                              max_str_len=1 << 20, max_bin_len=MAX_BYTES, max_array_len=1 << 20,
                              max_map_len=1 << 16, max_ext_len=0)
    except Exception as exc:  # every msgpack failure mode (ExtraData, UnicodeDecodeError, ...) is a bad packet
        raise PacketError("foreign", f"not msgpack ({type(exc).__name__})") from None
    if not (isinstance(raw, list) and len(raw) == 5 and raw[0] == MAGIC):
        raise PacketError("foreign", "not a softvr-cave packet")
    if raw[1] != VERSION or isinstance(raw[1], bool):
        raise PacketError("version", f"protocol version {raw[1]!r}, this node speaks {VERSION}")
    kind, sid, payload = raw[2], raw[3], raw[4]
    if kind not in KINDS:
        _fail(f"unknown kind {kind!r}")
    sid = _int(sid, "session", 0, (1 << 63) - 1)
    if not isinstance(payload, dict):
        _fail("payload: expected a map")
    checked = _PAYLOADS[kind](payload)
    if session is not None and sid != session and kind not in ("snapshot", "resync"):
        raise PacketError("session", f"session {sid} is not this run's ({session})")
    return Packet(kind, sid, checked)
