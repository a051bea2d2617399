"""Master and render nodes on loopback: the issue's synchronization checks.

Truths are the master's own per-frame state digests and the clock shared by the processes
(CLOCK_MONOTONIC): every node must present every frame with the master's digest; with the
swap barrier no node presents frame n before the last node has rendered it; a node that
loses frames or is killed and restarted must be presenting the master's state again within
1 s; CURVE keys keep out a node whose key the master does not hold.
"""

import json
import signal
import subprocess
import threading
import time

import numpy as np
import pytest

from softvr.cave import preset
from softvr.cave.command import node_command
from softvr.cave.app import WavingSheet, user_pose_facing
from softvr.cave.cluster import ClusterConfig, Master, Node, make_keys

pytestmark = pytest.mark.timeout(300)


def _navigation(n, t):
    return user_pose_facing((0.0, 0.0, 0.4), 0.3 * np.sin(t)), [0.1 * np.sin(2 * t), 0, 1.7, 1, 0, 0, 0], (
        [("toggle", ("grid",))] if n % 50 == 0 else [])


def _master(nodes, **config):
    return Master(WavingSheet(2_500), nodes, ClusterConfig(publish="tcp://127.0.0.1:0", control="tcp://127.0.0.1:0",
                                                             **config), navigation=_navigation)


def _start(master, name, out, *extra):
    return subprocess.Popen(node_command("cube", name, master.config.publish, master.config.control, out=out,
                                         extra=["--max-seconds", "120", *extra]))


def _finish(processes):
    for p in processes:
        assert p.wait(timeout=60) == 0


def _log(out, name):
    return json.loads((out / f"{name}.json").read_text())


def _digests(master):
    return {f["n"]: f["digest"] for f in master.log["frames"]}


NODES = [s.node for s in preset("cube").screens]


def test_four_nodes_present_every_frame_in_step_with_the_masters_state(tmp_path):
    """1000 frames: every node presents frames 0..999, each with the master's digest, and the
    barrier holds: for every frame the earliest present comes after the latest render."""
    with _master(NODES) as master:
        processes = [_start(master, name, tmp_path, "--scale", "0.04") for name in NODES]
        master.wait_for_nodes(60)
        summary = master.run(1000)
        _finish(processes)
    digests = _digests(master)
    assert summary["mismatches"] == 0 and summary["evictions"] == 0
    logs = {name: _log(tmp_path, name) for name in NODES}
    for name, log in logs.items():
        frames = [p[0] for p in log["presented_frames"]]
        assert frames == list(range(1000)), name
        assert all(digests[n] == d for n, d, *_ in log["presented_frames"]), name
        assert sum(log["counters"].values()) - log["counters"]["stale"] == 0, log["counters"]
    rendered = np.array([[p[2] for p in log["presented_frames"]] for log in logs.values()])
    presented = np.array([[p[3] for p in log["presented_frames"]] for log in logs.values()])
    assert (presented.min(axis=0) >= rendered.max(axis=0)).all()
    assert (tmp_path / "front_last.png").exists()


def _back_in_sync(log, digests):
    assert all(digests[n] == d for n, d, *_ in log["presented_frames"])
    for resync in log["resyncs"]:
        assert resync["synced_at"] - resync["gap_at"] < 1.0, resync


def test_with_5_percent_of_frames_dropped_every_node_resyncs_within_a_second(tmp_path):
    with _master(NODES) as master:
        processes = [_start(master, name, tmp_path, "--no-render", "--drop-rate", "0.05", "--seed", str(i))
                     for i, name in enumerate(NODES)]
        master.wait_for_nodes(60)
        summary = master.run(1000)
        _finish(processes)
    digests = _digests(master)
    assert summary["mismatches"] == 0
    for name in NODES:
        log = _log(tmp_path, name)
        assert log["counters"]["injected_drops"] > 20 and len(log["resyncs"]) > 5, name
        _back_in_sync(log, digests)
        assert log["presented_frames"][-1][:2] == [999, digests[999]]


def test_a_killed_and_restarted_node_is_back_in_sync_within_a_second(tmp_path):
    """At 100 frames per second a node is killed at frame 150 and started again at once: the
    others wait at most the barrier's node timeout (0.5 s), the new one presents the master's
    state less than 1 s after it asks to join, and all end on the same final digest."""
    with _master(NODES) as master:
        processes = {name: _start(master, name, tmp_path, "--no-render") for name in NODES}
        master.wait_for_nodes(60)
        for n in range(600):
            t0 = time.monotonic()
            master.step()
            if n == 150:
                processes["left"].send_signal(signal.SIGKILL)
                processes["left"].wait()
                processes["left"] = _start(master, "left", tmp_path, "--no-render")
            master._serve_for(0.01 - (time.monotonic() - t0))  # 100 frames per second
        master.run(0)  # says bye
        _finish(processes.values())
    digests = _digests(master)
    assert [e["node"] for e in master.log["evictions"]] == ["left"]
    for name in NODES:
        log = _log(tmp_path, name)
        _back_in_sync(log, digests)
        presented = log["presented_frames"]
        assert presented[-1][:2] == [599, digests[599]]
        if name == "left":
            assert presented[0][3] - log["joins"][0] < 1.0
        else:
            times = np.array([p[3] for p in presented])
            assert np.diff(times).max() < 1.0


def test_only_nodes_with_keys_the_master_holds_can_join(tmp_path):
    keys = make_keys(tmp_path / "keys", ["a", "b"])
    strangers = make_keys(tmp_path / "strangers", ["b"])
    master = Master(WavingSheet(100), ["a", "b"], ClusterConfig(publish="tcp://127.0.0.1:0",
                                                               control="tcp://127.0.0.1:0", keys=str(keys)))
    good = Node("a", ClusterConfig(publish=master.config.publish, control=master.config.control, keys=str(keys)))
    # Node b holds the master's public key but its own key pair is not among the authorized.
    (strangers / "master.key").write_bytes((keys / "master.key").read_bytes())
    bad = Node("b", ClusterConfig(publish=master.config.publish, control=master.config.control, keys=str(strangers)))
    threads = [threading.Thread(target=n.run, kwargs={"max_seconds": s}) for n, s in ((good, 20), (bad, 5))]
    try:
        for t in threads:
            t.start()
        with pytest.raises(TimeoutError, match=r"\['b'\]"):
            master.wait_for_nodes(2.0)
        master.run(20)
        for t in threads:
            t.join(30)
        assert good.summary()["presented"] == 20 and good.state.digest() == master.state.digest()
        assert bad.state is None and bad.summary()["presented"] == 0
    finally:
        bad.finished = True
        for n in (good, bad, master):
            n.close()


def test_nodes_on_the_wire_survive_100k_fuzzed_packets(tmp_path, frame_maker):
    """The fuzzer's packets go out on the master's own PUB socket between frames, through the
    transport to two node processes: they present every frame with the master's digest and
    count every fuzzed packet as dropped."""
    from cave_packets import fuzzed_packets

    valid = [frame_maker.next() for _ in range(5)] + [frame_maker.snapshot]
    names = ["left", "front"]
    with _master(names) as master:
        processes = [_start(master, name, tmp_path, "--no-render") for name in names]
        master.wait_for_nodes(60)
        packets = fuzzed_packets(valid, 100_000, seed=11)
        master.step()
        for _ in range(200):
            # After frame 1 the fuzzer's frame numbers (0) are stale: a still-valid beat or go
            # for frame 0 would be a current one (a beat makes a node re-send its ready). 500
            # a frame: the PUB socket holds at most PUB_SNDHWM (1000) messages for a node.
            master.step()
            for _ in range(500):
                master.pub.send(next(packets))
        master.run(0)
        _finish(processes)
    digests = _digests(master)
    for name in names:
        log = _log(tmp_path, name)
        assert [p[0] for p in log["presented_frames"]] == list(range(201))
        assert all(digests[n] == d for n, d, *_ in log["presented_frames"])
        dropped = sum(v for k, v in log["counters"].items() if k != "stale")
        assert dropped == 100_000, log["counters"]
