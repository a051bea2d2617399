"""Device helpers: the OpenBLAS thread limit applies inside the block and is undone after; a
replayed launch does what the launch does; a launch split over the CPU cores, and a split
replay, runs every thread once, with its own index (a split replay even when no worker
comes to take its chunks); a blocked replay or launch (several items a CPU thread) does every item once,
the last block's short tail included."""

import queue
import time

import numpy as np
import pytest
import warp as wp

import softvr.device as device_module
from softvr.device import (ITEMS_A_CPU_THREAD, HostMirror, LaunchBatch, _openblas_controls, blocked_launch, blocked_replayer, chunked_replayer,
                           launch, pull_all, replayer, single_threaded_blas)


@wp.kernel
def _add(values: wp.array(dtype=wp.float64), amount: wp.float64, scale: wp.array(dtype=wp.float64)):
    i = wp.tid()
    values[i] = values[i] + amount * scale[i]


def test_a_replayed_launch_runs_the_kernel_with_its_recorded_arguments(device):
    values = wp.zeros(4, dtype=wp.float64, device=device)
    scale = wp.array([1.0, 2.0, 3.0, 4.0], dtype=wp.float64, device=device)
    replay = replayer(wp.launch(_add, dim=4, inputs=[values, 0.5, scale], device=device, record_cmd=True))
    for _ in range(3):
        replay()
    # Three replays of values += 0.5 * scale, and nothing at recording time.
    np.testing.assert_array_equal(values.numpy(), 3 * 0.5 * np.array([1.0, 2.0, 3.0, 4.0]))


@wp.kernel
def _count(values: wp.array(dtype=wp.float64), counts: wp.array(dtype=wp.int32), amount: wp.float64, offset: int):
    i = wp.tid() + offset
    values[i] = amount * wp.float64(i)
    counts[i] = counts[i] + 1


def test_a_launch_batch_runs_its_replays_in_order_at_every_call(device):
    # Three recorded launches whose order matters: v += s, s += s, v += 10 s. Every call must run
    # all three in that order, the first (which captures them on CUDA) and the later ones (the
    # graph) alike: a call adds s + 20 s to v and doubles s.
    values = wp.zeros(4, dtype=wp.float64, device=device)
    scale = wp.array(np.ones(4), dtype=wp.float64, device=device)
    one = replayer(wp.launch(_add, dim=4, inputs=[values, 1.0, scale], device=device, record_cmd=True))
    double = replayer(wp.launch(_add, dim=4, inputs=[scale, 1.0, scale], device=device, record_cmd=True))
    ten = replayer(wp.launch(_add, dim=4, inputs=[values, 10.0, scale], device=device, record_cmd=True))
    batch = LaunchBatch([one, double, ten], device)
    expected, s = 0.0, 1.0
    for _ in range(3):
        batch()
        expected, s = expected + s + 10.0 * 2.0 * s, 2.0 * s
        np.testing.assert_array_equal(values.numpy(), expected)
        np.testing.assert_array_equal(scale.numpy(), s)


@pytest.mark.parametrize("copies", [False, True])
def test_a_host_mirror_shares_the_cpu_array_or_copies_it_across_push_and_pull(device, copies):
    start = np.arange(12.0).reshape(4, 3)
    array = wp.array(start, dtype=wp.vec3d, device=device)
    mirror = HostMirror(array, copies)
    row = mirror.host[1]  # a view a body would hold
    np.testing.assert_array_equal(mirror.host, start)
    shared = device == "cpu" and not copies
    assert mirror.copies is not shared and np.shares_memory(mirror.host, array.numpy()) is shared
    mirror.host[1] = -1.0  # the host writes: the array sees it at once only where shared
    np.testing.assert_array_equal(array.numpy()[1], -1.0 if shared else start[1])
    mirror.push()
    np.testing.assert_array_equal(array.numpy()[1], -1.0)
    array.fill_(wp.vec3d(7.0, 8.0, 9.0))  # the device writes: the host sees it after a pull
    np.testing.assert_array_equal(row, [7.0, 8.0, 9.0] if shared else [-1.0, -1.0, -1.0])
    mirror.pull()
    np.testing.assert_array_equal(row, [7.0, 8.0, 9.0])


def test_pull_all_brings_back_each_mirrors_first_rows_with_one_wait(device, monkeypatch):
    # Two copied mirrors (a 2-D int array and a 1-D array of 3x3 matrices), the first pulled for
    # its first 2 rows, the second whole: NumPy's slices of what the device wrote are the truth;
    # the rows past 2 keep what the host had; one synchronization for both.
    ints = wp.array(np.zeros((5, 4), np.int32), dtype=wp.int32, device=device)
    mats = wp.array(np.zeros((3, 3, 3)), dtype=wp.mat33d, device=device)
    first, second = HostMirror(ints, copies=True), HostMirror(mats, copies=True)
    written_ints, written_mats = np.arange(20, dtype=np.int32).reshape(5, 4), np.arange(27.0).reshape(3, 3, 3)
    ints.assign(written_ints)
    mats.assign(written_mats)
    waits = []
    monkeypatch.setattr(wp, "synchronize_device", lambda d=None: waits.append(d))
    pull_all([first, second], [2, None])
    np.testing.assert_array_equal(first.host[:2], written_ints[:2])
    np.testing.assert_array_equal(first.host[2:], 0)
    np.testing.assert_array_equal(second.host, written_mats)
    assert len(waits) == 1


def test_a_split_launch_runs_each_thread_once_with_its_own_index(monkeypatch):
    """Split in 12 chunks of uneven size (3 workers x 4), packed once and replayed per chunk:
    thread i writes 1.5 i (numpy.arange) and counts itself exactly once."""
    monkeypatch.setenv("SOFTVR_NUM_THREADS", "3")
    dim = 10_007
    values = wp.zeros(dim, dtype=wp.float64, device="cpu")
    counts = wp.zeros(dim, dtype=wp.int32, device="cpu")
    launch(_count, dim, [values, counts, 1.5], "cpu", min_chunk=100)
    np.testing.assert_array_equal(counts.numpy(), np.ones(dim, np.int32))
    np.testing.assert_array_equal(values.numpy(), 1.5 * np.arange(dim))


@wp.kernel
def _blocked_square(values: wp.array(dtype=wp.float64), counts: wp.array(dtype=wp.int32), amount: wp.float64,
                    block: int, offset: int):
    begin = (wp.tid() + offset) * block
    for i in range(begin, wp.min(begin + block, values.shape[0])):
        values[i] = amount * wp.float64(i) * wp.float64(i)
        counts[i] = counts[i] + 1


@pytest.mark.parametrize("how", ["replay", "launch"])
@pytest.mark.parametrize("workers", ["1", "3"])
def test_a_blocked_replay_does_every_item_once_the_short_last_block_included(device, workers, how, monkeypatch):
    """10 007 items (156 blocks of 64 and a last one of 23), replayed (or launched:
    ``blocked_launch``) 5 times, on one core and split over 3 (chunks counted in blocks): item i
    holds 0.5 i^2 as NumPy computes it per item (exact: i^2 < 2^53) and was done exactly 5 times;
    on CUDA a thread takes one item."""
    monkeypatch.setenv("SOFTVR_NUM_THREADS", workers)
    items = 10_007
    assert items % ITEMS_A_CPU_THREAD != 0
    values = wp.zeros(items, dtype=wp.float64, device=device)
    counts = wp.zeros(items, dtype=wp.int32, device=device)
    replay = blocked_replayer(_blocked_square, items, [values, counts, 0.5], device, min_chunk=256) if how == "replay" \
        else lambda: blocked_launch(_blocked_square, items, [values, counts, 0.5], device, min_chunk=256)
    for _ in range(5):
        replay()
    np.testing.assert_array_equal(counts.numpy(), np.full(items, 5, np.int32))
    np.testing.assert_array_equal(values.numpy(), 0.5 * np.arange(items, dtype=np.float64) ** 2)


@wp.kernel
def _total(total: wp.array(dtype=wp.int64), offset: int):
    wp.atomic_add(total, 0, wp.int64(1))


def test_a_kernel_that_accumulates_with_atomics_is_not_split(monkeypatch):
    """Warp's CPU atomics are a plain read-modify-write, so chunks of one launch on two threads
    can lose updates to one total: such a kernel is refused by a split launch and by a split
    replay, and with ``split=False`` its 200 000 threads each add exactly one."""
    monkeypatch.setenv("SOFTVR_NUM_THREADS", "2")
    dim = 200_000
    total = wp.zeros(1, dtype=wp.int64, device="cpu")
    with pytest.raises(ValueError, match="_total.*atomic"):
        launch(_total, dim, [total], "cpu")
    with pytest.raises(ValueError, match="_total.*atomic"):
        chunked_replayer(_total, dim, [total], "cpu")
    launch(_total, dim, [total], "cpu", split=False)
    assert int(total.numpy()[0]) == dim


def test_a_split_replay_runs_each_thread_once_per_call_with_its_own_index(monkeypatch):
    """3 workers, 6 chunks claimed as the threads come free, replayed 50 times: every thread
    counts itself 50 times and writes 1.5 i."""
    monkeypatch.setenv("SOFTVR_NUM_THREADS", "3")
    dim = 10_007
    values = wp.zeros(dim, dtype=wp.float64, device="cpu")
    counts = wp.zeros(dim, dtype=wp.int32, device="cpu")
    replay = chunked_replayer(_count, dim, [values, counts, 1.5], "cpu", min_chunk=100)
    for _ in range(50):
        replay()
    np.testing.assert_array_equal(counts.numpy(), np.full(dim, 50, np.int32))
    np.testing.assert_array_equal(values.numpy(), 1.5 * np.arange(dim))


def test_a_split_replay_that_no_worker_takes_up_is_run_by_its_caller(monkeypatch):
    """The workers' queue is never served (a loaded machine that does not schedule them): the
    caller runs every chunk itself and returns, without waiting for them."""
    monkeypatch.setenv("SOFTVR_NUM_THREADS", "2")
    idle: queue.SimpleQueue = queue.SimpleQueue()
    monkeypatch.setattr(device_module, "_split_workers", lambda workers: idle)
    dim = 4_096
    values = wp.zeros(dim, dtype=wp.float64, device="cpu")
    counts = wp.zeros(dim, dtype=wp.int32, device="cpu")
    replay = chunked_replayer(_count, dim, [values, counts, 2.0], "cpu", min_chunk=1024)
    replay.calls, replay.seconds = 2, [1.0, 0.0]  # the split way timed faster: it is taken
    for _ in range(3):
        replay()
    np.testing.assert_array_equal(counts.numpy(), np.full(dim, 3, np.int32))
    assert idle.qsize() == 3  # one call a replay offered to the one worker, none taken


def test_a_split_replay_whose_split_is_slower_runs_on_its_caller_but_for_probes(monkeypatch):
    """A split that waits 20 ms for its workers (a loaded machine): after the first call of
    each way the replay runs on the calling thread, but for one split call every SPLIT_PROBE,
    and still runs every thread once a call."""
    monkeypatch.setenv("SOFTVR_NUM_THREADS", "2")
    wait = device_module._SplitCall.wait
    monkeypatch.setattr(device_module._SplitCall, "wait", lambda call: (time.sleep(0.02), wait(call)))
    dim = 4_096
    values = wp.zeros(dim, dtype=wp.float64, device="cpu")
    counts = wp.zeros(dim, dtype=wp.int32, device="cpu")
    replay = chunked_replayer(_count, dim, [values, counts, 2.0], "cpu", min_chunk=1024)
    splits = 0
    for _ in range(40):
        before = replay.seconds[1]
        replay()
        splits += replay.seconds[1] != before
    np.testing.assert_array_equal(counts.numpy(), np.full(dim, 40, np.int32))
    assert splits == 1 + 40 // device_module.SPLIT_PROBE


def test_single_threaded_blas_limits_and_restores_every_openblas():
    import scipy.linalg  # noqa: F401 - both wheels' OpenBLAS loaded

    controls = _openblas_controls()
    if not controls:
        pytest.skip("no OpenBLAS loaded (not Linux, or another BLAS): nothing to limit")
    before = [get() for get, _ in controls]
    with single_threaded_blas():
        assert [get() for get, _ in controls] == [1] * len(controls)
        a = np.random.default_rng(0).standard_normal((200, 200))
        np.testing.assert_allclose(a @ np.linalg.inv(a), np.eye(200), atol=1e-8)  # BLAS still works
    assert [get() for get, _ in controls] == before
