"""Execution backends: run independent tasks on this machine's cores or on a Ray cluster.

Both backends take a module-level function and one argument tuple per task, and yield each
task's result as soon as that task finishes (completion order, not submission order), so a
caller can write finished work at once and an interrupted run loses only unfinished tasks.

- ``local``: a pool of worker processes on this machine (``workers``, default all cores).
  Process start-up is paid once per worker and a task costs about a millisecond of overhead.
  A worker exits within :data:`ORPHAN_CHECK_SECONDS` of its parent's death (a killed
  ``compare`` leaves no workers behind).
- ``ray``: Ray tasks, one CPU each. The cluster is found by Ray's own conventions
  (:func:`connect_ray`): ``--address ADDR``, else the ``RAY_ADDRESS`` environment variable,
  else the latest cluster started on this machine by ``ray start``, else a new local Ray. A
  Ray task costs milliseconds of scheduling and serialisation, more across machines, so
  callers give it at least :data:`RAY_TASK_SECONDS` of work (:func:`chunk_size`). Every node
  must have excite (same version) and its extras installed; a Ray already initialised in this
  process (``ray.init`` by the caller) is used as it is.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from contextlib import contextmanager
from typing import Any

from excite.errors import ExciteError
from excite.processes import shut_down_now

LOCAL, RAY = BACKENDS = ("local", "ray")
#: Least work (s) per Ray task, so scheduling and serialisation (milliseconds per task, more
#: between machines) stay a small fraction of the run.
RAY_TASK_SECONDS = 1.0
#: s between a local worker's checks that its parent is alive.
ORPHAN_CHECK_SECONDS = 1.0


def _start_worker() -> None:
    """Initializer of a local worker: a daemon thread ends the process when its parent is
    gone (reparented: the parent was killed, so no one will read its results); SIGTERM ends
    it (a forked worker inherits the command line's SIGTERM-as-Ctrl-C, under which a worker
    told to stop went on to its next task), and SIGINT is left to the parent, which ends the
    workers when it is interrupted (a terminal's Ctrl-C reaches every process of the job)."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(ORPHAN_CHECK_SECONDS)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="excite-orphan-check").start()


class BackendError(ExciteError, ValueError):
    """An unknown backend, or a Ray cluster that cannot be reached."""


def chunk_size(task_seconds: float, item_seconds: float) -> int:
    """Items per task so that a task carries at least ``task_seconds`` of work when each item
    costs ``item_seconds`` (measured); 1 when ``task_seconds`` is 0."""
    if task_seconds <= 0 or item_seconds <= 0:
        return 1
    return max(1, math.ceil(task_seconds / item_seconds))


def connect_ray(address: str | None = None) -> bool:
    """Connect this process to Ray (unless it already is): ``ray.init(address=address)``,
    which follows Ray's conventions (``address`` or ``"auto"``, else ``RAY_ADDRESS``, else the
    latest ``ray start`` cluster of this machine, else a new local Ray; ``"local"`` always
    starts a new one). Returns whether this call connected (so the caller shuts it down)."""
    import ray

    if ray.is_initialized():
        return False
    _check_reachable(address or os.environ.get("RAY_ADDRESS"))
    main = threading.current_thread() is threading.main_thread()
    on_term = signal.getsignal(signal.SIGTERM) if main else None
    try:
        ray.init(address=address, logging_level=logging.ERROR, include_dashboard=False)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = address or os.environ.get("RAY_ADDRESS") or "a local Ray"
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise BackendError(f"cannot connect to Ray at {where}: {message}") from None
    finally:
        if main and on_term is not None:  # ray.init's own SIGTERM handler exits at once;
            signal.signal(signal.SIGTERM, on_term)  # the caller's ends Ray in ray_session
    return True


def _check_reachable(address: str | None, timeout: float = 5.0) -> None:
    """BackendError at once when a HOST:PORT address (``ray://`` too) has nothing listening
    (Ray itself retries for minutes); the words ``auto`` and ``local`` pass."""
    if not address or address in ("auto", "local"):
        return
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit() or not host:
        raise BackendError(f"Ray address {address!r} is not HOST:PORT, auto or local")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise BackendError(f"cannot connect to Ray at {address}: nothing answers there "
                           f"({exc.strerror or exc}); start it with ray start --head") from None


@contextmanager
def ray_session(address: str | None = None) -> Iterator[None]:
    """Ray connected for the duration of the block (see :func:`connect_ray`); shut down at
    the end only if the block connected it."""
    import ray

    started = connect_ray(address)
    try:
        yield
    finally:
        if started:
            ray.shutdown()


class Executor:
    """A backend ready to run tasks (made by :func:`open_backend`)."""

    #: Least work (s) a task should carry on this backend (0: any size).
    task_seconds: float = 0.0

    def imap_unordered(self, fn: Callable[..., Any],
                       tasks: Sequence[tuple]) -> Iterator[Any]:
        """``fn(*task)`` for every task, each result yielded as its task finishes."""
        raise NotImplementedError


class _LocalExecutor(Executor):
    def __init__(self, pool: ProcessPoolExecutor):
        self.pool, self.pending = pool, set()

    def imap_unordered(self, fn, tasks):
        self.pending = {self.pool.submit(fn, *task) for task in tasks}
        while self.pending:
            finished, self.pending = wait(self.pending, return_when=FIRST_COMPLETED)
            for future in finished:
                yield future.result()


class _RayExecutor(Executor):
    task_seconds = RAY_TASK_SECONDS

    def __init__(self):
        self.pending = []

    def imap_unordered(self, fn, tasks):
        import ray

        remote = ray.remote(num_cpus=1)(fn)
        self.pending = [remote.remote(*task) for task in tasks]
        while self.pending:
            finished, self.pending = ray.wait(self.pending, num_returns=1)
            for ref in finished:
                try:
                    yield ray.get(ref)
                except ray.exceptions.RayTaskError as exc:  # excite's errors: their own line
                    if isinstance(exc.cause, ExciteError):
                        raise exc.cause from None
                    raise

    def cancel(self) -> None:
        """Cancel the tasks not finished yet (when the caller stops early)."""
        import ray

        for ref in self.pending:
            ray.cancel(ref, force=True)


def check_backend(name: str, address: str | None = None) -> None:
    """BackendError unless ``name`` is a backend and ``address`` fits it."""
    if name not in BACKENDS:
        raise BackendError(f"unknown backend {name!r}; choose from {', '.join(BACKENDS)}")
    if address is not None and name != RAY:
        raise BackendError("--address needs --backend ray")
    if address is not None and not address.strip():
        raise BackendError("--address is empty; give HOST:PORT of the Ray head, or auto")


@contextmanager
def open_backend(name: str = LOCAL, address: str | None = None,
                 workers: int | None = None) -> Iterator[Executor]:
    """An :class:`Executor` of backend ``name`` for the duration of the block; when the block
    ends early (an exception, Ctrl-C) pending tasks are cancelled and local workers
    terminated at once, their running tasks unwaited for. ``workers`` bounds the local
    pool's processes (Ray schedules by the cluster's CPUs)."""
    check_backend(name, address)
    if name == LOCAL:
        pool = ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1,
                                   initializer=_start_worker)
        executor: Executor = _LocalExecutor(pool)
        try:
            yield executor
        except BaseException:  # interrupted, or a task failed: the running tasks' results
            shut_down_now(pool)  # would not be kept, so the workers end now, unwaited for
            raise
        pool.shutdown()
    else:
        with ray_session(address):
            executor = _RayExecutor()
            try:
                yield executor
            finally:
                executor.cancel()
