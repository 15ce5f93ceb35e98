"""The hidden truth of a differential-drive robot, and the distribution it is drawn from.

Units: meters, radians, seconds, kilograms. Body frame: x forward, y left; the left wheel
sits at +b/2 on body y, the right wheel at -b/2, both on the axle (body x = 0). The body
frame's origin is the axle midpoint, the reference point of every pose in this package.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np

from excite.contracts import Traction
from excite.core.arena import DEFAULT_CHASSIS_SIZE


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


@dataclass(frozen=True)
class RobotSpec:
    """One robot's physical parameters (the truth the calibration tries to recover).

    Attributes:
        r_L, r_R: effective wheel radii (m).
        b: wheel separation (m).
        mass: chassis mass (kg).
        inertia: yaw moment of inertia about the center of mass (kg m^2).
        com_offset: center of mass ahead of the axle midpoint along body x (m). A spin about
            the axle midpoint needs the centripetal force mass * w^2 * com_offset from the
            wheels' lateral friction, so fast spins can slip.
        mu: wheel-floor friction coefficient (dimensionless).
        motor_tau: time constant of the first-order motor lag (s).
        max_wheel_speed: wheel angular speed limit (rad/s).
        wheel_load_fraction: share of the weight carried by the two drive wheels (the rest
            rests on a frictionless caster), in (0, 1].
        chassis_length, chassis_width: the rectangular chassis footprint (m) along body x and
            body y, centred on the axle midpoint; the walls collide with it.
    """

    r_L: float
    r_R: float
    b: float
    mass: float
    inertia: float
    com_offset: float
    mu: float
    motor_tau: float
    max_wheel_speed: float
    wheel_load_fraction: float
    chassis_length: float = DEFAULT_CHASSIS_SIZE
    chassis_width: float = DEFAULT_CHASSIS_SIZE

    def __post_init__(self) -> None:
        values = [getattr(self, f.name) for f in fields(self)]
        _require(_finite(*values), f"RobotSpec values must be finite, got {self}")
        for name in ("r_L", "r_R", "b", "mass", "inertia", "mu", "motor_tau", "max_wheel_speed",
                     "chassis_length", "chassis_width"):
            _require(getattr(self, name) > 0, f"RobotSpec.{name} must be > 0")
        _require(
            0 < self.wheel_load_fraction <= 1,
            f"RobotSpec.wheel_load_fraction must be in (0, 1], got {self.wheel_load_fraction}",
        )

    def kinematic_params(self) -> tuple[float, float, float]:
        """The calibrated quantities (r_L, r_R, b), in meters."""
        return (self.r_L, self.r_R, self.b)

    @property
    def chassis(self) -> tuple[float, float]:
        """The chassis footprint (length along body x, width along body y), in meters."""
        return (self.chassis_length, self.chassis_width)

    def fits_chassis(self) -> bool:
        """Whether both wheel contacts and the center of mass lie inside the chassis footprint
        (b < chassis width, |com_offset| < half the chassis length)."""
        return self.b < self.chassis_width and abs(self.com_offset) < 0.5 * self.chassis_length


@dataclass(frozen=True)
class RobotDistribution:
    """Nominal robot and the ranges hidden robots are drawn from.

    Relative ranges are half-widths: r_L, r_R and b are each drawn uniformly and independently
    in nominal * [1 - rel, 1 + rel]; mass likewise with `mass_rel`. The inertia scales with the
    drawn mass (same mass distribution). mu and com_offset are drawn uniformly in absolute
    ranges. Motor lag, speed limit, load fraction and the chassis are not randomized.

    Every robot the distribution can draw fits its chassis: the widest b is narrower than the
    chassis and the center of mass stays within half its length. The default values are the
    small default robot; `PRESETS` holds real robots and `robot_distribution` builds one from
    a preset name and overrides.
    """

    radius: float = 0.05
    separation: float = 0.30
    mass: float = 4.0
    inertia: float = 0.05
    com_offset: float = 0.04
    mu: float = 0.8
    motor_tau: float = 0.05
    max_wheel_speed: float = 20.0
    wheel_load_fraction: float = 0.8
    radius_rel: float = 0.05
    separation_rel: float = 0.05
    mass_rel: float = 0.20
    mu_range: tuple[float, float] = (0.5, 1.0)
    com_offset_range: tuple[float, float] = (0.0, 0.06)
    chassis_length: float = DEFAULT_CHASSIS_SIZE
    chassis_width: float = DEFAULT_CHASSIS_SIZE

    def __post_init__(self) -> None:
        nominal = self.nominal()  # validates the nominal values through RobotSpec
        for name in ("radius_rel", "separation_rel", "mass_rel"):
            rel = getattr(self, name)
            _require(
                _finite(rel) and 0 <= rel < 1,
                f"RobotDistribution.{name} must be in [0, 1), got {rel}",
            )
        for name in ("mu_range", "com_offset_range"):
            lo, hi = getattr(self, name)
            _require(
                _finite(lo, hi) and lo <= hi,
                f"RobotDistribution.{name} must be finite with low <= high, got {(lo, hi)}",
            )
        _require(self.mu_range[0] > 0, f"RobotDistribution.mu_range must be > 0: {self.mu_range}")
        widest = self.separation * (1 + self.separation_rel)
        farthest = max(abs(self.com_offset), *(abs(v) for v in self.com_offset_range))
        _require(
            nominal.fits_chassis() and widest < self.chassis_width
            and farthest < 0.5 * self.chassis_length,
            f"RobotDistribution: robots drawn must fit the {self.chassis_length} x "
            f"{self.chassis_width} m chassis: widest b {widest:.4g} m must be < the chassis "
            f"width, |com_offset| up to {farthest:.4g} m must be < half the chassis length",
        )

    @property
    def max_speed(self) -> float:
        """The nominal robot's top linear speed, radius * max_wheel_speed (m/s)."""
        return self.radius * self.max_wheel_speed

    def arena_size(self, segment_duration: float = 1.0) -> float:
        """Recommended side (m) of the square arena for this robot (:func:`arena_side` of its
        top speed and chassis). The default robot (1 m/s, 0.36 m chassis) gets exactly 4.0 m
        at 1-s segments."""
        return arena_side(self.max_speed, (self.chassis_length, self.chassis_width),
                          segment_duration)

    def nominal(self) -> RobotSpec:
        """The nominal robot (what the engineer believes before calibration)."""
        return RobotSpec(
            r_L=self.radius,
            r_R=self.radius,
            b=self.separation,
            mass=self.mass,
            inertia=self.inertia,
            com_offset=self.com_offset,
            mu=self.mu,
            motor_tau=self.motor_tau,
            max_wheel_speed=self.max_wheel_speed,
            wheel_load_fraction=self.wheel_load_fraction,
            chassis_length=self.chassis_length,
            chassis_width=self.chassis_width,
        )

    def sample(self, rng: np.random.Generator) -> RobotSpec:
        """Draw one hidden robot. Draw order is fixed, so a seeded rng gives the same robot."""
        r_L, r_R = self.radius * rng.uniform(1 - self.radius_rel, 1 + self.radius_rel, 2)
        b = self.separation * rng.uniform(1 - self.separation_rel, 1 + self.separation_rel)
        mass = self.mass * rng.uniform(1 - self.mass_rel, 1 + self.mass_rel)
        mu = rng.uniform(*self.mu_range)
        com_offset = rng.uniform(*self.com_offset_range)
        return RobotSpec(
            r_L=float(r_L),
            r_R=float(r_R),
            b=float(b),
            mass=float(mass),
            inertia=self.inertia * float(mass) / self.mass,
            com_offset=float(com_offset),
            mu=float(mu),
            motor_tau=self.motor_tau,
            max_wheel_speed=self.max_wheel_speed,
            wheel_load_fraction=self.wheel_load_fraction,
            chassis_length=self.chassis_length,
            chassis_width=self.chassis_width,
        )


def arena_side(max_speed: float, chassis: tuple[float, float],
               segment_duration: float = 1.0) -> float:
    """Recommended side (m) of the square arena (or a live session's area) for a robot of
    top speed ``max_speed`` (m/s) and footprint ``chassis`` (length, width in m): the larger
    of ARENA_SEGMENTS (4) segments driven straight at full speed (4 * max_speed *
    segment_duration) and ARENA_CHASSIS (10) lengths of the chassis' longer side, rounded to
    the millimetre."""
    _require(
        math.isfinite(segment_duration) and segment_duration > 0,
        f"segment_duration must be finite and > 0, got {segment_duration}",
    )
    travel = ARENA_SEGMENTS * max_speed * segment_duration
    return round(max(travel, ARENA_CHASSIS * max(chassis)), 3)


#: Full-speed segments that fit across the recommended arena (RobotDistribution.arena_size).
ARENA_SEGMENTS = 4
#: Chassis lengths (longer side) that fit across the recommended arena, at least.
ARENA_CHASSIS = 10
#: m/s^2, the acceleration at which a full-speed step from rest starts on every preset: the
#: default robot's (1.0 m/s top speed / 0.05 s motor lag). With it a full-speed step slips and
#: a step to 0.2 of the limit (4 m/s^2) stays near the grip limit (mu g load ~ 4-10 m/s^2) on
#: every preset, as on the default robot.
PRESET_STEP_ACCELERATION = 20.0


def scaled_distribution(
    *,
    radius: float,
    separation: float,
    mass: float,
    max_speed: float,
    chassis_length: float,
    chassis_width: float,
    wheel_load_fraction: float,
) -> RobotDistribution:
    """A robot distribution from published geometry, with the unpublished values estimated.

    Published (arguments): wheel radius and separation (m), mass (kg), top linear speed (m/s),
    chassis footprint (m), share of the weight on the driven wheels. Estimated, scaled to the
    robot the way the default robot's values sit on its 0.36 m chassis:

    - inertia: a uniform box of the footprint, mass * (length^2 + width^2) / 12;
    - com_offset: length / 9 ahead of the axle, drawn in (0, length / 6) (the default robot:
      0.04 m in (0, 0.06) on 0.36 m);
    - motor_tau: max_speed / PRESET_STEP_ACCELERATION (same starting acceleration of a
      full-speed step as the default robot);
    - max_wheel_speed: max_speed / radius (rad/s);
    - friction and the randomization half-widths: the default robot's.
    """
    return RobotDistribution(
        radius=radius,
        separation=separation,
        mass=mass,
        inertia=mass * (chassis_length**2 + chassis_width**2) / 12.0,
        com_offset=chassis_length / 9.0,
        com_offset_range=(0.0, chassis_length / 6.0),
        motor_tau=max_speed / PRESET_STEP_ACCELERATION,
        max_wheel_speed=max_speed / radius,
        wheel_load_fraction=wheel_load_fraction,
        chassis_length=chassis_length,
        chassis_width=chassis_width,
    )


#: Named robots. Each is modelled as a two-wheel differential drive with its published nominal
#: geometry; the hidden robots are drawn around it (5 % on r and b, 20 % on mass). Footprints
#: are centred on the axle midpoint (the real Burger's body sits 32 mm behind its axle).
#: Jackal and Husky are four-wheel skid-steer robots: all their weight is on driven wheels
#: (load fraction 1), and their real effective track, which calibration measures, is wider than
#: the geometric one (their ROS 1 controllers use wheel_separation_multiplier 1.5 and 1.875).
PRESETS: dict[str, RobotDistribution] = {
    # The small default robot (unchanged): 0.05 m wheels, b = 0.30 m, 4 kg, 1 m/s, 0.36 m chassis.
    "default": RobotDistribution(),
    # ROBOTIS TurtleBot3 Burger. Wheel radius 0.033 m and separation 0.160 m: ROBOTIS-GIT/
    # turtlebot3, turtlebot3_node/param/burger.yaml (wheels: radius, separation); mass 1 kg,
    # max translational velocity 0.22 m/s, size (L x W) 138 x 178 mm: ROBOTIS e-manual,
    # TurtleBot3 > Specifications > Hardware Specifications. The width is b + one 18 mm wheel.
    # Estimated: load fraction 0.8 (a ball caster carries the rest, like the default robot).
    "turtlebot3": scaled_distribution(
        radius=0.033, separation=0.160, mass=1.0, max_speed=0.22,
        chassis_length=0.138, chassis_width=0.178, wheel_load_fraction=0.8,
    ),
    # Clearpath Jackal. Wheel radius 0.098 m and track 0.37559 m: jackal/jackal,
    # jackal_description/urdf/jackal.urdf.xacro (wheel_radius, track); mass 17 kg, max speed
    # 2.0 m/s, external size 508 x 430 mm: Clearpath Jackal user manual, system
    # specifications. The width is about b + one 40 mm wheel (the URDF's wheel_width).
    "jackal": scaled_distribution(
        radius=0.098, separation=0.37559, mass=17.0, max_speed=2.0,
        chassis_length=0.508, chassis_width=0.430, wheel_load_fraction=1.0,
    ),
    # Clearpath Husky A200. Wheel radius 0.1651 m (13 in tyre): husky/husky,
    # husky_description/urdf/husky.urdf.xacro (wheel_radius); effective track 0.555 m, mass
    # 50 kg, max speed 1.0 m/s, size 990 x 670 mm: Clearpath Husky A200 user manual
    # (docs.clearpathrobotics.com, "Robot Equations" and "System Specifications").
    "husky": scaled_distribution(
        radius=0.1651, separation=0.555, mass=50.0, max_speed=1.0,
        chassis_length=0.990, chassis_width=0.670, wheel_load_fraction=1.0,
    ),
}

_FIELDS = tuple(f.name for f in fields(RobotDistribution))


def scaled_robot(base: RobotDistribution, scale: object) -> RobotDistribution:
    """A geometrically similar robot ``scale`` times the size of ``base``: every length times
    scale (wheel radius, separation, chassis, centre-of-mass offset and its range), the mass
    times scale^3 and the inertia times scale^5 (same density and shape), the same top linear
    speed (the wheel speed limit, rad/s, divided by scale) and motor lag; friction, load
    fraction and the randomization half-widths unchanged. Raises ValueError unless scale is a
    positive finite number."""
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (
            _finite(scale) and scale > 0):
        raise ValueError(f"robot scale must be a positive number, got {scale!r}")
    s = float(scale)
    low, high = base.com_offset_range
    return dataclasses.replace(
        base,
        radius=base.radius * s,
        separation=base.separation * s,
        mass=base.mass * s**3,
        inertia=base.inertia * s**5,
        com_offset=base.com_offset * s,
        com_offset_range=(low * s, high * s),
        max_wheel_speed=base.max_wheel_speed / s,
        chassis_length=base.chassis_length * s,
        chassis_width=base.chassis_width * s,
    )
_RANGES = ("mu_range", "com_offset_range")


def robot_distribution(
    spec: str | Mapping[str, object] | RobotDistribution | None = None,
) -> RobotDistribution:
    """The robot distribution a configuration names.

    spec: None or {} for the default robot; a preset name (a key of PRESETS); a mapping with an
    optional "preset" (default "default"), an optional "scale" (the preset made that many
    times larger, :func:`scaled_robot`) plus RobotDistribution field overrides, e.g.
    {"preset": "jackal", "radius_rel": 0.03}; or a RobotDistribution, returned as is.
    Overrides replace the (scaled) preset's values literally (derived values such as the
    inertia are not recomputed). Raises ValueError for an unknown preset or key (naming the
    valid ones) and for values the distribution rejects.
    """
    if spec is None or isinstance(spec, RobotDistribution):
        return spec if spec is not None else PRESETS["default"]
    if isinstance(spec, str):
        return _preset(spec)
    if not isinstance(spec, Mapping):
        raise ValueError(
            f"robot must be a preset name ({', '.join(PRESETS)}), a mapping of "
            f"RobotDistribution overrides or a RobotDistribution, got {spec!r}"
        )
    overrides = dict(spec)
    base = _preset(overrides.pop("preset", "default"))
    if "scale" in overrides:
        base = scaled_robot(base, overrides.pop("scale"))
    unknown = sorted(str(k) for k in overrides if k not in _FIELDS)
    if unknown:
        raise ValueError(
            f"unknown robot key(s) {', '.join(unknown)}; valid: preset, scale, "
            f"{', '.join(_FIELDS)}"
        )
    for name in _RANGES:
        if name in overrides:
            overrides[name] = _pair(name, overrides[name])
    try:
        return dataclasses.replace(base, **overrides)
    except TypeError as exc:  # e.g. a string where a number belongs
        raise ValueError(f"bad robot value: {exc}") from None


def _preset(name: object) -> RobotDistribution:
    key = name.strip().lower() if isinstance(name, str) else name
    if key not in PRESETS:
        raise ValueError(f"unknown robot preset {name!r}; valid presets: {', '.join(PRESETS)}")
    return PRESETS[key]


def _pair(name: str, value: object) -> tuple[float, float]:
    """A (low, high) range from any two-element sequence (YAML and JSON give lists)."""
    try:
        low, high = value  # type: ignore[misc]
        return (float(low), float(high))
    except (TypeError, ValueError):
        raise ValueError(f"robot {name} must be a (low, high) pair, got {value!r}") from None


#: m/s^2, the acceleration of gravity (the wheels' grip is mu g per unit load).
GRAVITY = 9.81


def traction_of(robot: RobotSpec) -> Traction:
    """What a planner may know of ``robot``'s traction (:class:`excite.contracts.Traction`):
    its motor lag, its grip mu g (load fraction on the wheels) and its spin inertia
    I / (m (b/2)^2), the quantities the physics' slip model uses."""
    return Traction(robot.motor_tau, robot.mu * GRAVITY * robot.wheel_load_fraction,
                    robot.inertia / (robot.mass * (0.5 * robot.b) ** 2))
