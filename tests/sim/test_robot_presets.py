"""Robots of any size: presets, the robot's own chassis and arena, physics at every size."""

from __future__ import annotations

import dataclasses
import hashlib
import math
import pickle

import numpy as np
import pytest

from envs.robot import (
    DEFAULT_CHASSIS_SIZE,
    PRESETS,
    RobotDistribution,
    RobotSpec,
    robot_distribution,
    scaled_robot,
)
from envs.simulation import SPAWN_MARGIN, Simulation, SimulationConfig, spawn_margin
from excite import Params, predict_increment
from excite.core.arena import Arena

NAMES = sorted(PRESETS)


def preset_sim(name: str, ideal: bool, arena: float | None = None) -> Simulation:
    size = arena or PRESETS[name].arena_size()
    return Simulation(SimulationConfig(arena_width=size, arena_height=size, ideal=ideal))


# -- presets ---------------------------------------------------------------------------------


def test_presets_include_the_published_robots():
    assert {"default", "turtlebot3", "jackal", "husky"} <= set(PRESETS)
    assert PRESETS["default"] == RobotDistribution()  # today's robot, unchanged
    published = {  # radius, separation, mass, top speed, chassis length x width
        "turtlebot3": (0.033, 0.160, 1.0, 0.22, 0.138, 0.178),
        "jackal": (0.098, 0.37559, 17.0, 2.0, 0.508, 0.430),
        "husky": (0.1651, 0.555, 50.0, 1.0, 0.990, 0.670),
    }
    for name, (radius, b, mass, speed, length, width) in published.items():
        dist = PRESETS[name]
        assert (dist.radius, dist.separation, dist.mass) == (radius, b, mass)
        assert dist.max_speed == pytest.approx(speed, rel=1e-12)
        assert dist.max_wheel_speed == pytest.approx(speed / radius, rel=1e-12)
        assert (dist.chassis_length, dist.chassis_width) == (length, width)
        # Estimated values, scaled to the robot: a uniform box of the footprint, the default
        # robot's com_offset per chassis length and its peak step acceleration.
        assert dist.inertia == pytest.approx(mass * (length**2 + width**2) / 12)
        assert dist.com_offset / length == pytest.approx(0.04 / 0.36)
        assert speed / dist.motor_tau == pytest.approx(1.0 / 0.05)


@pytest.mark.parametrize("name", NAMES)
def test_every_preset_constructs_samples_and_fits_its_chassis_and_arena(name):
    dist = PRESETS[name]
    nominal = dist.nominal()
    assert nominal.fits_chassis()
    assert nominal.chassis == (dist.chassis_length, dist.chassis_width)
    rng = np.random.default_rng(0)
    robots = [dist.sample(rng) for _ in range(300)]
    for robot in robots:
        assert robot.fits_chassis() and robot.chassis == nominal.chassis
        assert abs(robot.b / dist.separation - 1) <= dist.separation_rel
        assert robot.inertia / robot.mass == pytest.approx(dist.inertia / dist.mass)
    assert dist.sample(np.random.default_rng(3)) == dist.sample(np.random.default_rng(3))
    arena = dist.arena_size()
    assert arena > 2 * spawn_margin(nominal)
    assert arena > 2 * math.hypot(*nominal.chassis)
    sim = preset_sim(name, ideal=False)
    for robot in robots[:20]:
        sim.reset(robot, rng)
        x, y, theta = sim.pose
        assert max(abs(x), abs(y)) <= arena / 2 - spawn_margin(robot) + 1e-12
        assert sim.arena.contains_footprint(x, y, theta, chassis=robot.chassis)


def test_arena_size_rule():
    assert PRESETS["default"].arena_size() == 4.0  # exactly today's arena
    for name, dist in PRESETS.items():
        rule = max(4 * dist.max_speed, 10 * max(dist.chassis_length, dist.chassis_width))
        assert dist.arena_size() == pytest.approx(rule, abs=5e-4), name
    assert PRESETS["jackal"].arena_size() == 8.0  # 4 s at 2 m/s
    assert PRESETS["husky"].arena_size() == 9.9  # 10 lengths of 0.99 m
    assert PRESETS["turtlebot3"].arena_size() == 1.78  # 10 widths of 0.178 m
    assert PRESETS["default"].arena_size(segment_duration=2.0) == 8.0
    with pytest.raises(ValueError):
        PRESETS["default"].arena_size(segment_duration=0.0)


def test_spawn_margin_scales_with_the_chassis():
    assert spawn_margin(PRESETS["default"].nominal()) == SPAWN_MARGIN == 0.6
    husky = PRESETS["husky"].nominal()
    assert spawn_margin(husky) == pytest.approx(0.6 * 0.99 / 0.36)
    for dist in PRESETS.values():
        robot = dist.nominal()
        assert spawn_margin(robot) > 0.5 * math.hypot(*robot.chassis)  # any heading fits


# -- robot_distribution -----------------------------------------------------------------------


def test_robot_distribution_accepts_every_spec_form():
    default = PRESETS["default"]
    assert robot_distribution(None) == default
    assert robot_distribution({}) == default
    assert robot_distribution() == default
    for name in PRESETS:
        assert robot_distribution(name) == PRESETS[name]
        assert robot_distribution({"preset": name}) == PRESETS[name]
    assert robot_distribution(" Jackal ") == PRESETS["jackal"]
    custom = robot_distribution({"preset": "jackal", "radius_rel": 0.03})
    assert custom == dataclasses.replace(PRESETS["jackal"], radius_rel=0.03)
    assert robot_distribution({"radius_rel": 0.02}) == RobotDistribution(radius_rel=0.02)
    ranges = robot_distribution({"preset": "husky", "mu_range": [0.6, 0.9]})  # lists from YAML
    assert ranges.mu_range == (0.6, 0.9)
    assert robot_distribution(custom) is custom


@pytest.mark.parametrize(
    ("spec", "names"),
    [
        ("tank", PRESETS),
        ({"preset": "tank"}, PRESETS),
        ({"preset": "husky", "wheel_radius": 0.2}, ("preset", "radius", "radius_rel")),
        (3, PRESETS),
    ],
)
def test_robot_distribution_rejects_unknown_names_listing_the_valid_ones(spec, names):
    with pytest.raises(ValueError) as info:
        robot_distribution(spec)
    for name in names:
        assert name in str(info.value)


@pytest.mark.parametrize(
    "spec",
    [
        {"preset": "husky", "separation": 0.70},  # wider than the Husky's 0.67 m chassis
        {"preset": "turtlebot3", "com_offset_range": (0.0, 0.08)},  # past half of 0.138 m
        {"radius_rel": 1.5},
        {"mu_range": 0.5},
        {"mass": "heavy"},
        {"scale": 0.0},
        {"scale": -2.0},
        {"scale": float("nan")},
        {"scale": "big"},
        {"scale": True},
    ],
)
def test_robot_distribution_rejects_bad_values(spec):
    with pytest.raises(ValueError):
        robot_distribution(spec)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("scale", [0.5, 1.0, 2.5])
def test_a_scaled_preset_is_the_same_robot_made_larger(name, scale):
    """{"preset": P, "scale": s}: lengths x s, mass x s^3, inertia x s^5, the same top linear
    speed and motor lag; it fits its own chassis and arena and drives."""
    base, big = PRESETS[name], robot_distribution({"preset": name, "scale": scale})
    assert big == scaled_robot(base, scale)
    for field in ("radius", "separation", "com_offset", "chassis_length", "chassis_width"):
        assert getattr(big, field) == pytest.approx(getattr(base, field) * scale, rel=1e-12)
    assert big.com_offset_range == pytest.approx(tuple(v * scale for v in base.com_offset_range))
    assert big.mass == pytest.approx(base.mass * scale**3, rel=1e-12)
    assert big.inertia == pytest.approx(base.inertia * scale**5, rel=1e-12)
    assert big.radius * big.max_wheel_speed == pytest.approx(base.radius * base.max_wheel_speed)
    for same in ("motor_tau", "mu_range", "wheel_load_fraction", "radius_rel", "separation_rel"):
        assert getattr(big, same) == getattr(base, same)
    assert big.max_speed == pytest.approx(base.max_speed, rel=1e-12)  # the arena follows
    assert big.arena_size() >= 10 * max(big.chassis_length, big.chassis_width) - 1e-3
    rng = np.random.default_rng(3)
    robot = big.sample(rng)
    assert robot.fits_chassis()
    size = big.arena_size()
    sim = Simulation(SimulationConfig(arena_width=size, arena_height=size))
    sim.reset(robot, rng)
    w = robot.max_wheel_speed
    outs = [sim.run_segment(*cmd, 1.0) for cmd in rng.uniform(-0.3 * w, 0.3 * w, (5, 2))]
    assert all(np.isfinite(out.measurement).all() for out in outs)


# -- the big robot ----------------------------------------------------------------------------


@pytest.mark.parametrize("ideal", [True, False])
def test_a_robot_wider_than_the_old_chassis_runs(ideal):
    """The Husky (b = 0.555 m) failed with "robot does not fit the 0.36 m chassis"."""
    dist = PRESETS["husky"]
    rng = np.random.default_rng(21)
    robot = dist.sample(rng)
    assert robot.b > 0.5
    for arena in (4.0, dist.arena_size()):
        sim = preset_sim("husky", ideal, arena)
        sim.reset(robot, rng)
        w = robot.max_wheel_speed
        outs = [sim.run_segment(*cmd, 1.0) for cmd in rng.uniform(-w, w, (10, 2))]
        assert all(np.isfinite(out.measurement).all() for out in outs)
    copy = pickle.loads(pickle.dumps(sim))
    a, b = sim.run_segment(0.3 * w, 0.5 * w, 1.0), copy.run_segment(0.3 * w, 0.5 * w, 1.0)
    np.testing.assert_array_equal(a.path, b.path)


@pytest.mark.parametrize("ideal", [True, False])
def test_walls_stop_the_robots_own_chassis(ideal):
    """Driving straight into a wall stops the front of the robot's own chassis at the wall."""
    for name in NAMES:
        robot = PRESETS[name].nominal()
        sim = preset_sim(name, ideal)
        sim.reset(robot, np.random.default_rng(0), pose=np.zeros(3))
        half = 0.5 * sim.arena.width
        w, speed = 0.5 * robot.max_wheel_speed, 0.5 * PRESETS[name].max_speed
        duration = math.ceil((half - 0.5 * robot.chassis_length) / speed) + 1.0
        out = sim.run_segment(w, w, duration)
        assert out.collision, name
        # The front stops within one tick's travel before the wall (ideal) or pressed into it
        # (pymunk pushes half the overlap out per tick while the slipping wheels push on: an
        # equilibrium of about 2 mu g dt^2 + 1 mm slop, 5-7 mm at any size); with the old
        # 0.36 m square it would stop 0.11 m (Burger) to 0.32 m (Husky) off.
        tick = speed * sim.dt
        front = out.pose_end[0] + 0.5 * robot.chassis_length
        assert half - tick - 1e-9 <= front <= half + (1e-9 if ideal else 0.01), name
        assert abs(out.pose_end[1]) < 1e-3 and abs(out.pose_end[2]) < 1e-3, name


def test_contains_footprint_uses_the_chassis_rectangle():
    arena = Arena(4.0, 4.0)
    chassis = (0.99, 0.67)  # long along body x
    x = 2.0 - 0.99 / 2
    assert arena.contains_footprint(x - 1e-9, 0.0, 0.0, chassis=chassis)
    assert not arena.contains_footprint(x + 1e-6, 0.0, 0.0, chassis=chassis)
    # Turned a quarter turn, the narrow side faces the +x wall.
    assert arena.contains_footprint(2.0 - 0.67 / 2 - 1e-9, 0.0, math.pi / 2, chassis=chassis)
    assert arena.contains_footprint(0.0, x - 1e-9, math.pi / 2, chassis=chassis)
    assert not arena.contains_footprint(0.0, x + 1e-6, math.pi / 2, chassis=chassis)
    # The default chassis stays the default (callers that pass no chassis keep working).
    half = DEFAULT_CHASSIS_SIZE / 2
    theta = np.array([0.0, 0.3, math.pi / 4])
    reach = half * (np.abs(np.cos(theta)) + np.abs(np.sin(theta)))
    np.testing.assert_array_equal(
        arena.contains_footprint(2.0 - reach - 1e-12, 0.0, theta, 0.0), [True, True, True])
    assert not arena.contains_footprint(2.0 - reach[1] + 1e-9, 0.0, theta[1], 0.0)
    assert not arena.contains_footprint(0.0, 2.0 - half, 0.0, 0.01)


# -- physics at every size ---------------------------------------------------------------------


def max_overlap(path: np.ndarray, robot: RobotSpec, arena: Arena) -> float:
    """How far (m) the chassis footprint reaches past the walls along the path (< 0: clear)."""
    length, width = robot.chassis
    c, s = np.abs(np.cos(path[:, 2])), np.abs(np.sin(path[:, 2]))
    over_x = np.abs(path[:, 0]) + 0.5 * (length * c + width * s) - 0.5 * arena.width
    over_y = np.abs(path[:, 1]) + 0.5 * (length * s + width * c) - 0.5 * arena.height
    return float(max(over_x.max(), over_y.max()))


@pytest.mark.parametrize("ideal", [True, False])
@pytest.mark.parametrize("name", NAMES)
def test_random_driving_is_finite_and_never_tunnels(name, ideal):
    """300 full-range random 1-s segments (6 robots) in the recommended arena: no NaN, and
    the footprint never goes past a wall by more than one tick's travel of its fastest corner
    (pymunk resolves contacts after moving; the ideal drive stops before the wall)."""
    dist = PRESETS[name]
    sim = preset_sim(name, ideal)
    rng = np.random.default_rng(100)
    collisions = 0
    for _ in range(6):
        robot = dist.sample(rng)
        sim.reset(robot, rng)
        w = robot.max_wheel_speed
        speed = max(robot.r_L, robot.r_R) * w
        spin = (robot.r_L + robot.r_R) * w / robot.b
        tick_travel = (speed + spin * 0.5 * math.hypot(*robot.chassis)) * sim.dt
        for cmd in rng.uniform(-w, w, (50, 2)):
            out = sim.run_segment(*cmd, 1.0)
            assert np.isfinite(out.path).all() and np.isfinite(out.measurement).all()
            overlap = max_overlap(out.path, robot, sim.arena)
            assert overlap <= (1e-12 if ideal else tick_travel + 2e-3), (name, overlap)
            collisions += out.collision
    assert collisions > 0  # the walls were exercised


def relative_errors(outs: list, truth: Params) -> np.ndarray:
    """Per segment: |true increment - model increment| / |model increment|, heading as arc
    length at the wheels (b/2 * dtheta), with the true wheel increments and parameters."""
    scale = np.array([1.0, 1.0, 0.5 * truth.b])
    errors = []
    for out in outs:
        predicted = np.ravel(predict_increment(*out.true_dphi, truth))
        errors.append(np.linalg.norm(scale * (out.true_increment - predicted))
                      / np.linalg.norm(scale * predicted))
    return np.array(errors)


@pytest.mark.parametrize("ideal", [True, False])
@pytest.mark.parametrize("name", NAMES)
def test_gentle_commands_follow_the_kinematic_model(name, ideal):
    """Commands up to 0.2 of the motor limit, 4 robots per preset, in a walls-free arena:

    - a held command, after its motor transient, rolls exactly along the model;
    - stop-and-go segments (settled for 10+ motor time constants, so both wheels share the
      lag shape) stay within 1e-5: no slip to speak of (a 0.2 step starts at 4 m/s^2, about
      the weakest grip on every preset);
    - 200 continuously driven segments: while the commands change, the motor lag bends the
      path, by at most 1.5 (0.5 on average) motor time constants' share of the segment
      (measured: 0.8 and 0.3 on the Jackal, whose 0.1 s lag is the slowest).
    The ideal drive is exact throughout."""
    dist = PRESETS[name]
    sim = preset_sim(name, ideal, arena=1000.0)
    rng = np.random.default_rng(7)
    exact = 1e-12 if ideal else None
    lag = dist.motor_tau / 1.0  # share of a 1-s segment
    for _ in range(4):
        robot = dist.sample(rng)
        truth = Params(*robot.kinematic_params())
        limit = 0.2 * robot.max_wheel_speed

        sim.reset(robot, rng, pose=np.zeros(3))
        held = rng.uniform(-limit, limit, 2)
        sim.run_segment(*held, 1.0)  # motor transient
        assert relative_errors([sim.run_segment(*held, 1.0)], truth).max() < (exact or 1e-9)

        sim.reset(robot, rng, pose=np.zeros(3))
        stop_go = [sim.run_segment(*cmd, 1.0, settle=1.0)
                   for cmd in rng.uniform(-limit, limit, (10, 2))]
        assert relative_errors(stop_go, truth).max() < (exact or 1e-5)

        sim.reset(robot, rng, pose=np.zeros(3))
        driven = [sim.run_segment(*cmd, 1.0) for cmd in rng.uniform(-limit, limit, (50, 2))]
        errors = relative_errors(driven, truth)
        assert not any(out.collision for out in driven)
        assert errors.max() < (exact or 1.5 * lag) and errors.mean() < (exact or 0.5 * lag)


# -- the default robot is unchanged -------------------------------------------------------------

# Recorded by running the code before presets existed (a random start pose, 12 random 1-s
# segments reaching the walls, seed 2024): sha256 of the (12, 5) float64 measurements and of
# the concatenated tick paths, the collisions, and the first measurement row. The slip case's
# two sha256 were re-recorded when the traction moved into the compiled kernel
# (envs.traction_kernel: libm's hypot in the friction circle instead of CPython's, which
# differ in the last bit now and then): against the recording before, the measurements moved
# by at most 5.6e-17 (2 of 60 values), the paths by at most 1.1e-16; the collisions and the
# first row are the values recorded before presets existed. The ideal case's two sha256 and
# first row were re-recorded when excite.core.kinematics.sinc_family moved from sin and cos
# of u/2 to tan(u/2): the measurements moved by at most 2.8e-16 (3 of 60 values).
BEFORE = {
    False: (
        "178d3b1dba986f789f56aa50027b6b5bc2691a066a2722a2a32743d2bdfbb5b4",
        "e29a2b457dfdd1a830bfb2f76f77b9af9671b01b94fd74d0cc65bfb25c0433e4",
        [False] * 6 + [True] * 5 + [False],
        [-3.6309325249253126, -18.285050991596844, -0.1604976063745807, 0.3824772483141297,
         -2.3644165885814323],
    ),
    True: (
        "8eaab5ae62ea55a7b20d16e8b5a2f18b96347449ad184b9fa98c3eb76e83c77c",
        "1dd752d9b6526fe796c73780574083790a4ce0f6dd3ede7367ad64eb3c0c306f",
        [False] * 6 + [True, False, True, True, False, False],
        [-3.784330603713877, -19.061245270266976, -0.13727494204269816, 0.40088633865708956,
         -2.4901614526549185],
    ),
}
#: sha256 of env.unwrapped.segments.as_array() after reset(seed=5) and 10 seeded actions on
#: the default excite/DiffDriveCalib-v0, recorded before presets existed.
BEFORE_ENV = "28a2d103c61acb85eb7917899935c04de7ff8c041971173176a404d258f6632a"


def sha(array: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(array, dtype=np.float64).tobytes()).hexdigest()


@pytest.mark.parametrize("ideal", [False, True])
def test_default_robot_is_bit_identical_to_before(ideal):
    rng = np.random.default_rng(2024)
    sim = Simulation(SimulationConfig(ideal=ideal))
    sim.reset(RobotDistribution().sample(rng), rng)
    commands = np.random.default_rng(2124).uniform(-20, 20, (12, 2))
    outs = [sim.run_segment(*cmd, 1.0) for cmd in commands]
    measurements = np.array([out.measurement for out in outs])
    paths = np.concatenate([out.path for out in outs])
    measured_sha, path_sha, collisions, first_row = BEFORE[ideal]
    assert [out.collision for out in outs] == collisions
    assert measurements[0].tolist() == first_row
    assert sha(measurements) == measured_sha
    assert sha(paths) == path_sha


def test_default_env_log_is_bit_identical_to_before():
    gym = pytest.importorskip("gymnasium")
    import excite  # noqa: F401  (registers the ids)

    env = gym.make("excite/DiffDriveCalib-v0")
    env.reset(seed=5)
    for action in np.random.default_rng(1).uniform(-1, 1, (10, 2)).astype(np.float32):
        env.step(action)
    assert sha(env.unwrapped.segments.as_array()) == BEFORE_ENV
    env.close()


# -- rendering ------------------------------------------------------------------------------------


def chassis_box_px(name: str, arena: float) -> tuple[int, int]:
    """Pixel extent (x, y) of the drawn chassis (orange) of a preset's nominal robot."""
    pytest.importorskip("matplotlib")
    from envs.rendering import ArenaRenderer

    renderer = ArenaRenderer(arena)
    robot = PRESETS[name].nominal()
    frame = renderer.draw(np.zeros((2, 3)), np.array([0.3, 0.2, 0.0]), robot,
                          Params(*robot.kinematic_params()), 1.0, 1, 10).astype(int)
    renderer.close()
    orange = (frame[..., 0] > 200) & (np.abs(frame[..., 1] - 178) < 30) & (frame[..., 2] < 150)
    ys, xs = np.nonzero(orange)
    return xs.max() - xs.min() + 1, ys.max() - ys.min() + 1


@pytest.mark.parametrize(("name", "arena"), [("husky", 10.0), ("turtlebot3", 1.78)])
def test_rendering_draws_the_robots_own_chassis(name, arena):
    length, width = PRESETS[name].nominal().chassis
    px, py = chassis_box_px(name, arena)
    dx, dy = chassis_box_px("default", arena)
    assert px / dx == pytest.approx(length / DEFAULT_CHASSIS_SIZE, rel=0.1)
    assert py / dy == pytest.approx(width / DEFAULT_CHASSIS_SIZE, rel=0.1)
