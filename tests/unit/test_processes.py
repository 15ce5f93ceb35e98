"""excite.processes: a worker started under sigint_blocked is deaf to a Ctrl-C that reaches it
while it is still starting up (before its initializer ran), and a SIGINT sent to the blocking
thread meanwhile is delivered once the block ends, not lost."""

import multiprocessing
import os
import signal
import threading
import time

from excite.processes import deaf_to_sigint, sigint_blocked

#: s the child takes to "start up" (as importing numpy does) before it turns deaf.
STARTUP = 1.5


def _slow_start(ready) -> None:
    time.sleep(STARTUP)  # SIGINT arrives in here
    deaf_to_sigint()
    ready.set()
    time.sleep(0.5)  # a SIGINT now is ignored too


def _run_child(blocked: bool) -> int:
    context = multiprocessing.get_context("spawn")
    ready = context.Event()
    child = context.Process(target=_slow_start, args=(ready,))
    # the parent's SIGINT handled, as in a terminal (a test worker may ignore it, and an
    # ignored SIGINT is inherited by the child, which then needs no block)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        if blocked:
            with sigint_blocked():
                child.start()
        else:
            child.start()
    finally:
        signal.signal(signal.SIGINT, previous)
    time.sleep(0.5 * STARTUP)
    os.kill(child.pid, signal.SIGINT)
    assert ready.wait(10) or not blocked
    if ready.is_set():
        os.kill(child.pid, signal.SIGINT)
    child.join(10)
    return child.exitcode


def test_a_worker_started_with_sigint_blocked_survives_a_ctrl_c_during_its_start():
    assert _run_child(blocked=False) != 0  # the race the block closes: KeyboardInterrupt
    assert _run_child(blocked=True) == 0


def test_a_sigint_to_the_blocking_thread_is_held_and_delivered_after_the_block():
    """Held, not lost (a SIGINT to the whole process may reach another thread meanwhile, whose
    C handler passes it to the main thread's Python handler: not lost either)."""
    received = []
    previous = signal.signal(signal.SIGINT, lambda *_: received.append(True))
    try:
        with sigint_blocked():
            signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)
            time.sleep(0.05)
            assert not received
        time.sleep(0.05)
        assert received == [True]
    finally:
        signal.signal(signal.SIGINT, previous)
