"""The synchronized render cluster: one master, one render node per screen (thesis 6.3).

The master owns the input (scripted navigation, a head tracker, events) and the clock. Every
frame it publishes the frame number, the user and head poses, the events and the streamed
mesh states (:mod:`softvr.cave.stream`); each node applies them to its copy of the
:class:`~softvr.cave.app.ClusterState`, renders its screen and reports ``ready`` with the
state's digest. When every node has rendered frame ``n`` the master publishes ``go n`` and
the nodes present it (the software swap barrier; off with ``barrier=False`` where hardware
genlock exists).

Transport (ZeroMQ, the "clone" pattern of its guide): frames, heartbeats and ``go`` go out on
a PUB socket; nodes talk to the master on a ROUTER socket (``join`` -> full-state
``snapshot``; ``ready``). A node that starts late or restarts joins with a snapshot and
applies the frames it buffered meanwhile; a node that sees a sequence gap (a frame number
it skipped, or a heartbeat ahead of its state) resyncs the same way. Packets are msgpack with
a versioned schema (:mod:`softvr.cave.protocol`): bad ones are dropped and counted.

Secure by default: both sockets use CURVE (encryption and authentication), with keys made on
first use in a key folder (:mod:`softvr.cave.keys`). The master's ZAP handler lets in only
public keys from its ``authorized/`` folder and gives each connection the one node name its
key was authorized for; a ``join`` or ``ready`` in another name is refused. Routing ids are
ZeroMQ's random ones, so no client can take over another's connection. Without CURVE
(``curve=False``) the master binds loopback addresses only.

Bounds: one unacknowledged snapshot per node name at a time (another after the node's
``ready`` or ``snapshot_retry_s``); at most :data:`ROUTER_SNDHWM` messages wait for any one
peer on the control socket and :data:`PUB_SNDHWM` frames for any one node; subscriptions are
limited to :data:`SUBSCRIPTION_BYTES`; a node buffers at most :data:`NODE_BUFFER` frames while
it resyncs.

Liveness: the master publishes a ``beat`` every ``heartbeat_s`` while it waits (for joins, at
the barrier) and every ``beat_s`` between paced frames; a node waiting at the barrier answers
a beat for its frame by sending its ``ready`` again (it may have been lost), and re-sends it
every ``beat_s`` when idle (the master's view of its nodes). A node that hears nothing of its
master for ``master_timeout_s`` calls it lost, joins whichever master answers on the same
endpoints (a new session), and ends with a clear message (:attr:`Node.error`) when none
answers within ``master_wait_s``. A node silent for ``node_timeout_s`` at the barrier is
dropped from it (the frame goes on) until it reports again. A node whose ``ready`` carries
another digest than the master's is told to ``resync`` and held at the barrier until it does.
"""

from __future__ import annotations

import ipaddress
import math
import os
import random
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zmq
from zmq.auth.thread import ThreadAuthenticator
from zmq.utils import z85

from softvr.cave import keys as cave_keys
from softvr.cave.app import ClusterState, FrameBuilder
from softvr.cave.keys import check_name, make_keys
from softvr.cave.protocol import MAX_AHEAD, PacketError, decode, encode
from softvr.cave.stream import DEFAULT_QUANTUM
from softvr.errors import InputError, SoftvrError

__all__ = ["ClusterConfig", "JoinTimeout", "Master", "Node", "make_keys"]

#: Frames that may wait for one node in the master's PUB socket (then dropped for it: the
#: node sees a gap and resyncs).
PUB_SNDHWM = 1000
#: Messages (snapshots, resync requests) that may wait for one peer on the control socket.
ROUTER_SNDHWM = 4
#: Largest message a node may send the master [bytes] (a join or ready is under 100).
CONTROL_MESSAGE_BYTES = 4096
#: Largest message a PUB socket takes [bytes]: a subscription (nodes subscribe to everything,
#: 1 byte) or a CURVE handshake command (about 300).
SUBSCRIPTION_BYTES = 1024
#: Frames a node receives but has not processed, and frames it buffers while it resyncs.
NODE_RCVHWM = 1000
NODE_BUFFER = 1024
#: Messages a node queues for a master not connected (joins, readies; later ones supersede).
NODE_SNDHWM = 8
#: A node with no master recreates its sockets this often [s].
_RECONNECT_S = 2.0
#: Frame digests the master keeps to check late ``ready`` reports.
_DIGESTS_KEPT = 1024


@dataclass
class ClusterConfig:
    """Where and how master and nodes talk.

    Attributes
    ----------
    publish, control : str
        ZeroMQ endpoints of the master's PUB (frames) and ROUTER (join / ready) sockets. The
        master binds them (``tcp://127.0.0.1:0`` picks free ports; :attr:`Master.config`
        then holds the real ones), nodes connect.
    barrier : bool
        Software swap barrier on (nodes present frame n only when all rendered it).
    heartbeat_s : float [s]
        While it waits (for joins, at the barrier) the master repeats "frame n is out" this
        often: a node that lost frame n, its join or its ready notices within one period.
    beat_s : float [s]
        Heartbeat period when idle: the master's between paced frames, a node's re-sent
        ``ready``.
    node_timeout_s : float [s]
        A node that has not reported a frame for this long leaves the barrier (it rejoins by
        reporting again or asking for a snapshot).
    master_timeout_s : float [s]
        A node that hears nothing of its master for this long calls it lost and asks for a
        snapshot from whichever master answers.
    master_wait_s : float [s] or None
        How long a node waits for a (new) master before it ends with :attr:`Node.error`;
        None: for ever.
    snapshot_retry_s : float [s]
        The master sends a node another snapshot before it acknowledged the last one only
        after this long (the last one was lost).
    resend_s : float [s]
        A node re-sends its ``ready`` at most this often when a beat says the master still
        waits for it.
    keys : str or None
        Key folder (:mod:`softvr.cave.keys`); None: :func:`softvr.cave.keys.default_folder`.
    curve : bool
        CURVE encryption and authentication on both sockets (the default); off is allowed on
        loopback endpoints only.
    max_packet_bytes : int
        Larger packets are refused by the transport before they reach a node's decoder.
    """

    publish: str = "tcp://127.0.0.1:5560"
    control: str = "tcp://127.0.0.1:5561"
    barrier: bool = True
    heartbeat_s: float = 0.005
    beat_s: float = 0.25
    node_timeout_s: float = 0.5
    master_timeout_s: float = 2.0
    master_wait_s: float | None = 60.0
    snapshot_retry_s: float = 0.1
    resend_s: float = 0.02
    keys: str | None = None
    curve: bool = True
    max_packet_bytes: int = 256 << 20

    def key_folder(self) -> Path:
        return Path(self.keys) if self.keys else cave_keys.default_folder()

    def check_transport(self) -> None:
        """Refuse CURVE off on anything but loopback endpoints, saying how to fix it."""
        if self.curve:
            return
        exposed = [e for e in (self.publish, self.control) if not _loopback(e)]
        if exposed:
            raise InputError("cluster endpoints", "loopback addresses (127.0.0.1, ::1) when CURVE is off; "
                             "elsewhere keep CURVE on (the default; keys: softvr cave keys)", ", ".join(exposed))


def _loopback(endpoint: str) -> bool:
    if not endpoint.startswith("tcp://"):
        return False  # ipc and other transports reach other users of the host
    host = endpoint[len("tcp://"):].rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # "*", an interface name
        return False


class JoinTimeout(SoftvrError, TimeoutError):
    """Render nodes did not join the master in time; the message names them and what to check."""


class _NameAuthenticator(ThreadAuthenticator):
    """The master's ZAP handler: a CURVE client gets in only with a key from the key folder's
    ``authorized/``, and the connection's User-Id is the node name that key is for. An
    unknown key makes it read the folder again (at most every ``reload_s``): a node that
    authorized its new key there on first use gets in (libzmq does not retry a refused
    handshake, so a node reconnects itself while it waits for a master)."""

    def __init__(self, context: zmq.Context, folder: Path, reload_s: float = 0.01):
        super().__init__(context)
        self.folder, self.reload_s = folder, reload_s
        self.names = cave_keys.authorized_names(folder)
        self._read_at = -math.inf

    def callback(self, domain: str, key: bytes) -> bool:  # zmq.auth credentials provider
        if key not in self.names and time.monotonic() - self._read_at >= self.reload_s:
            self._read_at = -math.inf
            try:
                self.names = cave_keys.authorized_names(self.folder)
            except InputError:
                pass  # a bad file added meanwhile: keep the keys read before
        return key in self.names

    def curve_user_id(self, client_public_key: bytes) -> str:
        return self.names[z85.encode(client_public_key)]


class _Stats:
    """Per-frame timings [s] kept in a preallocated-as-you-go list (a few thousand frames)."""

    def __init__(self):
        self.values: list[float] = []

    def add(self, v: float) -> None:
        self.values.append(v)

    def summary(self, scale: float = 1e3) -> dict:
        if not self.values:
            return {"count": 0}
        a = np.asarray(self.values) * scale
        return {"count": len(a), "p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
                "max": float(a.max()), "mean": float(a.mean())}


# ------------------------------------------------------------------------------------ master
class Master:
    """The cluster's master (module docstring).

    Parameters
    ----------
    source, navigation, tracker, quantum
        What makes the frames (:class:`~softvr.cave.app.FrameBuilder`).
    nodes : list of str
        The render nodes that make the display (:class:`~softvr.cave.Display` screens' nodes).
    config : ClusterConfig
    context : zmq.Context, optional
        Default: a context of its own (its ZAP handler is the context's only one).

    Attributes
    ----------
    log : dict
        ``joins`` (snapshots sent: node, frame, time, the join's nonce), ``evictions``,
        ``mismatches`` (readies with another digest), ``resyncs`` (nodes told to resync),
        ``refused`` (control messages dropped, by reason: ``malformed``, ``unknown`` node,
        ``name`` not the key's, ``join_rate``: a join while the node's last snapshot is
        unacknowledged), ``frames``.
    unauthorized : list of str
        Nodes of the display whose public key the master does not hold (they cannot join).
    """

    def __init__(self, source, nodes, config: ClusterConfig | None = None, *, navigation=None, tracker=None,
                 quantum: float = DEFAULT_QUANTUM, context: zmq.Context | None = None):
        self.config = config or ClusterConfig()
        self.config.check_transport()
        self.nodes = [check_name(n) for n in nodes]
        self.session = random.SystemRandom().getrandbits(62)
        self.frames = FrameBuilder(source, navigation=navigation, tracker=tracker, quantum=quantum)
        self.members: dict[str, float] = {}  # node -> when it last reported [monotonic s]
        self.log: dict[str, Any] = {"joins": [], "evictions": [], "mismatches": 0, "resyncs": 0, "frames": [],
                    "refused": {"malformed": 0, "unknown": 0, "name": 0, "join_rate": 0}}
        self.unauthorized: list[str] = []
        self._digests: OrderedDict[int, bytes] = OrderedDict()
        self._digest = self._remember()
        self._snapshot_sent: dict[str, float] = {}  # node -> when its unacknowledged snapshot went out
        self._wrong: dict[str, tuple[int, float]] = {}  # node -> (frame reported with another digest, when told)
        self._snapshot_cache: tuple[int, dict] | None = None
        self._last_publish = time.monotonic()
        self.frame_bytes = _Stats()
        self.sync = _Stats()  # publish -> every member ready
        self._own_context = context is None
        self._ctx = context or zmq.Context()
        self._auth: _NameAuthenticator | None = None
        self.pub = self._ctx.socket(zmq.PUB)
        self.router = self._ctx.socket(zmq.ROUTER)
        try:
            self.pub.setsockopt(zmq.SNDHWM, PUB_SNDHWM)
            self.pub.setsockopt(zmq.MAXMSGSIZE, SUBSCRIPTION_BYTES)  # what a PUB receives: subscriptions
            self.router.setsockopt(zmq.SNDHWM, ROUTER_SNDHWM)
            self.router.setsockopt(zmq.MAXMSGSIZE, CONTROL_MESSAGE_BYTES)
            for s in (self.pub, self.router):
                s.setsockopt(zmq.LINGER, 0)
            if self.config.curve:
                self._secure(self.config.key_folder())
            for s, endpoint in ((self.pub, self.config.publish), (self.router, self.config.control)):
                try:
                    s.bind(endpoint)
                except zmq.ZMQError as exc:
                    raise InputError("master endpoint", "an address this host can bind", f"{endpoint}: {exc}") from None
        except BaseException:
            self.close()
            raise
        self.config.publish = self.pub.getsockopt_string(zmq.LAST_ENDPOINT)
        self.config.control = self.router.getsockopt_string(zmq.LAST_ENDPOINT)
        self.poller = zmq.Poller()
        self.poller.register(self.router, zmq.POLLIN)

    def _secure(self, folder: Path) -> None:
        public, secret = cave_keys.master_pair(folder)
        # The ZAP handler must run before the first bind: without one libzmq lets every key in.
        self._auth = _NameAuthenticator(self._ctx, folder)
        self.unauthorized = sorted(set(self.nodes) - set(self._auth.names.values()))
        self._auth.start()
        self._auth.configure_curve_callback("*", credentials_provider=self._auth)
        for s in (self.pub, self.router):
            s.curve_secretkey, s.curve_publickey, s.curve_server = secret, public, True

    @property
    def state(self) -> ClusterState:
        """The master's copy of the application state (what every node must hold)."""
        return self.frames.state

    def _remember(self) -> bytes:
        digest = self.state.digest()
        self._digests[self.state.n] = digest
        while len(self._digests) > _DIGESTS_KEPT:
            self._digests.popitem(last=False)
        return digest

    def _publish(self, data: bytes) -> None:
        self.pub.send(data)
        self._last_publish = time.monotonic()

    def _beat(self, period: float) -> None:
        """Publish a heartbeat when nothing went out for ``period`` [s]."""
        if time.monotonic() - self._last_publish >= period:
            self._publish(encode("beat", self.session, {"n": self.state.n}))

    # ------------------------------------------------------------------ control
    def _handle_control(self, barrier_frame: int | None, pending: set | None) -> None:
        """Serve every waiting ROUTER message (joins, ready reports)."""
        refused = self.log["refused"]
        while True:
            try:
                parts = self.router.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            try:
                if len(parts) != 2:
                    raise PacketError("malformed", "expected one message part")
                packet = decode(parts[1].bytes)
                if packet.kind not in ("join", "ready"):
                    raise PacketError("malformed", f"a {packet.kind} on the control socket")
            except PacketError:
                refused["malformed"] += 1
                continue
            node = packet.payload["node"]
            if node not in self.nodes:
                refused["unknown"] += 1  # not a screen of this display
                continue
            if self._auth is not None and parts[1].get("User-Id") != node:
                refused["name"] += 1  # a key authorized for another node
                continue
            identity, now = parts[0].bytes, time.monotonic()
            if packet.kind == "join":
                self._join(identity, node, packet.payload["nonce"], now, barrier_frame, pending)
            elif packet.session == self.session:
                self._ready(identity, node, packet.payload, now, barrier_frame, pending)

    def _join(self, identity: bytes, node: str, nonce: int, now: float, barrier_frame, pending) -> None:
        sent = self._snapshot_sent.get(node)
        if sent is not None and now - sent < self.config.snapshot_retry_s:
            self.log["refused"]["join_rate"] += 1
            return
        if self._snapshot_cache is None or self._snapshot_cache[0] != self.state.n:
            self._snapshot_cache = (self.state.n, self.state.snapshot())
        snapshot = {"n": self.state.n, "nonce": nonce, "state": self._snapshot_cache[1]}
        self.router.send_multipart([identity, encode("snapshot", self.session, snapshot)])
        self._snapshot_sent[node] = now
        self.members[node] = now
        self.log["joins"].append({"node": node, "frame": self.state.n, "time": now, "nonce": nonce})
        if pending is not None and barrier_frame == self.state.n and self.state.n >= 0:
            pending.add(node)

    def _ready(self, identity: bytes, node: str, payload: dict, now: float, barrier_frame, pending) -> None:
        n = payload["n"]
        self._snapshot_sent.pop(node, None)  # it holds a state: its snapshot arrived
        if node in self.members or n == self.state.n:
            self.members[node] = now  # a node dropped from the barrier that caught up is back
        expected = self._digests.get(n)
        if expected is not None and payload["hash"] != expected:
            told = self._wrong.get(node)
            if told is None or told[0] != n:  # a re-sent ready is the same report: one mismatch
                self.log["mismatches"] += 1
            if told is None or told[0] != n or now - told[1] >= self.config.snapshot_retry_s:
                # again if the node still reports it: the first request may have been lost
                self._wrong[node] = (n, now)
                self.log["resyncs"] += 1
                self.router.send_multipart([identity, encode("resync", self.session, {"n": n})])
            return  # not ready: it stays at the barrier until it holds the master's state
        if pending is not None and n == barrier_frame:
            pending.discard(node)

    def wait_for_nodes(self, timeout_s: float = 60.0) -> None:
        """Serve joins until every node of the display has joined and drawn the state it got
        (its renderer is up, so the first frames do not time out at the barrier); raises
        :class:`JoinTimeout` naming the missing ones."""
        deadline = time.monotonic() + timeout_s
        pending = set(self.nodes)
        while pending:
            left = deadline - time.monotonic()
            if left <= 0:
                missing = sorted(pending)
                hint = (f"; does the master hold their public keys ({self.config.key_folder()}/authorized/NAME.key)?"
                        if self.config.curve else "")
                raise JoinTimeout(f"render nodes {missing} did not join within {timeout_s:g} s (are they running "
                                  f"with --publish {self.config.publish} --control {self.config.control}{hint})")
            self._beat(self.config.heartbeat_s)  # a node whose first ready was lost sends it again
            if self.poller.poll(int(min(left, self.config.heartbeat_s) * 1e3)):  # pyzmq int()s a float too
                self._handle_control(self.state.n, pending)

    # ------------------------------------------------------------------- frames
    def step(self) -> dict:
        """Publish the next frame and, with the barrier, wait until every member rendered
        it; returns the frame's record."""
        packet = self.frames.next_packet(self.session)
        n = self.state.n
        self._digest = self._remember()
        t0 = time.perf_counter()
        self._publish(packet)
        self.frame_bytes.add(len(packet))
        record = {"n": n, "digest": self._digest.hex(), "bytes": len(packet), "members": sorted(self.members)}
        if self.config.barrier:
            record["sync_s"] = self._barrier(n, t0)
            self._publish(encode("go", self.session, {"n": n}))
        else:
            self._handle_control(None, None)
            self._evict_silent(n, max(self.config.node_timeout_s, 3 * self.config.beat_s))
        self.log["frames"].append(record)
        return record

    def _evict(self, node: str, n: int, now: float) -> None:
        self.members.pop(node, None)
        self.log["evictions"].append({"node": node, "frame": n, "time": now})

    def _evict_silent(self, n: int, silent_s: float) -> None:
        """Without the barrier: drop members whose heartbeat stopped."""
        now = time.monotonic()
        for node in [m for m, seen in self.members.items() if now - seen > silent_s]:
            self._evict(node, n, now)

    def _barrier(self, n: int, t0: float) -> float | None:
        pending = set(self.members)
        beat = encode("beat", self.session, {"n": n})
        start = time.monotonic()
        next_beat = start + self.config.heartbeat_s
        while pending:
            now = time.monotonic()
            if now >= start + self.config.node_timeout_s:
                for node in sorted(pending):
                    self._evict(node, n, now)
                return None
            wait = min(next_beat, start + self.config.node_timeout_s) - now
            if self.poller.poll(int(max(wait, 0.0) * 1e3)):
                self._handle_control(n, pending)
            if time.monotonic() >= next_beat and pending:
                self._publish(beat)
                next_beat += self.config.heartbeat_s
        elapsed = time.perf_counter() - t0
        self.sync.add(elapsed)
        return elapsed

    def run(self, frames: int, *, fps: float | None = None, progress: bool = False, on_frame=None) -> dict:
        """Publish ``frames`` frames (paced at ``fps`` when given; ``on_frame(record)`` after
        each, e.g. to draw the master's own view), then ``bye``; returns :meth:`summary`."""
        from tqdm import tqdm  # noqa: PLC0415

        period = 1.0 / fps if fps else 0.0
        next_time = time.monotonic()
        for _ in tqdm(range(frames), desc="cave master", unit="frame", disable=not progress):
            record = self.step()
            if on_frame is not None:
                on_frame(record)
            if period:
                next_time += period
                delay = next_time - time.monotonic()
                if delay > 0:
                    self._serve_for(delay)
        bye = encode("bye", self.session, {"n": self.state.n})
        for _ in range(3):  # on a lossy network one could be lost; a node ignores repeats
            self._publish(bye)
            time.sleep(0.01)
        return self.summary()

    def _serve_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self._beat(self.config.beat_s)
            if self.poller.poll(int(min(left, self.config.beat_s) * 1e3)):
                self._handle_control(None, None)

    def summary(self) -> dict:
        return {"session": self.session, "frames": self.state.n + 1, "mismatches": self.log["mismatches"],
                "joins": len(self.log["joins"]), "evictions": len(self.log["evictions"]),
                "refused": dict(self.log["refused"]), "frame_bytes": self.frame_bytes.summary(scale=1.0),
                "sync_ms": self.sync.summary()}

    def close(self) -> None:
        for s in (self.pub, self.router):
            s.close(0)
        if self._auth is not None:
            self._auth.stop()
            self._auth = None
        if self._own_context:
            self._ctx.term()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# -------------------------------------------------------------------------------------- node
@dataclass
class _NodeLog:
    presented: list = field(default_factory=list)  # [frame, digest hex, rendered at, presented at] (monotonic s)
    resyncs: list = field(default_factory=list)  # {"gap_at", "synced_at", "from", "to"}
    joins: list = field(default_factory=list)
    lost: list = field(default_factory=list)  # when the master went silent [monotonic s]
    counters: dict = field(default_factory=lambda: {"foreign": 0, "version": 0, "session": 0, "malformed": 0,
                                                    "inconsistent": 0, "stale": 0, "ahead": 0, "unasked": 0,
                                                    "injected_drops": 0})
    unsent: int = 0  # messages to the master dropped because it was not connected


class Node:
    """A render node of the cluster (module docstring).

    Parameters
    ----------
    name : str
        This node's name (a display screen's ``node``; with CURVE, the name its key is
        authorized for).
    config : ClusterConfig
    render : callable, optional
        ``render(state)`` draws the node's screen(s) for a :class:`ClusterState` (called once
        per applied frame, before ``ready``); None renders nothing (barrier measurements).
    present : callable, optional
        ``present(state)``: show the rendered frame (swap buffers, save an image).
    drop_rate : float
        Fraction of packets thrown away, both ways: received before decoding and sent before
        they leave (a lossy network, for tests and benchmarks).

    Attributes
    ----------
    nonce : int
        The current join's random number; only a snapshot that echoes it is taken.
    error : str or None
        Why :meth:`run` ended early (no master answered within ``master_wait_s``).
    """

    def __init__(self, name: str, config: ClusterConfig | None = None, *, render=None, present=None,
                 drop_rate: float = 0.0, seed: int | None = None, context: zmq.Context | None = None):
        self.name, self.config = check_name(name), config or ClusterConfig()
        self.config.check_transport()
        self.render_state, self.present_state = render, present
        self.drop_rate, self._rng = float(drop_rate), random.Random(seed)
        self.state: ClusterState | None = None
        self.session: int | None = None
        self.log = _NodeLog()
        self.finished = False
        self.error: str | None = None
        self.barrier_wait = _Stats()
        self.nonce = random.SystemRandom().getrandbits(62)
        self._awaiting = True  # no state yet, or resyncing: frames are buffered
        self._buffer: list = []
        self._pending: int | None = None  # rendered, not yet presented
        self._ready_sent = self._rendered_at = self._ready_at = 0.0
        self._last_ready: bytes | None = None
        self._join_sent = self._heard_at = time.monotonic()
        self._lost_at: float | None = self._heard_at  # no master yet
        self._gap_at: float | None = None
        self._ctx = context or zmq.Context.instance()
        self._curve = None
        if self.config.curve:
            folder = self.config.key_folder()
            server = cave_keys.master_public(folder)
            self._curve = (*cave_keys.node_pair(folder, name), server)
        self.sub: zmq.Socket | None = None
        self.dealer: zmq.Socket | None = None
        self._connect()

    def _connect(self) -> None:
        """(Re)create and connect both sockets."""
        if self.sub is not None:
            self.close()
        sub = self.sub = self._ctx.socket(zmq.SUB)
        dealer = self.dealer = self._ctx.socket(zmq.DEALER)
        dealer.setsockopt(zmq.SNDHWM, NODE_SNDHWM)
        for s in (sub, dealer):
            s.setsockopt(zmq.LINGER, 0)
            s.setsockopt(zmq.MAXMSGSIZE, self.config.max_packet_bytes)
            s.setsockopt(zmq.RCVHWM, NODE_RCVHWM)
            if self._curve is not None:
                s.curve_publickey, s.curve_secretkey, s.curve_serverkey = self._curve
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        sub.connect(self.config.publish)
        dealer.connect(self.config.control)
        self.poller = zmq.Poller()
        self.poller.register(sub, zmq.POLLIN)
        self.poller.register(dealer, zmq.POLLIN)
        self._connected_at = time.monotonic()

    # ---------------------------------------------------------------- protocol
    def _dropped(self) -> bool:
        if self.drop_rate and self._rng.random() < self.drop_rate:
            self.log.counters["injected_drops"] += 1
            return True
        return False

    def _send(self, data: bytes) -> None:
        if self._dropped():
            return
        # With NODE_SNDHWM messages queued for a master not connected (not up yet, gone, or
        # refusing our CURVE key) drop the message: joins are retried, readies re-sent.
        assert self.dealer is not None  # connected from __init__ on
        try:
            self.dealer.send(data, zmq.NOBLOCK)
        except zmq.Again:
            self.log.unsent += 1

    def _join(self) -> None:
        """Ask for a snapshot (again, with the same nonce, while one is awaited)."""
        self._awaiting = True
        self._join_sent = time.monotonic()
        self.log.joins.append(self._join_sent)
        self._send(encode("join", 0, {"node": self.name, "nonce": self.nonce}))

    @property
    def _held(self) -> ClusterState:
        """The state, in the methods that run only once a snapshot put one here (not awaiting one)."""
        assert self.state is not None
        return self.state

    def _resync(self) -> None:
        if not self._awaiting:
            self._gap_at = time.monotonic()
            self.log.resyncs.append({"gap_at": self._gap_at, "from": self._held.n})
            self.nonce = random.SystemRandom().getrandbits(62)
            self._join()

    def receive(self, data: bytes) -> None:
        """Handle one packet from the master's PUB socket (anything at all: bad packets are
        counted in ``log.counters`` and dropped)."""
        if self._dropped():
            return
        try:
            packet = decode(data, self.session)
        except PacketError as exc:
            self.log.counters[exc.reason] += 1
            return
        kind = packet.kind
        n: Any = packet.payload.get("n")  # an int in every kind compared below (decode checks the payloads)
        if kind not in ("frame", "beat", "go", "bye"):
            self.log.counters["malformed"] += 1  # node-to-master kinds, or a snapshot not on the control socket
            return
        if self.session is not None and self.state is not None:
            if n > self._held.n + MAX_AHEAD:
                self.log.counters["ahead"] += 1  # implausible: no resync for it (module protocol)
                return
            if n >= self._held.n:
                self._heard_at = time.monotonic()
        if kind == "bye":
            self._present()
            self.finished = True
            return
        if self._awaiting:
            if kind == "frame" and len(self._buffer) < NODE_BUFFER:
                self._buffer.append(packet)
            elif kind == "beat" and time.monotonic() - self._join_sent >= 1.5 * self.config.snapshot_retry_s:
                self._join()  # the master is there: our join or its snapshot was lost
            return
        if kind == "frame":
            self._frame(packet)
        elif kind == "beat" and n > self._held.n:
            self._resync()
        elif kind == "beat" and n == self._held.n:
            self._resend_ready(self.config.resend_s)  # the master may wait for it: ours may be lost
        elif kind == "go" and self._pending == n:
            self.barrier_wait.add(time.monotonic() - self._ready_sent)
            self._present()
        else:
            self.log.counters["stale"] += 1  # about a frame already done

    def _frame(self, packet) -> None:
        n = packet.payload["n"]
        if n <= self._held.n:
            self.log.counters["stale"] += 1
            return
        if n > self._held.n + 1:
            self._resync()
            self._buffer.append(packet)
            return
        self._present()  # a frame after n means every node rendered n: its go was lost
        if self._apply(packet):
            self._rendered()

    def _apply(self, packet) -> bool:
        """Apply a frame; one that does not fit the state (a mesh update of the wrong size)
        is counted and starts a resync."""
        try:
            self._held.apply_frame(packet.payload)
        except ValueError:
            self.log.counters["inconsistent"] += 1
            self._resync()
            return False
        return True

    def _rendered(self) -> None:
        """Render the current state, then report it (barrier) or present it."""
        if self.render_state is not None:
            self.render_state(self.state)
        self._rendered_at = time.monotonic()
        if self._held.n >= 0:  # (the state before the first frame has nothing to present)
            self._pending = self._held.n
            self._ready_sent = self._rendered_at
            if not self.config.barrier:
                self._present()
        # Before the first frame too: the master waits for every node's renderer to be up;
        # without the barrier the report is the node's heartbeat and digest check.
        assert self.session is not None  # set with the state, by the snapshot
        self._last_ready = encode("ready", self.session, {"node": self.name, "n": self._held.n,
                                                          "hash": self._held.digest()})
        self._resend_ready(0.0)

    def _resend_ready(self, after_s: float) -> None:
        """Send the last ``ready`` again if it went out more than ``after_s`` [s] ago."""
        now = time.monotonic()
        if self._last_ready is not None and now - self._ready_at >= after_s:
            self._ready_at = now
            self._send(self._last_ready)

    def _present(self) -> None:
        if self._pending is None or self.state is None or self._pending != self.state.n:
            return
        if self.present_state is not None:
            self.present_state(self.state)
        self.log.presented.append([self.state.n, self.state.digest().hex(), self._rendered_at, time.monotonic()])
        self._pending = None

    def _control(self, data: bytes) -> None:
        """Handle one message from the master's control socket (a snapshot or a resync)."""
        if self._dropped():
            return
        try:
            packet = decode(data)
            if packet.kind == "resync":
                # Its state descends from the one reported wrong (later frames add to it).
                if packet.session == self.session and self.state is not None and packet.payload["n"] <= self.state.n:
                    self._resync()
                else:
                    self.log.counters["stale"] += 1
                return
            if packet.kind != "snapshot":
                raise PacketError("malformed", "only snapshots and resyncs come on the control socket")
            if not self._awaiting:  # the answer to a repeated join: the state is already current
                self.log.counters["stale"] += 1
                return
            if packet.payload["nonce"] != self.nonce:
                self.log.counters["unasked"] += 1  # not the answer to this node's join
                return
            state = ClusterState.from_snapshot(packet.payload["state"])
            if state.n != packet.payload["n"]:
                raise PacketError("malformed", f"snapshot of frame {packet.payload['n']} holding frame {state.n}")
        except PacketError as exc:
            self.log.counters[exc.reason] += 1
            return
        except ValueError:  # a mesh key that does not fit its mesh
            self.log.counters["malformed"] += 1
            return
        self.session, self.state, self._awaiting, self._pending = packet.session, state, False, None
        self._heard_at, self._lost_at = time.monotonic(), None
        buffered, self._buffer = self._buffer, []
        for frame in sorted(buffered, key=lambda f: f.payload["n"]):
            n = frame.payload["n"]
            if frame.session != self.session or n <= self.state.n:
                continue
            if n > self.state.n + MAX_AHEAD:
                self.log.counters["ahead"] += 1
                continue
            if n != self.state.n + 1:
                self._resync()
                self._buffer = [f for f in buffered if f.session == self.session
                                and self.state.n < f.payload["n"] <= self.state.n + MAX_AHEAD]
                return
            if not self._apply(frame):
                return
        if self._gap_at is not None and self.log.resyncs:
            self.log.resyncs[-1].update(synced_at=time.monotonic(), to=self.state.n)
            self._gap_at = None
        self._rendered()

    def _check_master(self, now: float, join_retry_s: float) -> None:
        """Liveness: call a silent master lost, retry joins, give up after ``master_wait_s``."""
        c = self.config
        if self._lost_at is None and now - self._heard_at > c.master_timeout_s:
            self._lost_at = now
            self.log.lost.append(now)
            self.session, self._pending = None, None  # whichever master answers next: a new session
            self.nonce = random.SystemRandom().getrandbits(62)
            self._join()
        if self._awaiting:
            if now - self._join_sent > join_retry_s:
                if self._lost_at is not None and now - self._connected_at >= _RECONNECT_S:
                    self._connect()  # a handshake the master refused (our key was new to it) is not retried
                self._join()  # the master was not up yet, or the snapshot went missing
            if self._lost_at is not None and c.master_wait_s and now - self._lost_at > c.master_wait_s:
                what = ("the master went silent" if self.log.lost else "no master answered")
                self.error = (f"node {self.name}: {what} at {c.publish} / {c.control} and none answered within "
                              f"{c.master_wait_s:g} s" + ("" if self.log.lost or not c.curve else
                                                         f" (is it running, and does it hold this node's public "
                                                         f"key as authorized/{self.name}.key?)"))
                self.finished = True
        else:
            self._resend_ready(c.beat_s)  # the node's heartbeat

    # --------------------------------------------------------------------- loop
    def run(self, max_seconds: float | None = None, join_retry_s: float = 1.0) -> dict:
        """Join and follow the master until it says ``bye``, ``max_seconds`` pass or no
        master answers for ``master_wait_s`` (then :attr:`error` says so); returns
        :meth:`summary`."""
        start = time.monotonic()
        end = None if max_seconds is None else start + max_seconds
        self._heard_at = start
        if self._lost_at is not None:
            self._lost_at = start
        self._join()
        while not self.finished and (end is None or time.monotonic() < end):
            for socket, _ in self.poller.poll(50):
                while True:
                    try:
                        data = socket.recv(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    (self.receive if socket is self.sub else self._control)(data)
                    if self.finished:
                        break
            self._check_master(time.monotonic(), join_retry_s)
        return self.summary()

    def summary(self) -> dict:
        last = self.log.presented[-1] if self.log.presented else None
        return {"node": self.name, "pid": os.getpid(), "presented": len(self.log.presented),
                "last_frame": None if last is None else last[0], "counters": dict(self.log.counters),
                "unsent": self.log.unsent, "error": self.error, "lost": self.log.lost,
                "resyncs": self.log.resyncs, "joins": self.log.joins, "barrier_wait_ms": self.barrier_wait.summary()}

    def close(self) -> None:
        for s in (self.sub, self.dealer):
            assert s is not None  # connected from __init__ on
            s.close(0)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
