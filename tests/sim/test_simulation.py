"""Tests of the simulation layer: robot, drives, sensors and the Simulation facade."""

from __future__ import annotations

import ast
import math
import pickle
from pathlib import Path

import numpy as np
import pytest

from envs.robot import DEFAULT_CHASSIS_SIZE as CHASSIS_SIZE
from envs.robot import RobotDistribution, RobotSpec
from envs.sensors import RelativePoseSensor, WheelEncoders
from envs.simulation import SPAWN_MARGIN, Simulation, SimulationConfig
from excite.core import se2
from excite.core.arena import Arena
from excite.core.kinematics import predict_increment
from excite.core.models import compose_substeps

DIST = RobotDistribution()
BIG = {"arena_width": 200.0, "arena_height": 200.0}  # room for any segment without walls


def kinematic_increment(dphi: np.ndarray, robot: RobotSpec) -> np.ndarray:
    """The lesson's closed-form constant-curvature increment (dx, dy, dtheta)."""
    r_L, r_R, b = robot.kinematic_params()
    ds = 0.5 * (r_L * dphi[0] + r_R * dphi[1])
    dth = (r_R * dphi[1] - r_L * dphi[0]) / b
    if dth == 0.0:
        return np.array([ds, 0.0, 0.0])
    return np.array([ds * math.sin(dth) / dth, ds * (1 - math.cos(dth)) / dth, dth])


def make_sim(seed: int = 0, pose=(0.0, 0.0, 0.0), **config) -> Simulation:
    rng = np.random.default_rng(seed)
    sim = Simulation(SimulationConfig(**config))
    sim.reset(DIST.sample(rng), rng, pose=None if pose is None else np.array(pose))
    return sim


def test_robot_distribution_samples_within_ranges():
    rng = np.random.default_rng(1)
    nominal = DIST.nominal()
    assert nominal.kinematic_params() == (0.05, 0.05, 0.30)
    for _ in range(200):
        robot = DIST.sample(rng)
        assert abs(robot.r_L / 0.05 - 1) <= 0.05 and abs(robot.r_R / 0.05 - 1) <= 0.05
        assert abs(robot.b / 0.30 - 1) <= 0.05
        assert abs(robot.mass / 4.0 - 1) <= 0.2
        assert robot.inertia / robot.mass == pytest.approx(nominal.inertia / nominal.mass)
        assert 0.5 <= robot.mu <= 1.0 and 0.0 <= robot.com_offset <= 0.06
    assert DIST.sample(np.random.default_rng(7)) == DIST.sample(np.random.default_rng(7))


@pytest.mark.parametrize(
    "make",
    [
        lambda: RobotDistribution(radius_rel=1.5),
        lambda: RobotDistribution(mu_range=(1.0, 0.5)),
        lambda: RobotDistribution(mu_range=(0.0, 0.5)),
        lambda: RobotDistribution(mass=-1.0),
        lambda: RobotDistribution(com_offset_range=(0.0, math.nan)),
        lambda: RobotSpec(0.05, 0.05, 0.3, 4.0, 0.05, 0.04, 0.8, 0.05, 20.0, 1.5),
        lambda: RobotSpec(0.05, -0.05, 0.3, 4.0, 0.05, 0.04, 0.8, 0.05, 20.0, 0.8),
        lambda: SimulationConfig(physics_hz=0.0),
        lambda: SimulationConfig(arena_width=0.0),
        lambda: SimulationConfig(arena_height=math.nan),
        lambda: SimulationConfig(ticks_per_rev=0),
        lambda: SimulationConfig(sigma_xy=-1e-3),
        lambda: Simulation(SimulationConfig(ticks_per_rev=0)),
        lambda: Simulation(SimulationConfig(sigma_theta=-1.0)),
        lambda: Arena(0.0, 4.0),
        lambda: Arena(4.0, math.inf),
        lambda: WheelEncoders(10.5),
    ],
)
def test_bad_configuration_raises(make):
    with pytest.raises(ValueError):
        make()


def test_bad_segment_and_reset_arguments_raise():
    with pytest.raises(RuntimeError):
        Simulation().run_segment(1.0, 1.0, 1.0)
    sim = make_sim()
    for duration in (0.0, -1.0, 0.011, math.inf):
        with pytest.raises(ValueError):
            sim.run_segment(1.0, 1.0, duration)
    with pytest.raises(ValueError):
        sim.run_segment(math.nan, 1.0, 1.0)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError):
        sim.reset(DIST.nominal(), rng, pose=np.array([1.95, 0.0, 0.0]))  # overlaps a wall
    with pytest.raises(ValueError):
        sim.reset(DIST.nominal(), rng, pose=np.array([0.0, 0.0]))
    wide = RobotSpec(0.05, 0.05, CHASSIS_SIZE, 4.0, 0.05, 0.0, 0.8, 0.05, 20.0, 0.8)
    with pytest.raises(ValueError, match="does not fit its 0.36 x 0.36 m chassis"):
        sim.reset(wide, rng)
    small = Simulation(SimulationConfig(arena_width=1.0))  # the arena fit depends on the robot
    with pytest.raises(ValueError, match="arena is too small"):
        small.reset(DIST.nominal(), rng)


@pytest.mark.parametrize("ideal", [True, False])
def test_random_start_pose_is_well_inside(ideal):
    sim = Simulation(SimulationConfig(ideal=ideal))
    rng = np.random.default_rng(3)
    for _ in range(50):
        sim.reset(DIST.sample(rng), rng)
        x, y, theta = sim.pose
        assert max(abs(x), abs(y)) <= 2.0 - SPAWN_MARGIN + 1e-12
        assert -math.pi <= theta < math.pi


def test_ideal_reproduces_kinematics_exactly():
    sim = make_sim(seed=2, ideal=True, **BIG)
    rng = np.random.default_rng(4)
    w = sim.robot.max_wheel_speed
    commands = [(w, -w), (-w, w), (7.0, 7.0), (-3.0, -3.0), (0.0, 0.0), (0.0, 5.0)]
    commands += [tuple(c) for c in rng.uniform(-w, w, (40, 2))]
    for cmd in commands:
        duration = float(rng.choice([0.2, 1.0, 2.5]))
        out = sim.run_segment(*cmd, duration)
        expected = kinematic_increment(out.true_dphi, sim.robot)
        np.testing.assert_allclose(out.true_increment, expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(out.true_dphi, np.array(cmd) * duration, atol=1e-12)
        assert not out.collision
    spin = sim.run_segment(-w, w, 1.0)
    assert spin.true_increment[2] > math.pi  # pure spin beyond pi, continuous heading


def test_ideal_path_is_the_arc_at_physics_rate():
    sim = make_sim(ideal=True, physics_hz=50.0)
    out = sim.run_segment(4.0, 9.0, 0.6)
    assert out.path.shape == (31, 3)
    np.testing.assert_array_equal(out.path[0], out.pose_start)
    np.testing.assert_array_equal(out.path[-1], out.pose_end)
    half = se2.between_scalar(out.pose_start, out.path[15])
    expected = kinematic_increment(out.true_dphi / 2, sim.robot)
    np.testing.assert_allclose(half, expected, atol=1e-12)


def test_physics_matches_kinematics_at_gentle_speed_after_transient():
    rng = np.random.default_rng(5)
    for seed in range(10):
        sim = make_sim(seed=seed, **BIG)
        cmd = rng.uniform(-0.3, 0.3, 2) * sim.robot.max_wheel_speed
        sim.run_segment(*cmd, 0.5)  # motor transient
        out = sim.run_segment(*cmd, 1.0)
        expected = kinematic_increment(out.true_dphi, sim.robot)
        np.testing.assert_allclose(out.true_increment, expected, atol=1e-9)


def test_physics_slips_on_full_speed_spin_reversal():
    for seed in range(5):
        sim = make_sim(seed=seed, **BIG)
        w = sim.robot.max_wheel_speed
        sim.run_segment(-w, w, 1.0)
        out = sim.run_segment(w, -w, 1.0)
        predicted = kinematic_increment(out.true_dphi, sim.robot)[2]
        # The ground turns less than r*dphi/b predicts: the wheels spin while slipping.
        assert abs(out.true_increment[2] - predicted) > 0.1
        assert abs(out.true_increment[2]) < abs(predicted)


def test_physics_slips_on_hard_start():
    sim = make_sim(seed=1, **BIG)
    w = sim.robot.max_wheel_speed
    out = sim.run_segment(w, w, 0.2)
    predicted = kinematic_increment(out.true_dphi, sim.robot)[0]
    assert out.true_increment[0] < 0.95 * predicted


@pytest.mark.parametrize("ideal", [True, False])
def test_heading_is_continuous_over_multi_turn_spin(ideal):
    sim = make_sim(seed=3, ideal=ideal, **BIG)
    w = sim.robot.max_wheel_speed
    out = sim.run_segment(-w, w, 4.0)
    turned = out.true_increment[2]
    assert turned > 4 * math.pi  # several turns, not wrapped
    steps = np.diff(out.path[:, 2])
    assert np.all(steps > 0) and np.all(steps < math.pi / 4)
    assert out.pose_end[2] - out.pose_start[2] == pytest.approx(turned)
    assert sim.pose[2] == pytest.approx(out.pose_end[2])


def test_encoder_quantization():
    enc = WheelEncoders(ticks_per_rev=4096)
    res = 2 * math.pi / 4096
    assert enc.resolution == pytest.approx(res)
    np.testing.assert_array_equal(
        enc.count(np.array([0.0, res * 0.999, res, -1e-9])), [0, 0, 1, -1]
    )
    rng = np.random.default_rng(0)
    start = rng.uniform(-100, 100, (1000, 2))
    end = start + rng.uniform(-50, 50, (1000, 2))
    inc = enc.increments(start, end)
    ticks = inc / res
    np.testing.assert_allclose(ticks, np.round(ticks), atol=1e-6)
    assert np.all(np.abs(inc - (end - start)) < res)
    # Errors do not accumulate: a chain of increments sums to the one-shot increment.
    chain = np.cumsum(rng.uniform(-3, 3, 200))
    total = enc.increments(chain[:-1], chain[1:]).sum()
    assert total == pytest.approx(enc.increments(chain[0], chain[-1]), abs=1e-9)


def test_segment_measurement_layout():
    sim = make_sim(seed=6, ideal=True, ticks_per_rev=64)
    out = sim.run_segment(3.0, 5.0, 1.0)
    res = 2 * math.pi / 64
    assert out.measurement.shape == (5,)
    assert np.all(np.abs(out.measurement[:2] - out.true_dphi) < res)
    np.testing.assert_allclose(out.measurement[:2] / res, np.round(out.measurement[:2] / res))
    assert np.all(np.abs(out.measurement[2:] - out.true_increment) < 6 * sim.pose_sensor.sigma)
    for array in (out.measurement, out.true_increment, out.path, out.pose_end):
        assert not array.flags.writeable


def test_relative_pose_sensor_statistics():
    sensor = RelativePoseSensor(sigma_xy=2e-3, sigma_theta=1e-3)
    rng = np.random.default_rng(8)
    truth = np.array([0.3, -0.1, 2.0])
    draws = np.array([sensor.measure(truth, rng) for _ in range(20000)])
    err = draws - truth
    sigma = np.array([2e-3, 2e-3, 1e-3])
    assert np.all(np.abs(err.mean(axis=0)) < 4 * sigma / math.sqrt(len(err)))
    np.testing.assert_allclose(err.std(axis=0), sigma, rtol=0.03)
    assert np.all(np.abs(np.corrcoef(err.T) - np.eye(3)) < 0.03)
    absolute = np.array([sensor.absolute(truth, rng) for _ in range(20000)]) - truth
    np.testing.assert_allclose(absolute.std(axis=0), sigma, rtol=0.03)
    exact = RelativePoseSensor(0.0, 0.0)
    np.testing.assert_array_equal(exact.measure(truth, rng), truth)


def test_segment_noise_is_independent_across_segments():
    sim = make_sim(seed=9, ideal=True, **BIG)
    errors = []
    for cmd in np.random.default_rng(1).uniform(-10, 10, (3000, 2)):
        out = sim.run_segment(*cmd, 0.02)
        errors.append(out.measurement[2:] - out.true_increment)
    errors = np.array(errors)
    np.testing.assert_allclose(errors.std(axis=0), sim.pose_sensor.sigma, rtol=0.06)
    lag1 = [np.corrcoef(errors[:-1, k], errors[1:, k])[0, 1] for k in range(3)]
    assert np.all(np.abs(lag1) < 0.06)


def run_episode(sim: Simulation, commands: np.ndarray) -> list:
    return [sim.run_segment(*cmd, 1.0) for cmd in commands]


def same_outcomes(a: list, b: list) -> bool:
    fields = ("measurement", "true_increment", "true_dphi", "pose_start", "pose_end", "path")
    return all(
        x.collision == y.collision
        and all(np.array_equal(getattr(x, f), getattr(y, f)) for f in fields)
        for x, y in zip(a, b, strict=True)
    )


@pytest.mark.parametrize("ideal", [True, False])
def test_deterministic_under_seed(ideal):
    commands = np.random.default_rng(10).uniform(-20, 20, (40, 2))
    first = run_episode(make_sim(seed=11, pose=None, ideal=ideal), commands)
    reused = make_sim(seed=12, pose=None, ideal=ideal)
    run_episode(reused, commands[:5])
    rng = np.random.default_rng(11)
    reused.reset(DIST.sample(rng), rng)
    second = run_episode(reused, commands)
    assert any(o.collision for o in first)  # the walls are part of what must repeat
    assert same_outcomes(first, second)


@pytest.mark.parametrize("ideal", [True, False])
def test_pickle_round_trip_continues_identically(ideal):
    commands = np.random.default_rng(13).uniform(-20, 20, (60, 2))
    sim = make_sim(seed=14, pose=None, ideal=ideal)
    for k in range(len(commands)):
        out = sim.run_segment(*commands[k], 1.0)
        if out.collision and k > 5:
            break  # pickle right after a wall contact, the hardest case
    assert out.collision
    copy = pickle.loads(pickle.dumps(sim))
    np.testing.assert_array_equal(copy.pose, sim.pose)
    assert copy.robot == sim.robot
    rest = commands[k + 1 :]
    assert same_outcomes(run_episode(sim, rest), run_episode(copy, rest))


@pytest.mark.parametrize("ideal", [True, False])
def test_collision_reported_when_driving_into_a_wall(ideal):
    sim = make_sim(seed=15, pose=(1.0, 0.0, 0.0), ideal=ideal)
    w = sim.robot.max_wheel_speed
    free = sim.run_segment(0.2 * w, 0.2 * w, 0.4)
    assert not free.collision
    hit = sim.run_segment(w, w, 2.0)
    assert hit.collision
    x_front = hit.path[:, 0] + CHASSIS_SIZE / 2
    assert x_front.max() <= 2.0 + 0.03  # pymunk may overlap by about one tick's travel
    if ideal:
        assert x_front.max() <= 2.0
        expected = kinematic_increment(hit.true_dphi, sim.robot)
        np.testing.assert_allclose(hit.true_increment, expected, atol=1e-12)
        assert hit.true_dphi[0] < w * 2.0  # the wheels stopped with the robot
    away = sim.run_segment(-0.3 * w, -0.3 * w, 1.0)
    assert away.true_increment[0] < -0.1


def test_layer_imports_no_rl_or_agents():
    root = Path(__file__).resolve().parents[2] / "envs"
    for name in ("robot.py", "physics.py", "ideal_drive.py", "sensors.py", "simulation.py"):
        tree = ast.parse((root / name).read_text())
        modules = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        modules += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        for module in modules:
            assert module.split(".")[0] not in {"gymnasium", "gym", "torch", "agents"}, name


def test_stop_and_go_segments_follow_the_kinematic_arc_despite_motor_lag():
    """Starting and ending at rest (settle = 20 motor time constants), both wheels follow the
    same lag shape: a segment gentle enough not to slip (15% of the motor limit: at most
    3 m/s^2 from rest, below this low-grip robot's mu g) is exactly the constant-curvature
    arc of its wheel increments; driven continuously, the same commands curve differently."""
    from excite import Params, predict_increment

    robot = RobotDistribution().sample(np.random.default_rng(5))
    truth = Params(*robot.kinematic_params())

    def model_errors(settle: float) -> list[float]:
        sim = Simulation(SimulationConfig(arena_width=100.0, arena_height=100.0))
        rng = np.random.default_rng(6)
        sim.reset(robot, rng, pose=np.zeros(3))
        errors = []
        for _ in range(20):
            cmd = rng.uniform(-0.15, 0.15, 2) * robot.max_wheel_speed
            out = sim.run_segment(*cmd, 1.0, settle=settle)
            predicted = np.ravel(predict_increment(*out.true_dphi, truth))
            errors.append(np.abs(out.true_increment - predicted).max())
        return errors

    errors_stop, errors_continuous = model_errors(1.0), model_errors(0.0)
    assert max(errors_stop) < 1e-9
    assert max(errors_continuous) > 1e-5


def test_settle_must_be_whole_ticks():
    sim = Simulation()
    rng = np.random.default_rng(0)
    sim.reset(RobotDistribution().nominal(), rng)
    with pytest.raises(ValueError, match="settle must be a non-negative multiple"):
        sim.run_segment(1.0, 1.0, 1.0, settle=0.013)


def test_encoder_readings_within_a_segment_sum_to_its_increments():
    sim = make_sim(3, **BIG)
    outcome = sim.run_segment(4.0, 6.0, 1.0, settle=0.2)
    sub = sim.encoders.sub_increments(outcome.wheel_path, 10)
    assert sub.shape == (10, 2)
    np.testing.assert_allclose(sub.sum(axis=0), outcome.measurement[:2], rtol=1e-14)
    resolution = sim.encoders.resolution
    np.testing.assert_allclose(sub / resolution, np.round(sub / resolution), atol=1e-9)
    assert sim.encoders.sub_increments(outcome.wheel_path[:4], 10).shape == (3, 2)


def test_a_segment_that_turns_the_other_way_is_no_arc_but_its_readings_compose_it():
    """The motors lag the commands: a segment that starts while the robot still turns the
    other way bends its path, millimetres off the one arc of its increments; the arcs between
    ten readings (the stopping rule's segments in target mode) follow it."""
    for seed in range(3):
        sim = make_sim(seed, **BIG)
        robot = sim.robot
        speed = 0.16 * robot.max_wheel_speed
        sim.run_segment(0.3 * speed, 1.7 * speed, 1.0)
        outcome = sim.run_segment(1.7 * speed, 0.3 * speed, 1.0)
        one_arc = kinematic_increment(outcome.true_dphi, robot) - outcome.true_increment
        at = np.linspace(0, len(outcome.wheel_path) - 1, 11).round().astype(int)
        sub = np.diff(outcome.wheel_path[at], axis=0)
        arcs = np.array(predict_increment(sub[:, 0], sub[:, 1], robot.kinematic_params()))
        composed = compose_substeps(arcs, None)[0] - outcome.true_increment
        assert np.hypot(*one_arc[:2]) > 2e-3
        assert np.hypot(*composed[:2]) < 0.1 * np.hypot(*one_arc[:2])
