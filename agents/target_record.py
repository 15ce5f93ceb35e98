"""The target-mode columns of a comparison's segment record, and each episode's stop.

With ``excite compare --target T`` every episode runs in the env's target mode (docs/environment.md,
"Target mode"): it ends at the first segment where the stopping rule
(:class:`excite.stopping.StoppingRule`, the batch calibration of the segments so far) says
done, or at the budget. Each row of ``DIR/segments.csv`` then also holds:

- ``stop``: 1 at the segment where the rule said done (an episode's last), else 0;
- ``statistic``: the rule's statistic (the largest half-width over its tolerance,
  dimensionless; inf while the data do not determine the parameters);
- ``batch_r_L_err``, ``batch_r_R_err``, ``batch_b_err``: the signed relative errors of the
  rule's batch calibration against the hidden truth (nan when there is none yet);
- ``batch_x_err``, ``batch_y_err``: the errors of its sensor mounting x, y over the true b
  (dimensionless: the rule's tolerance there is target x b), ``batch_theta_err`` that of its
  angle (rad, wrapped to [-pi, pi)); nan on the axle model.

A stop is *false* when the truth lies outside the target there: one of the batch calibration's
relative errors of r_L, r_R, b above T, or (sensor pose estimated) x or y off by more than
T x b, or its angle by more than T rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agents.segment_record import PARAMETERS, last_rows
from excite.core.kinematics import wrap_angle

#: The batch calibration's errors at each segment (see the module docstring for units).
BATCH_ERRORS = ("batch_r_L_err", "batch_r_R_err", "batch_b_err", "batch_x_err", "batch_y_err",
                "batch_theta_err")
#: The columns target mode adds to DIR/segments.csv, after agents.compare.COLUMNS.
TARGET_COLUMNS = ("stop", "statistic", *BATCH_ERRORS)


def target_fields(env) -> dict[str, float | int]:
    """The target-mode columns of the segment just driven, from the env (its ``unwrapped``
    holds ``last_stop``, the rule's decision with its batch calibration, and the hidden truth
    ``true_theta``: r_L, r_R, b in m, then the sensor mounting x, y in m, theta in rad)."""
    base = env.unwrapped
    decision = base.last_stop
    fields: dict[str, float | int] = {
        "stop": int(decision is not None and decision.done),
        "statistic": math.nan if decision is None else float(decision.statistic),
        **dict.fromkeys(BATCH_ERRORS, math.nan)}
    result = None if decision is None else decision.result
    if result is None:
        return fields
    truth = np.asarray(base.true_theta, float)
    wheels = result.params.as_array() / truth[:3] - 1.0
    fields |= dict(zip(BATCH_ERRORS[:3], map(float, wheels), strict=True))
    if result.sensor_pose is not None and truth.size == 6:
        pose = result.sensor_pose.as_array()
        fields |= {"batch_x_err": float((pose[0] - truth[3]) / truth[2]),
                   "batch_y_err": float((pose[1] - truth[4]) / truth[2]),
                   "batch_theta_err": float(wrap_angle(pose[2] - truth[5]))}
    return fields


@dataclass(frozen=True)
class Stops:
    """How each episode of one (protocol, estimator) pair ended in target mode (arrays over
    its episodes, ordered by episode).

    episode: the episode numbers; rows: each episode's last row in the record; stopped: the
    rule said done there (else the budget ended the episode, censored); segments, seconds,
    metres: the segments, seconds (s) and metres (m) driven until that end; error: the max
    relative error of r_L, r_R, b of the batch calibration there (nan without one).
    """

    episode: np.ndarray
    rows: np.ndarray
    stopped: np.ndarray
    segments: np.ndarray
    seconds: np.ndarray
    metres: np.ndarray
    error: np.ndarray

    def to_target(self, driven: np.ndarray) -> np.ndarray:
        """A driven amount (one of segments, seconds, metres) until the target: inf where
        censored (not stopped within the budget)."""
        return np.where(self.stopped, driven, np.inf)


def stops_of(columns: dict[str, np.ndarray], protocol: str, estimator: str) -> Stops:
    """The :class:`Stops` of one pair from the segment record with the target columns."""
    last = last_rows(columns, protocol, estimator)
    wheels = np.column_stack([np.asarray(columns[f"batch_{p}_err"], float)[last]
                              for p in PARAMETERS])
    return Stops(
        episode=np.asarray(columns["episode"])[last], rows=last,
        stopped=np.asarray(columns["stop"])[last] == 1,
        segments=np.asarray(columns["segment"], float)[last],
        seconds=np.asarray(columns["time"], float)[last],
        metres=np.asarray(columns["distance"], float)[last],
        error=np.max(np.abs(wheels), axis=1))


def false_stops(columns: dict[str, np.ndarray], stops: Stops, target: float) -> np.ndarray:
    """Per episode of ``stops``: stopped while the truth lay outside ``target`` (relative):
    any of |batch_*_err| at the stop above it (nan, a parameter not estimated, counts as
    inside)."""
    errors = np.column_stack([np.asarray(columns[c], float)[stops.rows] for c in BATCH_ERRORS])
    with np.errstate(invalid="ignore"):
        return stops.stopped & np.any(np.abs(errors) > target, axis=1)
