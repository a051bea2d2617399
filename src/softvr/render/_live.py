"""softvr's one on-screen event loop: ``softvr view SCENE`` plays a player in it
(:func:`softvr.app.play_window`), ``softvr view VOLUME`` drags mesh nodes in it
(:class:`~softvr.render.VolumeViewer`)."""

from __future__ import annotations

import time

__all__ = ["LiveWindow"]


class LiveWindow:
    """The event loop of an on-screen VTK render window: the trackball camera (left rotates,
    right zooms, middle pans) and softvr's keys.

    The interactor and its style are made here, before the loop runs, so that a caller adds its
    own mouse observers to :attr:`interactor` / :attr:`style` and a test drives them with
    synthetic events (``interactor.SetEventInformation`` + ``InvokeEvent``) without a loop.
    Keys: while :meth:`run` plays an ``advance``, space pauses and resumes it and ``n`` advances
    one frame while paused; ``keys`` maps more characters to callables (overlay toggles, a
    reset), each followed by ``render()``; any other key is the trackball style's (``q`` / ``e``
    quit, ``r`` resets the view). :meth:`close` releases the observers.

    Parameters
    ----------
    window : vtkRenderWindow
        An on-screen window (:func:`~softvr.render.require_display` first).
    keys : dict of str -> callable, optional
    render : callable, optional
        Draws the window after a key (default ``window.Render``).
    """

    def __init__(self, window, keys: dict | None = None, *, render=None):
        from vtkmodules.vtkInteractionStyle import vtkInteractorStyleTrackballCamera  # noqa: PLC0415
        from vtkmodules.vtkRenderingCore import vtkRenderWindowInteractor  # noqa: PLC0415

        self.window = window
        self.keys = dict(keys or {})
        self.render = render if render is not None else window.Render
        self.interactor = vtkRenderWindowInteractor()
        self.interactor.SetRenderWindow(window)
        self.style = vtkInteractorStyleTrackballCamera()
        self.interactor.SetInteractorStyle(self.style)
        self.paused = False
        self._advance = None
        # (VTK takes event names as well as ids; its stubs list the ids only.)
        self.style.AddObserver("CharEvent", self._on_char)  # type: ignore[arg-type]

    def _on_char(self, *_) -> None:
        key = self.interactor.GetKeyCode()
        if key == " " and self._advance is not None:
            self.paused = not self.paused
        elif key == "n" and self.paused and self._advance is not None:
            self._advance()
        elif key in self.keys:
            self.keys[key]()
            self.render()
        else:
            self.style.OnChar()

    def run(self, advance=None, *, period_ms: int = 50, timeout_s: float | None = None, on_exit=None) -> None:
        """Run the loop until the window closes or ``timeout_s`` pass, calling ``advance()`` (step
        and draw one frame) every ``period_ms`` unless paused; ``on_exit()`` runs when
        ``timeout_s`` ends the loop, the window still up and drawn (a screenshot)."""
        deadline = None if timeout_s is None else time.perf_counter() + timeout_s

        def on_timer(*_) -> None:
            if deadline is not None and time.perf_counter() >= deadline:
                if on_exit is not None:
                    on_exit()
                self.interactor.TerminateApp()
            elif advance is not None and not self.paused:
                advance()

        self._advance = advance
        self.interactor.Initialize()
        timer = None
        if advance is not None or deadline is not None:
            timer = (self.interactor.AddObserver("TimerEvent", on_timer),  # type: ignore[arg-type]  # (an event name)
                     self.interactor.CreateRepeatingTimer(max(1, int(period_ms))))
        try:
            self.interactor.Start()
        finally:
            self._advance = None
            if timer is not None:  # a later run starts with none of this run's ticks
                self.interactor.RemoveObserver(timer[0])
                self.interactor.DestroyTimer(timer[1])

    def close(self) -> None:
        """Release the observers and the window: VTK holds them (bound methods and closures over
        the interactor), a cycle Python cannot collect; broken now, the window and its X
        connection are freed before the X server may be gone. The callables go too: one that is
        a bound method of the window's owner is a cycle the garbage collector would free later,
        inside whichever VTK event loop runs then (a segfault in the next window's loop)."""
        self.keys.clear()
        self.render = None
        self.style.RemoveAllObservers()
        self.interactor.RemoveAllObservers()
        # (None lets go of them; VTK's stubs do not say None is accepted.)
        self.interactor.SetRenderWindow(None)  # type: ignore[arg-type]
        self.interactor.SetInteractorStyle(None)  # type: ignore[arg-type]
