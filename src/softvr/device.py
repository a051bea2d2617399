"""Choice of Warp device, one helper that spreads a CPU launch over all cores, and one that
keeps OpenBLAS from competing with it.

Warp runs a CPU launch on one thread but releases the GIL while it runs, so launching
one chunk of the thread range per core from a thread pool uses every core (DESIGN.md:
1.9-2.0x on 2 cores). Kernels that go through :func:`launch` take the first thread
index of their chunk as their last argument and add it to ``wp.tid()``.
"""

from __future__ import annotations

import ctypes
import itertools
import logging
import math
import os
import queue
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from functools import lru_cache, partial
from typing import no_type_check

import numpy as np
import warp as wp

from softvr.errors import InputError

__all__ = [
    "ITEMS_A_CPU_THREAD", "HostMirror", "LaunchBatch", "blocked_launch", "blocked_replayer", "chunked_replayer",
    "cpu_workers", "cuda_driver_present", "in_order", "launch", "load_kernels", "pull_all", "record_copy", "replayer",
    "resolve_device",
    "single_threaded_blas", "stride_threads", "upload",
]


_log = logging.getLogger(__name__)

# What Warp's native library prints when it cannot dlopen the driver (warp/native/cuda_util.cpp).
_NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"


def cuda_driver_present() -> bool:
    """Whether the NVIDIA CUDA driver library loads here, tried as Warp's own init tries it."""
    names = ("nvcuda.dll",) if sys.platform == "win32" else ("libcuda.so", "libcuda.so.1")
    for name in names:
        try:
            ctypes.CDLL(name)
        except OSError:
            continue
        return True
    return False


@contextmanager
def _stderr_lines(out: list[str]):
    """Capture what native code writes to file descriptor 2 in the body into ``out`` (lines)."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            out.extend(tmp.read().decode("utf-8", "replace").splitlines(keepends=True))


@lru_cache(maxsize=1)
def _init() -> None:
    # Warp logs every module load at INFO; softvr's progress output is its own.
    if wp.config.log_level == wp.LOG_INFO:
        wp.config.log_level = wp.LOG_WARNING
    wp.config.quiet = True  # type: ignore[attr-defined]  # a Warp setting its type stubs omit
    if cuda_driver_present():
        wp.init()
        return
    # Without a driver, Warp 1.19's native init fprintf's a warning to stderr on every run (no config
    # switch turns it off): a CPU-only machine is an expected setup, not a fault. Everything else it
    # writes is passed through; the fact itself is one INFO line (shown with --verbose / logging INFO).
    lines: list[str] = []
    with _stderr_lines(lines):
        wp.init()
    rest = [line for line in lines if _NO_DRIVER not in line]
    if rest:
        sys.stderr.write("".join(rest))
    _log.info("no NVIDIA CUDA driver found: Warp runs on the CPU only")


def resolve_device(device: str | None = None) -> str:
    """Return the Warp device name to run on.

    Parameters
    ----------
    device : {"cpu", "cuda", "cuda:N", None}
        ``None`` picks ``"cuda"`` when a CUDA device is present, else ``"cpu"``.
    """
    _init()
    if device is None:
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    name = str(device)
    if name == "cuda":
        name = "cuda:0"
    if name.startswith("cuda") and not wp.is_cuda_available():
        raise InputError("device", "'cpu' (no CUDA device is present here)", repr(device))
    if name != "cpu" and not name.startswith("cuda"):
        raise InputError("device", "'cpu', 'cuda' or 'cuda:N'", repr(device))
    try:
        return str(wp.get_device(name))
    except Exception as exc:  # Warp raises a bare error for unknown ordinals
        raise InputError("device", "an existing Warp device", f"{device!r} ({exc})") from None


def cpu_workers() -> int:
    """Number of threads used for CPU launches (``SOFTVR_NUM_THREADS`` or all cores)."""
    env = os.environ.get("SOFTVR_NUM_THREADS")
    if env:
        return max(1, int(env))
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def load_kernels(kernel, device: str) -> None:
    """Compile (or load from Warp's disk cache) the module holding ``kernel`` for ``device``.

    Done once per module and device, before launch chunks could race to do it from several
    threads; callers may also do it up front so that no frame pays for compilation.
    """
    _load(kernel.module, device)


@lru_cache(maxsize=None)
def _load(module, device: str) -> None:
    wp.load_module(module, device=device)


def _check_splittable(kernel) -> None:
    """Refuse to split a kernel that calls ``wp.atomic_*`` itself: Warp's CPU atomics are a
    plain read-modify-write (one CPU launch runs on one thread), so chunks of one launch on two
    threads lose updates to a shared total (measured: 1 launch in 20 lost a count). Such a
    kernel writes per-thread results the caller reduces, or is launched with ``split=False``;
    so is one whose :func:`warp.func` helpers accumulate (its own source cannot show that)."""
    if "atomic_" in getattr(getattr(kernel, "adj", None), "source", ""):
        raise ValueError(f"kernel {kernel.key!r} accumulates with wp.atomic_*, which is not atomic across a "
                         "split CPU launch's threads: write per-thread results, or pass split=False")


def launch(kernel, dim: int, inputs: list, device: str, *, min_chunk: int = 1024, split: bool = True) -> None:
    """Launch a 1-D ``kernel`` over ``dim`` threads, split across CPU cores.

    The kernel's last parameter must be an ``int`` thread offset: chunk ``c`` is launched
    with ``dim_c`` threads and offset ``start_c``, and the kernel uses
    ``wp.tid() + offset``. On CUDA this is one launch with offset 0. Chunks run at the same
    time on different threads, so no two threads may write one element, and a kernel that
    accumulates with atomics is refused unless ``split`` is False (:func:`_check_splittable`).

    Parameters
    ----------
    kernel : warp.Kernel
    dim : int
        Total number of threads.
    inputs : list
        Kernel arguments, without the trailing offset.
    device : str
        Warp device name.
    min_chunk : int
        Below ``2 * min_chunk`` threads the launch is not split.
    split : bool
        False: one launch on the calling thread (a kernel whose threads accumulate into
        shared memory with atomics).
    """
    if dim <= 0:
        return
    load_kernels(kernel, device)
    workers = cpu_workers() if device == "cpu" else 1
    if split and workers > 1:
        _check_splittable(kernel)
    if not split or workers == 1 or dim < 2 * min_chunk:
        wp.launch(kernel, dim=dim, inputs=[*inputs, 0], device=device)
        return
    # More chunks than workers balance uneven per-thread work (rows of different length).
    chunks = min(workers * 4, max(1, dim // min_chunk))
    bounds = [dim * c // chunks for c in range(chunks + 1)]
    # The arguments are packed once (a wp.launch packs each on every call: ~0.2 ms for a
    # kernel of 30 arguments, under the GIL) and each chunk replays a copy with its own size
    # and offset.
    recorded = wp.launch(kernel, dim=bounds[1], inputs=[*inputs, 0], device=device, record_cmd=True)
    replays = _chunk_replays(recorded, bounds, len(inputs))
    if replays is None:  # not a packed replay: the chunks could not share the recorded launch
        replays = [partial(wp.launch, kernel, dim=bounds[c + 1] - bounds[c], inputs=[*inputs, bounds[c]],
                           device=device) for c in range(chunks)]
    _run_split(replays, workers)


def _chunk_replays(recorded, bounds: list[int], offset_arg: int) -> list[Callable[[], None]] | None:
    """Replays of the chunks ``bounds[c] .. bounds[c + 1]`` of a 1-D launch recorded over the first
    chunk with its thread offset (argument ``offset_arg``) 0, or None where it does not replay
    packed (:func:`replayer`). The other chunks copy the packed arguments (one C call) and set
    their offset and size: re-packing each (``set_dim``, ``set_param_at_index``, a struct filled
    field by field) cost ~0.1 ms of Python a chunk."""
    first = replayer(recorded)
    if not hasattr(first, "keep"):
        return None
    args = first.keep[1]  # set by replayer()
    offset_name = args._fields_[offset_arg][0]
    forward, bounds_type = recorded.hooks.forward, type(recorded.params[0])
    replays = [first]
    for c in range(1, len(bounds) - 1):
        packed = type(args).from_buffer_copy(args)
        setattr(packed, offset_name, bounds[c])
        # byref keeps its object alive; the arrays the copies point into live as long as ``first``,
        # which the caller holds with the rest.
        replays.append(partial(forward, ctypes.byref(bounds_type(bounds[c + 1] - bounds[c])), ctypes.byref(packed)))
    return replays


def upload(dst: wp.array, src) -> None:
    """Copy host data ``src`` (array-like of ``dst``'s shape, any float or int dtype) into the
    existing Warp array ``dst``, converted to its dtype. On the CPU it is written straight into
    the array's memory: ``dst.assign(wp.array(src))``, the usual way, allocates and checks a
    temporary array each time (~25 us: over a hundred a step in the per-object shoulder)."""
    if dst.device is not None and dst.device.is_cpu:
        dst.numpy()[...] = src
    else:
        dst.assign(wp.array(np.asarray(src), dtype=dst.dtype, device=dst.device))


class HostMirror:
    """A Warp array's contents on the host, for the Python side of a step (the bodies' ``q``
    and ``v`` a user reads and assigns, host-written inputs, flags a check reads).

    On the CPU ``host`` is the array's own memory (a NumPy view) and :meth:`push` /
    :meth:`pull` do nothing. On another device, or where ``copies`` asks for it on the CPU
    (tests run a CUDA step's host traffic that way), ``host`` is the NumPy view of a host array
    kept for it (page-locked for a GPU, so the copies need no staging): :meth:`push` copies it to
    the device after the host wrote it, :meth:`pull` copies the array back (and waits for it)
    after the device did. Code written against a mirror runs the same on both: what it forgets
    to push or pull is stale only where the copies are.

    Parameters
    ----------
    array : warp.array
    copies : bool
        Keep a copy even on the CPU.
    """

    def __init__(self, array: wp.array, copies: bool = False):
        self.array = array
        self._device = wp.get_device(array.device)
        self.copies = bool(copies) or not self._device.is_cpu
        self._host_array = wp.empty_like(array, device="cpu", pinned=self._device.is_cuda) if self.copies else array
        if self.copies:
            wp.copy(self._host_array, array)
            wp.synchronize_device(self._device)
        self.host: np.ndarray = self._host_array.numpy()

    def push(self, wait: bool = False) -> None:
        """Copy ``host`` to the device (after the host wrote it); stream-ordered before the
        launches that follow. ``wait``: also wait for it (a mirror about to be let go: its
        page-locked memory must outlive the copy)."""
        if self.copies:
            wp.copy(self.array, self._host_array)
            if wait:
                wp.synchronize_device(self._device)

    def pull(self, rows: int | None = None) -> None:
        """Copy the array (its first ``rows`` rows; all where None) into ``host`` (after the
        device wrote it) and wait for it; views of ``host`` stay valid."""
        pull_all([self], rows)

    def _copy_back(self, rows: int | None) -> None:
        if rows is None:
            wp.copy(self._host_array, self.array)
        elif rows > 0:
            shape = self.array.shape
            wp.copy(self._host_array, self.array, count=min(rows, shape[0]) * math.prod(shape[1:]))


def pull_all(mirrors, rows=None) -> None:
    """:meth:`HostMirror.pull` of several mirrors with one wait: each array (its first ``rows``
    rows; all where None; or per mirror, a sequence as long as ``mirrors``) copied back in
    stream order, then one synchronization (on a GPU each pull alone waits for the device: a
    step's contacts read field by field waited ~20 times)."""
    mirrors = list(mirrors)
    counts = list(rows) if isinstance(rows, (list, tuple)) else [rows] * len(mirrors)
    wait = None
    for mirror, count in zip(mirrors, counts):
        if mirror.copies:
            mirror._copy_back(count)
            wait = mirror._device
    if wait is not None:
        wp.synchronize_device(wait)


class LaunchBatch:
    """Replays run as one: on the CPU one after another; on CUDA captured as a CUDA graph on the
    first call (and launched), then launched as that graph (a node step's sweeps replay 3 or
    more launches a sweep, each a few us of host time on CUDA: ~100 a step on the bench cube).

    Nothing in ``replays`` may read device memory back, allocate, or decide on the host: a
    capture records launches, not host work. Where the capture fails (a driver or stream that
    cannot capture), the replays run one by one from then on, as on the CPU, and the failure is
    logged once.

    Parameters
    ----------
    replays : sequence of callables
        Each replays recorded launches (:func:`replayer`, :func:`in_order`).
    device : str
        Their Warp device.
    """

    def __init__(self, replays, device: str):
        self.replays = tuple(replays)
        self._device = wp.get_device(device)
        self._graph: wp.Graph | None = None
        self._try_capture = self._device.is_cuda

    def __call__(self) -> None:
        if self._graph is not None:
            wp.capture_launch(self._graph)
            return
        if self._try_capture:
            self._try_capture = False
            try:
                with wp.ScopedCapture(device=self._device) as capture:
                    for replay in self.replays:
                        replay()
            except Exception as exc:  # noqa: BLE001 - any failure: run them uncaptured, as on the CPU
                _log.warning("launches not captured as a CUDA graph (%s): replayed one by one", exc)
            else:
                self._graph = graph = capture.graph
                if graph is not None:
                    wp.capture_launch(graph)
                    return
        for replay in self.replays:
            replay()


def replayer(recorded) -> Callable[[], None]:
    """A function that replays a recorded launch (``wp.launch(..., record_cmd=True)``).

    On the CPU, ``Launch.launch()`` packs every argument into a fresh ctypes struct on each
    call (~1 µs per argument: 20-30 µs for a contact kernel, more than the kernel itself on a
    small scene). The struct is packed once here and the compiled entry point called with it,
    which is what Warp's own CPU ``invoke`` does after packing. Anything else (CUDA, tiled
    launches, a Warp without these internals) replays through ``Launch.launch``.
    """
    try:
        if not recorded.device.is_cpu or recorded.adjoint or getattr(recorded, "block_dim", 1) > 1:
            return recorded.launch
        params, forward = recorded.params, recorded.hooks.forward
        args = recorded.kernel.adj.args
        # The layout this relies on (Warp 1.19's CPU invoke): launch bounds, then one ctypes
        # value per kernel argument. Anything else replays the documented way.
        if not callable(forward) or len(params) != 1 + len(args):
            return recorded.launch
        fields = tuple((arg.label, type(params[1 + i])) for i, arg in enumerate(args))
    except AttributeError:
        return recorded.launch
    args = _args_struct(fields)()
    for i, (name, _) in enumerate(fields):
        setattr(args, name, params[1 + i])
    bounds, packed = ctypes.byref(params[0]), ctypes.byref(args)

    def replay() -> None:
        forward(bounds, packed)

    replay.keep = (recorded, args)  # type: ignore[attr-defined]  # the struct points into the launch's arrays
    return replay


@lru_cache(maxsize=256)
def _args_struct(fields: tuple) -> type:
    """The ctypes struct of a kernel's packed arguments (``fields``: (name, ctypes type) pairs),
    made once per kernel signature: making the class costs ~40 us, more than filling it
    (a split launch makes one per chunk, 16 a frame for the rasterizer)."""
    return type("ArgsStruct", (ctypes.Structure,), {"_fields_": list(fields)})


@wp.kernel
@no_type_check  # Warp's annotations (wp.array(dtype=...)) are not Python types
def _copy_int32(src: wp.array(dtype=wp.int32), dst: wp.array(dtype=wp.int32)):
    i = wp.tid()
    dst[i] = src[i]


def record_copy(dst: wp.array, src: wp.array) -> Callable[[], None]:
    """A replay copying ``src`` into ``dst`` (int32 arrays of one length on one device) as a
    kernel launch, not ``wp.copy``: it sits in a :class:`LaunchBatch` as any launch does, and a
    check that refuses copies (reads back) inside a batch lets it be."""
    if src.dtype != wp.int32 or dst.dtype != wp.int32 or src.shape != dst.shape or src.device != dst.device:
        raise ValueError(f"record_copy: expected int32 arrays of one shape on one device, found {src.dtype} "
                         f"{src.shape} on {src.device} into {dst.dtype} {dst.shape} on {dst.device}")
    return replayer(wp.launch(_copy_int32, dim=len(src), inputs=[src, dst], device=src.device, record_cmd=True))


def in_order(*replays: Callable[[], None]) -> Callable[[], None]:
    """One replay running ``replays`` (recorded launches, or other replays) one after the other."""
    def run() -> None:
        for replay in replays:
            replay()

    return run


class _SplitCall:
    """One call of a split replay (:func:`chunked_replayer`): its chunks are claimed one at a
    time by the calling thread and the workers (:func:`_split_workers`), so a worker that a
    loaded machine has not scheduled yet leaves its chunks to the caller instead of keeping it
    waiting; the caller waits only for a chunk a worker is running. ``next`` on an
    ``itertools.count`` is one C call, atomic under the GIL."""

    __slots__ = ("replays", "claim", "done", "finished", "complete", "error")

    def __init__(self, replays: list[Callable[[], None]]):
        self.replays = replays
        self.claim, self.done = itertools.count(), itertools.count(1)
        self.finished = threading.Lock()
        self.finished.acquire()  # released with the last chunk
        self.complete = False
        self.error: BaseException | None = None

    def __call__(self) -> None:
        count = len(self.replays)
        for c in self.claim:
            if c >= count:
                return
            try:
                self.replays[c]()
            except BaseException as exc:  # raised in the caller; the chunk still counts as done
                self.error = exc
            if next(self.done) == count:
                self.complete = True
                self.finished.release()

    def wait(self) -> None:
        """Until every chunk has run (re-raising a chunk's error)."""
        if not self.complete:
            self.finished.acquire()
        if self.error is not None:
            raise self.error


@lru_cache(maxsize=8)
def _split_workers(workers: int) -> queue.SimpleQueue:
    """A queue of :class:`_SplitCall` served by ``workers - 1`` daemon threads. Lighter than a
    thread pool's futures (a C queue and one lock a call, no condition variables): on the
    candy pile's Jacobi update (2 731 nodes, ~135 us) the pool's hand-off cost ~45 us of CPU
    a call, this one ~20."""
    tasks: queue.SimpleQueue = queue.SimpleQueue()

    def serve() -> None:
        while True:
            tasks.get()()

    for _ in range(workers - 1):
        threading.Thread(target=serve, name="softvr-split", daemon=True).start()
    return tasks


def _run_split(replays: list[Callable[[], None]], workers: int) -> None:
    """Run ``replays`` (a split launch's chunks) on the calling thread and ``workers - 1``
    workers (:func:`_split_workers`), each claiming the next chunk as it comes free; return
    when all have run."""
    call = _SplitCall(replays)
    tasks = _split_workers(workers)
    for _ in range(workers - 1):
        tasks.put(call)
    call()
    call.wait()


def chunked_replayer(kernel, dim: int, inputs: list, device: str, *, min_chunk: int = 1024) -> Callable[[], None]:
    """Record a 1-D ``kernel`` over ``dim`` threads in chunks (the last parameter an ``int``
    thread offset, as :func:`launch`) and return a function replaying it: on the CPU from
    ``2 * min_chunk`` threads in two chunks per core (of at least ``min_chunk / 2``), which
    the calling thread and the workers claim as they come free (:class:`_SplitCall`), or all
    on the calling thread where that has been faster (:class:`_SplitReplay`); one replay where
    one chunk suffices (CUDA, one core, a small ``dim``). A kernel that accumulates with
    atomics is refused, as by :func:`launch`."""
    load_kernels(kernel, device)
    workers = cpu_workers() if device == "cpu" else 1
    if workers > 1:
        _check_splittable(kernel)
    chunks = 1 if workers == 1 or dim < 2 * min_chunk else min(2 * workers, max(1, dim // max(1, min_chunk // 2)))
    bounds = [dim * c // chunks for c in range(chunks + 1)]
    replays = [replayer(wp.launch(kernel, dim=bounds[c + 1] - bounds[c], inputs=[*inputs, bounds[c]], device=device,
                                  record_cmd=True))
               for c in range(chunks) if bounds[c + 1] > bounds[c]]
    if not replays:  # no threads (a scene without collision points): nothing to replay
        return lambda: None
    if len(replays) == 1:
        return replays[0]
    return _SplitReplay(replays, workers)


#: Items one thread of a blocked kernel (:func:`blocked_replayer`) takes on the CPU (1 on CUDA).
#: Warp's CPU launch calls the compiled kernel once a thread, and each call copies the kernel's
#: arguments into locals and constructs (zeroes) its vector and matrix locals, which costs more
#: than the work of a cheap item (the candy's edge queries: 1.6 ms a step one edge a thread,
#: 0.7 ms 64 edges a thread, same results).
ITEMS_A_CPU_THREAD = 64


def blocked_replayer(kernel, items: int, inputs: list, device: str, *, min_chunk: int = 1024) -> Callable[[], None]:
    """:func:`chunked_replayer` of a blocked kernel over ``items``: a thread takes ``block``
    items, from (``wp.tid()`` + offset) x ``block`` up to the item count the kernel reads from
    its arrays, its last two parameters ``block: int, offset: int``; ``block`` is
    :data:`ITEMS_A_CPU_THREAD` on the CPU and 1 on CUDA. ``min_chunk`` counts items."""
    block = ITEMS_A_CPU_THREAD if wp.get_device(device).is_cpu else 1
    return chunked_replayer(kernel, -(-items // block), [*inputs, block], device,
                            min_chunk=max(1, min_chunk // block))


def blocked_launch(kernel, items: int, inputs: list, device: str, *, min_chunk: int = 1024) -> None:
    """:func:`launch` of a blocked kernel over ``items`` (as :func:`blocked_replayer`, once): a
    thread takes ``block`` items, from (``wp.tid()`` + offset) x ``block`` up to the item count
    the kernel reads from its arrays, its last two parameters ``block: int, offset: int``;
    ``block`` is :data:`ITEMS_A_CPU_THREAD` on the CPU and 1 on CUDA. ``min_chunk`` counts items."""
    block = ITEMS_A_CPU_THREAD if wp.get_device(device).is_cpu else 1
    launch(kernel, -(-items // block), [*inputs, block], device, min_chunk=max(1, min_chunk // block))


def stride_threads(device: str, cuda_threads: int) -> int:
    """Threads of a launch whose threads stride over items up to a count the kernel reads (a
    step's contacts): ``cuda_threads`` on CUDA, one on the CPU, where such a launch replays on
    one core anyway and every thread costs a call of the compiled kernel (the shoulder's contact
    marking: 1 024 threads over ~200 contacts ~14 us, one thread ~7)."""
    return 1 if wp.get_device(device).is_cpu else int(cuda_threads)


class _SplitReplay:
    """The chunks of a split launch, replayed split (:class:`_SplitCall`) or all on the calling
    thread, whichever has taken less wall time of late: the results are the same either way
    (each thread writes its own outputs), but on a loaded machine a worker is scheduled late
    and the split took 1.9x the single thread's wall time (candy's Jacobi at load 6.5), while
    on an idle one it is about half of it. Each way's time is a moving average (weight
    :data:`SPLIT_AVERAGE`) and every :data:`SPLIT_PROBE`-th call times the other way."""

    __slots__ = ("replays", "workers", "seconds", "calls")

    def __init__(self, replays: list[Callable[[], None]], workers: int):
        self.replays, self.workers = replays, workers
        self.seconds = [0.0, 0.0]  # single, split; each tried once first
        self.calls = 0

    def __call__(self) -> None:
        self.calls += 1
        if self.calls <= 2:
            way = self.calls - 1
        else:
            best = int(self.seconds[1] < self.seconds[0])
            way = 1 - best if self.calls % SPLIT_PROBE == 0 else best
        start = time.perf_counter()
        if way:
            _run_split(self.replays, self.workers)
        else:
            for replay in self.replays:
                replay()
        took = time.perf_counter() - start
        self.seconds[way] = took if self.calls <= 2 else self.seconds[way] + SPLIT_AVERAGE * (took - self.seconds[way])


#: Weight of a call's wall time in the moving average of its way (:class:`_SplitReplay`).
SPLIT_AVERAGE = 0.25
#: Every this many calls a split replay times the way it does not take.
SPLIT_PROBE = 16


_SET = ("openblas_set_num_threads", "scipy_openblas_set_num_threads", "scipy_openblas_set_num_threads64_",
        "openblas_set_num_threads64_")
_GET = ("openblas_get_num_threads", "scipy_openblas_get_num_threads", "scipy_openblas_get_num_threads64_",
        "openblas_get_num_threads64_")


@lru_cache(maxsize=1)
def _openblas_controls() -> tuple:
    """(get, set) of every OpenBLAS loaded in this process (numpy's and SciPy's wheels each bundle one)."""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            paths = {line.split()[-1] for line in f if "openblas" in line.lower() and ".so" in line}
    except OSError:  # not Linux: leave the thread count alone
        return ()
    out = []
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        get = next((getattr(lib, n) for n in _GET if hasattr(lib, n)), None)
        put = next((getattr(lib, n) for n in _SET if hasattr(lib, n)), None)
        if get is not None and put is not None:
            get.restype, put.argtypes = ctypes.c_int, [ctypes.c_int]
            out.append((get, put))
    return tuple(out)


@contextmanager
def single_threaded_blas():
    """Run the body with OpenBLAS on one thread, then restore the previous thread counts.

    The contact solver works on many small dense and sparse systems (a Delassus matrix of a
    few hundred rows, a SuperLU solve per step) while :func:`launch` already keeps every core
    busy; OpenBLAS threads only add synchronisation there (the contact benchmark's cube runs
    1.3x faster on one BLAS thread, the soft-cube demo 2-6x on a busy machine).
    :meth:`softvr.Scene.step` runs in it. Linux only (elsewhere this does nothing).
    """
    import scipy.linalg  # noqa: F401, PLC0415 - load SciPy's OpenBLAS too, so it is limited as well

    controls = _openblas_controls()
    before = [get() for get, _ in controls]
    for _, put in controls:
        put(1)
    try:
        yield
    finally:
        for (_, put), n in zip(controls, before):
            put(max(int(n), 1))
