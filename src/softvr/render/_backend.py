"""Choosing a VTK OpenGL render window that works with or without a display.

VTK >= 9.4 PyPI wheels carry no OpenGL library of their own: they load one at run time
through one of three window classes of :mod:`vtkmodules.vtkRenderingOpenGL2`:

``vtkXOpenGLRenderWindow``
    On-screen (GLX); needs an X server (``DISPLAY``). Used by :mod:`softvr.render.viewer`.
``vtkEGLRenderWindow``
    Off-screen through ``libEGL.so.1`` (Debian: ``libegl1`` + ``libegl-mesa0`` +
    ``libgl1-mesa-dri``, which gives Mesa's llvmpipe software rasteriser when there is
    no GPU; the NVIDIA driver's EGL when there is one). No X server needed.
``vtkOSOpenGLRenderWindow``
    Off-screen through ``libOSMesa.so.8`` (Debian: ``libosmesa6``), always software.

The generic ``vtkRenderWindow()`` factory tries X first (printing "bad X server
connection" warnings when there is none) and then falls back; the environment variable
``VTK_DEFAULT_OPENGL_WINDOW`` overrides that, for the whole process. softvr instead
instantiates the off-screen classes directly, so no environment set-up is needed and an
interactive viewer can still open an X window in the same process:

1. ``SOFTVR_RENDER_BACKEND=egl`` or ``=osmesa`` forces one class (for debugging).
2. Otherwise EGL is tried first (it can use a GPU), then OSMesa. A class counts as working
   if its library can be loaded and a 2x2 test render raises no VTK error.

The choice is made once per process and cached; :func:`offscreen_backend` reports it.

Two limits of mixing kinds in one process (VTK 9.7, Mesa 22), both handled here:

* an on-screen GLX context cannot be created while an EGL context is current (X error
  BadAccess in ``glXMakeCurrent``), so off-screen renderers release their context after
  every frame (``ReleaseCurrent``); EGL and X windows then coexist;
* OSMesa and an on-screen window cannot be used in the same process at all (a segfault
  in the next on-screen render), so creating the second kind raises
  :class:`RenderBackendError` instead.
"""

from __future__ import annotations

import ctypes
import os
import sys
from functools import lru_cache

from softvr.errors import InputError, SoftvrError

__all__ = [
    "APT_PACKAGES",
    "RenderBackendError",
    "has_display",
    "new_offscreen_window",
    "new_onscreen_window",
    "offscreen_backend",
    "require_display",
]

#: Debian/Ubuntu packages that off-screen (EGL or OSMesa) and on-screen (X/GLX) rendering need.
APT_PACKAGES = (
    "libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 libgl1 libglx-mesa0 libx11-6 libxrender1 libxcursor1"
)

_BACKENDS = {
    "egl": ("vtkEGLRenderWindow", ("libEGL.so.1", "libEGL.so")),
    "osmesa": ("vtkOSOpenGLRenderWindow", ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")),
}


class RenderBackendError(SoftvrError, RuntimeError):
    """No usable OpenGL window: missing system libraries, or OSMesa mixed with an on-screen window."""


#: Window kinds created so far in this process ("egl", "osmesa", "onscreen").
_CREATED: set[str] = set()

_NO_MIX = (
    "VTK cannot use OSMesa and an on-screen window in the same process (their OpenGL "
    "functions clash and it crashes); run the viewer in its own process, or use EGL off-screen "
    "(install libegl1 libegl-mesa0 libgl1-mesa-dri)"
)


def _library_loads(names: tuple[str, ...]) -> bool:
    for name in names:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


def _window_class(backend: str):
    import vtkmodules.vtkRenderingOpenGL2 as gl  # noqa: PLC0415 - import VTK lazily

    return getattr(gl, _BACKENDS[backend][0], None)


def _probe(backend: str) -> str | None:
    """None if ``backend`` renders here, else the reason why not."""
    cls_name, libs = _BACKENDS[backend]
    if sys.platform.startswith("linux") and not _library_loads(libs):
        return f"cannot load {' or '.join(libs)}"
    cls = _window_class(backend)
    if cls is None:
        return f"this VTK build has no {cls_name}"
    if backend == "osmesa" and "onscreen" in _CREATED:
        return _NO_MIX
    _CREATED.add(backend)
    from vtkmodules.vtkRenderingCore import vtkRenderer  # noqa: PLC0415

    errors: list[str] = []
    window = cls()
    window.AddObserver("ErrorEvent", lambda obj, evt: errors.append(evt))
    window.SetOffScreenRendering(1)
    window.SetSize(2, 2)
    renderer = vtkRenderer()
    window.AddRenderer(renderer)
    try:
        window.Render()
        if not window.SupportsOpenGL():
            errors.append("no OpenGL 3.2 context")
    finally:
        window.RemoveRenderer(renderer)
        window.Finalize()
    return "; ".join(errors) if errors else None


@lru_cache(maxsize=None)
def offscreen_backend(preferred: str | None = None) -> str:
    """The off-screen window kind softvr renders with in this process.

    Parameters
    ----------
    preferred : {"egl", "osmesa"}, optional
        Try only this one. Default: ``$SOFTVR_RENDER_BACKEND`` if set, else EGL then OSMesa.

    Returns
    -------
    str
        ``"egl"`` or ``"osmesa"``.

    Raises
    ------
    RenderBackendError
        If none works; the message lists the Debian packages to install.

    Examples
    --------
    >>> from softvr.render import offscreen_backend
    >>> offscreen_backend() in ("egl", "osmesa")
    True
    """
    preferred = preferred or os.environ.get("SOFTVR_RENDER_BACKEND") or None
    if preferred is not None and preferred not in _BACKENDS:
        raise RenderBackendError(
            f"unknown render backend {preferred!r} (SOFTVR_RENDER_BACKEND): expected 'egl' or 'osmesa'"
        )
    reasons = []
    for name in [preferred] if preferred else list(_BACKENDS):
        reason = _probe(name)
        if reason is None:
            return name
        reasons.append(f"{name}: {reason}")
    raise RenderBackendError(
        "no off-screen OpenGL available (" + "; ".join(reasons) + "). On Debian/Ubuntu install: "
        f"apt-get install {APT_PACKAGES}"
    )


def new_offscreen_window(width: int, height: int, backend: str | None = None):
    """A new off-screen ``vtkOpenGLRenderWindow`` of ``width`` x ``height`` pixels.

    After rendering, call ``ReleaseCurrent()`` on it: an on-screen GLX context cannot be
    created (BadAccess) while an EGL context is current in the thread.
    """
    name = offscreen_backend(backend)
    if name == "osmesa" and "onscreen" in _CREATED:
        raise RenderBackendError(_NO_MIX)
    _CREATED.add(name)
    window = _window_class(name)()
    window.SetOffScreenRendering(1)
    window.SetSize(int(width), int(height))
    window.SetMultiSamples(0)
    return window


def has_display() -> bool:
    """True if an on-screen window can be opened: ``DISPLAY`` names a reachable X server.

    ``WAYLAND_DISPLAY`` alone is not enough: VTK's Linux wheels draw through X (XWayland
    provides ``DISPLAY`` on Wayland desktops). Other platforms are assumed to have a display.
    """
    if not sys.platform.startswith("linux"):
        return True
    if not os.environ.get("DISPLAY"):
        return False
    try:
        xlib = ctypes.CDLL("libX11.so.6")
    except OSError:
        return False
    xlib.XOpenDisplay.restype = ctypes.c_void_p
    xlib.XOpenDisplay.argtypes = [ctypes.c_char_p]
    xlib.XCloseDisplay.argtypes = [ctypes.c_void_p]
    dpy = xlib.XOpenDisplay(None)
    if not dpy:
        return False
    xlib.XCloseDisplay(dpy)
    return True


def new_onscreen_window(width: int, height: int):
    """A new on-screen render window (X/GLX on Linux); call only when :func:`has_display`."""
    if "osmesa" in _CREATED:
        raise RenderBackendError(_NO_MIX)
    _CREATED.add("onscreen")
    if sys.platform.startswith("linux"):
        import vtkmodules.vtkRenderingOpenGL2 as gl  # noqa: PLC0415

        window = gl.vtkXOpenGLRenderWindow()
    else:
        import vtkmodules.vtkRenderingOpenGL2  # noqa: F401, PLC0415 - registers the factory
        from vtkmodules.vtkRenderingCore import vtkRenderWindow  # noqa: PLC0415

        window = vtkRenderWindow()
    window.SetSize(int(width), int(height))
    return window


def require_display() -> None:
    """Raise :class:`InputError` unless an on-screen window can be opened."""
    if not has_display():
        found = "DISPLAY and WAYLAND_DISPLAY unset"
        if os.environ.get("DISPLAY"):
            found = f"DISPLAY={os.environ['DISPLAY']!r} but no X server answers there"
        elif os.environ.get("WAYLAND_DISPLAY"):
            found = "only WAYLAND_DISPLAY (VTK needs X; start XWayland so that DISPLAY is set)"
        raise InputError(
            "display",
            "a graphical display for the interactive viewer (for off-screen output, such as "
            "images and videos, run `softvr demo` instead)",
            found,
        )
