"""The wiring check: swapped or reversed wheels and orientation-less pose sources are named
before any fit; a robot wired as the model assumes never trips it, whatever the noise."""

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from excite.calibration.pipeline import calibrate
from excite.calibration.wiring import check_pose_source, check_wiring
from excite.core.kinematics import Params
from excite.core.models import SENSOR_POSE, SensorPose
from excite.errors import DataError
from excite.logs.segments import Segments
from excite.logs.synthetic import lesson_dataset, synthetic_log
from excite.logs.timeseries_csv import write_timeseries
from excite.validation.dead_reckoning import dead_reckon
from tests.conftest import run_cli

TRUTH = Params(0.050, 0.051, 0.300)
SENSOR = SensorPose(0.1, -0.03, 0.4)


def _sensor_segments(rng: np.random.Generator, n: int, sigma: float,
                     pose: SensorPose = SENSOR, straight: float | None = None,
                     robot: Params = TRUTH) -> Segments:
    """Random commands seen by an off-axle sensor, with noise ``sigma`` on every channel;
    ``straight``: the right wheel turns that many times the left (nearly straight driving)."""
    dphi = rng.normal(0.0, 0.4, (2, n))
    if straight is not None:
        dphi[1] = straight * dphi[0]
    theta = np.append(robot.as_array(), pose.as_array())
    measured = SENSOR_POSE.predict(dphi[0], dphi[1], theta)
    measured = measured + rng.normal(0.0, sigma, measured.shape)
    return Segments(dphi[0], dphi[1], *np.moveaxis(measured, -1, 0))


def _rewired(seg: Segments, how: str) -> Segments:
    return {"swapped": dataclasses.replace(seg, dphi_L=seg.dphi_R, dphi_R=seg.dphi_L),
            "right": dataclasses.replace(seg, dphi_R=-seg.dphi_R),
            "left": dataclasses.replace(seg, dphi_L=-seg.dphi_L),
            "no heading": dataclasses.replace(seg, dtheta=np.zeros(len(seg)))}[how]


@pytest.mark.parametrize("how, words", [("swapped", "swapped"), ("right", "right wheel"),
                                        ("left", "left wheel"),
                                        ("no heading", "heading never changes")])
def test_miswired_data_are_named(how, words):
    seg = _sensor_segments(np.random.default_rng(1), 60, 0.002)
    check_wiring(seg)  # as recorded: fine
    with pytest.raises(DataError, match=words):
        check_wiring(_rewired(seg, how), "log.csv")
    with pytest.raises(DataError, match=words):  # the library entry point checks too
        calibrate(_rewired(seg, how))


@pytest.mark.parametrize("encoder_noise", [0.0, 1e-6, 1e-4, 1e-3, 1e-2])
def test_spins_only_swapped_are_named_from_the_turn_rate(encoder_noise):
    """Spins only: the ratios are not told apart (exactly, or nearly when the encoders are a
    little noisy), but their sum is, far better than either."""
    rng = np.random.default_rng(2)
    spin = rng.normal(0.0, 5.0, 40)
    theta = np.append(TRUTH.as_array(), SENSOR.as_array())
    measured = SENSOR_POSE.predict(-spin, spin, theta) + rng.normal(0.0, 0.002, (40, 3))
    noisy = rng.normal(0.0, encoder_noise, (2, 40))
    seg = Segments(-spin + noisy[0], spin + noisy[1], *measured.T)
    check_wiring(seg)
    with pytest.raises(DataError, match="swapped"):
        check_wiring(_rewired(seg, "swapped"))


def test_wrapped_headings_are_named_as_a_possible_cause():
    """Segments turning 1.2-1.8 pi with dtheta wrapped (a contract violation: increments are
    continuous) look miswired; the message says wrapping may be why."""
    from excite.core.kinematics import predict_increment, wrap_angle

    rng = np.random.default_rng(1)
    turn = rng.uniform(1.2 * np.pi, 1.8 * np.pi, 60) * rng.choice([-1, 1], 60)
    forward, apart = rng.uniform(-10, 10, 60), turn * TRUTH.b / TRUTH.r_R
    phi_L, phi_R = forward - apart / 2, forward + apart / 2
    measured = np.column_stack(predict_increment(phi_L, phi_R, TRUTH))
    measured += rng.normal(0.0, 1e-3, measured.shape)
    check_wiring(Segments(phi_L, phi_R, *measured.T))  # continuous: fine
    with pytest.raises(DataError, match="dtheta is wrapped"):
        check_wiring(Segments(phi_L, phi_R, measured[:, 0], measured[:, 1],
                              wrap_angle(measured[:, 2])))


def test_exact_straight_driving_is_not_called_orientation_less():
    phi = np.random.default_rng(5).uniform(1.0, 3.0, 10)
    measured = np.column_stack([TRUTH.r_L * phi, np.zeros(10), np.zeros(10)])
    check_wiring(Segments(phi, phi * TRUTH.r_L / TRUTH.r_R, *measured.T))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(4, 80),
       sigma=st.floats(1e-6, 0.05), straight=st.none() | st.floats(0.9, 1.1),
       angle=st.floats(-np.pi, np.pi), r_L=st.floats(0.0475, 0.0525),
       r_R=st.floats(0.0475, 0.0525))
def test_a_correctly_wired_robot_never_trips_the_check(seed, n, sigma, straight, angle, r_L,
                                                       r_R):
    """Any robot of a +-5% spread, any noise level (up to 0.05 rad per segment, a quarter of a
    typical turn), any number of segments, any sensor mounting angle, and nearly straight
    driving (one combination of the ratios determined, of either sign): no false alarm."""
    rng = np.random.default_rng(seed)
    check_wiring(_sensor_segments(rng, n, sigma, SensorPose(0.1, -0.03, angle), straight,
                                  Params(r_L, r_R, 0.3)))


def test_lesson_data_pass():
    check_wiring(lesson_dataset(np.random.default_rng(0)))


def test_calibrate_names_the_file_of_a_swapped_log(capsys, tmp_path):
    log = synthetic_log(np.random.default_rng(3), 30, TRUTH, SENSOR, pose_noise=(0.002, 0.002))
    series = dataclasses.replace(log.series, phi_L=log.series.phi_R, phi_R=log.series.phi_L)
    path = tmp_path / "swapped.csv"
    write_timeseries(path, series)
    code, out, err = run_cli(capsys, "calibrate", str(path))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"excite: error: {path}")
    assert "swapped" in err


def test_nearly_straight_driving_of_a_lopsided_robot_is_not_called_miswired():
    """r_L > r_R driven with the right wheel turning 5% more: the robot veers right (dtheta < 0)
    although phi_R > phi_L. Only the combination r_R/b x 1.05 - r_L/b is determined, of
    either sign for a correctly wired robot, so it must not be tested."""
    robot = Params(0.0525, 0.0475, 0.3)
    rng = np.random.default_rng(6)
    seg = _sensor_segments(rng, 60, 1e-4, straight=1.05, robot=robot)
    assert np.all(np.sign(seg.dtheta) == -np.sign(seg.dphi_L))
    check_wiring(seg)


def test_poses_dead_reckoned_from_the_encoders_are_named():
    rng = np.random.default_rng(2)
    dphi = rng.normal(0.0, 0.4, (2, 60))
    exact = SENSOR_POSE.predict(dphi[0], dphi[1], np.append(TRUTH.as_array(), np.zeros(3)))
    seg = Segments(dphi[0], dphi[1], *np.moveaxis(exact, -1, 0))
    note = check_pose_source(seg, "odom.csv")
    assert note is not None and note.startswith("odom.csv: the pose headings follow the wheel")
    with pytest.raises(DataError, match=r"odom.csv: .* dead reckoning \(wheel odometry"):
        check_pose_source(seg, "odom.csv", nominal=tuple(TRUTH.as_array()))
    assert check_pose_source(seg, "odom.csv", nominal=(0.05, 0.05, 0.3)) is not None
    # an external sensor: even motion-capture heading noise (0.1 mrad) is far from exact
    for sigma in (1e-4, 1e-5):
        assert check_pose_source(_sensor_segments(rng, 60, sigma), nominal=(0.05, 0.051, 0.3)) \
            is None
    # straight driving at one wheel ratio tells nothing
    assert check_pose_source(_sensor_segments(rng, 60, 0.0, straight=1.0)) is None


def test_calibrate_refuses_the_nominal_robots_wheel_odometry(capsys, tmp_path):
    """A pose stream dead-reckoned from the log's own encoders with the nominal robot (what
    /odom is): with --init the nominal robot, an error; without, a note."""
    rng = np.random.default_rng(5)
    log = synthetic_log(rng, 40, TRUTH)
    series = log.series
    t_enc, t_pose = series.t_enc, series.t_pose
    phi_L = np.interp(t_pose, t_enc, series.phi_L)
    phi_R = np.interp(t_pose, t_enc, series.phi_R)
    encoders = dataclasses.replace(series, t_enc=t_pose, phi_L=phi_L, phi_R=phi_R)
    x, y, theta = dead_reckon(encoders, 0.0, Params(0.05, 0.05, 0.3)).T
    odometry = dataclasses.replace(encoders, x=x, y=y, theta=theta)
    path = tmp_path / "odom.csv"
    write_timeseries(path, odometry)
    code, out, err = run_cli(capsys, "calibrate", str(path), "--init", "0.05,0.05,0.3")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"excite: error: {path}: the pose headings")
    code, out, err = run_cli(capsys, "calibrate", str(path))
    assert f"excite: note: {path}: the pose headings follow the wheel angles exactly" in err
    code, out, _ = run_cli(capsys, "calibrate", str(path), "--json")
    notes = json.loads(out)["notes"]  # --json keeps what the note said
    assert any(note.startswith(f"{path}: the pose headings follow the wheel angles exactly")
               for note in notes), notes


def test_headings_in_degrees_are_named():
    """theta written in degrees: the heading turns ~57 times faster per wheel radian than the
    robot's r/b, faster than any differential drive can (r/b < 1)."""
    seg = _sensor_segments(np.random.default_rng(3), 60, 0.002)
    check_wiring(seg)
    in_degrees = dataclasses.replace(seg, dtheta=np.degrees(seg.dtheta))
    with pytest.raises(DataError, match=r"log.csv: the heading turns .* more than any "
                                        r"differential drive .* headings in degrees, or wheel "
                                        r"angles in revolutions\?"):
        check_wiring(in_degrees, "log.csv")
