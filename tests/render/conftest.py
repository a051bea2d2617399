"""Fixtures for the rendering tests: synthetic volumes and a private Xvfb X server."""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import subprocess
import time

import numpy as np
import pytest

from softvr.render import Preset
from softvr.volume import Volume

#: White where the value is >= 0.5, fully opaque, no shading: pixels are 0 or 255.
OPAQUE = Preset(
    "opaque",
    colors=((0.0, 1.0, 1.0, 1.0), (1.0, 1.0, 1.0, 1.0)),
    opacities=((0.0, 0.0), (0.499, 0.0), (0.501, 1.0), (1.0, 1.0)),
    shade=False,
)


def sphere_volume(radius: float, spacing, shape, origin=None) -> Volume:
    """float32 volume: 1 at voxel centres within ``radius`` of the grid centre, 0 elsewhere.

    With ``origin=None`` the grid centre is at world (0, 0, 0).
    """
    spacing = np.asarray(spacing, float)
    shape = np.asarray(shape)
    centre = (shape - 1) / 2 * spacing
    axes = [np.arange(n) * s - c for n, s, c in zip(shape, spacing, centre)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    data = (x**2 + y**2 + z**2 <= radius**2).astype(np.float32)
    return Volume(data, spacing=spacing, origin=-centre if origin is None else origin)


def ct_phantom(n: int = 40) -> Volume:
    """A small int16 'head' in Hounsfield units: soft tissue, a skull shell and a bony nose (+y)."""
    c = (n - 1) / 2
    x, y, z = np.meshgrid(*(np.arange(n) - c,) * 3, indexing="ij")
    r = np.sqrt((x / 1.0) ** 2 + (y / 1.15) ** 2 + (z / 1.05) ** 2)
    data = np.full((n, n, n), -1000, np.int16)
    data[r < 0.45 * n] = 40
    data[(r < 0.40 * n) & (r > 0.33 * n)] = 1200
    data[(np.abs(x) < 0.06 * n) & (y > 0.3 * n) & (y < 0.5 * n) & (np.abs(z) < 0.12 * n)] = 700
    return Volume(data, spacing=(1.0, 1.0, 1.2), origin=(-c, -c, -1.2 * c))


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


@pytest.fixture
def opaque_preset() -> Preset:
    """The :data:`OPAQUE` transfer function."""
    return OPAQUE


@pytest.fixture
def make_sphere():
    """The :func:`sphere_volume` factory."""
    return sphere_volume


@pytest.fixture
def phantom() -> Volume:
    """A 40^3 int16 CT phantom (see :func:`ct_phantom`)."""
    return ct_phantom()
