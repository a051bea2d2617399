"""Playing a simulation live in an on-screen window: one frame per timer tick."""

from __future__ import annotations

import time

__all__ = ["play"]


def play(window, advance, *, period_ms: int, timeout_s: float | None = None, keys: dict | None = None,
         on_exit=None, setup=None) -> None:
    """Run ``window``'s event loop, calling ``advance()`` (step and draw one frame) every
    ``period_ms`` until the window closes or ``timeout_s`` pass. Mouse: trackball camera;
    space pauses and resumes, ``n`` advances one frame while paused, ``q`` quits; ``keys``
    maps more characters to callables (overlay toggles); ``on_exit()`` runs when ``timeout_s``
    ends the loop, the window still up (a screenshot); ``setup(interactor, style)`` adds
    observers of its own (mouse tools) before the loop starts. The observers and the window are released on the
    way out."""
    from vtkmodules.vtkInteractionStyle import vtkInteractorStyleTrackballCamera  # noqa: PLC0415
    from vtkmodules.vtkRenderingCore import vtkRenderWindowInteractor  # noqa: PLC0415

    interactor = vtkRenderWindowInteractor()
    interactor.SetRenderWindow(window)
    style = vtkInteractorStyleTrackballCamera()
    interactor.SetInteractorStyle(style)
    state = {"paused": False}
    deadline = None if timeout_s is None else time.perf_counter() + timeout_s

    def on_timer(*_) -> None:
        if deadline is not None and time.perf_counter() >= deadline:
            if on_exit is not None:  # while the window is still up and drawn
                on_exit()
            interactor.TerminateApp()
        elif not state["paused"]:
            advance()

    def on_char(*_) -> None:
        key = interactor.GetKeyCode()
        if key == " ":
            state["paused"] = not state["paused"]
        elif key == "n" and state["paused"]:
            advance()
        elif keys and key in keys:
            keys[key]()
            window.Render()
        else:
            style.OnChar()

    interactor.Initialize()
    if setup is not None:
        setup(interactor, style)
    interactor.AddObserver("TimerEvent", on_timer)
    style.AddObserver("CharEvent", on_char)
    interactor.CreateRepeatingTimer(max(1, int(period_ms)))
    try:
        interactor.Start()
    finally:
        # VTK holds the observers (closures over the interactor): break the cycle now so the
        # window and its X connection are freed before the X server may be gone.
        style.RemoveAllObservers()
        interactor.RemoveAllObservers()
        interactor.SetRenderWindow(None)
