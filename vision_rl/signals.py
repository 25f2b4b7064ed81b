"""The first SIGINT or SIGTERM held until the run is consistent, then acted on as its own handler would have; a
second one acts at once. A signal whose handler is the system's (``SIG_DFL``, ``SIG_IGN``) is left alone: only what
would have raised in Python waits. An exception raised by a handler inside arbitrary code can leave that code's locks
taken (a train-repr run hung so in Lightning's teardown: docs/guarantees.md)."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class HeldSignal:
    """A SIGINT or SIGTERM waiting for :meth:`release`; install with :meth:`installed`."""

    def __init__(self) -> None:
        self.pending: tuple[int, Any] | None = None
        self._handlers: dict[int, Callable[[int, Any], Any]] = {}

    def _hold(self, signum: int, frame: Any) -> None:
        if self.pending is not None:  # the second signal: no more waiting
            self.pending = None
            self._handlers[signum](signum, frame)
            return
        self.pending = (signum, frame)

    def release(self) -> None:
        """Where the run is consistent: act on a held signal as its own handler would have (that may raise)."""
        if self.pending is not None:
            signum, frame = self.pending
            self.pending = None
            self._handlers[signum](signum, frame)

    @contextlib.contextmanager
    def installed(self) -> Iterator[HeldSignal]:
        """Hold the signals inside; on the way out, restore the handlers and act on one still held."""
        if threading.current_thread() is threading.main_thread():  # signals reach only the main thread
            for signum in _SIGNALS:
                handler = signal.getsignal(signum)
                if callable(handler):
                    self._handlers[signum] = handler
                    signal.signal(signum, self._hold)
        try:
            yield self
        finally:
            for signum, handler in self._handlers.items():
                signal.signal(signum, handler)
        self.release()
