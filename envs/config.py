"""The environment's configuration keys: default, type, unit and meaning of each, in one table.

:data:`CONFIG_KEYS` is the one source of the keys. :func:`default_config` takes its defaults,
:func:`make_config` its key set (an unknown key is an error), :func:`check_config` its
checks, and :func:`config_reference` renders it as the Markdown table that ends the docstring
of :class:`envs.env.DiffDriveCalibEnv` (its "Configuration" section, the environment's docs
page).
"""

from __future__ import annotations

import copy
import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from excite.registration import DEFAULT_BUDGET

#: The budget of an episode in target mode when none is given: long enough that good
#: protocols stop before it (segments).
TARGET_BUDGET = 150


def _check_budget(value: Any) -> None:
    if value is None:
        return
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < 1:
        raise ValueError(f"budget must be a whole number of segments >= 1 or None, got "
                         f"{value!r}")


def _real(value: Any) -> bool:
    return (isinstance(value, numbers.Real) and not isinstance(value, bool)
            and math.isfinite(value))


def _finite(name: str) -> Callable[[Any], None]:
    """The check of a key whose value is any finite number (a reward term's weight)."""
    def check(value: Any) -> None:
        if not _real(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")
    return check


def _positive(name: str, unit: str) -> Callable[[Any], None]:
    """The check of a key whose value is a positive finite number (``unit``)."""
    def check(value: Any) -> None:
        if not (_real(value) and value > 0):
            raise ValueError(f"{name} must be a positive number ({unit}), got {value!r}")
    return check


def _check_target(value: Any) -> None:
    if value is None:
        return
    if not (_real(value) and 0.0 < value < 1.0):
        raise ValueError("target must be a relative error in (0, 1) (0.002 = 0.2%) or None, "
                         f"got {value!r}")


def _check_target_confidence(value: Any) -> None:
    if not (_real(value) and 0.0 < value < 1.0):
        raise ValueError(f"target_confidence must be in (0, 1), got {value!r}")


@dataclass(frozen=True)
class ConfigKey:
    """One configuration key of the environment.

    name: the key; default: its value when not given (each configuration gets its own copy);
    kind: its type and valid range, as text; unit: its unit (empty: none); description: what
    it sets; check: raises ValueError for a bad value (None: the part of the environment that
    uses the value raises its own errors).
    """

    name: str
    default: Any
    kind: str
    unit: str
    description: str
    check: Callable[[Any], None] | None = None


#: Every configuration key, in the order of the configuration dict.
CONFIG_KEYS = (
    ConfigKey("ideal", False, "bool", "",
              "True: roll without slip or lag (the kinematic model is exact); False: pymunk "
              "physics with motor lag and friction-capped traction"),
    ConfigKey("budget", None, "int >= 1 or None", "segments",
              f"segments per episode (the episode is truncated after them); None: "
              f"{DEFAULT_BUDGET}, or {TARGET_BUDGET} with a target", _check_budget),
    ConfigKey("segment_duration", 1.0, "float > 0, a multiple of 1 / physics_hz", "s",
              "how long each action's wheel-speed command is held"),
    ConfigKey("settle_time", 0.0, "float >= 0, a multiple of 1 / physics_hz", "s",
              "zero command after the held one (> 0: stop-and-go segments, starting and "
              "ending at rest)"),
    ConfigKey("arena_size", None, "float > 0 or None", "m",
              "side of the square walled arena; None: scaled with the robot (4 m for the "
              "default robot)"),
    ConfigKey("physics_hz", 50.0, "float > 0", "Hz", "physics tick rate"),
    ConfigKey("ticks_per_rev", 4096, "int >= 1", "ticks per revolution",
              "wheel encoder resolution"),
    ConfigKey("sigma_xy", 2e-3, "float > 0", "m",
              "pose sensor noise: standard deviation of x and y of each segment increment "
              "and of each measured pose", _positive("sigma_xy", "m")),
    ConfigKey("sigma_theta", 1e-3, "float > 0", "rad",
              "pose sensor noise: standard deviation of the heading",
              _positive("sigma_theta", "rad")),
    ConfigKey("robot", {}, "str, dict or RobotDistribution", "",
              'the hidden robots\' distribution: a preset ("default", "turtlebot3", '
              '"jackal", "husky"), a preset scaled ({"preset": "default", "scale": 1.5}: '
              'lengths x 1.5, mass x 1.5^3, inertia x 1.5^5, same top speed) or '
              'RobotDistribution overrides ({"preset": "jackal", "radius_rel": 0.03}); the '
              'chassis, inertia and arena scale with the robot'),
    ConfigKey("information_scale", 100.0, "float > 0", "sigma_min per reward unit",
              "the information term's unit", _positive("information_scale",
                                                       "sigma_min per reward unit")),
    ConfigKey("collision_penalty", 1.0, "float", "reward",
              "paid per segment whose chassis touched a wall", _finite("collision_penalty")),
    ConfigKey("effort_cost", 0.0, "float", "reward per mean squared action",
              "paid per segment on the mean of the squared wheel commands",
              _finite("effort_cost")),
    ConfigKey("time_cost", 0.0, "float", "reward per segment", "paid per segment",
              _finite("time_cost")),
    ConfigKey("accuracy_weight", 0.0, "float", "reward per percent of max relative error",
              "weight of the privileged accuracy term (uses the hidden truth; training in "
              "simulation only)", _finite("accuracy_weight")),
    ConfigKey("error_weight", 0.0, "float", "reward per e-fold of max relative error",
              "weight of the privileged error term, the log-error-vs-time area (uses the "
              "hidden truth; training in simulation only)", _finite("error_weight")),
    ConfigKey("target_sigma_min", None, "float or None", "sigma_min (dimensionless)",
              "terminate the episode once sigma_min reaches it; None: never"),
    ConfigKey("target", None, "float in (0, 1) or None", "relative error",
              "target mode: terminate the episode when the stopping rule "
              "(excite.stopping.StoppingRule, the batch calibration of the segments so far) "
              "says every parameter is within this relative error at target_confidence "
              "(sensor x, y within target x b, its angle within target rad); None: off",
              _check_target),
    ConfigKey("target_confidence", 0.95, "float in (0, 1)", "",
              "the stopping rule's confidence that every parameter is within the target",
              _check_target_confidence),
    ConfigKey("target_bonus", 0.0, "float", "reward",
              "paid once, at the segment where the stopping rule says done",
              _finite("target_bonus")),
    ConfigKey("sensor_pose", None, "dict or None", "m, m, rad",
              'None: the pose sensor sits on the axle; else the ranges its hidden mounting is '
              'drawn from, uniformly per episode: {"x": (lo, hi), "y": (lo, hi), '
              '"theta": (lo, hi)} (a missing axis: (0, 0); theta within [-pi, pi])'),
    ConfigKey("record", False, "bool", "",
              "record the episode's time series (env.unwrapped.recording): encoder ticks at "
              "every physics tick and the sensor's world pose at record_pose_hz, each "
              "recorded pose with its own noise, the truth beside them"),
    ConfigKey("record_pose_hz", 100.0, "float > 0", "Hz", "rate of the recorded poses"),
    ConfigKey("record_sigma_xy", 1e-3, "float >= 0", "m",
              "noise of each recorded pose's x and y (standard deviation)"),
    ConfigKey("record_sigma_theta", 2e-3, "float >= 0", "rad",
              "noise of each recorded pose's heading (standard deviation)"),
)


def episode_budget(cfg: Mapping[str, Any]) -> int:
    """The segments of an episode: the key ``budget``, or its default (DEFAULT_BUDGET, or
    TARGET_BUDGET in target mode)."""
    if cfg["budget"] is not None:
        return int(cfg["budget"])
    return DEFAULT_BUDGET if cfg["target"] is None else TARGET_BUDGET


def default_config() -> dict[str, Any]:
    """Every key with its default value (a new dict, with its own copies of the defaults)."""
    return {key.name: copy.deepcopy(key.default) for key in CONFIG_KEYS}


def make_config(config: Mapping[str, Any] | None, overrides: Mapping[str, Any]) -> dict[str, Any]:
    """The defaults updated with ``config``, then ``overrides``. Raises ValueError for a key
    that is not in :data:`CONFIG_KEYS`."""
    cfg = default_config()
    for key, value in {**(config or {}), **overrides}.items():
        if key not in cfg:
            raise ValueError(f"unknown config key {key!r}; known: {', '.join(cfg)}")
        cfg[key] = value
    return cfg


def check_config(cfg: Mapping[str, Any]) -> None:
    """Run the checks of :data:`CONFIG_KEYS` on a configuration (ValueError for a bad value)."""
    for key in CONFIG_KEYS:
        if key.check is not None:
            key.check(cfg[key.name])


def sensor_ranges(value: dict | None) -> np.ndarray | None:
    """The (3, 2) ranges (low, high) of the hidden sensor mounting (x, y [m], theta [rad]) of
    the key ``sensor_pose``; None on the axle."""
    if value is None:
        return None
    if not isinstance(value, dict) or set(value) - {"x", "y", "theta"}:
        raise ValueError('sensor_pose must be None or {"x": (lo, hi), "y": (lo, hi), '
                         f'"theta": (lo, hi)}}, got {value!r}')
    ranges = np.array([value.get(k, (0.0, 0.0)) for k in ("x", "y", "theta")], dtype=float)
    if ranges.shape != (3, 2) or not np.all(np.isfinite(ranges)) or np.any(
            ranges[:, 0] > ranges[:, 1]) or np.any(np.abs(ranges[2]) > math.pi):
        raise ValueError(f"sensor_pose ranges must be finite (lo, hi) pairs with lo <= hi "
                         f"(theta within [-pi, pi]), got {value!r}")
    return ranges


def config_reference() -> str:
    """The Markdown table of every configuration key: key, default, type and range, unit
    ("-": none), meaning."""
    lines = ["| key | default | type | unit | meaning |", "|---|---|---|---|---|"]
    lines += [f"| `{key.name}` | `{key.default!r}` | {key.kind} | {key.unit or '-'} | "
              f"{key.description} |" for key in CONFIG_KEYS]
    return "\n".join(lines)
