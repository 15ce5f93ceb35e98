"""Worker processes and Ctrl-C. :func:`shut_down_now` ends a pool at once, for work whose
running tasks are of no use any more (a live session that ended, a comparison interrupted:
their results would not be kept), where ``ProcessPoolExecutor.shutdown`` would wait for them.
:func:`sigint_blocked` and :func:`deaf_to_sigint` keep a terminal's Ctrl-C, which reaches every
process of the job, from a worker still starting up (importing numpy, before its initializer
could ignore it): started with SIGINT blocked, it ignores it from its first instruction."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager

__all__ = ["deaf_to_sigint", "shut_down_now", "sigint_blocked"]

#: s to wait for each terminated worker to end.
JOIN_SECONDS = 2.0


def shut_down_now(pool: ProcessPoolExecutor) -> None:
    """Cancel the pool's pending tasks and terminate its workers (SIGTERM) without waiting for
    the tasks they run; each worker is waited for up to JOIN_SECONDS."""
    processes = list((getattr(pool, "_processes", None) or {}).values())  # CPython's
    calls = getattr(pool, "_call_queue", None)  # CPython's: the tasks' queue to the workers
    pool.shutdown(wait=False, cancel_futures=True)
    if calls is not None:  # its feeder thread is not joined at exit: the workers that would
        calls.cancel_join_thread()  # read what it still holds are terminated below
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(timeout=JOIN_SECONDS)


@contextmanager
def sigint_blocked() -> Iterator[None]:
    """SIGINT held back (pending, not lost) in this thread for the block: a process started
    inside it starts with SIGINT blocked too (the signal mask survives fork and exec), so that
    it cannot be interrupted before its initializer runs :func:`deaf_to_sigint`. A SIGINT that
    arrives meanwhile reaches this process when the block ends."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def deaf_to_sigint() -> None:
    """In a worker started under :func:`sigint_blocked`: SIGINT ignored (one pending since its
    start is discarded), then unblocked."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
