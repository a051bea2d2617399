"""Shared fuzz harness: run a reader or a ``softvr`` command on untrusted inputs in a child
process with a wall-clock timeout and an address-space limit, and classify what happened.

Outcomes (:class:`Outcome.kind`):

``ok``        the reader returned / the command exited 0
``clean``     a refusal: a :class:`softvr.errors.SoftvrError` (reader) or exit status 2 with
              ``softvr CMD: error: ...`` and no traceback (command)
``traceback`` any other exception, or a traceback on stderr
``exit``      the reader called ``sys.exit`` (e.g. meshio on an unreadable file)
``crash``     the child died by a signal (SIGSEGV, SIGABRT, ...)
``hang``      it ran past the timeout (killed)
``memory``    a ``MemoryError`` (the allocation hit the limit) or peak RSS above the limit

Readers run many inputs per child (``run_reader``): the child reports each outcome as one
JSON line, so only the inputs that kill it (crash, hang) cost a restart. Usage::

    from harness import run_reader, run_cli, summary
    outcomes = run_reader("softvr.scene.schema:read_scene", paths)
    assert summary(outcomes)["bad"] == [], summary(outcomes)

The tests import this module by its name (``tests/`` holds no packages; pytest puts the
test's folder on ``sys.path``).
"""

from __future__ import annotations

import json
import os
import resource
import selectors
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["MEMORY_LIMIT", "Outcome", "names_file_and_field", "run_cli", "run_reader", "summary"]

#: Address-space limit of a fuzz child [bytes] (RLIMIT_AS). Python + NumPy + Warp + VTK
#: import reserves ~1.5 GiB of virtual memory; an input that makes a reader allocate beyond
#: this fails with MemoryError (classified ``memory``) instead of exhausting the machine.
MEMORY_LIMIT = int(os.environ.get("SOFTVR_FUZZ_MEMORY", 4 << 30))
#: Peak resident memory a child may reach [bytes] before its outcome counts as ``memory``.
RSS_LIMIT = int(os.environ.get("SOFTVR_FUZZ_RSS", 1536 << 20))
BAD_KINDS = ("traceback", "exit", "crash", "hang", "memory")
_RESTART = 75  # a worker's exit status asking for a fresh child (it reported its last input)


@dataclass
class Outcome:
    """What one input did. ``detail`` is the error message (clean), the traceback or the
    stderr tail; ``what`` / ``source`` the InputError's field and file (readers only)."""

    label: str
    kind: str
    detail: str = ""
    what: str | None = None
    source: str | None = None
    seconds: float = 0.0
    rss_bytes: int = 0
    extra: dict = field(default_factory=dict)


def _limits(memory_bytes: int):
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # a crash must not write a core file
        os.setsid()  # its own process group: a hang is killed with everything it started
    return apply


def _env(env: dict | None) -> dict:
    merged = dict(os.environ)
    # No thread pools sized for the whole machine (each reserves address space), no GPU.
    merged.update({"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                   "CUDA_VISIBLE_DEVICES": "", "PYTHONFAULTHANDLER": "", "PYTHONUNBUFFERED": "1"})
    merged.update(env or {})
    return merged


def _kill(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def _reap(proc: subprocess.Popen, rss_file: str | None = None) -> tuple[int, int]:
    """(return code, peak RSS [bytes]) of a finished or killed child: the peak the child wrote
    to ``rss_file`` at its exit (:func:`_own_peak_rss`), 0 when it wrote none (killed)."""
    _, status, _ = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    try:
        return proc.returncode, int(Path(rss_file).read_text() or 0) if rss_file else 0
    except (OSError, ValueError):
        return proc.returncode, 0


def _own_peak_rss() -> int:
    """This process's own peak resident memory [bytes] (Linux ``VmHWM``). Not ``ru_maxrss``:
    that keeps the forking parent's resident size across exec, so under a pytest process of
    1.5 GiB every child would count as over the limit."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def run_cli(args: list[str], *, label: str | None = None, timeout_s: float = 60.0,
            memory_bytes: int = MEMORY_LIMIT, cwd=None, env: dict | None = None) -> Outcome:
    """``python -m softvr ARGS`` in a limited child; its outcome (module docstring)."""
    label = label or " ".join(map(str, args))
    start = time.monotonic()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err, \
            tempfile.NamedTemporaryFile(suffix=".rss") as rss_file:
        # ``softvr ARGS`` run by this file's --cli mode, which writes its own peak RSS at exit.
        proc = subprocess.Popen([sys.executable, __file__, "--cli", rss_file.name, *map(str, args)],
                                stdin=subprocess.DEVNULL, stdout=out, stderr=err, cwd=cwd, env=_env(env),
                                preexec_fn=_limits(memory_bytes))
        hung = False
        while os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is None:
            if time.monotonic() - start > timeout_s:
                hung = True
                _kill(proc)
                break
            time.sleep(0.02)
        code, rss = _reap(proc, rss_file.name)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read().decode("utf-8", "replace"), err.read().decode("utf-8", "replace")
    kind, tail = _classify(code, rss, hung, stderr, timeout_s)
    if kind is None:
        if "Traceback (most recent call last)" in stderr or "internal error" in stderr:
            kind = "traceback"
        elif code == 0:
            kind = "ok"
        elif code == 2 and ": error: " in stderr:
            kind = "clean"
        else:
            kind, tail = "exit", f"exit status {code}\n{tail}"
    return Outcome(label, kind, tail.strip(), seconds=time.monotonic() - start, rss_bytes=rss,
                   extra={"stdout": stdout[-2000:], "code": code})


def _classify(code: int, rss: int, hung: bool, stderr: str, timeout_s: float) -> tuple[str | None, str]:
    """hang / crash / memory from how a child ended; (None, stderr tail) otherwise."""
    tail = stderr[-2000:]
    if hung:
        return "hang", f"no answer within {timeout_s} s\n{tail}"
    if code < 0:
        return "crash", f"signal {signal.Signals(-code).name}\n{tail}"
    if "MemoryError" in stderr or rss > RSS_LIMIT:
        return "memory", f"peak RSS {rss >> 20} MiB\n{tail}"
    return None, tail


def run_reader(target: str, inputs: list, *, labels: list[str] | None = None, timeout_s: float = 20.0,
               memory_bytes: int = MEMORY_LIMIT, env: dict | None = None, startup_s: float = 60.0) -> list[Outcome]:
    """``module:function`` called on each of ``inputs`` (paths or JSON values) in children that
    each take as many inputs as they survive; one :class:`Outcome` per input, in order.

    ``timeout_s`` [s] bounds one input, ``startup_s`` [s] the child's imports."""
    labels = [str(x) for x in inputs] if labels is None else labels
    outcomes: list = [None] * len(inputs)
    todo = 0
    while todo < len(inputs):
        todo = _batch(target, inputs, labels, todo, outcomes, timeout_s, startup_s, memory_bytes, env)
    return outcomes


def _batch(target, inputs, labels, first, outcomes, timeout_s, startup_s, memory_bytes, env) -> int:
    """Run inputs[first:] in one child until it ends; fill ``outcomes``; the next index to run."""
    with tempfile.NamedTemporaryFile("w", suffix=".json") as todo, tempfile.TemporaryFile() as err:
        json.dump([str(x) if isinstance(x, Path) else x for x in inputs[first:]], todo)
        todo.flush()
        proc = subprocess.Popen([sys.executable, __file__, target, todo.name], stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=err, env=_env(env), preexec_fn=_limits(memory_bytes))
        index, hung, started, seen_rss = first, False, time.monotonic(), 0
        deadline = started + startup_s + timeout_s
        buffer = b""
        with selectors.DefaultSelector() as sel:
            sel.register(proc.stdout, selectors.EVENT_READ)
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    hung = True
                    _kill(proc)
                    break
                if not sel.select(timeout=left):
                    continue
                chunk = os.read(proc.stdout.fileno(), 1 << 16)
                if not chunk:
                    break
                buffer += chunk
                while b"\n" in buffer:
                    line, buffer = buffer.split(b"\n", 1)
                    record = json.loads(line)
                    if not record.get("ready"):
                        outcomes[index] = Outcome(labels[index], record["kind"], record.get("detail", ""),
                                                  record.get("what"), record.get("source"), record["seconds"],
                                                  record["rss"], {"fields": record.get("fields", [])})
                        index += 1
                        seen_rss = max(seen_rss, record["rss"])
                    started = time.monotonic()
                    deadline = started + timeout_s
        proc.stdout.close()
        code, _ = _reap(proc)
        rss = seen_rss  # the child's own peak by its last report (a killed child writes nothing)
        err.seek(0)
        stderr = err.read().decode("utf-8", "replace")
    if index >= len(inputs) or (code == _RESTART and not hung):
        return index
    # The child ended (or was killed) while reading inputs[index]: that input is the culprit.
    kind, detail = _classify(code, rss, hung, stderr, timeout_s)
    if kind is None:
        kind, detail = "exit", f"exit status {code}\n{detail}"
    outcomes[index] = Outcome(labels[index], kind, detail.strip(), seconds=time.monotonic() - started, rss_bytes=rss)
    return index + 1


def names_file_and_field(outcome: Outcome, path) -> bool:
    """Whether a clean refusal names the input file (its name) and a field: a reader's
    InputError its ``what`` and every one of its problems' fields; a command's message
    ``FILE...: FIELD: expected``."""
    name = Path(path).name
    if outcome.what is not None:  # a reader's InputError
        fields = outcome.extra.get("fields") or [outcome.what]
        return outcome.source is not None and name in outcome.source and all(fields)
    return name in outcome.detail and ": expected " in outcome.detail


def summary(outcomes: list[Outcome], paths: list | None = None) -> dict:
    """Counts per kind; ``bad``: the outcomes that are not ok / clean (at most 20 shown);
    ``unnamed``: clean refusals that do not name file and field (with ``paths``)."""
    counts: dict = {}
    for o in outcomes:
        counts[o.kind] = counts.get(o.kind, 0) + 1
    bad = [(o.label, o.kind, o.detail[-600:]) for o in outcomes if o.kind in BAD_KINDS]
    result = {"inputs": len(outcomes), "counts": counts, "bad": bad[:20], "n_bad": len(bad),
              "seconds": round(sum(o.seconds for o in outcomes), 2)}
    if paths is not None:
        unnamed = [(o.label, o.detail[-300:]) for o, p in zip(outcomes, paths)
                   if o.kind == "clean" and not names_file_and_field(o, p)]
        result["unnamed"], result["n_unnamed"] = unnamed[:20], len(unnamed)
    return result


def _worker(target: str, todo: str) -> None:
    """The child: call ``target`` on each input of the JSON list in the file ``todo``; one JSON
    line per input on the original stdout (the reader's own prints go to stderr)."""
    import importlib
    import traceback

    report = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    module, _, name = target.partition(":")
    func = getattr(importlib.import_module(module), name)
    from softvr.errors import SoftvrError

    report.write(json.dumps({"ready": True}) + "\n")
    report.flush()
    for item in json.loads(Path(todo).read_text()):
        start = time.monotonic()
        record: dict = {"kind": "ok"}
        try:
            func(item)
        except SoftvrError as exc:
            record = {"kind": "clean", "detail": str(exc), "what": getattr(exc, "what", ""),
                      "source": getattr(exc, "source", None),
                      "fields": [p[0] for p in getattr(exc, "problems", [])]}
        except MemoryError:
            record = {"kind": "memory", "detail": traceback.format_exc()[-2000:]}
        except SystemExit as exc:
            record = {"kind": "exit", "detail": f"sys.exit({exc.code!r})\n{traceback.format_exc()[-1500:]}"}
        except BaseException:  # noqa: BLE001 - classifying every other exception is the point
            record = {"kind": "traceback", "detail": traceback.format_exc()[-2000:]}
        record["seconds"] = time.monotonic() - start
        # The child's peak resident memory so far: an input that pushed it over the limit
        # allocated what it asked for without a check, even if it then failed cleanly.
        record["rss"] = _own_peak_rss()
        if record["rss"] > RSS_LIMIT and record["kind"] in ("ok", "clean"):
            record = {**record, "kind": "memory", "detail": f"peak RSS {record['rss'] >> 20} MiB after: "
                                                            f"{record.get('detail', '')}"}
        report.write(json.dumps(record) + "\n")
        report.flush()
        if record["rss"] > RSS_LIMIT:
            os._exit(_RESTART)  # a fresh child for the next input: its peak RSS starts low again


def _cli(rss_file: str, args: list[str]) -> None:
    """The child of :func:`run_cli`: ``python -m softvr ARGS``, then its own peak RSS into
    ``rss_file`` (also when the command exits by ``sys.exit``)."""
    import atexit
    import runpy

    atexit.register(lambda: Path(rss_file).write_text(str(_own_peak_rss())))
    sys.argv = ["softvr", *args]
    runpy.run_module("softvr", run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    if sys.argv[1] == "--cli":
        _cli(sys.argv[2], sys.argv[3:])
    else:
        _worker(sys.argv[1], sys.argv[2])
