"""Shared fixtures: the Warp devices every kernel test runs on, and a private Xvfb X server
for the on-screen windows."""

import ctypes
import os
import shutil
import signal
import subprocess
import time

import pytest
import warp as wp

wp.config.quiet = True
wp.config.log_level = wp.LOG_WARNING
wp.init()

DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


def pytest_addoption(parser):
    parser.addoption("--host-copies", action="store_true",
                     help="step every scene's node arrays through host copies (what a CUDA step does), on the CPU")
    parser.addoption("--gpu-forms", action="store_true",
                     help="step every scene's node arrays with the GPU's forms of the kernels (a thread per contact, "
                          "candidate pair or node), on the CPU")
    parser.addoption("--cpu-blocks", action="store_true",
                     help="run the lanes of every thread block (the GPU forms' one-block sweeps) as Warp's cooperative "
                          "CPU fibers, as a GPU's block runs them, instead of one lane")


def pytest_collection_modifyitems(config, items):
    if not config.getoption("--host-copies"):
        return
    skip = pytest.mark.skip(reason="drives the CPU's own node arrays directly (--host-copies: they are copies)")
    for item in items:
        if "cpu_arrays" in item.keywords:
            item.add_marker(skip)


def _every_stepper_sets(monkeypatch, attribute: str) -> None:
    """Set ``Scene.<attribute>`` True on every scene a NodeStepper is built for."""
    from softvr.sim import _node_step

    original = _node_step.NodeStepper.__init__

    def setting(self, scene, *args, **kwargs):
        setattr(scene, attribute, True)
        original(self, scene, *args, **kwargs)

    monkeypatch.setattr(_node_step.NodeStepper, "__init__", setting)


@pytest.fixture(autouse=True)
def _node_host_copies(request, monkeypatch):
    """With ``--host-copies``: every NodeStepper keeps host copies of its arrays, so the
    suite's physics checks run a CUDA step's host traffic (push / pull) where no GPU is."""
    if request.config.getoption("--host-copies"):
        _every_stepper_sets(monkeypatch, "_host_copies")


@pytest.fixture(autouse=True)
def _node_gpu_forms(request, monkeypatch):
    """With ``--gpu-forms``: every node step takes the kernels' GPU forms (a thread per contact,
    candidate pair or node instead of one thread walking them: the contact step's Jacobi passes on
    split masses, the gather, the carry, the coarse and share sums, adhesion's evolve), on the CPU."""
    if request.config.getoption("--gpu-forms"):
        _every_stepper_sets(monkeypatch, "_gpu_forms")


@pytest.fixture(autouse=True)
def _cpu_blocks(request, monkeypatch):
    """With ``--cpu-blocks``: a block launched with many lanes runs them all on the CPU, as
    cooperative fibers switching at its barriers (``wp.config.enable_cpu_blocks``), so the GPU
    forms' one-block sweeps take the lanes, and the lane-to-lane semantics, a GPU's block takes."""
    if request.config.getoption("--cpu-blocks"):
        monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)


@pytest.fixture(params=DEVICES)
def device(request):
    """Each kernel test runs once per available Warp device (CPU always, CUDA when present)."""
    return request.param


def _die_with_parent() -> None:
    """In the child: get SIGTERM when the test process dies, even abruptly (Linux).

    An X client that loses its server, or an X protocol error, makes Xlib call exit()
    without running fixture teardown; this keeps Xvfb from outliving the tests then.
    """
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


@pytest.fixture(scope="session")
def xvfb_display():
    """Start a private Xvfb server; yield its DISPLAY string (e.g. ':3')."""
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.skip("Xvfb is not installed (Debian package xvfb)")
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen(
        [exe, "-displayfd", str(write_fd), "-screen", "0", "1024x768x24", "-nolisten", "tcp", "-noreset"],
        pass_fds=(write_fd,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        preexec_fn=_die_with_parent,
    )
    os.close(write_fd)
    number = b""
    deadline = time.monotonic() + 20
    with os.fdopen(read_fd, "rb") as pipe:
        while not number.endswith(b"\n") and time.monotonic() < deadline:
            chunk = pipe.read(1)
            if not chunk:
                break
            number += chunk
    if not number.strip():
        proc.kill()
        pytest.fail("Xvfb did not report a display number")
    try:
        yield f":{number.decode().strip()}"
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


@pytest.fixture
def display(xvfb_display, monkeypatch):
    """DISPLAY set to the private Xvfb server for one test."""
    monkeypatch.setenv("DISPLAY", xvfb_display)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    return xvfb_display
