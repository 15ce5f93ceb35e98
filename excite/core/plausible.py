"""The wheel parameters no real differential drive lies outside of, and what a value outside
them most likely means: nominal values typed in the wrong unit (``--init``), or a calibration
of a log recorded in other units than excite reads (positions in mm, wheel angles in degrees).

A calibrated wheel radius more than :data:`NOMINAL_FACTOR` times larger or smaller than the
robot's nominal one is no calibration either (tyres and wear move it by a few percent): the
wheel angles are in other units, or behind a gearbox (:func:`far_from_nominal`); the wheel
separation is left out (a skid-steer robot's effective track is up to twice its geometric
one).

Bounds (m): each wheel radius in :data:`RADIUS_RANGE`, the two radii within a factor
:data:`MAX_RADIUS_RATIO` of each other, the wheel separation longer than the larger radius and
at most :data:`MAX_SEPARATION`; a sensor's offset from the axle midpoint at most
:data:`MAX_SENSOR_OFFSET` in x and y. Hints name a unit when the values converted from it fall
in the typical ranges (:data:`TYPICAL_RADIUS`, :data:`TYPICAL_SEPARATION`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["RADIUS_RANGE", "MAX_RADIUS_RATIO", "MAX_SEPARATION", "MAX_SENSOR_OFFSET",
           "TYPICAL_RADIUS", "TYPICAL_SEPARATION", "Violation", "implausible",
           "implausible_mounting", "violation", "NOMINAL_FACTOR", "METRE_RADII",
           "far_from_nominal", "metre_radii",
           "typical", "log_unit_hint"]

RADIUS_RANGE = (0.005, 2.0)
MAX_RADIUS_RATIO = 2.0
MAX_SEPARATION = 20.0
#: m: no sensor is mounted farther from the axle midpoint (in x or y).
MAX_SENSOR_OFFSET = MAX_SEPARATION
#: A calibrated wheel radius farther than this factor from the nominal one is no calibration
#: (``--init`` is also a rough first guess, so a guess twice the truth is no error; wheel
#: angles in other units are 2 pi, 9.5 or 57 times off, a gearbox usually 3 times or more).
NOMINAL_FACTOR = 2.5
TYPICAL_RADIUS = (0.01, 1.0)
TYPICAL_SEPARATION = (0.05, 5.0)

#: How a log in other units scales the calibrated (r_L, r_R, b): positions in cm or mm read as
#: m scale all three up; wheel angles in degrees (or revolutions) read as rad scale the radii
#: by pi / 180 (or 2 pi) and leave b.
_LOG_UNITS = (("positions in millimetres", (1000.0, 1000.0, 1000.0)),
              ("positions in centimetres", (100.0, 100.0, 100.0)),
              ("wheel angles in degrees", (math.pi / 180.0, math.pi / 180.0, 1.0)),
              ("wheel angles in revolutions", (2.0 * math.pi, 2.0 * math.pi, 1.0)))


def typical(r_L: float, r_R: float, b: float) -> bool:
    """Whether the three values (m) are a typical robot's."""
    low, high = TYPICAL_RADIUS
    return (low <= min(r_L, r_R) and max(r_L, r_R) <= high and max(r_L, r_R) < b
            and TYPICAL_SEPARATION[0] <= b <= TYPICAL_SEPARATION[1])


@dataclass(frozen=True)
class Violation:
    """The first bound the wheel parameters (m) break.

    Attributes
    ----------
    kind : str
        "large" or "small" (a wheel radius outside RADIUS_RANGE), "ratio" (the radii more
        than MAX_RADIUS_RATIO apart), "far" (the separation over MAX_SEPARATION) or "short"
        (the separation no longer than the larger radius).
    index : int
        Which value: 0 or 1 a radius (r_L, r_R), 2 the separation.
    subject : str
        The values in words, e.g. 'a wheel radius of 50 m'.
    bound : str
        The bound in words, e.g. 'real ones are 5 mm to 2 m'.
    """

    kind: str
    index: int
    subject: str
    bound: str


def violation(r_L: float, r_R: float, b: float) -> Violation | None:
    """The first bound the wheel parameters (m) break, in the order of the module doc; None
    when they are plausible."""
    low, high = RADIUS_RANGE
    for index, radius in enumerate((r_L, r_R)):
        if not low <= radius <= high:
            return Violation("large" if radius > high else "small", index,
                             f"a wheel radius of {radius:.4g} m",
                             f"real ones are {1e3 * low:g} mm to {high:g} m")
    if max(r_L, r_R) > MAX_RADIUS_RATIO * min(r_L, r_R):
        return Violation("ratio", 0, f"wheel radii of {r_L:.4g} m and {r_R:.4g} m",
                         f"a factor {max(r_L, r_R) / min(r_L, r_R):.3g} apart")
    if b > MAX_SEPARATION:
        return Violation("far", 2, f"a wheel separation of {b:.4g} m",
                         f"at most {MAX_SEPARATION:g} m")
    if b <= max(r_L, r_R):
        return Violation("short", 2, f"a wheel separation of {b:.4g} m, no longer than the "
                         f"wheel radius {max(r_L, r_R):.4g} m", "")
    return None


def implausible(r_L: float, r_R: float, b: float) -> str | None:
    """What about the wheel parameters (m) no real differential drive has, in words (e.g.
    'a wheel radius of 50 m (real ones are 5 mm to 2 m)'); None when nothing."""
    broken = violation(r_L, r_R, b)
    if broken is None:
        return None
    return broken.subject + (f" ({broken.bound})" if broken.bound else "")


def implausible_mounting(x: float, y: float) -> str | None:
    """What about a sensor mounting (m, body frame) no robot has, in words; None when
    nothing."""
    if max(abs(x), abs(y)) > MAX_SENSOR_OFFSET:
        return (f"a sensor {max(abs(x), abs(y)):.4g} m from the axle midpoint (at most "
                f"{MAX_SENSOR_OFFSET:g} m)")
    return None


def log_unit_hint(r_L: float, r_R: float, b: float) -> str:
    """The units of a log that would have given these calibrated values (m) for a typical
    robot, e.g. 'positions in millimetres read as metres? (a robot with r_L 0.05 m, r_R
    0.051 m, b 0.3 m would give these values)'; '' when none would."""
    for words, scale in _LOG_UNITS:
        values = (r_L / scale[0], r_R / scale[1], b / scale[2])
        if typical(*values):
            unit = "metres" if words.startswith("positions") else "radians"
            return (f"{words} read as {unit}? (a robot with r_L {values[0]:.3g} m, r_R "
                    f"{values[1]:.3g} m, b {values[2]:.3g} m would give these values)")
    return ""


#: The wheel angles' units that scale a calibrated radius by a known factor (calibrated /
#: true): angles in degrees, speeds in rpm, revolutions, speeds in rad/s labelled rpm.
_RADIUS_SCALES = (("wheel angles (or speeds) in degrees read as radians", math.pi / 180.0),
                  ("wheel speeds in rpm read as rad/s", math.pi / 30.0),
                  ("wheel angles in revolutions read as radians", 2.0 * math.pi),
                  ("wheel speeds in rad/s read as rpm", 30.0 / math.pi))


#: What calibrated wheel radii of 1 m most likely mean.
METRE_RADII = ("wheel travel in metres (or surface speeds in m/s) read as radians (rad/s), "
               "which gives radii of 1 m")


def metre_radii(r_L: float, r_R: float) -> bool:
    """Whether both calibrated wheel radii (m) are within 2% of 1 m (:data:`METRE_RADII`)."""
    return abs(r_L - 1.0) <= 0.02 and abs(r_R - 1.0) <= 0.02


def far_from_nominal(radii: tuple[float, float], nominal: tuple[float, float]) -> str | None:
    """What is wrong when a calibrated wheel radius (m) is more than :data:`NOMINAL_FACTOR`
    times larger or smaller than its nominal one (m), in words with the likely cause (e.g.
    'wheel radii of 1 m and 1 m, 3.33 and 3.33 times the nominal 0.3 m and 0.3 m: wheel
    travel in metres ... read as radians?'); None when both are within the factor."""
    ratios = [value / given for value, given in zip(radii, nominal, strict=True)]
    if all(1.0 / NOMINAL_FACTOR <= ratio <= NOMINAL_FACTOR for ratio in ratios):
        return None
    what = (f"wheel radii of {radii[0]:.4g} m and {radii[1]:.4g} m, {ratios[0]:.3g} and "
            f"{ratios[1]:.3g} times the nominal {nominal[0]:.4g} m and {nominal[1]:.4g} m "
            "(no calibration moves a radius so far)")
    mean = math.sqrt(ratios[0] * ratios[1])
    if metre_radii(*radii):
        cause = METRE_RADII
    else:
        cause = next((words for words, scale in _RADIUS_SCALES
                      if abs(mean / scale - 1.0) <= 0.05), None)
        if cause is None and mean < 1.0:
            cause = (f"motor angles before a gearbox read as wheel angles (a gear ratio of "
                     f"about {1.0 / mean:.3g})")
        elif cause is None:
            cause = (f"wheel angles that turn {mean:.3g} times slower than the wheels, or "
                     "nominal values in other units")
    return f"{what}: {cause}? check the wheel columns and --init"
