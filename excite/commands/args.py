"""Argument types and value checks of the subcommands, each turning one command-line string
into a value. An argparse type (``type=``) raises :class:`argparse.ArgumentTypeError`, which
argparse reports naming the option; a check a command calls on an option's value raises
:class:`UsageError` naming the option itself. Either ends the command with one line
(:mod:`excite.commands.exit_status`)."""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Sequence
from pathlib import Path

from excite.core.plausible import (
    MAX_SEPARATION,
    RADIUS_RANGE,
    TYPICAL_RADIUS,
    TYPICAL_SEPARATION,
    implausible_mounting,
    typical,
    violation,
)
from excite.errors import ExciteError

__all__ = ["PARAMS_VALUES", "SIGMA_VALUES", "POSE_VALUES", "POSE_NOISE_VALUES", "UsageError",
           "floats", "sigma_arg", "params_arg", "plausible_params",
           "sensor_pose_arg", "check_not_an_input", "check_writable", "seed_int",
           "pose_noise_arg",
           "fraction_arg", "positive_int", "nonnegative_int", "env_id", "robot_preset",
           "output_folder", "check_parent_folder", "check_output_file", "time_offset_arg"]

#: The comma-separated values of the options that take several numbers, as their metavars and
#: error messages name them: wheel radii and separation (m); noise std of dx, dy, dtheta (m, m,
#: rad); a sensor pose in the body frame (m, m, rad); pose-noise std (m, rad).
PARAMS_VALUES = "RL,RR,B"
SIGMA_VALUES = "SX,SY,STH"
POSE_VALUES = "X,Y,THETA"
POSE_NOISE_VALUES = "SXY,STH"


class UsageError(ExciteError):
    """Bad input or usage: reported as one line, exit status EXIT_USAGE (2)."""


def floats(text: str, names: str, what: str, positive: bool = True) -> tuple[float, ...]:
    """Comma-separated finite numbers, one per name of ``names`` (comma-separated, such as
    PARAMS_VALUES; ``what`` is the option), each > 0 unless ``positive`` is False."""
    expected = names.split(",")
    parts = text.split(",")
    if len(parts) != len(expected):
        raise UsageError(f"{what} needs {len(expected)} comma-separated values ({names}), "
                         f"got {text!r}")
    values = []
    for name, part in zip(expected, parts, strict=True):
        try:
            value = float(part)
        except ValueError:
            raise UsageError(f"{what}: {name} is not a number: {part!r}") from None
        if not math.isfinite(value) or (positive and value <= 0):
            raise UsageError(f"{what}: {name} must be {'positive and ' if positive else ''}"
                             f"finite, got {part!r}")
        values.append(value)
    return tuple(values)


def finite_number(text: str) -> float:
    """A finite number (an argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def time_offset_arg(text: str) -> float | str:
    """A clock offset: a finite number of seconds or 'estimate' (an argparse type)."""
    if text == "estimate":
        return text
    try:
        float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number of seconds or 'estimate', "
                                         f"got {text!r}") from None
    return finite_number(text)


def positive_number(text: str) -> float:
    """A finite number > 0 (an argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < value < math.inf:
        raise argparse.ArgumentTypeError(f"must be positive and finite, got {text!r}")
    return value


def sigma_arg(text: str) -> tuple[float, ...]:
    """--sigma SX,SY,STH (m, m, rad)."""
    return floats(text, SIGMA_VALUES, "--sigma")


_UNITS = (("centimetres", "cm", 100.0), ("millimetres", "mm", 1000.0))


def _unit_hint(values: tuple[float, float, float], index: int) -> str:
    """'centimetres given as metres? 5 cm = 0.05' for the units in which all three values
    (else the value at ``index`` alone) are typical; '' when none is."""
    units = [u for u in _UNITS if typical(*(v / u[2] for v in values))]
    if not units:
        low, high = TYPICAL_SEPARATION if index == 2 else TYPICAL_RADIUS
        units = [u for u in _UNITS if low <= values[index] / u[2] <= high]
    if not units:
        return ""
    value = values[index]
    names = " or ".join(name for name, _, _ in units)
    examples = ", ".join(f"{value:g} {short} = {value / factor:.6g}"
                         for _, short, factor in units)
    return f"{names} given as metres? {examples}"


def plausible_params(values: tuple[float, float, float], text: str, what: str) -> None:
    """UsageError, naming the likely unit, unless the nominal wheel parameters RL,RR,B (m)
    lie within the bounds no real differential drive violates
    (:func:`excite.core.plausible.violation`)."""
    broken = violation(*values)
    if broken is None:
        return
    r_L, r_R, b = values
    low, high = RADIUS_RANGE
    subject, verb = broken.subject, "is"
    if broken.kind == "large":
        hint = (_unit_hint(values, broken.index)
                or f"wheel radii are {1e3 * low:g} mm to {high:g} m")
    elif broken.kind == "small":
        hint = f"wheel radii are {1e3 * low:g} mm to {high:g} m; {PARAMS_VALUES} are in metres"
    elif broken.kind == "ratio":
        verb = "are"
        hint = (f"they differ by a factor {max(r_L, r_R) / min(r_L, r_R):.3g}; "
                f"{PARAMS_VALUES} are the left and right wheel radii and the wheel separation")
    elif broken.kind == "far":
        hint = _unit_hint(values, 2) or f"at most {MAX_SEPARATION:g} m"
    else:
        subject += ","
        hint = f"{PARAMS_VALUES}: B is the distance between the wheels' contact points"
    raise UsageError(f"{what} {text}: {subject} {verb} implausible ({hint})")


def params_arg(text: str, what: str = "--init"):
    """Nominal wheel parameters RL,RR,B (m) as :class:`excite.Params`; implausible values
    (:func:`plausible_params`) are a UsageError naming the likely unit."""
    from excite.core.kinematics import Params

    values = floats(text, PARAMS_VALUES, what)
    plausible_params(values, text, what)
    return Params(*values)


def sensor_pose_arg(text: str, option: str = "--sensor-pose"):
    """A sensor pose X,Y,THETA (m, m, rad) in the body frame; for ``--sensor-pose`` also the
    words auto, axle, estimate."""
    from excite.core.models import SensorPose

    words = option == "--sensor-pose"
    if words and text in ("auto", "axle", "estimate"):
        return text
    expected = f"auto, axle, estimate or {POSE_VALUES}" if words else POSE_VALUES
    parts = text.split(",")
    if len(parts) != 3:
        raise UsageError(f"{option} must be {expected} (m, m, rad), got {text!r}")
    try:
        values = [float(part) for part in parts]
        pose = SensorPose(*values)
    except ValueError:
        raise UsageError(f"{option}: {POSE_VALUES} must be finite numbers, got {text!r}") from None
    if abs(values[2]) > math.pi:
        raise UsageError(f"{option} {text}: the angle {values[2]:g} rad is beyond pi (degrees? "
                         f"{values[2]:g} deg = {math.radians(values[2]):.4g} rad)")
    what = implausible_mounting(pose.x, pose.y)
    if what is not None:
        raise UsageError(f"{option} {text}: {what} is implausible ({POSE_VALUES} are in m, m, "
                         "rad)")
    return pose


def pose_noise_arg(text: str) -> tuple[float, float]:
    """--pose-noise SXY,STH: two finite numbers >= 0 (m, rad); 0 turns that noise off."""
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 2 or not all(0 <= v < math.inf for v in values):
        raise argparse.ArgumentTypeError(f"must be {POSE_NOISE_VALUES}: two finite numbers >= 0 "
                                         f"(m, rad), got {text!r}")
    return values[0], values[1]


def fraction_arg(text: str) -> float:
    """A fraction in [0, 0.5) (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value < 0.5:
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 0.5), got {text!r}")
    return value


def _whole_number(text: str, minimum: int) -> int:
    """A whole number >= minimum (for argparse types)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
    return value


def positive_int(text: str) -> int:
    """A whole number >= 1 (argparse type)."""
    return _whole_number(text, 1)


def nonnegative_int(text: str) -> int:
    """A whole number >= 0 (argparse type)."""
    return _whole_number(text, 0)


#: Seeds are below this: numpy's legacy seeding (stable-baselines3, Ray) takes 32 bits.
SEED_LIMIT = 2**32


def seed_int(text: str) -> int:
    """A seed: a whole number in [0, SEED_LIMIT) (argparse type)."""
    value = _whole_number(text, 0)
    if value >= SEED_LIMIT:
        raise argparse.ArgumentTypeError(f"must be below 2**32 = {SEED_LIMIT}, got {value}")
    return value


def env_id(text: str) -> str:
    """An environment id registered with excite's environment class (its own or a user's)."""
    import gymnasium

    from excite.registration import ENTRY_POINT

    ours = [k for k, spec in gymnasium.registry.items() if spec.entry_point == ENTRY_POINT]
    if text not in ours:
        raise UsageError(f"unknown environment {text!r}; use one of {', '.join(ours)}")
    return text


def robot_preset(text: str) -> str:
    """A robot preset name of :data:`envs.robot.PRESETS`."""
    from envs.robot import PRESETS

    if text not in PRESETS:
        raise UsageError(f"unknown robot preset {text!r}; choose from {', '.join(PRESETS)}")
    return text


def output_folder(text: str) -> Path:
    """--out DIR: a folder that is written (made if missing); not empty, not a file
    (argparse type)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty; give a folder")
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a file, not a folder")
    return path


def check_parent_folder(out: Path) -> None:
    """UsageError unless the folder ``out`` goes into exists (a file on the way is named)."""
    if out.parent.exists() and not out.parent.is_dir():
        raise UsageError(f"cannot write {out}: {out.parent} is a file, not a folder")
    if not out.parent.is_dir():
        raise UsageError(f"cannot write {out}: no such directory {out.parent}")


def check_output_file(out: Path) -> None:
    """UsageError unless ``out`` can be written as a file: its folder exists, and it is not
    itself a folder."""
    if out.is_dir():
        raise UsageError(f"cannot write {out}: it is a folder; give a file name")
    check_parent_folder(out)


def check_not_an_input(out: str | os.PathLike[str], inputs: Sequence[str | os.PathLike[str]],
                       option: str) -> None:
    """UsageError when the output ``out`` (of ``option``) is one of the ``inputs`` (the same
    file, by any name): writing it would destroy the input."""
    if not os.path.exists(out):
        return
    for path in inputs:
        try:
            same = os.path.samefile(out, path)
        except OSError:  # an input that is no file (checked where it is read)
            continue
        if same:
            raise UsageError(f"{option} {out} is the input {path}: writing it would overwrite "
                             f"the input; choose another {option}")


def check_writable(out: Path) -> None:
    """UsageError unless the file ``out`` can be written now (opened for appending; a file
    this creates is removed again): for results written only after a long run, such as a
    live session on a robot."""
    check_output_file(out)
    existed = out.exists()
    try:
        with open(out, "a"):
            pass
    except OSError as exc:
        raise UsageError(f"cannot write {out}: {exc.strerror or exc}") from None
    if not existed:
        out.unlink()
