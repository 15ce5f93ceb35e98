"""Target mode: the episode ends when the stopping rule says the calibration is done.

With the configuration key ``target`` set, each robot's episode is judged after every segment
by :class:`excite.stopping.StoppingRule` on the batch calibration of its segments so far
(noise levels estimated from the data, never the hidden truth), with the env's own model:
the axle model, or the sensor-pose model on the sensor id (the mounting estimated). The
episode terminates at the first *done*, and truncates at the budget otherwise.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from excite.core.models import AXLE, SegmentModel
from excite.logs.segments import Segments
from excite.stopping import StopDecision, StoppingRule


def stopping_rule(config: Mapping[str, Any], model: SegmentModel) -> StoppingRule | None:
    """The rule of target mode for this configuration and model; None when ``target`` is
    None (target mode off)."""
    if config["target"] is None:
        return None
    return StoppingRule(target=float(config["target"]),
                        confidence=float(config["target_confidence"]),
                        sensor_pose="axle" if model is AXLE else "estimate")


def decide(rule: StoppingRule, log: np.ndarray, nominal: np.ndarray) -> StopDecision:
    """The rule's decision on one robot's segment rows (n, 5) so far, the calibration started
    at the nominal wheel parameters (3,) (m)."""
    return rule.decide(Segments.from_array(log), nominal=nominal[:3])
