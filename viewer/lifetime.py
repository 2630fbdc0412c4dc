"""How the viewer's process ends: when its window closes, on Ctrl-C or ``kill`` (SIGINT, SIGTERM), or when
its display goes away.

Open3D's ``Application.run()`` keeps the main thread in C++ until the last window closes, and Python runs a
signal's handler only in the main thread, between bytecodes: a viewer run that way ignores Ctrl-C and
``kill``. :meth:`Lifetime.run` turns the GUI loop itself (``run_one_tick``, which waits at most a few
milliseconds for events) so the handlers run between ticks; a signal closes the window, which ends the
loop, and the re-run child goes with the window (:mod:`viewer.rerun`).

A display that goes away (the X server ended or killed) leaves GLFW's loop without events and the process
alive. :class:`DisplayWatch` holds a connection of its own to the X server, with no events selected: the
server sends nothing on it until it closes it, so end-of-file there means the server is gone. A thread
looks every :data:`_DISPLAY_CHECK` seconds, since the main thread may be inside a call that never returns
once its display is gone; the process then ends at once (nothing can be drawn or closed any more), after
its re-run child. The viewer writes files only through atomic exports, so ending at any point leaves every
file whole.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import select
import signal
import socket
import sys
import threading
import time
from typing import Callable

# Seconds between two looks at the display connection.
_DISPLAY_CHECK = 0.25
# Seconds the window may take to close after a signal before the process ends without it.
_CLOSE_GRACE = 3.0


class DisplayWatch:
    """A connection of our own to the X server of ``display`` (default ``$DISPLAY``) that tells when the server
    has gone (module notes). Without an X server, or without libX11, it never says so."""

    def __init__(self, display: str | None = None):
        self._sock = None
        self._keep = None
        name = os.environ.get("DISPLAY") if display is None else display
        path = ctypes.util.find_library("X11")
        if not name or path is None:
            return
        x11 = ctypes.CDLL(path)
        x11.XOpenDisplay.restype = ctypes.c_void_p
        x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
        x11.XConnectionNumber.argtypes = [ctypes.c_void_p]
        dpy = x11.XOpenDisplay(name.encode())
        if not dpy:
            return
        self._keep = (x11, dpy)  # the connection stays open (never closed: Xlib must not touch it once lost)
        self._sock = socket.socket(fileno=os.dup(x11.XConnectionNumber(dpy)))

    def lost(self) -> bool:
        """Whether the server closed the connection (end-of-file on it)."""
        if self._sock is None:
            return False
        readable, _, _ = select.select([self._sock], [], [], 0.0)
        if not readable:
            return False
        try:
            return self._sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
        except BlockingIOError:
            return False
        except OSError:  # reset by the server
            return True


def _signal_name(signum: int) -> str:
    return signal.Signals(signum).name


class Lifetime:
    """SIGINT and SIGTERM taken as requests to close the window, from entering the ``with`` block (before the
    window is made, so that a signal while it loads is not lost) to leaving it, which restores the previous
    handlers; :meth:`run` runs the GUI loop (module notes)."""

    def __init__(self, watch: DisplayWatch | None = None, say: Callable[[str], None] | None = None):
        self.received: list[int] = []
        self._watch = watch
        self._say = say or (lambda text: print(f"fracref view: {text}", file=sys.stderr, flush=True))
        self._previous: dict = {}

    def __enter__(self) -> "Lifetime":
        def on_signal(signum, _frame):
            self.received.append(signum)

        self._previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(self, *exc) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)

    def run(self, app, close: Callable[[], None], on_exit: Callable[[], None]) -> int:
        """Run the GUI loop of ``app`` (an initialised ``open3d.visualization.gui.Application`` with its window)
        until its last window closes: 0, or ``128 + signal`` after SIGINT or SIGTERM, which call ``close()``
        (the window's close, on the GUI thread between ticks). ``on_exit()`` ends what the window started (the
        re-run child); it runs after the loop, or before the process ends when the display is lost (exit
        status 1)."""
        done = threading.Event()
        watch = self._watch if self._watch is not None else DisplayWatch()

        def watch_display():
            while not done.wait(_DISPLAY_CHECK):
                if watch.lost():
                    self._say("the display went away; the viewer ends")
                    try:
                        on_exit()
                    finally:
                        os._exit(1)

        threading.Thread(target=watch_display, name="fracref-display-watch", daemon=True).start()
        closing_since = None
        try:
            while app.run_one_tick():
                if self.received and closing_since is None:
                    self._say(f"{signal.Signals(self.received[0]).name} received; closing the window")
                    closing_since = time.monotonic()
                    close()
                elif closing_since is not None and time.monotonic() - closing_since > _CLOSE_GRACE:
                    break  # the window did not close: end without it
            on_exit()
        finally:
            done.set()
        return 128 + self.received[0] if self.received else 0
