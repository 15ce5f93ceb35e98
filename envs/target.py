"""Target mode: the episode ends when the stopping rule says the calibration is done.

With the configuration key ``target`` set, each robot's episode is judged after every segment
by :class:`excite.stopping.StoppingRule` on the batch calibration of its segments so far
(noise levels estimated from the data, never the hidden truth), with the env's own model:
the axle model, or the sensor-pose model on the sensor id (the mounting estimated). The
episode terminates at the first *done*, and truncates at the budget otherwise.

The rule reads the wheel encoders ENCODER_READINGS times per segment, as a robot's joint
states would give them (:meth:`envs.sensors.WheelEncoders.sub_increments`): each segment is
the composition of the arcs between readings, not one arc. The wheels' speeds change at the
start of each segment (the motors lag the commands), so a segment's path is no arc: one arc per
segment would bias the calibration (the lateral error of a segment that starts turning the
other way is millimetres), which its std does not cover.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from excite.core.models import AXLE, SegmentModel
from excite.logs.segments import Segments
from excite.stopping import StopDecision, StoppingRule

#: Encoder readings per segment the stopping rule gets (evenly spaced over its physics ticks).
ENCODER_READINGS = 10


def stopping_rule(config: Mapping[str, Any], model: SegmentModel) -> StoppingRule | None:
    """The rule of target mode for this configuration and model; None when ``target`` is
    None (target mode off)."""
    if config["target"] is None:
        return None
    return StoppingRule(target=float(config["target"]),
                        confidence=float(config["target_confidence"]),
                        sensor_pose="axle" if model is AXLE else "estimate")


def rule_segments(log: np.ndarray, sub_increments: np.ndarray) -> Segments:
    """The segments the rule decides on: one robot's segment rows (n, 5) so far with their
    encoder sub-increments (n, K, 2) (rad, left and right, summing to the rows' dphi_L,
    dphi_R)."""
    return Segments(*np.asarray(log, dtype=float).T, sub_dphi_L=sub_increments[..., 0],
                    sub_dphi_R=sub_increments[..., 1])


def decide(rule: StoppingRule, log: np.ndarray, sub_increments: np.ndarray,
           nominal: np.ndarray) -> StopDecision:
    """The rule's decision on :func:`rule_segments` of ``log`` and ``sub_increments``, the
    calibration started at the nominal wheel parameters (3,) (m)."""
    return rule.decide(rule_segments(log, sub_increments), nominal=nominal[:3])
