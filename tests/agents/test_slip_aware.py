"""The slip-aware planner: its nominal slip model against the simulator, and its contract
(inside the action space, within its smoothness limit, never into a wall, parameters declared
and checked, deterministic, runs in compare)."""

import dataclasses
import json

import numpy as np
import pytest

from agents.catalog import ProtocolError, ProtocolSpec, make_protocol, parse_protocols
from agents.compare import make_env
from agents.motion import safe_actions
from agents.slip_aware import SlipAwarePlanner, nominal_segment, predicted_bias
from agents.tuning import candidates
from envs.physics import PymunkDrive
from envs.robot import robot_distribution, traction_of
from excite.contracts import RobotKnowledge
from excite.core.arena import Arena
from excite.core.kinematics import Params
from excite.core.models import AXLE
from tests.conftest import run_cli

SIGMA = np.array([2e-3, 2e-3, 1e-3])


def _knowledge(spec, pose=(0.0, 0.0, 0.0), arena_size=40.0, traction=True):
    nominal = Params(*spec.kinematic_params())
    return RobotKnowledge(
        observation=np.zeros(16), estimate=nominal, information=np.zeros((3, 3)),
        log=np.zeros((0, 5)), pose=np.array(pose, dtype=float), nominal=nominal, sigma=SIGMA,
        max_wheel_speed=spec.max_wheel_speed, segment_duration=1.0, arena_size=arena_size,
        budget=30, chassis=spec.chassis,
        traction=traction_of(spec) if traction else None)


def _simulated_error(spec, previous, command):
    """The simulator's segment after steady rolling at ``previous``: encoder increments and the
    whitened error of the single arc they predict against the body's true motion."""
    drive = PymunkDrive(Arena(40.0, 40.0), 50.0)
    drive.reset(spec, np.zeros(3), np.zeros(2))
    drive.run(*(np.asarray(previous) * spec.max_wheel_speed), 100)
    start, wheels_start = drive.pose, drive.wheel_angles
    path, wheels, _ = drive.run(*(np.asarray(command) * spec.max_wheel_speed), 50)
    dx, dy, dth = path[-1] - start
    c, s = np.cos(start[2]), np.sin(start[2])
    body = np.array([c * dx + s * dy, -s * dx + c * dy, dth])
    dphi = wheels[-1] - wheels_start
    single = AXLE.predict(dphi[0], dphi[1], np.array(spec.kinematic_params()))
    return dphi, (body - single) / SIGMA


def test_the_nominal_slip_model_predicts_the_simulators_slip_and_lag_bias():
    """For the nominal robot with its centre of mass on the axle (the one thing the model
    leaves out), the predicted encoder increments and whitened single-arc error match the
    pymunk drive, in gentle changes (lag only) and in hard ones that slip (errors of many
    sigma)."""
    spec = dataclasses.replace(robot_distribution({}).nominal(), com_offset=0.0)
    knowledge = _knowledge(spec)
    rng = np.random.default_rng(3)
    pairs = [((0.0, 0.0), (1.0, 1.0)), ((0.3, 0.3), (-0.3, 0.3)), ((0.5, 0.5), (0.3, 0.7))]
    pairs += [tuple(rng.uniform(-0.8, 0.8, (2, 2))) for _ in range(5)]
    largest = 0.0
    for previous, command in pairs:
        dphi, error = _simulated_error(spec, previous, command)
        encoder, _ = nominal_segment(np.array(previous), np.array([command]), knowledge)
        _, predicted = predicted_bias(np.array(previous), np.array([command]), knowledge)
        np.testing.assert_allclose(encoder[0], dphi, atol=1e-6)
        assert np.all(np.abs(predicted[0] - error) <= 0.15 + 0.02 * np.abs(error)), (
            previous, command, predicted[0], error)
        largest = max(largest, np.abs(error).max())
    assert largest > 10.0  # the cases include real slip, not only lag


def test_no_change_of_command_predicts_no_bias():
    spec = robot_distribution({}).nominal()
    previous = np.array([0.4, 0.7])
    _, error = predicted_bias(previous, previous[None, :], _knowledge(spec))
    np.testing.assert_allclose(error, 0.0, atol=1e-9)


def test_plans_inside_the_action_space_within_the_smoothness_limit_without_collisions():
    """On the slip env the plan is always what the robot does (the wall guard never has to
    step in), each command within max_step of the last, and nothing hits a wall."""
    env = make_env("excite/DiffDriveCalib-v0", 30)
    for seed, settings in ((0, {}), (1, {"max_step": 0.1, "max_speed": 0.46})):
        env.reset(seed=seed)
        planner = SlipAwarePlanner(**settings)
        planner.reset(np.random.default_rng(seed))
        previous = np.zeros(2)
        for _ in range(30):
            knowledge = env.unwrapped.knowledge()
            plan = np.clip(planner.plan(knowledge), -1, 1)
            action = planner.act(knowledge)
            np.testing.assert_array_equal(action, plan)
            assert env.action_space.contains(action.astype(np.float32))
            assert np.abs(action).max() <= planner.max_speed + 1e-12
            assert np.abs(action - previous).max() <= planner.max_step + 1e-12
            previous = action
            *_, info = env.step(action)
            assert not info["collision"], (seed, settings)


def test_never_plans_into_a_wall_when_heading_at_one_fast():
    """Driving at a wall at 0.6 m/s: while a smooth way out exists the plan takes it (clear of
    the wall, with a smooth continuation, and the guard leaves it); once cornered (a state its
    own plans avoid) it slows down as fast as its smoothness limit allows."""
    spec = robot_distribution({}).nominal()
    planner = SlipAwarePlanner()
    for x, cornered in ((0.3, False), (0.6, False), (0.8, False), (1.5, True)):
        knowledge = _knowledge(spec, pose=(x, 0.3, 0.1), arena_size=4.0)
        planner.reset(np.random.default_rng(0))
        planner.previous = np.array([0.6, 0.6])
        plan = planner.plan(knowledge)
        assert np.abs(plan - planner.previous).max() <= planner.max_step + 1e-12
        clear = safe_actions(plan[None, :], knowledge, planner.speed_margin)[0]
        escapes = planner.escapes(plan[None, :], knowledge)[0]
        assert (clear and escapes) is not cornered, x
        if cornered:
            np.testing.assert_allclose(plan, [0.4, 0.4])
        else:
            np.testing.assert_array_equal(planner.act(knowledge), plan)


def _actions(env, planner, seed: int, segments: int) -> np.ndarray:
    """The planner's commands (segments, 2) over an episode of ``env`` reset with ``seed``."""
    env.reset(seed=seed)
    planner.reset(np.random.default_rng(seed))
    actions = []
    for _ in range(segments):
        actions.append(planner.act(env.unwrapped.knowledge()))
        env.step(actions[-1])
    return np.array(actions)


def test_deterministic_given_its_rng_and_the_episode():
    env = make_env("excite/DiffDriveCalib-v0", 8)
    runs = [_actions(env, make_protocol("slip_aware"), 4, 8) for _ in range(2)]
    np.testing.assert_array_equal(runs[0], runs[1])
    assert np.abs(np.diff(runs[0], axis=0)).max() > 0  # it does change its commands


def test_keeps_informing_its_weakest_direction_on_the_sensor_env():
    """Valued over the next segment alone, the planner holds a spin for ever on the sensor
    env once no command within max_step informs its weakest direction (the overall scale of
    the wheels and the track): sigma_min stands still from segment 60 to 120. Valued over
    ``lookahead`` segments (the default) it ramps to maneuvers that inform it."""
    env = make_env("excite/DiffDriveCalibSensor-v0", 120)

    def sigma_min_growth(**settings) -> float:
        env.reset(seed=7)
        planner = SlipAwarePlanner(**settings)
        planner.reset(np.random.default_rng(7))
        found = {}
        for n in range(1, 121):
            *_, info = env.step(planner.act(env.unwrapped.knowledge()))
            found[n] = info["sigma_min"]
        return found[120] / found[60]

    assert sigma_min_growth(lookahead=1) < 1.01  # the planner this replaced: stuck
    assert sigma_min_growth() > 1.2


def test_a_step_that_reaches_anywhere_values_the_next_segment_alone():
    """With max_step 2 (TurtleBot3's and the ideal env's tuned setting) one step reaches any
    command: nothing is out of reach, and the lookahead (holding a target for six segments)
    is not applied; the plan is lookahead 1's, command for command."""
    assert SlipAwarePlanner(max_step=2.0).steps == 1
    assert SlipAwarePlanner(max_step=0.5).steps == 4
    assert SlipAwarePlanner().steps == 6
    env = make_env("excite/DiffDriveCalib-v0", 15)
    np.testing.assert_array_equal(_actions(env, SlipAwarePlanner(max_step=2.0), 4, 15),
                                  _actions(env, SlipAwarePlanner(max_step=2.0, lookahead=1), 4,
                                           15))


def test_parameters_are_declared_checked_and_tunable():
    assert [s.label for s in parse_protocols("slip_aware:max_step=0.1:bias_weight=3")] == [
        "slip_aware:max_step=0.1:bias_weight=3.0"]
    for text, fragment in (("slip_aware:max_step=0", "max_step must be in [0.02, 2.0]"),
                           ("slip_aware:horizon=2.5", "horizon must be a whole number"),
                           ("slip_aware:grip=3", "has no parameter 'grip'")):
        with pytest.raises(ProtocolError, match=fragment.replace("[", r"\[")):
            parse_protocols(text)
    tried = candidates(ProtocolSpec("slip_aware"))
    assert len(tried) == 2 * 3  # max_speed x max_step
    assert len({c.label for c in tried}) == len(tried)


def test_without_the_nominal_traction_it_says_what_it_needs():
    planner = SlipAwarePlanner()
    planner.reset(np.random.default_rng(0))
    knowledge = _knowledge(robot_distribution({}).nominal(), arena_size=4.0, traction=False)
    with pytest.raises(ProtocolError, match="RobotKnowledge.traction"):
        planner.act(knowledge)


@pytest.mark.slow
def test_runs_in_compare_beside_greedy(tmp_path, capsys):
    code, out, _ = run_cli(capsys, "compare", "--protocols", "slip_aware,greedy", "--episodes",
                           "2", "--segments", "6", "--workers", "1", "--tuned", "none",
                           "--out", tmp_path)
    assert code == 0 and "slip_aware" in out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["settings"]["protocols"] == ["slip_aware", "greedy"]
