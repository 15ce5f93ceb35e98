"""The live session without ROS: a made-up transport around a kinematic robot
(examples/live_session.py), its watchdogs, its area and its result."""

from __future__ import annotations

import importlib.util
import math
from concurrent.futures import Executor, Future
from pathlib import Path

import numpy as np
import pytest

from agents.catalog import make_protocol
from excite import Params
from excite.contracts import Traction
from excite.live import Area, LiveSession, LiveSettings
from excite.live.watch import judge
from excite.logs.timeseries import during

ROOT = Path(__file__).resolve().parents[3]
NOMINAL = Params(0.05, 0.05, 0.30)
TRUTH = Params(0.0505, 0.0497, 0.306)
TRACTION = Traction(motor_tau=0.05, grip=5.0)


def _example():
    spec = importlib.util.spec_from_file_location("live_session",
                                                  ROOT / "examples" / "live_session.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


EXAMPLE = _example()


def _settings(**changes) -> LiveSettings:
    base = dict(nominal=NOMINAL, max_wheel_speed=20.0, target=0.005, sensor_pose="axle",
                max_time=120.0, traction=TRACTION)
    return LiveSettings(**{**base, **changes})


def _drive(session, robot, dt=0.02, until=math.inf, poses=True, wheels=True, follow=True,
           on_tick=None):
    """Run the made-up transport until the session ends or time ``until``; the commands
    sent (t, left, right). on_tick(): called after each command."""
    sent = []
    while not session.ended and robot.t < until:
        robot.step(dt)
        if wheels:
            session.add_wheels(*robot.wheel_angles())
        if poses:
            session.add_pose(*robot.measured_pose())
        command = session.command(robot.t)
        if follow:
            robot.speeds = np.array([command.left, command.right])
        sent.append((robot.t, command.left, command.right))
        if on_tick is not None:
            on_tick()
    return np.array(sent)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_session_reaches_the_target_with_the_truth_inside(seed):
    robot = EXAMPLE.ToyRobot(TRUTH, seed=seed)
    session = LiveSession(_settings(), make_protocol("slip_aware"), seed=seed)
    sent = _drive(session, robot)
    result = session.finish()
    assert result.outcome == "done", result.reason
    assert np.all(sent[-1, 1:] == 0.0)  # the last command is zero
    z = (result.calibration.params.as_array() - TRUTH.as_array()) / result.calibration.std
    assert np.all(np.abs(z) < 3), z
    assert len(result.statuses) >= 10
    assert result.statuses[-1].statistic <= 1.0 or result.decision.done
    # the area: a square of area_size around the start, never left
    assert result.area.extent == (4.0, 4.0)
    assert min(s.clearance for s in result.statuses) > 0


def test_the_final_calibration_is_excite_calibrate_of_the_recorded_log(tmp_path, capsys):
    import json

    from excite.cli import main

    robot = EXAMPLE.ToyRobot(TRUTH, seed=2)
    session = LiveSession(_settings(), make_protocol("slip_aware"), seed=2)
    _drive(session, robot)
    result = session.finish()
    s = result.series
    path = tmp_path / "session.csv"
    enc = np.column_stack([s.t_enc, s.phi_L, s.phi_R])
    pose = np.column_stack([s.t_pose, s.x, s.y, s.theta])
    np.savetxt(tmp_path / "enc.csv", enc, delimiter=",", header="t,phi_L,phi_R", comments="",
               fmt="%.17g")
    np.savetxt(path, pose, delimiter=",", header="t,x,y,theta", comments="", fmt="%.17g")
    start = [] if result.calibrated_from is None else ["--start", repr(result.calibrated_from)]
    code = main(["calibrate", str(tmp_path / "enc.csv"), str(path), "--split-at-gaps",
                 "--init", "0.05,0.05,0.3", "--sensor-pose", "axle", "--json", *start,
                 "--time-offset", repr(result.time_offset)])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    np.testing.assert_allclose([out["params"][k] for k in ("r_L", "r_R", "b")],
                               result.calibration.params.as_array(), rtol=1e-9)


class LaggingExecutor(Executor):
    """Runs each decision when it is submitted but hands it back only at :meth:`release`:
    an executor whose decisions lag, as a busy computer's do, deterministically."""

    def __init__(self) -> None:
        self.held: list[tuple[Future, object]] = []

    def submit(self, fn, /, *args, **kwargs) -> Future:
        future = Future()
        self.held.append((future, fn(*args, **kwargs)))
        return future

    def release(self) -> None:
        for future, result in self.held:
            future.set_result(result)
        self.held = []


def _drive_lagging(session, robot, lag, change=None, dt=0.02):
    """Drive with the decisions released every ``lag`` s; ``change`` = (t, Params): the
    robot's wheels become those at t (s). The (t, state, command, reason) of every tick."""
    ticks, release = [], lag
    while not session.ended and robot.t < session.settings.max_time:
        robot.step(dt)
        if change is not None and robot.t >= change[0]:
            robot.truth = change[1]
        if robot.t >= release:
            session.executor.release()
            release += lag
        session.add_wheels(*robot.wheel_angles())
        session.add_pose(*robot.measured_pose())
        command = session.command(robot.t)
        robot.speeds = np.array([command.left, command.right])
        ticks.append((robot.t, session.state, command, session.reason))
    return ticks


def test_a_lagging_done_stops_the_robot_and_is_decided_again_on_the_whole_log():
    """A decision from the executor saw the log up to an earlier segment: its *done* stops
    the robot at once, and the session ends done only when the rule, deciding again on the
    whole log, says so; the session's answer is then the calibration the rule judged."""
    robot = EXAMPLE.ToyRobot(TRUTH, seed=0)
    session = LiveSession(_settings(), make_protocol("slip_aware"), seed=0,
                          executor=LaggingExecutor())
    ticks = _drive_lagging(session, robot, lag=6.0)
    confirming = [t for t in ticks if t[1] == "confirming"]
    assert confirming and all(t[2].is_zero for t in confirming)
    result = session.finish()
    assert result.outcome == "done", result.reason
    assert result.decision.n_segments == result.calibration.n_segments
    np.testing.assert_allclose(result.decision.result.params.as_array(),
                               result.calibration.params.as_array(), rtol=1e-6)


def test_a_lagging_done_that_the_whole_log_refutes_drives_on():
    """The robot's wheels change after the data of a lagging *done* (a tyre swapped, in
    effect): deciding again on the whole log says not yet, the robot drives on, and the
    session ends done on the robot it has become."""
    changed = Params(TRUTH.r_L * 1.03, TRUTH.r_R, TRUTH.b)
    robot = EXAMPLE.ToyRobot(TRUTH, seed=0)
    session = LiveSession(_settings(), make_protocol("slip_aware"), seed=0,
                          executor=LaggingExecutor())
    ticks = _drive_lagging(session, robot, lag=6.0, change=(19.0, changed))
    states = [t[1] for t in ticks]
    first = states.index("confirming")
    resumed = states.index("running", first)
    assert any(not t[2].is_zero for t in ticks[resumed:])
    result = session.finish()
    assert result.outcome == "done", result.reason
    z = (result.calibration.params.as_array() - changed.as_array()) / result.calibration.std
    assert np.all(np.abs(z) < 3), z


class _FailingOnce(LaggingExecutor):
    """Hands back the first decision as a numerical failure (a singular matrix), the others
    as they came."""

    def release(self) -> None:
        if self.held and not getattr(self, "failed", False):
            self.failed = True
            future, _ = self.held.pop(0)
            future.set_exception(np.linalg.LinAlgError("Singular matrix"))
        super().release()


def test_a_look_that_fails_numerically_is_skipped_and_the_session_goes_on():
    robot = EXAMPLE.ToyRobot(TRUTH, seed=0)
    session = LiveSession(_settings(), make_protocol("slip_aware"), seed=0,
                          executor=_FailingOnce())
    reasons = [tick[3] for tick in _drive_lagging(session, robot, lag=2.0)]
    assert any(r.startswith("the stopping rule's calibration failed on the log so far "
                            "(LinAlgError: Singular matrix)") for r in reasons), reasons
    assert session.finish().outcome == "done"


def test_silent_streams_stop_the_robot_then_it_resumes_or_aborts():
    robot = EXAMPLE.ToyRobot(TRUTH, seed=3)
    session = LiveSession(_settings(abort_timeout=3.0), make_protocol("arcs"), seed=3)
    _drive(session, robot, until=4.0)
    assert session.state == "running"
    # the poses stop: the command is zero within the silence timeout (plus one tick)
    sent = _drive(session, robot, until=6.0, poses=False)
    moving = sent[np.any(sent[:, 1:] != 0, axis=1), 0]
    assert moving.max() <= 4.0 + 0.5 + 0.02
    assert session.state == "paused"
    assert "poses silent" in session.reason
    # they return: the session drives again
    sent = _drive(session, robot, until=8.0)
    assert session.state == "running" and np.any(sent[:, 1:] != 0)
    # silent for longer than the abort timeout: aborted, zero
    sent = _drive(session, robot, until=13.0, wheels=False)
    assert session.state == "aborted" and "wheel angles silent" in session.reason
    assert np.all(sent[-1, 1:] == 0.0)
    assert session.command(robot.t + 1.0).is_zero


def test_a_pose_source_that_repeats_one_pose_stops_the_robot_then_aborts():
    """Poses that keep arriving but repeat one value while the wheels turn (a lost
    motion-capture body held at its last pose): the robot drove on blind, out of the safe
    area by metres (found by fuzzing). Now as blind as a silence: stopped, then aborted."""
    robot = EXAMPLE.ToyRobot(TRUTH, seed=3)
    session = LiveSession(_settings(abort_timeout=3.0), make_protocol("arcs"), seed=3)
    _drive(session, robot, until=4.0)
    assert session.state == "running"
    frozen = robot.measured_pose()[1:]
    sent = []
    while not session.ended and robot.t < 10.0:
        robot.step(0.02)
        session.add_wheels(*robot.wheel_angles())
        session.add_pose(robot.t, *frozen)  # fresh stamps, the same pose
        command = session.command(robot.t)
        robot.speeds = np.array([command.left, command.right])
        sent.append((robot.t, command.left, command.right))
    sent = np.array(sent)
    moving = sent[np.any(sent[:, 1:] != 0, axis=1), 0]
    assert moving.max() <= 4.0 + 1.5  # stopped within the silence timeout of the freeze
    assert session.state == "aborted"
    assert ("poses silent for longer than 3 s (they repeat one pose while the wheels turn)"
            in session.reason)



def test_a_silence_says_why_the_stream_went_silent():
    """A stream that goes silent because its messages cannot be used says why (found by
    fuzzing: a JointState that stopped naming a wheel, or stamps that jumped, read "the wheel
    angles silent" or "the wheels do not turn"): the transport's reason, stamps that went
    back, or messages arriving later than the silence timeout after their stamps."""
    robot = EXAMPLE.ToyRobot(TRUTH, seed=3)
    session = LiveSession(_settings(abort_timeout=3.0), make_protocol("arcs"), seed=3)
    _drive(session, robot, until=4.0)
    assert session.state == "running"
    why = "messages on /joint_states left out: no joint 'left' in them (joints: right)"
    session.left_out("wheels", why)
    _drive(session, robot, until=5.0, wheels=False)
    assert session.state == "paused"
    assert f"the wheel angles silent ({why})" in session.reason
    # a usable sample clears the reason: the stream is running again
    _drive(session, robot, until=6.0)
    assert session.state == "running"
    # stamps that go back: every later sample is left out, and said so
    last = robot.t
    sent = []
    while robot.t < 7.0:
        robot.step(0.02)
        _, phi_L, phi_R = robot.wheel_angles()
        session.add_wheels(last - 10.0, phi_L, phi_R)
        session.add_pose(*robot.measured_pose())
        sent.append(session.command(robot.t))
    assert session.state == "paused" and sent[-1].is_zero
    assert "the wheel angles silent (stamps at or before" in session.reason
    assert "they went back" in session.reason
    # poses that arrive a second after their stamps (on another clock): the session never
    # starts, and aborts saying why
    robot = EXAMPLE.ToyRobot(TRUTH, seed=4)
    session = LiveSession(_settings(abort_timeout=3.0), make_protocol("arcs"), seed=4)
    while not session.ended and robot.t < 5.0:
        robot.step(0.02)
        session.add_wheels(*robot.wheel_angles(), received=robot.t)
        t, x, y, theta = robot.measured_pose()
        session.add_pose(t - 1.0, x, y, theta, received=t)
        assert session.command(robot.t).is_zero
    assert session.state == "aborted"
    assert "the poses silent for longer than 3 s (they arrive 1 s after their stamps" \
        in session.reason
    with pytest.raises(ValueError, match="stream must be"):
        session.left_out("joints", "x")

def test_the_time_limit_ends_the_session_out_of_time():
    robot = EXAMPLE.ToyRobot(TRUTH, seed=4)
    session = LiveSession(_settings(max_time=5.0), make_protocol("slip_aware"), seed=4)
    sent = _drive(session, robot)
    assert session.state == "out_of_time"
    assert np.all(sent[-1, 1:] == 0.0)
    assert sent[-1, 0] <= 5.0 + 0.1


@pytest.mark.parametrize("mapping, words", [
    (np.zeros((2, 2)), "do not turn"),
    (np.array([[0.0, 1.0], [1.0, 0.0]]), "against the command"),
    (np.diag([-1.0, 1.0]), "left wheel turns backwards"),
])
def test_wheels_that_do_not_follow_abort_within_two_seconds(mapping, words):
    robot = EXAMPLE.ToyRobot(TRUTH, seed=5)
    session = LiveSession(_settings(), make_protocol("arcs"), seed=5)
    sent = []
    while not session.ended and robot.t < 10.0:
        robot.step(0.02)
        session.add_wheels(*robot.wheel_angles())
        session.add_pose(*robot.measured_pose())
        command = session.command(robot.t)
        robot.speeds = mapping @ np.array([command.left, command.right])
        sent.append((robot.t, command.left, command.right))
    sent = np.array(sent)
    assert session.state == "aborted" and words in session.reason, session.reason
    first = sent[np.argmax(np.any(sent[:, 1:] != 0, axis=1)), 0]
    assert robot.t - first <= 2.0
    assert np.all(sent[-1, 1:] == 0.0)


def test_judge():
    assert judge(np.array([10.0, 5.0]), np.array([9.0, 4.8])) is None
    assert "do not turn" in judge(np.array([10.0, 5.0]), np.array([0.1, 0.0]))
    assert "swapped" in judge(np.array([10.0, 5.0]), np.array([5.0, 10.0]))
    assert "both wheels" in judge(np.array([10.0, 5.0]), np.array([-10.0, -5.0]))
    # a straight command cannot tell swapped wheels, and need not
    assert judge(np.array([10.0, 10.0]), np.array([10.0, 10.0])) is None
    # a controller of another geometry: the wheels turn faster than commanded
    assert judge(np.array([10.0, 5.0]), np.array([16.8, 8.4])).startswith(
        "the wheels turn 1.68 times the commanded speed (commanded 10.00, 5.00 rad/s, "
        "measured 16.80, 8.40): the controller's wheel radii or separation are not the "
        "nominal ones")
    assert judge(np.array([10.0, 5.0]), np.array([13.5, 6.75])) is None
    # still slowing down from a faster command (a slowdown): no fault until settled
    assert judge(np.array([10.0, 5.0]), np.array([16.8, 8.4]), settled=False) is None


def test_wheels_faster_than_the_command_are_judged_once_settled():
    """A command held for the response time and the window: wheels still slowing down from
    a faster one (after a slowdown) are no fault; wheels that hold 1.68 times it are."""
    from excite.live.watch import MotionWatch

    watch = MotionWatch(window=0.5, response_time=0.2, command_speed=20.0)
    watch.commanded(-0.1, 10.0, 5.0)
    command = np.array([10.0, 5.0])

    def slowing(t: float) -> np.ndarray:  # the angles of speeds from 3 times the command
        if t < 0.6:                        # down to it at 0.6 s: 1.53 times it on average
            return command * (3.0 * t - t * t / 0.6)
        return command * (1.2 + (t - 0.6))

    assert watch.check(0.7, slowing) is None
    fault = watch.check(0.7, lambda t: 1.68 * command * t)
    assert fault is not None and "1.68 times the commanded speed" in fault


def test_wheels_that_follow_a_ramp_of_commands_are_no_fault():
    """Commands ramping up within STEADY of the limit count as one held command; wheels that
    reach the last (fastest) of them are no fault, though they turn 1.41 times the ramp's
    mean (a live session against the simulated robot aborted so); 1.68 times the fastest
    still is a fault."""
    from excite.live.watch import MotionWatch

    watch = MotionWatch(window=0.5, response_time=0.2, command_speed=20.0)
    ramp = np.array([[2.0, 0.5], [3.0, 1.5], [4.0, 2.5]])
    for t, (left, right) in zip((-0.3, 0.0, 0.3), ramp, strict=True):
        watch.commanded(t, left, right)
    assert watch.check(0.7, lambda t: ramp[-1] * t) is None
    fault = watch.check(0.7, lambda t: 1.68 * ramp[-1] * t)
    assert fault is not None and "1.68 times the commanded speed (commanded 4.00, 2.50" in fault

def test_area():
    area = Area.square((1.0, 2.0), 4.0)
    assert (area.x0, area.y0, area.x1, area.y1) == (-1.0, 0.0, 3.0, 4.0)
    assert area.clearance(np.array([1.0, 2.0, 0.0]), (0.4, 0.2)) == pytest.approx(1.8)
    assert area.clearance(np.array([2.9, 2.0, 0.0]), (0.4, 0.2)) < 0
    around = Area.around((0.0, 0.0), 1.0)
    assert np.hypot(around.x1, around.y1) == pytest.approx(1.0)
    np.testing.assert_allclose(area.to_local(np.array([1.0, 2.0, 0.3])), [0.0, 0.0, 0.3])
    with pytest.raises(ValueError, match="X0 < X1"):
        Area(1.0, 0.0, 0.0, 1.0)


@pytest.mark.parametrize("changes, words", [
    ({"max_wheel_speed": 0.0}, "max_wheel_speed"),
    ({"speed_fraction": 1.5}, "speed_fraction"),
    ({"target": 2.0}, "target"),
    ({"area": Area(0, 0, 1, 1), "radius": 1.0}, "not both"),
    ({"sigma": (1e-3, 0.0, 1e-3)}, "sigma"),
    ({"silence_timeout": 5.0, "abort_timeout": 1.0}, "abort_timeout"),
])
def test_bad_settings_are_refused(changes, words):
    with pytest.raises(ValueError, match=words):
        _settings(**changes)


def test_a_rectangle_area_is_kept_by_the_guard():
    """An area narrower than the default square: the footprint stays inside."""
    robot = EXAMPLE.ToyRobot(TRUTH, seed=6)
    session = LiveSession(_settings(area=Area(-0.8, -3.0, 0.8, 3.0), max_time=40.0),
                          make_protocol("slip_aware"), seed=6)
    poses = []
    while not session.ended:
        robot.step(0.02)
        session.add_wheels(*robot.wheel_angles())
        session.add_pose(*robot.measured_pose())
        c = session.command(robot.t)
        robot.speeds = np.array([c.left, c.right])
        poses.append(robot.pose.copy())
    area = session.area
    assert min(area.clearance(p) for p in poses) > 0


def test_during_keeps_the_samples_between_two_times():
    robot = EXAMPLE.ToyRobot(TRUTH, seed=7)
    session = LiveSession(_settings(max_time=6.0), make_protocol("arcs"), seed=7)
    _drive(session, robot)
    series = session.finish().series
    part = during(series, 2.0, 4.0)
    assert part.t_enc.min() >= 2.0 and part.t_enc.max() <= 4.0
    assert part.t_pose.min() >= 2.0 and part.t_pose.max() <= 4.0
    from excite.errors import DataError
    with pytest.raises(DataError, match=r"fewer than 2 encoder samples between 100\.000 and inf s "
                                        r"\(its stamps run from 0\.\d+ to 6\.\d+ s; --start and "
                                        r"--end are in the log's own stamps\)"):
        during(series, 100.0, None)


@pytest.mark.slow
@pytest.mark.statistical
def test_sessions_stop_with_the_truth_in_the_95_percent_ellipse():
    """Monte Carlo over 40 made-up robots and pose noises: the truth lies in the final
    calibration's 95% ellipse (r_L, r_R, b) about 95% of the time, although every session
    stopped when the rule first said done (optional stopping), and every stop is within the
    target."""
    from scipy.stats import binom, chi2

    rng = np.random.default_rng(2026)
    inside, within, runs = 0, 0, 40
    for k in range(runs):
        truth = Params(*(NOMINAL.as_array() * rng.uniform(0.97, 1.03, 3)))
        robot = EXAMPLE.ToyRobot(truth, seed=100 + k)
        session = LiveSession(_settings(), make_protocol("slip_aware"), seed=k)
        _drive(session, robot)
        result = session.finish()
        assert result.outcome == "done", result.reason
        c = result.calibration
        error = c.params.as_array() - truth.as_array()
        inside += error @ np.linalg.solve(c.covariance, error) <= chi2.ppf(0.95, 3)
        within += np.all(np.abs(error / truth.as_array()) <= 0.005)
    print(f"truth in the 95% ellipse: {inside}/{runs}; within the target: {within}/{runs}")
    # at least the 1% lower quantile of Binomial(40, 0.95)
    assert inside >= binom.ppf(0.01, runs, 0.95), inside
    assert within >= binom.ppf(0.01, runs, 0.95), within


class _Straight:
    """A protocol without a wall guard (a user's): full speed ahead, always."""

    def reset(self, rng) -> None:
        pass

    def act(self, knowledge) -> np.ndarray:
        return np.array([1.0, 1.0])


@pytest.mark.parametrize("acceleration", [math.inf, 20.0, 2.0])
def test_the_stopping_guard_keeps_any_protocol_inside_the_area(acceleration):
    """Full speed at the edge, whatever the command's ramp: the session slows the robot so
    that it stops before its footprint leaves the area (the robot's true pose), and it
    drove there."""
    robot = EXAMPLE.ToyRobot(TRUTH, seed=11)
    session = LiveSession(_settings(radius=1.5, max_wheel_acceleration=acceleration),
                          _Straight(), seed=11)
    clearance = []

    def watch() -> None:
        if session.area is not None:
            clearance.append(session.area.clearance(robot.pose, session.settings.chassis))

    _drive(session, robot, until=20.0, on_tick=watch)
    assert min(clearance) >= 0.0, min(clearance)
    assert min(clearance) < 0.1  # it drove up to the edge
    assert session.state != "aborted", session.reason


def test_a_robot_outside_the_area_is_stopped():
    """At the start: bad input (an area or radius that does not hold the robot), never a
    command; later (a pose that jumps out of the area): the session aborted, the command
    zero."""
    from excite.errors import DataError

    robot = EXAMPLE.ToyRobot(TRUTH, seed=8)
    for area in (Area(1.0, 1.0, 3.0, 3.0), None):
        session = LiveSession(_settings(area=area, radius=0.1 if area is None else None),
                              make_protocol("arcs"))
        with pytest.raises(DataError, match=r"the robot.s footprint reaches [\d.]+ m outside the "
                           r"safe area .* at the start: give an area that holds it \(--area, "
                           "--radius\\)"):
            _drive(session, robot, until=2.0)
        assert session.state == "waiting"
    session = LiveSession(_settings(), make_protocol("arcs"))
    _drive(session, robot, until=robot.t + 2.0)
    assert session.state == "running"
    robot.pose = robot.pose + np.array([10.0, 0.0, 0.0])
    sent = _drive(session, robot, until=robot.t + 1.0)
    assert session.state == "aborted" and "outside the safe area" in session.reason
    assert np.all(sent[:, 1:] == 0.0)


@pytest.mark.parametrize("sensor_pose", ["axle", "estimate"])
def test_the_learned_policy_drives_a_session_through_the_observation(sensor_pose):
    """The shipped policy (trained on the wheels-only env) reads the observation built from
    live data (envs.observation), on the axle model's view while the session plans for the
    mounting too, and its commands stay in the area."""
    pytest.importorskip("stable_baselines3")
    from envs.observation import observer_for

    robot = EXAMPLE.ToyRobot(TRUTH, seed=9)
    protocol = make_protocol("learned")
    session = LiveSession(_settings(max_time=20.0, sensor_pose=sensor_pose), protocol,
                          seed=9, observe=observer_for(protocol.observation_shape))
    sent = _drive(session, robot)
    assert session.state in ("done", "out_of_time"), session.reason
    assert np.any(sent[:, 1:] != 0)
    assert min(s.clearance for s in session.statuses) > 0


def test_the_planner_plans_for_the_mounting_while_it_is_estimated():
    """While the stopping rule's target covers the sensor's mounting (estimated), the
    planners get the sensor-pose model (its six parameters, the log's information on them);
    with the mounting given or on the axle, or once auto's calibration chooses the axle
    model, the axle model. A live session on the default robot planned for the wheels
    alone and drove until out of time while the mounting's std stood still."""
    from excite.core.models import AXLE, SENSOR_POSE, SensorPose

    def planned(sensor_pose, seconds, target=0.005):
        robot = EXAMPLE.ToyRobot(TRUTH, seed=12)
        session = LiveSession(_settings(sensor_pose=sensor_pose, max_time=seconds,
                                        target=target), make_protocol("slip_aware"), seed=12)
        _drive(session, robot)
        return session, session.knowledge()

    for sensor_pose in ("estimate", "auto"):
        _, knowledge = planned(sensor_pose, 3.0)
        assert knowledge.model is SENSOR_POSE and knowledge.theta.shape == (6,)
        assert knowledge.information.shape == (6, 6)
        assert np.linalg.eigvalsh(knowledge.information)[-1] > 0
    for sensor_pose in ("axle", SensorPose(0.05, 0.0, 0.0)):
        _, knowledge = planned(sensor_pose, 3.0)
        assert knowledge.model is AXLE and knowledge.information.shape == (3, 3)
    # the toy's sensor is on the axle: auto's calibration chooses the axle model, and the
    # planner drives on with it (its predicted slip bias had six entries: an internal error)
    session, knowledge = planned("auto", 40.0, target=0.0005)
    assert session.state == "out_of_time", (session.state, session.reason)
    assert session.decision.result.model == "axle", session.decision.result.model
    assert knowledge.model is AXLE


def test_the_planner_weighs_segments_with_their_increment_noise():
    """Cut from a pose stream, a segment's increment is the difference of two samples: the
    planner's sigma is sqrt(2) times the samples' noise (1 mm, 2 mrad in the toy), not the
    near-zero white segment noise."""
    from excite.live.log import increment_noise

    robot = EXAMPLE.ToyRobot(TRUTH, seed=10)
    # the toy's clocks agree: an estimated offset's error (1.5 ms here) moves the split of
    # 13 segments' noise between the heading samples and the timing
    session = LiveSession(_settings(time_offset=0.0), make_protocol("slip_aware"), seed=10)
    _drive(session, robot)
    result = session.finish().calibration
    assert result.pose_sigma is not None
    np.testing.assert_allclose(increment_noise(result, 1.0),
                               np.sqrt(2.0) * np.array([1e-3, 1e-3, 2e-3]), rtol=0.35)
    np.testing.assert_allclose(session.knowledge().sigma, increment_noise(
        session.decision.result, 1.0), rtol=1e-12)


def test_the_planners_noise_carries_the_wheel_slip_to_the_increment():
    """A calibration may explain the heading's noise by wheel slip and find no pose-sample
    noise in theta (a live session on the slip env did): the planner's sigma then comes
    from the slip, as a Monte Carlo of the wheels' random walk through the kinematics gives
    it, never near zero (its information matrix was singular: an internal error that ended
    a session)."""
    from dataclasses import replace

    from excite import predict_increment
    from excite.core.information import information_matrix
    from excite.live.log import increment_noise

    robot = EXAMPLE.ToyRobot(TRUTH, seed=12)
    session = LiveSession(_settings(), make_protocol("slip_aware"), seed=12)
    _drive(session, robot)
    result = replace(session.finish().calibration, sigma=np.full(3, 1e-11),
                     pose_sigma=np.array([1e-11, 1e-11]), slip=0.01)
    duration = 0.5
    model = increment_noise(result, duration)
    rng = np.random.default_rng(12)
    slip = rng.normal(0.0, result.slip * math.sqrt(duration), (200_000, 2))
    wheels = np.array([3.0, 3.4])  # a gentle left arc
    drawn = np.column_stack(predict_increment(*(wheels + slip).T, result.params))
    observed = drawn.std(axis=0)
    np.testing.assert_allclose(model[[0, 2]], observed[[0, 2]], rtol=0.03)
    assert observed[1] <= model[1]  # y: zero to first order, given x's level
    log = session.knowledge().log  # the planner's rows: dphi_L, dphi_R, dx, dy, dtheta
    information = information_matrix(log[:, 0], log[:, 1], result.params, model,
                                     scale=NOMINAL)
    assert np.linalg.eigvalsh(information)[0] > 0 and np.linalg.cond(information) < 1e6


def test_commands_change_at_most_at_the_acceleration_limit_and_stop_at_once():
    robot = EXAMPLE.ToyRobot(TRUTH, seed=11)
    session = LiveSession(_settings(max_wheel_acceleration=10.0, max_time=6.0),
                          make_protocol("arcs"), seed=11)
    sent = _drive(session, robot, dt=0.02)
    steps = np.abs(np.diff(sent[:, 1:], axis=0))
    assert np.abs(sent[:, 1:]).max() > 2.0  # it drove, ramping up and down
    assert steps[:-1].max() <= 10.0 * 0.02 + 1e-9  # at most 10 rad/s^2 while running
    assert session.state == "out_of_time" and np.all(sent[-1, 1:] == 0.0)  # zero at once


def test_an_action_that_is_not_two_finite_numbers_never_becomes_a_command():
    """A protocol's NaN (a learned policy's, say) ends the session with an error at the
    segment it planned (the transport stops the robot); no command carries it."""

    class NaNLater:
        def reset(self, rng):
            self.calls = 0

        def act(self, knowledge):
            self.calls += 1
            return np.array([0.3, 0.4]) if self.calls < 3 else np.array([np.nan, 0.2])

    robot = EXAMPLE.ToyRobot(TRUTH, seed=13)
    session = LiveSession(_settings(), NaNLater(), seed=13)
    with pytest.raises(ValueError, match="two finite wheel-speed fractions"):
        _drive(session, robot)
    assert np.isfinite(robot.speeds).all()


def test_a_pose_latency_given_as_the_time_offset_calibrates_as_calibrate_does():
    """Poses stamped 60 ms late: with --time-offset -0.06 (pose time + offset = wheel time)
    the session cuts its log as excite calibrate --time-offset -0.06 does and ends as the
    session on prompt poses does: done as soon, within a std of its estimates (its last 60 ms
    of poses never arrive, so its segments are not quite the same). With 0 it ran out of
    its 120 s at std of 1-2.4% (done in 13 s at 0.03-0.06%)."""
    from excite.calibration import calibrate
    from excite.logs.segmentation import segment_timeseries

    results = []
    for latency in (0.0, 0.06):
        robot = EXAMPLE.ToyRobot(TRUTH, seed=3, latency=latency)
        session = LiveSession(_settings(time_offset=-latency), make_protocol("slip_aware"),
                              seed=3)
        _drive(session, robot)
        results.append(session.finish())
    prompt, late = results
    assert prompt.outcome == late.outcome == "done", late.reason
    assert late.series.t_enc[-1] == prompt.series.t_enc[-1]
    shift = (late.calibration.params.as_array() - prompt.calibration.params.as_array())
    assert np.all(np.abs(shift) < prompt.calibration.std), shift / prompt.calibration.std
    series = late.series if late.calibrated_from is None else during(
        late.series, late.calibrated_from)
    again = calibrate(segment_timeseries(series, time_offset=-0.06).segments,
                      initial=NOMINAL, sensor_pose="axle")
    np.testing.assert_allclose(again.params.as_array(), late.calibration.params.as_array(),
                               rtol=1e-9)
    with pytest.raises(ValueError, match="time_offset must be finite"):
        _settings(time_offset=math.nan)
    with pytest.raises(ValueError, match="time_offset must be finite .* or 'estimate'"):
        _settings(time_offset="soon")


def test_an_estimated_time_offset_calibrates_late_poses_as_prompt_ones():
    """Poses stamped 60 ms late, time_offset="estimate": every look cuts the log with the
    offset estimated from it, and the session ends done as soon as on prompt poses; its result
    names the offset (within 3 ms of the latency) and its calibration is calibrate's on the log
    cut with that offset. The estimate's own error (about 1 ms) is not in the std: it moves b
    by 1.1 std between the two sessions here (the estimates at 40 made-up robots with 30 ms
    late poses: the truth in the 95% ellipse 33/40, against 36/40 with the true offset
    given), so within 2 std."""
    from excite.calibration import calibrate
    from excite.live.report import closing_lines
    from excite.logs.segmentation import segment_timeseries

    results = []
    for latency in (0.0, 0.06):
        robot = EXAMPLE.ToyRobot(TRUTH, seed=3, latency=latency)
        session = LiveSession(_settings(time_offset="estimate"), make_protocol("slip_aware"),
                              seed=3)
        _drive(session, robot)
        results.append(session.finish())
    prompt, late = results
    assert prompt.outcome == late.outcome == "done", late.reason
    assert abs(prompt.time_offset) < 0.003 and abs(late.time_offset + 0.06) < 0.003
    assert late.duration <= prompt.duration + 1.0
    shift = late.calibration.params.as_array() - prompt.calibration.params.as_array()
    assert np.all(np.abs(shift) < 2 * prompt.calibration.std), shift / prompt.calibration.std
    series = late.series if late.calibrated_from is None else during(
        late.series, late.calibrated_from)
    again = calibrate(segment_timeseries(series, time_offset=late.time_offset).segments,
                      initial=NOMINAL, sensor_pose="axle")
    np.testing.assert_allclose(again.params.as_array(), late.calibration.params.as_array(),
                               rtol=1e-9)
    assert late.suggested_time_offset is None
    assert f"clock offset of {late.time_offset:+.4f} s" in "\n".join(closing_lines(late))


def test_a_session_kept_from_its_target_by_late_poses_names_the_offset_that_reaches_it():
    """Poses 60 ms late and a zero offset: the fit fails, the session slows down and runs out
    of time; its result names the offset with which the whole log reaches the target (within
    3 ms of the latency). A session on prompt poses that merely ran out of time names none."""
    from excite.live.report import closing_lines, result_dict

    outcomes = []
    for latency, max_time in ((0.06, 40.0), (0.0, 8.0)):
        robot = EXAMPLE.ToyRobot(TRUTH, seed=3, latency=latency)
        session = LiveSession(_settings(max_time=max_time, time_offset=0.0),
                              make_protocol("slip_aware"), seed=3)
        _drive(session, robot)
        outcomes.append(session.finish())
    late, short = outcomes
    assert late.outcome == short.outcome == "out_of_time"
    assert abs(late.suggested_time_offset + 0.06) < 0.003
    assert (f"the pose stamps seem offset: with a clock offset of "
            f"{late.suggested_time_offset:+.4f} s (not the +0.0000 s used)") in "\n".join(
        closing_lines(late))
    assert result_dict(late)["live"]["suggested_time_offset"] == late.suggested_time_offset
    assert short.suggested_time_offset is None


def test_a_log_that_cannot_give_its_clock_offset_is_cut_with_zero_or_waits_for_it():
    """With time_offset="estimate": a log too short to estimate the offset from (the streams
    must overlap for 4 x MAX_TIME_OFFSET s), or whose heading is too noisy to compare its rate
    with the wheels', is cut with 0 (the data say nothing about the clocks); one whose best
    fit lies beyond the search range (poses 2 s late) is *not yet*, saying so; a long enough
    one is cut with the estimate."""
    from excite.live.log import clock_offset, decide_log
    from excite.logs.synthetic import synthetic_log
    from excite.stopping import StoppingRule

    rule = StoppingRule(target=0.005, sensor_pose="axle")
    logs = {}
    for latency in (0.04, 2.0):
        robot = EXAMPLE.ToyRobot(TRUTH, seed=4, latency=latency)
        session = LiveSession(_settings(time_offset=0.0, target=1e-4, max_time=12.0),
                              make_protocol("slip_aware"), seed=4)
        logs[latency] = EXAMPLE.run(session, robot).series
    late = logs[0.04]
    assert clock_offset(during(late, None, late.t_enc[0] + 3.0), "estimate") == 0.0
    noisy = synthetic_log(np.random.default_rng(0), 20.0, pose_rate=200.0,
                          pose_noise=(0.005, 0.01)).series
    assert clock_offset(noisy, "estimate") == 0.0
    decision, offset = decide_log(rule, late, 1.0, NOMINAL, time_offset="estimate")
    assert abs(offset + 0.04) < 0.003 and decision.n_segments >= 10
    decision, offset = decide_log(rule, logs[2.0], 1.0, NOMINAL, time_offset="estimate")
    assert offset is None and not decision.done and decision.result is None
    assert decision.reason.startswith("no clock offset: cannot estimate the time offset: "
                                      "it is not within +-1.0 s"), decision.reason


@pytest.mark.slow
@pytest.mark.statistical
def test_late_poses_make_no_false_stops_with_the_offset_estimated():
    """Monte Carlo over 20 made-up robots whose poses arrive 30 ms late (stamped on arrival):
    with the clock offset estimated (live's default) at most one session stops *done* with the
    truth outside the target (none of 120 in the benchmark, BENCHMARKS.md "Poses that arrive
    late"); cut with 0, 6 of the 30 that ended done did, a rate at which 20 sessions show at
    most one false stop 7% of the time."""
    rng = np.random.default_rng(2027)
    false_stops = 0
    for k in range(20):
        truth = Params(*(NOMINAL.as_array() * rng.uniform(0.97, 1.03, 3)))
        robot = EXAMPLE.ToyRobot(truth, seed=300 + k, latency=0.03)
        result = EXAMPLE.run(LiveSession(_settings(), make_protocol("slip_aware"), seed=k),
                             robot)
        error = np.abs(result.calibration.params.as_array() / truth.as_array() - 1.0)
        false_stops += result.outcome == "done" and bool(np.any(error > 0.005))
    assert false_stops <= 1, false_stops
