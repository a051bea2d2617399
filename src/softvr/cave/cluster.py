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
it skipped, or a heartbeat ahead of its state) resyncs the same way. A node silent for
``node_timeout_s`` at the barrier is dropped from it until it joins again. Packets are
msgpack with a versioned schema (:mod:`softvr.cave.protocol`): bad ones are dropped and
counted. With ``keys`` (:func:`make_keys`) both sockets use CURVE: only nodes whose public
keys the master holds can connect.
"""

from __future__ import annotations

import os
import random
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zmq

from softvr.cave.app import ClusterState, FrameBuilder
from softvr.cave.protocol import PacketError, decode, encode
from softvr.cave.stream import DEFAULT_QUANTUM
from softvr.errors import InputError

__all__ = ["ClusterConfig", "Master", "Node", "make_keys"]


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
        While waiting at the barrier the master repeats "frame n is out" this often, so a
        node that lost frame n notices within one period.
    node_timeout_s : float [s]
        A node that has not reported a frame for this long leaves the barrier (it rejoins by
        asking for a snapshot).
    keys : str or None
        Folder made by :func:`make_keys`: CURVE encryption and authentication on both sockets.
    max_packet_bytes : int
        Larger packets are refused by the transport before they reach a node's decoder.
    """

    publish: str = "tcp://127.0.0.1:5560"
    control: str = "tcp://127.0.0.1:5561"
    barrier: bool = True
    heartbeat_s: float = 0.005
    node_timeout_s: float = 0.5
    keys: str | None = None
    max_packet_bytes: int = 256 << 20


def make_keys(folder, nodes) -> Path:
    """Create CURVE key pairs for a cluster in ``folder``: ``master.key`` (public) and
    ``master.key_secret``; per node ``nodes/<name>.key`` + ``.key_secret``; and
    ``authorized/<name>.key``, the public keys the master accepts. Copy ``master.key`` and a
    node's own pair to that node's machine. Returns ``folder``."""
    import zmq.auth  # noqa: PLC0415

    folder = Path(folder)
    for sub in ("nodes", "authorized"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    zmq.auth.create_certificates(str(folder), "master")
    for name in nodes:
        public, _ = zmq.auth.create_certificates(str(folder / "nodes"), name)
        shutil.copy(public, folder / "authorized" / f"{name}.key")
    return folder


def _load_pair(path: Path, what: str):
    import zmq.auth  # noqa: PLC0415

    if not path.is_file():
        raise InputError(what, f"a CURVE key file at {path} (softvr cave keys)", "no such file")
    return zmq.auth.load_certificate(str(path))


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
    """

    def __init__(self, source, nodes, config: ClusterConfig | None = None, *, navigation=None, tracker=None,
                 quantum: float = DEFAULT_QUANTUM, context: zmq.Context | None = None):
        self.config = config or ClusterConfig()
        self.nodes = list(nodes)
        self.session = random.SystemRandom().getrandbits(62)
        self.frames = FrameBuilder(source, navigation=navigation, tracker=tracker, quantum=quantum)
        self.members: dict[str, float] = {}  # node -> when it last reported [monotonic s]
        self.log = {"joins": [], "evictions": [], "mismatches": 0, "frames": []}
        self._digest = self.state.digest()
        self.frame_bytes = _Stats()
        self.sync = _Stats()  # publish -> every member ready
        self._ctx = context or zmq.Context.instance()
        self._auth = None
        self.pub = self._ctx.socket(zmq.PUB)
        self.router = self._ctx.socket(zmq.ROUTER)
        self.router.setsockopt(zmq.ROUTER_HANDOVER, 1)  # a restarted node takes its name back
        self.router.setsockopt(zmq.MAXMSGSIZE, 1 << 20)
        for s in (self.pub, self.router):
            s.setsockopt(zmq.LINGER, 0)
            s.setsockopt(zmq.SNDHWM, 100_000)
        if self.config.keys:
            self._secure(Path(self.config.keys))
        self.pub.bind(self.config.publish)
        self.router.bind(self.config.control)
        self.config.publish = self.pub.getsockopt_string(zmq.LAST_ENDPOINT)
        self.config.control = self.router.getsockopt_string(zmq.LAST_ENDPOINT)
        self.poller = zmq.Poller()
        self.poller.register(self.router, zmq.POLLIN)

    def _secure(self, keys: Path) -> None:
        from zmq.auth.thread import ThreadAuthenticator  # noqa: PLC0415

        public, secret = _load_pair(keys / "master.key_secret", "master key")
        self._auth = ThreadAuthenticator(self._ctx)
        self._auth.start()
        self._auth.configure_curve(domain="*", location=str(keys / "authorized"))
        for s in (self.pub, self.router):
            s.curve_secretkey, s.curve_publickey, s.curve_server = secret, public, True

    @property
    def state(self) -> ClusterState:
        """The master's copy of the application state (what every node must hold)."""
        return self.frames.state

    # ------------------------------------------------------------------ control
    def _handle_control(self, barrier_frame: int | None, pending: set | None) -> None:
        """Serve every waiting ROUTER message (joins, ready reports)."""
        while True:
            try:
                identity, data = self.router.recv_multipart(zmq.NOBLOCK)[:2]
            except zmq.Again:
                return
            except ValueError:
                continue
            try:
                packet = decode(data)
            except PacketError:
                continue
            now = time.monotonic()
            node = packet.payload.get("node")
            if node not in self.nodes:
                continue  # not a screen of this display
            if packet.kind == "join":
                snapshot = {"n": self.state.n, "state": self.state.snapshot()}
                self.router.send_multipart([identity, encode("snapshot", self.session, snapshot)])
                self.members[node] = now
                self.log["joins"].append({"node": node, "frame": self.state.n, "time": now})
                if pending is not None and barrier_frame == self.state.n and self.state.n >= 0:
                    pending.add(node)
            elif packet.kind == "ready" and packet.session == self.session:
                if node in self.members or packet.payload["n"] == self.state.n:
                    self.members[node] = now  # a node dropped from the barrier that caught up is back
                if pending is not None and packet.payload["n"] == barrier_frame and node in pending:
                    pending.discard(node)
                    if packet.payload["hash"] != self._digest:
                        self.log["mismatches"] += 1

    def wait_for_nodes(self, timeout_s: float = 60.0) -> None:
        """Serve joins until every node of the display has joined and drawn the state it got
        (its renderer is up, so the first frames do not time out at the barrier); raises
        ``TimeoutError`` naming the missing ones."""
        deadline = time.monotonic() + timeout_s
        pending = set(self.nodes)
        while pending:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"render nodes {sorted(pending)} did not join within {timeout_s:g} s")
            if self.poller.poll(min(left, 0.05) * 1e3):
                self._handle_control(self.state.n, pending)

    # ------------------------------------------------------------------- frames
    def step(self) -> dict:
        """Publish the next frame and, with the barrier, wait until every member rendered
        it; returns the frame's record."""
        packet = self.frames.next_packet(self.session)
        n = self.state.n
        self._digest = self.state.digest()
        t0 = time.perf_counter()
        self.pub.send(packet)
        self.frame_bytes.add(len(packet))
        record = {"n": n, "digest": self._digest.hex(), "bytes": len(packet), "members": sorted(self.members)}
        if self.config.barrier:
            record["sync_s"] = self._barrier(n, t0)
            self.pub.send(encode("go", self.session, {"n": n}))
        else:
            self._handle_control(None, None)
        self.log["frames"].append(record)
        return record

    def _barrier(self, n: int, t0: float) -> float | None:
        pending = set(self.members)
        beat = encode("beat", self.session, {"n": n})
        start = time.monotonic()
        next_beat = start + self.config.heartbeat_s
        while pending:
            now = time.monotonic()
            if now >= start + self.config.node_timeout_s:
                for node in sorted(pending):
                    self.members.pop(node, None)
                    self.log["evictions"].append({"node": node, "frame": n, "time": now})
                return None
            wait = min(next_beat, start + self.config.node_timeout_s) - now
            if self.poller.poll(max(wait, 0.0) * 1e3):
                self._handle_control(n, pending)
            if time.monotonic() >= next_beat and pending:
                self.pub.send(beat)
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
            self.pub.send(bye)
            time.sleep(0.01)
        return self.summary()

    def _serve_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            if self.poller.poll(left * 1e3):
                self._handle_control(None, None)

    def summary(self) -> dict:
        return {"session": self.session, "frames": self.state.n + 1, "mismatches": self.log["mismatches"],
                "joins": len(self.log["joins"]), "evictions": len(self.log["evictions"]),
                "frame_bytes": self.frame_bytes.summary(scale=1.0), "sync_ms": self.sync.summary()}

    def close(self) -> None:
        for s in (self.pub, self.router):
            s.close(0)
        if self._auth is not None:
            self._auth.stop()

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
    counters: dict = field(default_factory=lambda: {"foreign": 0, "version": 0, "session": 0, "malformed": 0,
                                                    "inconsistent": 0, "stale": 0, "injected_drops": 0})
    unsent: int = 0  # messages to the master dropped because it was not connected


class Node:
    """A render node of the cluster (module docstring).

    Parameters
    ----------
    name : str
        This node's name (a display screen's ``node``).
    config : ClusterConfig
    render : callable, optional
        ``render(state)`` draws the node's screen(s) for a :class:`ClusterState` (called once
        per applied frame, before ``ready``); None renders nothing (barrier measurements).
    present : callable, optional
        ``present(state)``: show the rendered frame (swap buffers, save an image).
    drop_rate : float
        Fraction of received PUB packets thrown away before decoding (a lossy network, for
        tests and benchmarks).
    """

    def __init__(self, name: str, config: ClusterConfig | None = None, *, render=None, present=None,
                 drop_rate: float = 0.0, seed: int | None = None, context: zmq.Context | None = None):
        self.name, self.config = name, config or ClusterConfig()
        self.render_state, self.present_state = render, present
        self.drop_rate, self._rng = float(drop_rate), random.Random(seed)
        self.state: ClusterState | None = None
        self.session: int | None = None
        self.log = _NodeLog()
        self.finished = False
        self.barrier_wait = _Stats()
        self._awaiting = True  # no state yet, or resyncing: frames are buffered
        self._buffer: list = []
        self._pending: int | None = None  # rendered, not yet presented
        self._ready_sent = self._rendered_at = 0.0
        self._join_sent = 0.0
        self._gap_at: float | None = None
        self._ctx = context or zmq.Context.instance()
        self.sub = self._ctx.socket(zmq.SUB)
        self.dealer = self._ctx.socket(zmq.DEALER)
        self.dealer.setsockopt(zmq.ROUTING_ID, name.encode())
        for s in (self.sub, self.dealer):
            s.setsockopt(zmq.LINGER, 0)
            s.setsockopt(zmq.MAXMSGSIZE, self.config.max_packet_bytes)
            s.setsockopt(zmq.RCVHWM, 100_000)
        if self.config.keys:
            keys = Path(self.config.keys)
            server, _ = _load_pair(keys / "master.key", "master public key")
            public, secret = _load_pair(keys / "nodes" / f"{name}.key_secret", f"node {name} key")
            for s in (self.sub, self.dealer):
                s.curve_secretkey, s.curve_publickey, s.curve_serverkey = secret, public, server
        self.sub.setsockopt(zmq.SUBSCRIBE, b"")
        self.sub.connect(self.config.publish)
        self.dealer.connect(self.config.control)
        self.poller = zmq.Poller()
        self.poller.register(self.sub, zmq.POLLIN)
        self.poller.register(self.dealer, zmq.POLLIN)

    # ---------------------------------------------------------------- protocol
    def _send(self, data: bytes) -> None:
        # A DEALER with no connected master (not up yet, gone, or refusing our CURVE key)
        # would block in send: drop the message instead; joins are retried, readies are
        # superseded by the next frame's.
        try:
            self.dealer.send(data, zmq.NOBLOCK)
        except zmq.Again:
            self.log.unsent += 1

    def _join(self) -> None:
        self._awaiting = True
        self._join_sent = time.monotonic()
        self.log.joins.append(self._join_sent)
        self._send(encode("join", 0, {"node": self.name}))

    def _resync(self) -> None:
        if not self._awaiting:
            self._gap_at = time.monotonic()
            self.log.resyncs.append({"gap_at": self._gap_at, "from": self.state.n})
            self._join()

    def receive(self, data: bytes) -> None:
        """Handle one packet from the master's PUB socket (anything at all: bad packets are
        counted in ``log.counters`` and dropped)."""
        if self.drop_rate and self._rng.random() < self.drop_rate:
            self.log.counters["injected_drops"] += 1
            return
        try:
            packet = decode(data, self.session)
        except PacketError as exc:
            self.log.counters[exc.reason] += 1
            return
        kind, p = packet.kind, packet.payload
        if kind not in ("frame", "beat", "go", "bye"):
            self.log.counters["malformed"] += 1  # node-to-master kinds, or a snapshot not on the control socket
            return
        if kind == "bye":
            self._present()
            self.finished = True
            return
        if self._awaiting:
            if kind == "frame" and len(self._buffer) < 1024:
                self._buffer.append(packet)
            return
        if kind == "frame":
            self._frame(packet)
        elif kind == "beat" and p["n"] > self.state.n:
            self._resync()
        elif kind == "go" and self._pending == p["n"]:
            self.barrier_wait.add(time.monotonic() - self._ready_sent)
            self._present()
        else:
            self.log.counters["stale"] += 1  # about a frame already done

    def _frame(self, packet) -> None:
        n = packet.payload["n"]
        if n <= self.state.n:
            self.log.counters["stale"] += 1
            return
        if n > self.state.n + 1:
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
            self.state.apply_frame(packet.payload)
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
        if self.state.n >= 0:  # (the state before the first frame has nothing to present)
            self._pending = self.state.n
            if not self.config.barrier:
                self._present()
                return
            self._ready_sent = self._rendered_at
        # Before the first frame too: the master waits for every node's renderer to be up.
        self._send(encode("ready", self.session, {"node": self.name, "n": self.state.n, "hash": self.state.digest()}))

    def _present(self) -> None:
        if self._pending is None or self.state is None or self._pending != self.state.n:
            return
        if self.present_state is not None:
            self.present_state(self.state)
        self.log.presented.append([self.state.n, self.state.digest().hex(), self._rendered_at, time.monotonic()])
        self._pending = None

    def _control(self, data: bytes) -> None:
        try:
            packet = decode(data)
            if packet.kind != "snapshot":
                raise PacketError("malformed", "only snapshots come on the control socket")
            if not self._awaiting:  # the answer to a repeated join: the state is already current
                self.log.counters["stale"] += 1
                return
            state = ClusterState.from_snapshot(packet.payload["state"])
        except PacketError as exc:
            self.log.counters[exc.reason] += 1
            return
        except ValueError:  # a mesh key that does not fit its mesh
            self.log.counters["malformed"] += 1
            return
        self.session, self.state, self._awaiting, self._pending = packet.session, state, False, None
        buffered, self._buffer = self._buffer, []
        for frame in sorted(buffered, key=lambda f: f.payload["n"]):
            if frame.session != self.session or frame.payload["n"] <= self.state.n:
                continue
            if frame.payload["n"] != self.state.n + 1:
                self._resync()
                self._buffer = [f for f in buffered if f.payload["n"] > self.state.n]
                return
            if not self._apply(frame):
                return
        if self._gap_at is not None and self.log.resyncs:
            self.log.resyncs[-1].update(synced_at=time.monotonic(), to=self.state.n)
            self._gap_at = None
        self._rendered()

    # --------------------------------------------------------------------- loop
    def run(self, max_seconds: float | None = None, join_retry_s: float = 1.0) -> dict:
        """Join and follow the master until it says ``bye`` (or ``max_seconds`` pass);
        returns :meth:`summary`."""
        end = None if max_seconds is None else time.monotonic() + max_seconds
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
            if self._awaiting and time.monotonic() - self._join_sent > join_retry_s:
                self._join()  # the master was not up yet, or the snapshot went missing
        return self.summary()

    def summary(self) -> dict:
        last = self.log.presented[-1] if self.log.presented else None
        return {"node": self.name, "pid": os.getpid(), "presented": len(self.log.presented),
                "last_frame": None if last is None else last[0], "counters": dict(self.log.counters),
                "unsent": self.log.unsent,
                "resyncs": self.log.resyncs, "joins": self.log.joins, "barrier_wait_ms": self.barrier_wait.summary()}

    def close(self) -> None:
        for s in (self.sub, self.dealer):
            s.close(0)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
