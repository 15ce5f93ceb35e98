"""What a live session gives: the command to send now (:class:`Command`), where it stands
(:class:`LiveStatus`), and what it leaves when it ends (:class:`LiveResult`).

Units: m, rad, s; wheel speeds in rad/s.
"""

from __future__ import annotations

from dataclasses import dataclass

from excite.calibration.result import CalibrationResult
from excite.live.area import Area
from excite.logs.timeseries import TimeSeries
from excite.stopping import StopDecision

__all__ = ["OUTCOMES", "STOP", "Command", "LiveResult", "LiveStatus"]

#: How a session ends.
OUTCOMES = ("done", "out_of_time", "aborted")


@dataclass(frozen=True)
class Command:
    """The command to send now: wheel speeds ``left``, ``right`` (rad/s), and the same as
    ``v`` (m/s) and ``omega`` (rad/s) with the nominal geometry."""

    left: float
    right: float
    v: float
    omega: float

    @property
    def is_zero(self) -> bool:
        return self.left == 0.0 and self.right == 0.0


#: The command that stops the robot.
STOP = Command(0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class LiveStatus:
    """Where a session stands.

    Attributes
    ----------
    state : str
        "waiting" (no data yet), "running", "paused" (a stream is silent), "confirming"
        (stopped while the stopping rule decides again on the whole log), or the outcome
        ("done", "out_of_time", "aborted").
    elapsed : float
        Seconds since the session started driving.
    segments : int
        Commands the protocol has given so far.
    calibrated_segments : int
        Segments of the log the last decision saw.
    estimate : (float, float, float)
        r_L, r_R, b (m): the last batch calibration's, or the nominal values before one.
    std : (float, float, float) or None
        Their standard deviations (m); None before a calibration.
    statistic : float
        The stopping statistic (done at <= 1; inf before a calibration).
    seconds_to_go : float or None
        The predicted further driving (s) at the current way of driving.
    clearance : float or None
        The smallest distance (m) from the footprint to the area's edges.
    reason : str
        The stopping rule's reason, or why the session paused or ended.
    """

    state: str
    elapsed: float
    segments: int
    calibrated_segments: int
    estimate: tuple[float, float, float]
    std: tuple[float, float, float] | None
    statistic: float
    seconds_to_go: float | None
    clearance: float | None
    reason: str


@dataclass(frozen=True)
class LiveResult:
    """What a finished session leaves.

    Attributes
    ----------
    outcome : str
        "done", "out_of_time" or "aborted".
    reason : str
        Why it ended, in one line.
    calibration : CalibrationResult or None
        The full offline calibration of the whole session; None when the data did not allow
        one (``calibration_error`` says why).
    calibration_error : str or None
        Why there is no calibration.
    decision : StopDecision or None
        The stopping rule's last decision during the session.
    series : TimeSeries or None
        The session's wheel angles and poses (None without data).
    area : Area or None
        The safe area (pose frame).
    statuses : tuple of LiveStatus
        The status after every segment.
    duration : float
        Seconds of driving.
    calibrated_from : float or None
        The stamp (s) from which the session's data are calibrated: the last slowdown (the
        model did not fit the faster driving before it), or None for all of them
        (``excite calibrate --start`` on the recorded bag gives the same calibration).
    slowdowns : tuple of (float, float)
        Each slowdown's stamp (s) and the share of the speed limit driven from then on.
    time_offset : float or None
        The clock offset (s; pose time + offset = wheel time) the session's log was cut with
        for ``calibration``: the one given, or the log's estimate (``time_offset="estimate"``);
        None when the log could not be cut.
    suggested_time_offset : float or None
        For a session that did not end done with a given offset: the offset (s) at which its
        wheel rates explain its heading rate best
        (:func:`excite.logs.time_offset.untested_offset`) when the stopping rule says done on
        the log cut with it; else None.
    """

    outcome: str
    reason: str
    calibration: CalibrationResult | None
    calibration_error: str | None
    decision: StopDecision | None
    series: TimeSeries | None
    area: Area | None
    statuses: tuple[LiveStatus, ...]
    duration: float
    calibrated_from: float | None = None
    slowdowns: tuple[tuple[float, float], ...] = ()
    time_offset: float | None = None
    suggested_time_offset: float | None = None
