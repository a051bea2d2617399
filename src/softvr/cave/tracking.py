"""Head tracking: where the viewer's head is, in the tracker frame (thesis 6.2.1, 6.2.2).

The thesis maps a tracked observer's position to the *local origin* of the virtual camera
cluster: every screen's frustum is recomputed from it each frame. The tracker frame is the
frame the screens of a :class:`~softvr.cave.Display` are given in: metres, z up, the front
screen at y > 0. A head pose is a position there and an orientation whose axes are, at the
identity, right = +x, forward = +y (towards the front screen), up = +z.

:class:`Tracker` is the plug-in point: ``poll()`` returns the latest :class:`HeadPose` and never
blocks, so a render loop can call it once per frame. Three are built in:

* :class:`FixedTracker`: one pose (no tracking hardware; the thesis' untracked set-up);
* :class:`ScriptedTracker`: keyframes interpolated in time (linear positions, slerp rotations),
  for demos and tests;
* :class:`OscTracker`: poses received over UDP as OSC 1.0 messages, the lingua franca of
  tracking middleware (OptiTrack / Vicon bridges, VRPN-to-OSC, TouchDesigner). One message::

      /softvr/head ,fffffff  x y z qw qx qy qz      (float32, big-endian; metres, unit quaternion)

  OSC bundles (``#bundle``) are unpacked; the last valid pose received wins; anything else
  (foreign addresses, malformed packets) is counted in ``dropped`` and otherwise ignored.

:func:`encode_osc` / :func:`encode_osc_bundle` build packets (for senders and tests) and
:func:`decode_osc` parses them, with python-osc; softvr adds the input limits a network port
needs (:func:`decode_osc`).

Examples
--------
>>> import socket
>>> from softvr.cave import HeadPose, OscTracker, encode_osc
>>> with OscTracker(port=0) as tracker, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
...     _ = sender.sendto(encode_osc("/softvr/head", [0.1, 0.2, 1.7, 1, 0, 0, 0]), ("127.0.0.1", tracker.port))
...     pose = tracker.wait(timeout=1.0)
>>> [round(v, 3) for v in pose.position], pose.forward.round(3).tolist()
([0.1, 0.2, 1.7], [0.0, 1.0, 0.0])
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pythonosc import osc_bundle, osc_message
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message import OscMessage
from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.parsing import osc_types
from scipy.spatial.transform import Rotation, Slerp

from softvr.cave.display import eye_pair
from softvr.errors import InputError

__all__ = ["DEFAULT_HEAD", "FixedTracker", "HeadPose", "OscTracker", "ScriptedTracker", "Tracker", "decode_osc",
           "encode_osc", "encode_osc_bundle", "quaternion_about"]

OSC_ADDRESS = "/softvr/head"
_MAX_BUNDLE_DEPTH = 8  # bundles nest; a hostile packet must not recurse without bound


def _finite(values, shape: tuple, what: str, unit: str) -> np.ndarray:
    try:
        a = np.asarray(values, float)
    except (TypeError, ValueError):
        raise InputError(what, f"numbers of shape {list(shape)} [{unit}]", repr(values)) from None
    if a.shape != shape or not np.isfinite(a).all():
        raise InputError(what, f"finite numbers of shape {list(shape)} [{unit}]", f"{values!r} (shape {a.shape})")
    return a


def _unit_quaternion(q, what: str) -> np.ndarray:
    """``q`` (w, x, y, z) normalised; off unit length by more than 1e-3 is refused (a typo or a
    wrong convention, not rounding: float32 senders are off by ~1e-7)."""
    a = _finite(q, (4,), what, "unit quaternion (w, x, y, z)")
    norm = float(np.linalg.norm(a))
    if abs(norm - 1.0) > 1e-3:
        raise InputError(what, "a unit quaternion (w, x, y, z)", f"{q!r} of norm {norm:.6g}")
    return a / norm


def quaternion_about(axis, angle: float) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z) of a rotation by ``angle`` [rad] about ``axis`` [3]
    (right-handed; e.g. a positive angle about +z turns forward = +y towards -x, to the left)."""
    a = _finite(axis, (3,), "axis", "unit-free")
    if np.linalg.norm(a) == 0:
        raise InputError("axis", "a non-zero vector", repr(axis))
    x, y, z, w = Rotation.from_rotvec(float(angle) * a / np.linalg.norm(a)).as_quat()
    return (float(w), float(x), float(y), float(z))


@dataclass(frozen=True)
class HeadPose:
    """The viewer's head in the tracker frame (thesis 6.2.1: the tracked *local origin*).

    Parameters
    ----------
    position : array_like, shape [3] [m]
        The point between the eyes, in the tracker frame (the frame of the display's screens).
    orientation : array_like, shape [4]
        Unit quaternion (w, x, y, z) rotating head axes into the tracker frame; the identity
        looks along +y with +z up and +x to the right. Normalised on construction; a norm off 1
        by more than 1e-3 is an :class:`~softvr.errors.InputError`.
    """

    position: tuple
    orientation: tuple = (1.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        # Tuples of floats keep the frozen pose hashable and comparable with ==.
        object.__setattr__(self, "position", tuple(float(v) for v in _finite(self.position, (3,), "position", "m")))
        object.__setattr__(self, "orientation", tuple(float(v) for v in _unit_quaternion(self.orientation,
                                                                                         "orientation")))

    @property
    def rotation(self) -> np.ndarray:
        """Rotation [3, 3], head axes to the tracker frame: columns right, forward, up."""
        w, x, y, z = self.orientation
        return Rotation.from_quat((x, y, z, w)).as_matrix()

    @property
    def right(self) -> np.ndarray:
        """The head's right axis [3] (unit) in the tracker frame; +x at the identity."""
        return self.rotation[:, 0]

    @property
    def forward(self) -> np.ndarray:
        """The viewing direction [3] (unit) in the tracker frame; +y at the identity."""
        return self.rotation[:, 1]

    @property
    def up(self) -> np.ndarray:
        """The head's up axis [3] (unit) in the tracker frame; +z at the identity."""
        return self.rotation[:, 2]

    @property
    def matrix(self) -> np.ndarray:
        """Head to tracker frame [4, 4] (rotation, then the position [m])."""
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.position
        return m

    def eyes(self, separation: float) -> tuple[np.ndarray, np.ndarray]:
        """Left and right eye positions [3] [m]: -/+ ``separation`` / 2 [m] along :attr:`right`."""
        return eye_pair(self.position, self.right, separation)


#: A 1.7 m tall viewer standing at the tracker origin, looking at the front screen (+y).
DEFAULT_HEAD = HeadPose((0.0, 0.0, 1.7))


class Tracker:
    """Base of head trackers: the plug-in point for tracking hardware.

    Subclasses implement :meth:`poll` (the latest pose; it must not block: the render loop
    calls it once a frame) and, when they hold resources, :meth:`close`. Trackers are context
    managers.
    """

    def poll(self) -> HeadPose:
        """The latest head pose (never blocks)."""
        raise NotImplementedError

    def close(self) -> None:
        """Release what the tracker holds (sockets, devices); nothing by default."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class FixedTracker(Tracker):
    """Always the same pose (no tracking hardware): ``FixedTracker(DEFAULT_HEAD)``."""

    def __init__(self, pose: HeadPose = DEFAULT_HEAD):
        if not isinstance(pose, HeadPose):
            raise InputError("pose", "a HeadPose", type(pose).__name__)
        self.pose = pose

    def poll(self) -> HeadPose:
        return self.pose


class ScriptedTracker(Tracker):
    """A head path from keyframes, played against a clock.

    Parameters
    ----------
    times : array_like, shape [k] [s]
        Keyframe times, strictly increasing, from the tracker's start (its construction or
        :meth:`restart`).
    positions : array_like, shape [k, 3] [m]
        Head positions at the keyframes (tracker frame), interpolated linearly.
    orientations : array_like, shape [k, 4], optional
        Unit quaternions (w, x, y, z) at the keyframes, interpolated by SciPy's ``Slerp`` (the
        shorter arc: ``q`` and ``-q`` are one rotation); default identity.
    clock : callable, optional
        Returns the time [s]; default :func:`time.monotonic` (tests pass a fake clock).
    loop : bool
        Repeat the path after the last keyframe; otherwise the first and last poses hold
        before and after it.
    """

    def __init__(self, times, positions, orientations=None, *, clock=None, loop: bool = False):
        try:
            t = np.asarray(times, float)
        except (TypeError, ValueError):
            t = np.full(0, np.nan)
        if t.ndim != 1 or len(t) == 0 or not np.isfinite(t).all() or (np.diff(t) <= 0).any():
            raise InputError("times", "a non-empty, strictly increasing list of finite times [s]", repr(times))
        k = len(t)
        self.times = t
        self.positions = _finite(positions, (k, 3), "positions", "m")
        if orientations is None:
            self.orientations = np.tile([1.0, 0.0, 0.0, 0.0], (k, 1))
        else:
            q = _finite(orientations, (k, 4), "orientations", "unit quaternions (w, x, y, z)")
            self.orientations = np.array([_unit_quaternion(row, f"orientations[{i}]") for i, row in enumerate(q)])
        # x, y, z, w: SciPy's order. Slerp needs two keys; one key is held at every time.
        self._slerp = Slerp(t, Rotation.from_quat(np.roll(self.orientations, -1, axis=1))) if k > 1 else None
        self.clock = time.monotonic if clock is None else clock
        if not callable(self.clock):
            raise InputError("clock", "a callable returning seconds", repr(clock))
        self.loop = bool(loop)
        self.restart()

    def restart(self) -> None:
        """Play the path from its start, now."""
        self._start = float(self.clock())

    def pose_at(self, t: float) -> HeadPose:
        """The pose ``t`` [s] after the start."""
        times = self.times
        if self.loop and len(times) > 1:
            t = times[0] + (t - times[0]) % (times[-1] - times[0])
        if t <= times[0]:
            return HeadPose(self.positions[0], self.orientations[0])
        if t >= times[-1]:
            return HeadPose(self.positions[-1], self.orientations[-1])
        i = int(np.searchsorted(times, t, side="right")) - 1
        s = (t - times[i]) / (times[i + 1] - times[i])
        position = (1 - s) * self.positions[i] + s * self.positions[i + 1]
        assert self._slerp is not None  # two keys at least: one is held before and after (above)
        x, y, z, w = self._slerp(t).as_quat()
        return HeadPose(position, (w, x, y, z))

    def poll(self) -> HeadPose:
        return self.pose_at(float(self.clock()) - self._start)


# ------------------------------------------------------------------------------------ OSC 1.0
# python-osc builds and parses the packets. What it leaves to its callers, and a UDP port open to
# the network must not: it loops forever on a bundle element of negative size, recurses into
# bundles without bound, pads a missing last float with zeros (a truncated pose would decode as a
# pose) and ignores trailing bytes. _check_frames (before it parses) and _canonical (after) refuse those.
_TAGS = "fidsTF"  # the argument types softvr reads; python-osc logs a warning per unknown tag
_WRITERS: dict[str, Callable[[Any], bytes]] = {
    "f": osc_types.write_float, "i": osc_types.write_int, "d": osc_types.write_double,
    "s": osc_types.write_string}  # T and F carry no bytes


def encode_osc(address: str, values) -> bytes:
    """One OSC 1.0 message (python-osc's ``OscMessageBuilder``): ``address`` (starting with
    "/") and ``values``, each number as float32 (type tag ``f``) and each string as ``s``.

    A head pose is ``encode_osc("/softvr/head", [x, y, z, qw, qx, qy, qz])`` (metres, unit
    quaternion).
    """
    if not isinstance(address, str) or not address.startswith("/"):
        raise InputError("OSC address", 'a string starting with "/"', repr(address))
    builder = OscMessageBuilder(address)
    for i, v in enumerate(values):
        if isinstance(v, str):
            builder.add_arg(v, OscMessageBuilder.ARG_TYPE_STRING)
        elif isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
            builder.add_arg(float(v), OscMessageBuilder.ARG_TYPE_FLOAT)
        else:
            raise InputError(f"OSC value [{i}]", "a number or a string", repr(v))
    return builder.build().dgram


def encode_osc_bundle(elements, timestamp: float = IMMEDIATELY) -> bytes:
    """An OSC bundle (python-osc's ``OscBundleBuilder``) of encoded messages or bundles
    (``bytes``); ``timestamp`` [s since the Unix epoch, UTC], default: immediately."""
    builder = OscBundleBuilder(timestamp)  # type: ignore[arg-type]  # python-osc writes float times (annotated int)
    for i, element in enumerate(elements):
        if not isinstance(element, (bytes, bytearray)) or len(element) % 4:
            raise InputError(f"bundle element [{i}]", "an encoded OSC message or bundle (bytes, 4-byte aligned)",
                             type(element).__name__)
        element = bytes(element)
        try:
            _check_frames(element)
            builder.add_content(OscBundle(element) if OscBundle.dgram_is_bundle(element) else OscMessage(element))
        except (InputError, osc_bundle.ParseError, osc_message.ParseError, UnicodeDecodeError) as exc:
            raise InputError(f"bundle element [{i}]", "an encoded OSC message or bundle", str(exc)) from None
    return builder.build().dgram


def _message_head(data: bytes) -> tuple[str, str]:
    """Address and type tags of a message (python-osc's string reader), checked."""
    try:
        address, pos = osc_types.get_string(data, 0)
        tags, _ = osc_types.get_string(data, pos) if pos < len(data) else ("", pos)
    except osc_types.ParseError as exc:
        raise InputError("OSC string", "NUL-terminated strings padded to 4 bytes", str(exc)) from None
    except UnicodeDecodeError as exc:
        raise InputError("OSC string", "UTF-8 text", f"undecodable bytes at {exc.start}") from None
    if not address.startswith("/"):
        raise InputError("OSC address", 'a pattern starting with "/"', repr(address[:40]))
    if not tags.startswith(","):
        raise InputError("OSC type tags", 'a string starting with ","', repr(tags[:40]))
    unknown = next((t for t in tags[1:] if t not in _TAGS), None)
    if unknown is not None:
        raise InputError("OSC type tag", "one of " + " ".join(_TAGS), repr(unknown))
    return address, tags


def _check_frames(data: bytes, depth: int = 0) -> None:
    """The limits python-osc does not enforce, before it parses ``data``: 4-byte alignment,
    bundle element sizes within the packet, nesting depth, known type tags."""
    if len(data) % 4:
        raise InputError("OSC packet", "a multiple of 4 bytes", f"{len(data)} bytes")
    if not OscBundle.dgram_is_bundle(data):
        _message_head(data)
        return
    if depth >= _MAX_BUNDLE_DEPTH:
        raise InputError("OSC bundle", f"at most {_MAX_BUNDLE_DEPTH} levels of nesting", "deeper")
    if len(data) < 16:
        raise InputError("OSC bundle", "#bundle, a time tag and elements", f"{len(data)} bytes")
    pos = 16
    while pos < len(data):
        size = int.from_bytes(data[pos:pos + 4], "big", signed=True) if pos + 4 <= len(data) else -1
        if size <= 0 or size % 4 or pos + 4 + size > len(data):
            raise InputError("OSC bundle element", "a size, a multiple of 4, within the packet",
                             f"{size} at byte {pos}")
        _check_frames(data[pos + 4:pos + 4 + size], depth + 1)
        pos += 4 + size


def _canonical(message: OscMessage) -> tuple[str, tuple]:
    """``(address, values)`` of a parsed message whose bytes are exactly what its values encode
    to: no missing (zero-padded by python-osc) or trailing arguments, NUL padding."""
    address, tags = _message_head(message.dgram)
    values = message.params
    # python-osc's own writers, not its builder: build() parses its output again (48 -> 6 us a pose).
    expected = b"".join([osc_types.write_string(address), osc_types.write_string(tags),
                         *(_WRITERS[t](v) for t, v in zip(tags[1:], values) if t in _WRITERS)])
    if expected != message.dgram:
        if len(expected) != len(message.dgram):
            found = f"{len(message.dgram)} bytes where the arguments take {len(expected)}"
        else:
            k = next(k for k, (a, b) in enumerate(zip(expected, message.dgram)) if a != b)
            found = f"bytes that differ from their encoding at byte {k} (padding not NUL?)"
        raise InputError("OSC packet", f"exactly the arguments of {tags}, NUL-padded", found)
    return message.address, tuple(values)


def _messages(element) -> list:
    """The messages of a parsed python-osc packet, bundles flattened in order."""
    if isinstance(element, OscMessage):
        return [element]
    return [m for content in element for m in _messages(content)]


def decode_osc(packet: bytes) -> list[tuple[str, tuple]]:
    """The messages of an OSC 1.0 packet (a message, or a bundle, flattened in order), each
    ``(address, values)``; type tags f, i, d, s, T, F. Parsed by python-osc after softvr's
    limits (at most 8 nested bundles, element sizes within the packet, exact argument bytes);
    a malformed packet is an :class:`~softvr.errors.InputError` saying what is wrong."""
    data = bytes(packet)
    _check_frames(data)
    try:
        root = OscBundle(data) if OscBundle.dgram_is_bundle(data) else OscMessage(data)
    except (osc_bundle.ParseError, osc_message.ParseError) as exc:
        raise InputError("OSC packet", "an OSC 1.0 message or bundle", str(exc)) from None
    except UnicodeDecodeError as exc:
        raise InputError("OSC string", "UTF-8 text", f"undecodable bytes at {exc.start}") from None
    return [_canonical(m) for m in _messages(root)]


class OscTracker(Tracker):
    """Head poses received as OSC messages over UDP (module docstring for the message).

    Parameters
    ----------
    port : int
        UDP port to listen on; 0 picks a free one (read it back from :attr:`port`).
    host : str
        IPv4 address to bind: ``"127.0.0.1"`` (this machine only) or ``"0.0.0.0"`` (the
        tracking PC on the network).
    address : str
        OSC address of pose messages (seven float arguments: type tags ``f``, or ``d`` from
        senders that send doubles); other messages are counted in :attr:`dropped`.
    initial : HeadPose
        What :meth:`poll` returns until the first pose arrives.

    Attributes
    ----------
    port : int
        The bound port.
    received, dropped : int
        Valid pose messages taken, and packets or messages refused (malformed, foreign
        address, wrong arguments, not a unit quaternion).
    """

    def __init__(self, port: int, host: str = "127.0.0.1", address: str = OSC_ADDRESS,
                 initial: HeadPose = DEFAULT_HEAD):
        if not isinstance(port, int) or isinstance(port, bool) or not 0 <= port <= 65535:
            raise InputError("port", "a UDP port in 0..65535 (0: any free one)", repr(port))
        if not isinstance(address, str) or not address.startswith("/"):
            raise InputError("address", 'an OSC address starting with "/"', repr(address))
        if not isinstance(initial, HeadPose):
            raise InputError("initial", "a HeadPose", type(initial).__name__)
        self.address, self.received, self.dropped = address, 0, 0
        self._pose = initial
        self._socket: socket.socket | None = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            # Room for a burst of a 1 kHz tracker between two frames, so the newest is not lost.
            self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            self._socket.bind((host, port))
        except OSError as exc:
            self._socket.close()
            raise InputError("host / port", "a local address and a free UDP port", f"{host}:{port} ({exc})") from None
        self._socket.setblocking(False)
        self.port = self._socket.getsockname()[1]

    def poll(self) -> HeadPose:
        """Take every datagram waiting and return the newest valid pose (never blocks)."""
        if self._socket is None:
            raise InputError("OscTracker", "an open tracker", "a closed one")
        while True:
            try:
                data = self._socket.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. an ICMP error reported on the socket: nothing to read
                break
            self._take(data)
        return self._pose

    def wait(self, timeout: float = 1.0) -> HeadPose:
        """Poll until a new valid pose arrives or ``timeout`` [s] passes (for start-up and
        tests; render loops use :meth:`poll`)."""
        deadline, before = time.monotonic() + timeout, self.received
        while True:
            pose = self.poll()
            if self.received > before or time.monotonic() >= deadline:
                return pose
            time.sleep(0.001)

    def _take(self, data: bytes) -> None:
        try:
            messages = decode_osc(data)
        except InputError:
            self.dropped += 1
            return
        for address, values in messages:
            pose = None
            if address == self.address and len(values) == 7 and all(type(v) is float for v in values):
                try:
                    pose = HeadPose(values[:3], values[3:])
                except InputError:
                    pose = None
            if pose is None:
                self.dropped += 1
            else:
                self._pose, self.received = pose, self.received + 1

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None
