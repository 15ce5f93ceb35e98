"""Signal handlers for the length of a block: :func:`handled`, the one place excite installs
them (the command line's SIGTERM as Ctrl-C, a live session's stop on a signal, a finished
session's report written whatever comes).

Python installs handlers in the main thread only; elsewhere the block runs with the handlers
as they are.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

__all__ = ["handled"]

Handler = Callable[[int, Any], Any] | int


@contextmanager
def handled(signals: Sequence[signal.Signals], handler: Handler) -> Iterator[None]:
    """While inside: ``handler`` (a function of the signal number and frame, or
    ``signal.SIG_IGN``) for each of ``signals``; the previous handlers restored on the way
    out. Nothing is installed outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, handler) for s in signals}
    try:
        yield
    finally:
        for s, old in previous.items():
            signal.signal(s, old)
