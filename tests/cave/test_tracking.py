"""Head tracking: pose axes, OSC packets, UDP reception and scripted paths.

Truths: the rotation of a quaternion about z by 90 degrees maps +y to -x (right-handed); OSC 1.0
packets have a known byte layout (address and type tags NUL-padded to 4 bytes, big-endian
float32); float32 round-trips a value to within half a unit in the last place (2^-24
relative); slerp of a 90-degree rotation at t = 0.5 is the 45-degree rotation about the same
axis; linear interpolation of positions halfway is the midpoint.
"""

import math
import socket
import struct

import numpy as np
import pytest

from softvr.cave import (FixedTracker, HeadPose, OscTracker, ScriptedTracker, Tracker, decode_osc, encode_osc,
                         encode_osc_bundle, quaternion_about)
from softvr.errors import InputError

F32 = 2.0 ** -23  # float32's relative spacing: a float32 round trip is within half of it


def test_head_axes_follow_the_display_convention():
    """Identity: right +x, forward +y (the front screen), up +z. A 90-degree turn to the left
    (about +z) looks along -x with +y on the right; exact up to rounding of cos/sin (1e-15)."""
    still = HeadPose((0.0, 0.0, 1.7))
    np.testing.assert_array_equal(np.c_[still.right, still.forward, still.up], np.eye(3))
    turned = HeadPose((0.0, 0.0, 1.7), quaternion_about((0, 0, 1), math.pi / 2))
    np.testing.assert_allclose(turned.forward, [-1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(turned.right, [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(turned.up, [0, 0, 1], atol=1e-15)
    left, right = turned.eyes(0.064)
    np.testing.assert_allclose(right - left, [0, 0.064, 0], atol=1e-15)
    with pytest.raises(InputError, match="unit quaternion"):
        HeadPose((0, 0, 0), (2, 0, 0, 0))
    with pytest.raises(InputError, match="position"):
        HeadPose((0, 0), (1, 0, 0, 0))
    with FixedTracker(still) as tracker:
        assert isinstance(tracker, Tracker) and tracker.poll() is still


def test_osc_message_bytes_and_round_trip():
    """The byte layout of OSC 1.0 (address, ",fff..." and big-endian float32, each string NUL
    padded to a multiple of 4); decoding gives the values back to float32 precision."""
    values = [0.25, -1.5, 1.75, 1.0, 0.0, 0.0, 0.0]
    packet = encode_osc("/softvr/head", values)
    assert packet[:16] == b"/softvr/head\0\0\0\0" and packet[16:28] == b",fffffff\0\0\0\0"
    assert packet[28:32] == struct.pack(">f", 0.25) and len(packet) == 28 + 7 * 4
    assert decode_osc(packet) == [("/softvr/head", tuple(values))]  # these values are exact in float32
    x = [0.1, math.pi, -2.0 / 3.0]
    (address, got), = decode_osc(encode_osc("/a", x + ["text"]))
    assert address == "/a" and got[3] == "text"
    np.testing.assert_allclose(got[:3], x, rtol=F32 / 2)
    bundle = encode_osc_bundle([encode_osc("/x", [1]), encode_osc_bundle([encode_osc("/y", [2, 3])])])
    assert decode_osc(bundle) == [("/x", (1.0,)), ("/y", (2.0, 3.0))]
    with pytest.raises(InputError, match="OSC address"):
        encode_osc("softvr/head", [1.0])


def _pose_packet(pose: HeadPose, address="/softvr/head") -> bytes:
    return encode_osc(address, [*pose.position, *pose.orientation])


def test_loopback_udp_poll_returns_the_last_pose():
    """Poses sent over loopback UDP arrive in order (no loss on loopback below the receive
    buffer), so poll returns the last one sent; bundles unpack, the last element winning;
    foreign addresses are counted, not taken. Positions compared to float32 precision."""
    with OscTracker(port=0) as tracker, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        target = ("127.0.0.1", tracker.port)
        poses = [HeadPose((0.1 * i, 0.2, 1.6 + 0.01 * i), quaternion_about((0, 0, 1), 0.1 * i)) for i in range(5)]
        for pose in poses:
            sender.sendto(_pose_packet(pose), target)
        sender.sendto(encode_osc("/other/device", [1.0, 2.0]), target)
        got = tracker.wait(timeout=2.0)
        deadline = 200
        while tracker.received + tracker.dropped < 6 and deadline:  # the rest of the burst
            got, deadline = tracker.poll(), deadline - 1
            tracker.wait(timeout=0.01)
        assert (tracker.received, tracker.dropped) == (5, 1)
        np.testing.assert_allclose(got.position, poses[-1].position, rtol=F32, atol=F32)
        np.testing.assert_allclose(got.orientation, poses[-1].orientation, atol=F32)
        sender.sendto(encode_osc_bundle([_pose_packet(poses[1]), _pose_packet(poses[3])]), target)
        got = tracker.wait(timeout=2.0)
        np.testing.assert_allclose(got.position, poses[3].position, rtol=F32, atol=F32)
    with pytest.raises(InputError, match="closed"):
        tracker.poll()


def test_garbage_packets_never_raise_and_are_counted():
    """10 000 random datagrams, truncations of a valid message and well-formed messages with
    wrong arguments (six floats, integers, a quaternion of norm 2, NaN): none is a valid pose
    (a random datagram would have to decode as OSC, carry the exact address and seven floats
    forming a unit quaternion; a truncated message lacks arguments or is no multiple of 4
    bytes), so each counts once in ``dropped``, none raises, and the pose stays the initial one."""
    rng = np.random.default_rng(7)
    valid = _pose_packet(HeadPose((1.0, 2.0, 3.0)))
    packets = [valid[:n] for n in range(len(valid))]  # every truncation, the empty packet included
    packets += [encode_osc("/softvr/head", [0.0] * 6), encode_osc("/softvr/head", [0, 0, 0, 0, 0, 0, 0]),
                encode_osc("/softvr/head", [0, 0, 0, 2, 0, 0, 0]), encode_osc("/softvr/head", [math.nan] * 7)]
    packets += [b"#bundle\0" + bytes(rng.integers(0, 256, 12, dtype=np.uint8))]
    while len(packets) < 10_000:
        packets.append(rng.integers(0, 256, int(rng.integers(0, 200)), dtype=np.uint8).tobytes())
    with OscTracker(port=0) as tracker, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        initial = tracker.poll()
        for start in range(0, len(packets), 50):  # batches well within the receive buffer
            for p in packets[start:start + 50]:
                sender.sendto(p, ("127.0.0.1", tracker.port))
            for _ in range(1000):
                tracker.poll()
                if tracker.dropped + tracker.received >= start + len(packets[start:start + 50]):
                    break
        assert (tracker.dropped, tracker.received) == (10_000, 0)
        assert tracker.poll() == initial


def test_scripted_tracker_interpolates_linearly_and_by_slerp():
    """Keyframes at 0 s and 2 s, from the identity to 90 degrees about z and from (0, 0, 1.6)
    to (1, 2, 1.8): at 1 s (s = 0.5) the position is the midpoint and the rotation is 45
    degrees about z (forward = (-sin 45, cos 45, 0)); before and after, the end poses hold;
    with ``loop`` the path repeats. Tolerance 1e-12: only floating-point rounding."""
    now = [5.0]
    path = ScriptedTracker([0.0, 2.0], [[0, 0, 1.6], [1, 2, 1.8]],
                           [(1, 0, 0, 0), quaternion_about((0, 0, 1), math.pi / 2)], clock=lambda: now[0])
    h = math.sqrt(0.5)
    for t, position, forward in ((0.0, (0, 0, 1.6), (0, 1, 0)), (1.0, (0.5, 1.0, 1.7), (-h, h, 0)),
                                 (2.0, (1, 2, 1.8), (-1, 0, 0)), (-1.0, (0, 0, 1.6), (0, 1, 0)),
                                 (9.0, (1, 2, 1.8), (-1, 0, 0))):
        now[0] = 5.0 + t
        pose = path.poll()
        np.testing.assert_allclose(pose.position, position, atol=1e-12)
        np.testing.assert_allclose(pose.forward, forward, atol=1e-12)
    np.testing.assert_allclose(path.pose_at(0.5).orientation, quaternion_about((0, 0, 1), math.pi / 8), atol=1e-12)
    looped = ScriptedTracker([0.0, 2.0], [[0, 0, 0], [2, 0, 0]], loop=True, clock=lambda: 0.0)
    np.testing.assert_allclose(looped.pose_at(5.0).position, [1, 0, 0], atol=1e-12)
    with pytest.raises(InputError, match="strictly increasing"):
        ScriptedTracker([0.0, 0.0], [[0, 0, 0], [1, 0, 0]])
    with pytest.raises(InputError, match="positions"):
        ScriptedTracker([0.0, 1.0], [[0, 0, 0]])
