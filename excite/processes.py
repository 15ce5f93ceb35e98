"""Process pools ended at once: :func:`shut_down_now`, for work whose running tasks are of no
use any more (a live session that ended, a comparison interrupted: their results would not be
kept), where ``ProcessPoolExecutor.shutdown`` would wait for them."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

__all__ = ["shut_down_now"]

#: s to wait for each terminated worker to end.
JOIN_SECONDS = 2.0


def shut_down_now(pool: ProcessPoolExecutor) -> None:
    """Cancel the pool's pending tasks and terminate its workers (SIGTERM) without waiting for
    the tasks they run; each worker is waited for up to JOIN_SECONDS."""
    processes = list((getattr(pool, "_processes", None) or {}).values())  # CPython's
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(timeout=JOIN_SECONDS)
