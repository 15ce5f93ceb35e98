"""What a live session shows people: one status line per segment, the closing lines, and
the result as JSON (``excite calibrate --json``'s object with a ``live`` section)."""

from __future__ import annotations

import math

from excite.live.result import LiveResult, LiveStatus
from excite.stopping import finite_or_none

__all__ = ["status_line", "result_dict", "closing_lines"]


def _value(x: float, s: float | None) -> str:
    return f"{x:.5f}" if s is None else f"{x:.5f}±{s:.5f}"


def status_line(status: LiveStatus) -> str:
    """One line: segment, time, estimate ± std (m), the stopping statistic, the predicted
    time left and the clearance to the area's edges."""
    std = status.std or (None, None, None)
    names = ("r_L", "r_R", "b")
    estimate = "  ".join(f"{n} {_value(x, s)}" for n, x, s in zip(names, status.estimate, std,
                                                                   strict=True))
    stat = "-" if not math.isfinite(status.statistic) else f"{status.statistic:.2f}"
    to_go = ("?" if status.seconds_to_go is None or not math.isfinite(status.seconds_to_go)
             else f"{status.seconds_to_go:.0f} s")
    clearance = "?" if status.clearance is None else f"{status.clearance:.2f} m"
    return (f"segment {status.segments:3d}  t {status.elapsed:6.1f} s  {estimate}  "
            f"stop statistic {stat} (done at 1)  to go {to_go}  clearance {clearance}")


def closing_lines(result: LiveResult) -> list[str]:
    """How the session ended, and where its calibration stands."""
    segments = result.statuses[-1].segments if result.statuses else 0
    lines = [f"live session {result.outcome.replace('_', ' ')} after {result.duration:.1f} s "
             f"({segments} segments): {result.reason}"]
    if result.calibration is None:
        lines.append(f"no calibration of the session: {result.calibration_error}")
    elif result.time_offset:
        lines.append(f"the session's log was cut with a clock offset of "
                     f"{result.time_offset:+.4f} s (pose time + offset = wheel time)")
    if result.suggested_time_offset is not None:
        lines.append(f"the pose stamps seem offset: with a clock offset of "
                     f"{result.suggested_time_offset:+.4f} s (not the "
                     f"{result.time_offset or 0.0:+.4f} s used) the session's data reach the "
                     "target (--time-offset estimate)")
    return lines


def result_dict(result: LiveResult, nominal=None) -> dict:
    """``calibrate --json``'s object for the session's calibration (null fields without
    one) with a ``live`` section: outcome, reason, duration (s), segments, area (m, pose
    frame: x0, y0, x1, y1), calibrated_from (the stamp in s the calibration starts at, null:
    all), time_offset (s, pose time + offset = wheel time: the one the log was cut with, null
    when it could not be), suggested_time_offset (s: for a session not done, the offset the
    data show instead of the one given, with which they reach the target; null: none),
    slowdowns ([stamp, speed share] each), the last stopping decision, and every status."""
    out = result.calibration.to_dict() if result.calibration is not None else {
        "calibration_error": result.calibration_error}
    if nominal is not None:
        out["nominal"] = dict(zip(("r_L", "r_R", "b"), nominal.as_array().tolist(),
                                  strict=True))
    area = result.area
    out["live"] = {
        "outcome": result.outcome, "reason": result.reason, "duration": result.duration,
        "segments": result.statuses[-1].segments if result.statuses else 0,
        "area": None if area is None else [area.x0, area.y0, area.x1, area.y1],
        "calibrated_from": result.calibrated_from,
        "time_offset": result.time_offset,
        "suggested_time_offset": result.suggested_time_offset,
        "slowdowns": [list(x) for x in result.slowdowns],
        "decision": None if result.decision is None else result.decision.to_dict(),
        "statuses": [_status_dict(s) for s in result.statuses],
    }
    return out


def _status_dict(s: LiveStatus) -> dict:
    to_go = None if s.seconds_to_go is None else finite_or_none(s.seconds_to_go)
    return {"state": s.state, "elapsed": s.elapsed, "segments": s.segments,
            "calibrated_segments": s.calibrated_segments, "estimate": list(s.estimate),
            "std": None if s.std is None else list(s.std),
            "statistic": finite_or_none(s.statistic), "seconds_to_go": to_go,
            "clearance": s.clearance,
            "reason": s.reason}
