"""The reward's terms of one segment, for one robot (the single env) or N (the vector env).

The terms and their weights are documented in :class:`envs.env.DiffDriveCalibEnv`'s docstring
("Reward"); the weights are configuration keys (:mod:`envs.config`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: The reward's terms, in the order the envs report them in ``info["reward_terms"]``.
REWARD_TERMS = ("information", "collision", "effort", "time", "accuracy", "error", "stop")

#: The error term's floor on relative errors (a robot drawn without spread starts at 0).
ERROR_FLOOR = 1e-12


def uses_error(config: dict[str, Any]) -> bool:
    """Whether a reward term needs the max relative error against the hidden truth."""
    return bool(config["accuracy_weight"] or config["error_weight"])


def reward_terms(config: dict[str, Any], sigma_gain: float | np.ndarray,
                 collision: bool | np.ndarray, effort: float | np.ndarray,
                 errors: tuple[Any, Any, Any], done: bool | np.ndarray = False
                 ) -> dict[str, Any]:
    """The reward's terms (see DiffDriveCalibEnv, "Reward") of one segment of one robot
    (floats) or of N robots (arrays (N,); ``time``, and ``accuracy`` and ``error`` when they
    are off, stay scalars for the caller to broadcast).

    config: the env's configuration; sigma_gain: sigma_min's increase (relative information
    units); collision: whether the chassis touched a wall; effort: the sum of the squared
    normalised wheel commands; errors: the max relative error at the episode's start, before
    and after the segment (unused unless :func:`uses_error`); done: whether the stopping rule
    of target mode said done at this segment (:mod:`envs.target`)."""
    accuracy, area = config["accuracy_weight"], config["error_weight"]
    start, previous, error = errors
    return {
        "information": sigma_gain / config["information_scale"],
        "collision": -float(config["collision_penalty"]) * collision + 0.0,  # 0.0, not -0.0
        "effort": -float(config["effort_cost"]) * 0.5 * effort,
        "time": -float(config["time_cost"]),
        "accuracy": -accuracy * 100.0 * (error - previous) if accuracy else 0.0,
        "error": -area * np.log(np.maximum(error, ERROR_FLOOR) / np.maximum(start, ERROR_FLOOR))
        if area else 0.0,
        "stop": float(config["target_bonus"]) * done + 0.0,
    }
