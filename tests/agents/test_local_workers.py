"""A killed or terminated compare leaves no worker processes behind (Linux: /proc)."""

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")


def _children(pid: int) -> set[int]:
    found = set()
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":\t", 1) for line in status.read_text().splitlines()
                          if ":\t" in line)
        except OSError:
            continue
        if fields.get("PPid", "").strip() == str(pid):
            found.add(int(status.parent.name))
    return found


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            continue
        state = Path(f"/proc/{pid}/stat")
        if state.exists() and state.read_text().split()[2] != "Z":
            alive.add(pid)
    return alive


def _as_from_a_terminal() -> None:
    """In the child before exec: SIGINT as a shell gives it to a command (default), whatever
    the test process has (an ignored SIGINT would be inherited, and compare then never sees
    the Ctrl-C the test sends)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _started_compare(out: Path, segments: int = 30) -> tuple[subprocess.Popen, set[int]]:
    proc = subprocess.Popen([sys.executable, "-m", "excite.cli", "compare", "--protocols",
                             "greedy", "--episodes", "40", "--segments", str(segments),
                             "--workers", "2", "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_as_from_a_terminal)
    deadline = time.monotonic() + 120
    workers: set[int] = set()
    while time.monotonic() < deadline and len(workers) < 2:
        time.sleep(0.5)
        workers = {p for p in _children(proc.pid)}
        if proc.poll() is not None:
            break
    assert len(workers) >= 2, "the worker pool did not start"
    return proc, workers


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_workers_end_with_their_parent(tmp_path, sig):
    proc, workers = _started_compare(tmp_path / "out")
    time.sleep(2.0)  # some tasks under way
    proc.send_signal(sig)
    proc.wait(timeout=60)
    if sig == signal.SIGTERM:  # as Ctrl-C: one line, finished work kept
        assert proc.returncode == 130 and "interrupted" in proc.stderr.read()
    deadline = time.monotonic() + 15
    while _alive(workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _alive(workers)


@pytest.mark.slow
@pytest.mark.parametrize("to_job", [False, True], ids=["SIGTERM to compare", "SIGINT to the job"])
def test_an_interrupted_compare_does_not_wait_for_its_running_episodes(tmp_path, to_job):
    """SIGTERM to compare alone (``kill``, a job scheduler), or SIGINT to every process of
    the job (a terminal's Ctrl-C), while long episodes run: their results would not be kept,
    and on SIGTERM compare waited for them to finish; now it ends at once, with the one line
    of an interrupt."""
    proc, workers = _started_compare(tmp_path / "out", segments=5000)
    try:
        time.sleep(2.0)
        start = time.monotonic()
        if to_job:
            for pid in {proc.pid} | workers:
                os.kill(pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
    except BaseException:  # a compare that does not end: never leave it behind
        for pid in {proc.pid} | workers:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        raise
    assert time.monotonic() - start < 10.0
    assert proc.returncode == 130 and "interrupted" in proc.stderr.read()
    deadline = time.monotonic() + 15
    while _alive(workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _alive(workers)
