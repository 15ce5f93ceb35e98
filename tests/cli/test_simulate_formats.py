"""Simulated time-series logs: the environment's recording (encoder ticks at the physics rate,
the hidden sensor's noisy world pose at 100 Hz, the truth beside them), written as time-series
CSVs and real ROS bags (rosbag2 sqlite3 and mcap, ROS 1), read back, segmented and calibrated
against the truth; and ``excite simulate --format segments|timeseries|bag``."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import excite  # noqa: F401  (registers the environment ids)
from envs.env import DiffDriveCalibEnv
from envs.recording import START_TIME_NS, Recording, along_arc
from excite import calibrate
from excite.cli import main
from excite.core import se2
from excite.logs.segmentation import segment_timeseries
from excite.logs.timeseries import TimeSeries
from excite.logs.timeseries_csv import read_timeseries, write_timeseries

IDEAL, SENSOR = "excite/DiffDriveCalibIdeal-v0", "excite/DiffDriveCalibSensor-v0"
STREAMS = ("t_enc", "phi_L", "phi_R", "t_pose", "x", "y", "theta")
WHEELS = ("left_wheel_joint", "right_wheel_joint")


def run_episode(env_id: str = SENSOR, segments: int = 8, seed: int = 5, **config) -> gym.Env:
    """An episode of random wheel commands (within 60% of the motor limit)."""
    env = gym.make(env_id, budget=segments, **config)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(segments):
        env.step(rng.uniform(-0.6, 0.6, 2))
    return env


def assert_same_series(a: TimeSeries, b: TimeSeries) -> None:
    for name in STREAMS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)


@pytest.fixture(scope="module")
def recorded() -> gym.Env:
    """The slip env with an off-axle sensor, recording with the default pose noise."""
    return run_episode(record=True, settle_time=0.2)


@pytest.fixture(scope="module")
def exact() -> gym.Env:
    """The ideal drive with an off-axle sensor, recording noise-free poses; an arena large
    enough that no wall stops the robot."""
    return run_episode(ideal=True, segments=12, arena_size=30.0, record=True,
                       record_sigma_xy=0.0, record_sigma_theta=0.0)


# --------------------------------------------------------------------------- the recording


@pytest.mark.parametrize("env_id", [IDEAL, SENSOR])
def test_recording_is_off_by_default_and_changes_nothing(env_id):
    plain, recording = run_episode(env_id, settle_time=0.2), run_episode(
        env_id, settle_time=0.2, record=True)
    assert plain.unwrapped.recording is None
    assert isinstance(recording.unwrapped.recording, Recording)
    np.testing.assert_array_equal(plain.unwrapped.segments.as_array(),
                                  recording.unwrapped.segments.as_array())
    np.testing.assert_array_equal(plain.unwrapped.path, recording.unwrapped.path)
    np.testing.assert_array_equal(plain.unwrapped.knowledge().observation,
                                  recording.unwrapped.knowledge().observation)


def test_recording_defaults_are_the_env_config():
    config = DiffDriveCalibEnv.default_config()
    assert config["record"] is False
    assert (config["record_pose_hz"], config["record_sigma_xy"],
            config["record_sigma_theta"]) == (100.0, 1e-3, 2e-3)
    with pytest.raises(ValueError, match="pose_hz must be finite and > 0"):
        DiffDriveCalibEnv(record=True, record_pose_hz=0.0)
    with pytest.raises(ValueError, match="sigma_xy must be finite and >= 0"):
        DiffDriveCalibEnv(record=True, record_sigma_xy=-1.0)
    env = gym.make(IDEAL, record=True)
    env.reset(seed=0)
    with pytest.raises(RuntimeError, match="run a segment first"):
        _ = env.unwrapped.recording


def test_streams_clock_ticks_and_noise(recorded):
    base = recorded.unwrapped
    rec = base.recording
    ts = rec.series
    n_ticks = 8 * 60  # 8 segments of 1.2 s at 50 Hz
    start = START_TIME_NS * 1e-9
    np.testing.assert_array_equal(ts.t_enc, (START_TIME_NS + 20_000_000 * np.arange(n_ticks + 1))
                                  * 1e-9)
    np.testing.assert_array_equal(ts.t_pose, (START_TIME_NS + 10_000_000
                                              * np.arange(2 * n_ticks + 1)) * 1e-9)
    assert ts.t_enc[0] == ts.t_pose[0] == start
    # Encoders: the quantized true wheel angles at every physics tick.
    resolution = 2 * np.pi / rec.ticks_per_rev
    assert rec.ticks_per_rev == base.config["ticks_per_rev"] == 4096
    np.testing.assert_array_equal(ts.phi_L, np.floor(rec.true_wheel_angles[:, 0] / resolution)
                                  * resolution)
    np.testing.assert_array_equal(rec.true_wheel_angles[-1], base.sim.wheel_angles)
    # Poses: the hidden sensor's true world pose (on the ticks: the body path composed with the
    # mounting), plus independent noise of the configured levels.
    mount = base.true_sensor_pose.as_array()
    np.testing.assert_array_equal(rec.sensor_pose, mount)
    np.testing.assert_allclose(rec.true_poses[::2], se2.compose(base.path, mount), rtol=0,
                               atol=1e-15)
    np.testing.assert_array_equal(rec.sigma, [1e-3, 1e-3, 2e-3])
    noise = np.column_stack([ts.x, ts.y, ts.theta]) - rec.true_poses
    assert np.all(np.abs(noise.std(axis=0) / rec.sigma - 1) < 0.1)
    assert abs(np.corrcoef(noise[1:, 0], noise[:-1, 0])[0, 1]) < 0.1


def test_poses_between_ticks_follow_the_arc():
    """Ideal drive: the 100 Hz poses interpolated between 50 Hz ticks are the poses a 100 Hz
    simulation of the same robot and commands passes through."""
    coarse, fine = (run_episode(IDEAL, segments=4, record=True, physics_hz=hz).unwrapped
                    for hz in (50.0, 100.0))
    np.testing.assert_allclose(coarse.recording.true_poses, fine.recording.true_poses,
                               rtol=0, atol=1e-12)
    start, end = np.array([[1.0, 2.0, 3.0]]), np.array([[1.5, 2.2, 3.7]])
    np.testing.assert_array_equal(along_arc(start, end, [0.0]), start)
    np.testing.assert_allclose(along_arc(start, end, [1.0]), end, rtol=0, atol=1e-15)


def test_seeds_make_recordings_deterministic():
    a, b = (run_episode(record=True, segments=3).unwrapped.recording for _ in range(2))
    assert_same_series(a.series, b.series)
    c = run_episode(record=True, segments=3, seed=6).unwrapped.recording
    assert not np.array_equal(a.series.x, c.series.x)


# --------------------------------------------------------------------------- files


def test_timeseries_csv_reads_back_the_recording(tmp_path, recorded):
    rec = recorded.unwrapped.recording
    ticks, angles = tmp_path / "ticks.csv", tmp_path / "angles.csv"
    write_timeseries(ticks, rec.series, ticks_per_rev=rec.ticks_per_rev)
    write_timeseries(angles, rec.series)
    lines = ticks.read_text().splitlines()
    assert lines[0] == "t,ticks_L,ticks_R,x,y,theta"
    assert lines[2].startswith("1.01,,,") and len(lines) == 1 + rec.series.t_pose.size
    assert angles.read_text().startswith("t,phi_L,phi_R,x,y,theta\n")
    assert_same_series(read_timeseries(ticks, ticks_per_rev=rec.ticks_per_rev), rec.series)
    assert_same_series(read_timeseries(angles), rec.series)
    with pytest.raises(excite.DataError, match="not a whole number of ticks"):
        write_timeseries(tmp_path / "x.csv", rec.series, ticks_per_rev=1000)


@pytest.mark.slow
def test_bags_of_every_storage_read_back_identically(tmp_path, recorded):
    pytest.importorskip("rosbags")
    from excite.logs.bag_reader import read_bag
    from excite.logs.bag_writer import STORAGES, write_bag

    series = recorded.unwrapped.recording.series
    logs = [read_bag(write_bag(tmp_path / ("log.bag" if s == "ros1" else s), series, storage=s),
                     *WHEELS, pose_topic="/pose") for s in STORAGES]
    for log in logs[1:]:
        assert_same_series(log, logs[0])
    for name in STREAMS[:-1]:
        np.testing.assert_array_equal(getattr(logs[0], name), getattr(series, name), name)
    np.testing.assert_allclose(logs[0].theta, series.theta, rtol=0, atol=1e-13)


def test_noise_free_log_segments_into_the_true_sensor_motion(exact):
    """Segments of the noise-free log: pose increments are the true sensor motion, encoder
    increments the true wheel turns to within a tick, and calibration finds the hidden robot
    and sensor mounting (from half-second segments: 12 are too few to estimate the seven
    noise levels)."""
    base = exact.unwrapped
    rec = base.recording
    cut = segment_timeseries(rec.series)
    rows = cut.segments.as_array()
    assert len(rows) == 12
    first = np.searchsorted(rec.series.t_pose, cut.t_start)
    last = np.searchsorted(rec.series.t_pose, cut.t_end)
    np.testing.assert_allclose(rows[:, 2:], se2.between(rec.true_poses[first],
                                                        rec.true_poses[last]),
                               rtol=0, atol=1e-12)
    resolution = 2 * np.pi / rec.ticks_per_rev
    for k in range(2):
        turn = (np.interp(cut.t_end, rec.series.t_enc, rec.true_wheel_angles[:, k])
                - np.interp(cut.t_start, rec.series.t_enc, rec.true_wheel_angles[:, k]))
        assert np.abs(rows[:, k] - turn).max() < resolution
    result = calibrate(segment_timeseries(rec.series, window=0.5).segments,
                       sensor_pose="estimate")
    assert np.abs(result.params.as_array() / base.true_params.as_array() - 1).max() < 2e-4
    np.testing.assert_allclose(result.sensor_pose.as_array(),
                               base.true_sensor_pose.as_array(), rtol=0, atol=1e-3)


def test_noise_free_log_without_quantization_calibrates_to_the_truth():
    """No pose noise and (practically) no encoder quantization: the recording and the
    segmentation have no model error, so calibration returns the hidden robot and sensor
    mounting to ~1e-6 (the noise-level floors leave ~1e-11 here)."""
    base = run_episode(segments=40, ideal=True, arena_size=30.0, record=True,
                       record_sigma_xy=0.0, record_sigma_theta=0.0,
                       ticks_per_rev=2**30).unwrapped
    result = calibrate(segment_timeseries(base.recording.series).segments,
                       sensor_pose="estimate")
    assert np.abs(result.params.as_array() / base.true_params.as_array() - 1).max() < 1e-6
    np.testing.assert_allclose(result.sensor_pose.as_array(),
                               base.true_sensor_pose.as_array(), rtol=0, atol=1e-6)


# --------------------------------------------------------------------------- the command line


def simulate(tmp_path: Path, *options: str, out: str = "log.csv", env: str = SENSOR,
             seed: int = 3) -> tuple[Path, dict]:
    """Run excite simulate (random protocol, 4 segments); the output and its truth."""
    path = tmp_path / out
    assert main(["simulate", "--protocol", "random", "--segments", "4", "--seed", str(seed),
                 "--env", env, "--out", str(path), *options]) == 0
    truth = path.with_name(path.stem + ".truth.json")  # log.csv, run.bag, run: NAME.truth.json
    return path, json.loads(truth.read_text())


def test_simulate_timeseries(tmp_path, capsys):
    path, truth = simulate(tmp_path, "--format", "timeseries", "--pose-noise", "0.002,0")
    assert "a 4 s log (201 encoder samples, 401 sensor poses)" in capsys.readouterr().out
    for key in ("r_L", "r_R", "b", "robot", "sigma", "env", "protocol", "seed", "segments",
                "collisions"):
        assert key in truth
    assert truth["format"] == "timeseries" and truth["ticks_per_rev"] == 4096
    assert truth["pose_noise"] == {"xy": 0.002, "theta": 0.0} and truth["pose_rate"] == 100.0
    assert truth["calibrate_args"] == ["--ticks-per-rev", "4096"]
    mount = np.array([truth["sensor_pose"][k] for k in ("x", "y", "theta")])
    assert np.linalg.norm(mount) > 0  # the Sensor id's hidden mounting
    ts = read_timeseries(path, ticks_per_rev=truth["ticks_per_rev"])
    assert ts.t_enc.size == 201 and ts.t_pose.size == 401
    again, _ = simulate(tmp_path, "--format", "timeseries", "--pose-noise", "0.002,0",
                        out="again.csv")
    assert again.read_text() == path.read_text()
    other, _ = simulate(tmp_path, "--format", "timeseries", out="other.csv", seed=4)
    assert other.read_text() != path.read_text()


def test_robot_seed_gives_logs_of_one_robot(tmp_path):
    """--robot-seed R: the hidden robot and mounting of seed R's episode, the rest (start,
    noise, protocol draws) of --seed's; R = --seed is the plain run."""
    plain, plain_truth = simulate(tmp_path, "--format", "timeseries", out="plain.csv")
    same, same_truth = simulate(tmp_path, "--format", "timeseries", "--robot-seed", "3",
                                out="same.csv")
    assert same.read_text() == plain.read_text()
    assert plain_truth["robot_seed"] == same_truth["robot_seed"] == 3
    held, held_truth = simulate(tmp_path, "--format", "timeseries", "--robot-seed", "3",
                                out="held.csv", seed=8)
    other, other_truth = simulate(tmp_path, "--format", "timeseries", out="other.csv", seed=8)
    assert held_truth["robot_seed"] == 3 and held_truth["seed"] == 8
    for key in ("r_L", "r_R", "b", "robot", "sensor_pose"):
        assert held_truth[key] == plain_truth[key], key
        assert other_truth[key] != plain_truth[key], key
    assert held.read_text() not in (plain.read_text(), other.read_text())


def test_reset_option_sensor_pose_fixes_the_mounting():
    env = gym.make(SENSOR).unwrapped
    mount = excite.SensorPose(0.05, -0.02, 0.3)
    env.reset(seed=1, options={"sensor_pose": mount})
    assert env.true_sensor_pose == mount
    env.reset(seed=1)
    assert env.true_sensor_pose != mount
    with pytest.raises(ValueError, match="sensor is on the axle"):
        gym.make(IDEAL).unwrapped.reset(seed=1, options={"sensor_pose": mount})


def test_simulate_segments_is_unchanged(tmp_path):
    path, truth = simulate(tmp_path, env=IDEAL)
    assert truth["format"] == "segments" and truth["calibrate_args"] == []
    assert truth["sensor_pose"] == {"x": 0.0, "y": 0.0, "theta": 0.0}
    assert "pose_noise" not in truth
    assert len(excite.load_segments(path)) == 4 == truth["segments"]


@pytest.mark.parametrize("storage, out", [("sqlite3", "run"), ("mcap", "run"),
                                          ("ros1", "run.bag")])
def test_simulate_bag(tmp_path, storage, out):
    pytest.importorskip("rosbags")
    from excite.logs.bag_reader import read_bag

    path, truth = simulate(tmp_path, "--format", "bag", "--storage", storage, out=out)
    csv, _ = simulate(tmp_path, "--format", "timeseries", out="log.csv")
    args = truth["calibrate_args"]
    assert args == ["--joint-states", "/joint_states", "--left-wheel", WHEELS[0],
                    "--right-wheel", WHEELS[1], "--pose-topic", "/pose"]
    assert truth["storage"] == storage and truth["pose_noise"] == {"xy": 1e-3, "theta": 2e-3}
    options = dict(zip(args[::2], args[1::2], strict=True))
    bag = read_bag(path, options["--left-wheel"], options["--right-wheel"],
                   pose_topic=options["--pose-topic"], joint_states=options["--joint-states"])
    log = read_timeseries(csv, ticks_per_rev=truth["ticks_per_rev"])
    for name in STREAMS[:-1]:
        np.testing.assert_array_equal(getattr(bag, name), getattr(log, name), name)
    np.testing.assert_allclose(bag.theta, log.theta, rtol=0, atol=1e-13)


@pytest.mark.parametrize(
    "options, out, fragment",
    [
        (["--storage", "mcap"], "x.csv", "--storage applies to --format bag"),
        (["--pose-noise", "0.1,0.1"], "x.csv", "--pose-noise applies to --format timeseries"),
        (["--format", "timeseries", "--pose-noise", "0.1"], "x.csv",
         "argument --pose-noise: must be SXY,STH"),
        (["--format", "timeseries", "--pose-noise=-1,0"], "x.csv",
         "two finite numbers >= 0"),
        (["--format", "bag", "--storage", "ros1"], "run", "give --out NAME.bag"),
        (["--format", "bag"], "run.mcap", "writes a rosbag2 directory: give --out without"),
        (["--format", "bag"], "exists", "exists; a bag is never overwritten"),
        (["--format", "csv"], "x.csv", "argument --format: invalid choice"),
    ],
)
def test_simulate_bad_options(tmp_path, capsys, options, out, fragment):
    (tmp_path / "exists").mkdir()
    code = main(["simulate", "--protocol", "random", "--segments", "2", "--env", IDEAL,
                 "--out", str(tmp_path / out), *options])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("excite: error: ")
    assert fragment in err[0]


def test_simulate_bag_without_rosbags_names_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "rosbags.rosbag2", None)
    code = main(["simulate", "--protocol", "random", "--segments", "2", "--env", IDEAL,
                 "--format", "bag", "--out", str(tmp_path / "run")])
    assert code == 2
    assert capsys.readouterr().err == ("excite: error: writing bags needs the ros extra: "
                                       "pip install 'excite[ros]'\n")


def test_calibrate_models_the_declared_encoder_resolution(tmp_path, capsys):
    """`calibrate --ticks-per-rev N` reads ticks and puts their rounding in the noise model:
    the command's result is excite.calibrate(..., ticks_per_rev=N) on the same segments, and
    differs from the model without quantization."""
    path = tmp_path / "log.csv"
    assert main(["simulate", "--protocol", "random", "--segments", "20", "--seed", "7",
                 "--env", IDEAL, "--pose-noise", "0.0002,0.0002", "--format", "timeseries",
                 "--out", str(path)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(path), "--ticks-per-rev", "4096", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    segments = segment_timeseries(read_timeseries(path, ticks_per_rev=4096)).segments
    with_ticks = calibrate(segments, ticks_per_rev=4096)
    without = calibrate(segments)
    cli_std = np.array([report["std"][k] for k in ("r_L", "r_R", "b")])
    np.testing.assert_allclose(cli_std, with_ticks.std, rtol=1e-9)
    assert np.abs(cli_std / without.std - 1).max() > 1e-3
