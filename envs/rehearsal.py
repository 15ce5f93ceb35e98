"""Rehearse a live session: ``excite sim-robot`` and ``excite live`` as two processes on this
machine, talking over real DDS with discovery on localhost only and a ROS_DOMAIN_ID of their
own (the live tests and ``benchmarks/bench_live.py`` use it; needs the sim and ros2 extras).

:func:`rehearse` starts the simulated robot, waits until it is up, runs ``excite live``
against it (with ``--use-sim-time``, ``--out`` and ``--record`` into a folder), optionally
sends the live process a signal, and returns a :class:`Rehearsal`: the live process' exit
status and output, its JSON result, the robot's hidden truth and its own log. Neither process
outlives the call.
"""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["EXCITE", "Rehearsal", "rehearse", "ros_env"]

#: The excite command of this venv.
EXCITE = [str(Path(sys.executable).with_name("excite"))]
#: Simulated seconds per wall second of the simulated robot, by default.
SPEED = 2.0
#: Domain ids handed out: from 40 (each pytest-xdist worker and each process its own range;
#: Fast DDS takes domain ids up to 232).
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").lstrip("gw") or 0)
_IDS = itertools.count(40 + 40 * _WORKER + os.getpid() % 4 * 10)


def ros_env() -> dict[str, str]:
    """The environment of one test's nodes: a domain of their own, localhost discovery."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(next(_IDS))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@dataclass
class Rehearsal:
    """What one live session left: the live process' exit status and output, its JSON
    result, the robot's truth and own log (t, x, y, theta, v, omega, received,
    received_wall), the wall time a signal was sent (None without one), the folder."""

    code: int
    out: str
    err: str
    result: dict | None
    truth: dict
    log: np.ndarray
    signalled: float | None
    folder: Path

    def zero_after(self, t: float, wall: bool = False) -> float:
        """The first time (s, simulated; wall-clock with ``wall``) a zero command reached the
        robot at or after ``t`` (inf if none did)."""
        column = 7 if wall else 6
        zero = (self.log[:, 4] == 0) & (self.log[:, 5] == 0) & (self.log[:, column] >= t)
        return float(self.log[np.argmax(zero), column]) if zero.any() else np.inf


def rehearse(folder: Path, live_args: list[str], sim_args: list[str] = (),
             signal_after: tuple[int, int] | None = None, timeout: float = 240.0,
             speed: float = SPEED, signal_to: str = "live",
             companion: list[str] | None = None, sim_time: bool = True) -> Rehearsal:
    """``excite sim-robot`` (``sim_args``, ``speed`` times real time) and ``excite live``
    (``live_args``) against it, their files in ``folder``; ``signal_after`` (signal,
    segments): send the signal once live printed that many status lines, to ``signal_to``:
    "live", "job" (live's whole process group, as a terminal's Ctrl-C) or "robot" (the
    simulated robot); ``timeout``: wall seconds the live process may take; ``companion``: a
    command run beside them in their domain (e.g. a node that advertises a topic), stopped
    at the end; ``sim_time``: live follows the robot's ``/clock`` (--use-sim-time)."""
    env = ros_env()
    truth, log = folder / "truth.json", folder / "robot.csv"
    live = other = None
    sim = subprocess.Popen(
        [*EXCITE, "sim-robot", "--speed", str(speed), "--truth", str(truth), "--log",
         str(log), *sim_args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    try:
        line = sim.stdout.readline()
        assert "ready" in line, (line, sim.stderr.read() if sim.poll() is not None else "")
        if companion is not None:
            other = subprocess.Popen(companion, env=env, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        live = subprocess.Popen(
            [*EXCITE, "live", *(["--use-sim-time"] if sim_time else []),
             "--out", str(folder / "result.json"),
             "--record", str(folder / "session.mcap"), *live_args],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            start_new_session=signal_to == "job")
        signalled = None
        lines: list[str] = []
        if signal_after is not None:
            sig, count = signal_after
            while len([x for x in lines if x.startswith("segment")]) < count:
                text = live.stdout.readline()
                assert text, "live ended before the signal"
                lines.append(text)
            signalled = time.time()
            if signal_to == "job":
                os.killpg(live.pid, sig)
            else:
                (sim if signal_to == "robot" else live).send_signal(sig)
        out, err = live.communicate(timeout=timeout)
        out = "".join(lines) + out
    finally:
        for process in (live, sim, other):  # never leave a node behind, whatever happened
            if process is not None and process.poll() is None:
                process.send_signal(signal.SIGINT)
        if live is not None:
            try:
                live.wait(timeout=30)
            except subprocess.TimeoutExpired:
                live.kill()
        try:
            sim.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            sim.kill()
        if other is not None:
            try:
                other.wait(timeout=30)
            except subprocess.TimeoutExpired:
                other.kill()
    result_path = folder / "result.json"
    robot_log = (np.loadtxt(log, delimiter=",", skiprows=1, ndmin=2) if log.exists()
                 else np.zeros((0, 8)))  # none from a robot killed
    return Rehearsal(live.returncode, out, err,
                   json.loads(result_path.read_text()) if result_path.exists() else None,
                   json.loads(truth.read_text()) if truth.exists() else {},
                   robot_log, signalled, folder)
