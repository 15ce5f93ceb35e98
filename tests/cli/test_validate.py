"""excite validate: dead reckoning with nominal and calibrated parameters on held-out logs."""

import json
import math
import subprocess
import sys
import time

import numpy as np
import pytest

from excite import save_segments
from excite.core.kinematics import Params
from excite.core.models import SensorPose
from excite.logs.segmentation import segment_timeseries
from excite.logs.synthetic import synthetic_log
from excite.logs.timeseries import TimeSeries
from excite.validation.dead_reckoning import (
    dead_reckon,
    find_loops,
    read_params_file,
    summarize,
    validate_log,
)
from tests.conftest import assert_one_line_error, run_cli

NOMINAL = Params(0.050, 0.050, 0.300)
#: The hidden robot: 5% off nominal on every parameter.
TRUTH = Params(0.050 * 1.05, 0.050 * 0.95, 0.300 * 1.05)
SENSOR = SensorPose(0.12, -0.04, 0.3)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"




def write_log(directory, name: str, series: TimeSeries) -> list[str]:
    """The log as two stream CSVs (encoders, then poses), as given on the command line."""
    enc, pose = directory / f"{name}.enc.csv", directory / f"{name}.pose.csv"
    np.savetxt(enc, np.column_stack([series.t_enc, series.phi_L, series.phi_R]), fmt="%.17g",
               delimiter=",", header="t,phi_L,phi_R", comments="")
    np.savetxt(pose, np.column_stack([series.t_pose, series.x, series.y, series.theta]),
               fmt="%.17g", delimiter=",", header="t,x,y,theta", comments="")
    return [str(enc), str(pose)]


def write_params(path, params: Params, sensor_pose: SensorPose | None = SENSOR, **extra):
    """A params file like the output of excite calibrate --json (the keys validate reads)."""
    data = {"params": {"r_L": params.r_L, "r_R": params.r_R, "b": params.b},
            "sensor_pose": None if sensor_pose is None else {
                "x": sensor_pose.x, "y": sensor_pose.y, "theta": sensor_pose.theta},
            "model": "axle" if sensor_pose is None else "sensor_pose", **extra}
    path.write_text(json.dumps(data))
    return path


def square_log(rng, directions=("cw", "cw", "ccw", "ccw"), side=1.5, params=TRUTH,
               sensor_pose=SENSOR, pose_noise=(0.002, 0.001)) -> TimeSeries:
    """A robot driving square loops (straight sides at 0.3 m/s, turns on the spot at 1 rad/s)
    with exact kinematics: encoders at 100 Hz, poses at 50 Hz with Gaussian noise."""
    dt, legs = 0.01, []
    for direction in directions:
        turn = math.pi / 2 if direction == "ccw" else -math.pi / 2
        legs += [("straight", side), ("turn", turn)] * 4
    steps = []  # (wheel increments L, R [rad], body increment ds [m], dtheta [rad]) per step
    for kind, amount in legs:
        if kind == "straight":
            n = round(amount / (0.3 * dt))
            ds = amount / n
            steps += [(ds / params.r_L, ds / params.r_R, ds, 0.0)] * n
        else:
            n = round(abs(amount) / (1.0 * dt))
            dth = amount / n
            arc = 0.5 * params.b * dth  # each wheel's ground arc (m)
            steps += [(-arc / params.r_L, arc / params.r_R, 0.0, dth)] * n
    wheels_L, wheels_R, ds, dth = np.array(steps).T
    theta = 0.4 + np.concatenate(([0.0], np.cumsum(dth)))
    x = 2.0 + np.concatenate(([0.0], np.cumsum(ds * np.cos(theta[:-1]))))
    y = -1.0 + np.concatenate(([0.0], np.cumsum(ds * np.sin(theta[:-1]))))
    t = dt * np.arange(theta.size)
    l_x, l_y, l_th = sensor_pose.as_array()
    c, s = np.cos(theta), np.sin(theta)
    sensor = np.column_stack([x + c * l_x - s * l_y, y + s * l_x + c * l_y, theta + l_th])[::2]
    sensor += rng.normal(size=sensor.shape) * [pose_noise[0], pose_noise[0], pose_noise[1]]
    phi_L = np.concatenate(([0.0], np.cumsum(wheels_L)))
    phi_R = np.concatenate(([0.0], np.cumsum(wheels_R)))
    return TimeSeries(t, phi_L, phi_R, t[::2], *sensor.T)


@pytest.fixture
def rng():
    return np.random.default_rng(2024)


@pytest.fixture
def noisy_log(rng):
    return synthetic_log(rng, 60.0, TRUTH, SENSOR, pose_noise=(0.005, 0.002), slip=0.002,
                         step=0.002)


# --------------------------------------------------------------------------- library


#: Smooth driving (the simulation's step, s, far inside the 10 ms encoder interval), and how far
#: the encoder intervals' arcs with the curvature-change term may then be from the poses over
#: 40 s (m: 1.2e-8 with the poses on encoder samples, up to 2.4e-7 between them, five logs;
#: one arc per interval alone drifts by 1.2e-5 m).
SMOOTH_STEP, SMOOTH_ATOL = 2e-4, 5e-7


@pytest.mark.parametrize("offset", [0.0, 0.37])
def test_true_params_reproduce_external_poses(rng, offset):
    log = synthetic_log(rng, 40.0, TRUTH, SENSOR, encoder_rate=100.0, pose_rate=50.0,
                        step=SMOOTH_STEP)
    s = log.series
    shifted = TimeSeries(s.t_enc, s.phi_L, s.phi_R, s.t_pose - offset, s.x, s.y, s.theta)
    v = validate_log(shifted, offset, (TRUTH, SENSOR), (NOMINAL, SENSOR))
    assert v.t.size == s.t_pose.size
    np.testing.assert_allclose(v.t, s.t_pose, atol=1e-12)
    np.testing.assert_allclose(v.calibrated_path, v.measured, atol=SMOOTH_ATOL, rtol=0)
    assert v.calibrated.end_position_error < SMOOTH_ATOL
    assert v.calibrated.rms_path_error < SMOOTH_ATOL
    assert v.nominal.end_position_error > 0.1


def test_dead_reckoning_starts_at_first_pose_inside_encoder_range(rng):
    log = synthetic_log(rng, 20.0, TRUTH, SENSOR, encoder_rate=100.0, pose_rate=50.0,
                        step=SMOOTH_STEP)
    s = log.series
    late = TimeSeries(s.t_enc[100:], s.phi_L[100:], s.phi_R[100:], s.t_pose, s.x, s.y,
                      s.theta)  # encoders start at 1 s: the first 50 poses are outside
    v = validate_log(late, 0.0, (TRUTH, SENSOR), (NOMINAL, SENSOR))
    assert v.t[0] == pytest.approx(1.0) and v.t.size == s.t_pose.size - 50
    np.testing.assert_allclose(v.calibrated_path, v.measured, atol=SMOOTH_ATOL, rtol=0)
    odometry = dead_reckon(late, 0.0, TRUTH)
    np.testing.assert_array_equal(odometry[0], 0.0)


def test_calibration_beats_nominal(noisy_log):
    v = validate_log(noisy_log.series, 0.0, (TRUTH, SENSOR), (NOMINAL, SENSOR), name="log")
    assert v.calibrated.end_position_error < 0.1 * v.nominal.end_position_error
    assert v.calibrated.rms_path_error < 0.1 * v.nominal.rms_path_error
    assert v.calibrated.end_heading_error < 0.1 * v.nominal.end_heading_error
    assert all(0 <= r < 0.1 for r in v.ratio.values())
    result = summarize([v, v])
    assert result.calibrated == v.calibrated and result.ratio == v.ratio
    assert v.umbmark is None  # random curves are no square


def test_dead_reckoning_an_hour_at_100_hz_is_fast():
    n = 360_000
    t = np.arange(n) / 100.0
    wheels = np.cumsum(np.random.default_rng(0).normal(0.1, 0.05, (2, n)), axis=1)
    series = TimeSeries(t, *wheels, t[::2], np.zeros(n // 2), np.zeros(n // 2),
                        np.zeros(n // 2))
    start = time.perf_counter()
    odometry = dead_reckon(series, 0.0, TRUTH)
    assert time.perf_counter() - start < 1.0
    assert odometry.shape == (n // 2, 3) and np.isfinite(odometry).all()


def test_umbmark_on_a_bidirectional_square(rng):
    series = square_log(rng)
    v = validate_log(series, 0.0, (TRUTH, SENSOR), (NOMINAL, SENSOR))
    u = v.umbmark
    assert u is not None
    assert [loop.direction for loop in u.loops] == ["cw", "cw", "ccw", "ccw"]
    assert u.count("cw") == 2 and u.count("ccw") == 2
    # The calibrated robot is the true one: only pose noise remains (mm); the nominal one
    # is 5% off (decimetres on 1.5 m sides).
    assert u.calibrated.e_max_syst < 0.02 < 0.1 < u.nominal.e_max_syst
    assert u.ratio < 0.1
    assert u.nominal.errors.shape == (4, 2)
    np.testing.assert_allclose(u.nominal.centroid_cw, u.nominal.errors[:2].mean(axis=0))
    d = v.to_dict()["umbmark"]
    assert set(d) == {"loops", "nominal", "calibrated", "ratio"}
    assert set(d["nominal"]) == {"centroid_cw", "centroid_ccw", "e_max_syst", "errors"}
    assert d["loops"][0]["direction"] == "cw" and d["loops"][0]["t_start"] < 1.0


def test_umbmark_needs_both_directions(rng):
    series = square_log(rng, directions=("ccw", "ccw"))
    assert len(find_loops(series.t_pose, np.column_stack(
        [series.x, series.y, series.theta]))) == 2
    assert validate_log(series, 0.0, (TRUTH, SENSOR), (NOMINAL, SENSOR)).umbmark is None


def test_read_params_file(tmp_path):
    path = write_params(tmp_path / "r.json", TRUTH, None,
                        nominal={"r_L": 0.05, "r_R": 0.05, "b": 0.3})
    result = read_params_file(str(path))
    assert result.params == TRUTH and result.sensor_pose is None
    assert result.nominal == NOMINAL
    path = write_params(tmp_path / "s.json", TRUTH, SENSOR)
    result = read_params_file(str(path))
    assert result.sensor_pose == SENSOR and result.nominal is None


# --------------------------------------------------------------------------- command line


@pytest.fixture
def log_files(tmp_path, noisy_log):
    return write_log(tmp_path, "held_out", noisy_log.series)


@pytest.fixture
def params_file(tmp_path):
    return write_params(tmp_path / "result.json", TRUTH)


def test_json_schema(capsys, tmp_path, log_files, params_file, rng):
    square = write_log(tmp_path, "square", square_log(rng))
    code, out, err = run_cli(capsys, "validate", *log_files, *square, "--params", params_file,
                             "--nominal", "0.05,0.05,0.3", "--json")
    assert code == 0 and err == ""
    d = json.loads(out)
    assert set(d) == {"logs", "overall"}
    metrics = {"end_position_error", "end_heading_error", "rms_path_error"}
    for entry in d["logs"]:
        assert set(entry) == {"file", "nominal", "calibrated", "ratio", "verdict", "umbmark"}
        assert entry["verdict"] == "better"
        for key in ("nominal", "calibrated", "ratio"):
            assert set(entry[key]) == metrics
        assert entry["calibrated"]["end_position_error"] < 0.1 * entry["nominal"][
            "end_position_error"]
    assert d["logs"][0]["file"] == "+".join(log_files) and d["logs"][0]["umbmark"] is None
    assert d["logs"][1]["umbmark"]["calibrated"]["e_max_syst"] < 0.02
    assert set(d["overall"]) == {"nominal", "calibrated", "ratio", "verdict"}
    assert d["overall"]["verdict"] == "better"
    mean = np.mean([e["nominal"]["rms_path_error"] for e in d["logs"]])
    assert d["overall"]["nominal"]["rms_path_error"] == pytest.approx(mean)
    assert d["overall"]["ratio"]["rms_path_error"] == pytest.approx(
        d["overall"]["calibrated"]["rms_path_error"] / mean)


def test_text_report_with_nominal_from_params_file(capsys, tmp_path, log_files):
    params = write_params(tmp_path / "r.json", TRUTH,
                          nominal={"r_L": 0.05, "r_R": 0.05, "b": 0.3})
    code, out, err = run_cli(capsys, "validate", *log_files, "--params", params)
    assert code == 0 and err == ""
    for word in ("nominal", "calibrated", "ratio", "end pos [m]", "RMS path [m]",
                 "overall (mean over logs; ratio of the means)", "held_out.pose.csv"):
        assert word in out


def test_nominal_sensor_pose_override(capsys, log_files, params_file):
    def nominal_rms(*extra):
        code, out, _ = run_cli(capsys, "validate", *log_files, "--params", params_file,
                               "--nominal", f"{TRUTH.r_L},{TRUTH.r_R},{TRUTH.b}", "--json",
                               *extra)
        assert code == 0
        d = json.loads(out)["logs"][0]
        return d["nominal"]["rms_path_error"], d["ratio"]["rms_path_error"]

    assert nominal_rms()[1] == pytest.approx(1.0)  # same robot: same path
    rms, ratio = nominal_rms("--nominal-sensor-pose", "0,0,0")
    assert ratio < 0.5


@pytest.mark.slow
def test_params_from_calibrate_and_plot(capsys, tmp_path, rng, log_files):
    # Calibrate on one log, validate on another: the calibrate --json output is the input.
    training = synthetic_log(rng, 120.0, TRUTH, SENSOR, pose_noise=(0.002, 0.001), step=0.002)
    segments = tmp_path / "train.csv"
    save_segments(segments, segment_timeseries(training.series, window=0.5).segments)
    code, out, _ = run_cli(capsys, "calibrate", segments, "--json", "--sensor-pose",
                           "estimate")
    assert code == 0
    params = tmp_path / "result.json"
    params.write_text(out)
    png = tmp_path / "overlay.png"
    code, out, err = run_cli(capsys, "validate", *log_files, "--params", params, "--nominal",
                             "0.05,0.05,0.3", "--plot", png)
    assert code == 0 and err == "" and str(png) in out
    assert png.read_bytes()[:8] == PNG_SIGNATURE
    pdf = tmp_path / "overlay.pdf"  # the suffix sets the format
    code, _, _ = run_cli(capsys, "validate", *log_files, "--params", params, "--nominal",
                         "0.05,0.05,0.3", "--plot", pdf)
    assert code == 0 and pdf.read_bytes()[:5] == b"%PDF-"
    for bad in ("overlay.gif", ""):
        code, _, err = run_cli(capsys, "validate", *log_files, "--params", params,
                               "--nominal", "0.05,0.05,0.3", "--plot", bad)
        assert_one_line_error(code, err, f"--plot {bad!r}: name a .png, .pdf, .svg, .jpg file")


@pytest.mark.slow
def test_core_path_does_not_import_matplotlib(log_files, params_file):
    argv = ["validate", *log_files, "--params", str(params_file), "--nominal",
            "0.05,0.05,0.3", "--json"]
    script = (f"import sys\nfrom excite.cli import main\nassert main({argv!r}) == 0\n"
              "assert 'matplotlib' not in sys.modules")
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True)


def test_plot_without_matplotlib_names_the_extra(capsys, monkeypatch, tmp_path, log_files,
                                                 params_file):
    for name in ["matplotlib", *(m for m in sys.modules if m.startswith("matplotlib."))]:
        monkeypatch.setitem(sys.modules, name, None)
    code, out, err = run_cli(capsys, "validate", *log_files, "--params", params_file,
                             "--nominal", "0.05,0.05,0.3", "--plot", tmp_path / "p.png")
    assert_one_line_error(code, err, "sim extra", "pip install 'excite[sim]'")


NOMINAL_OPTION = ["--nominal", "0.05,0.05,0.3"]
GOOD = '{"params": {"r_L": 0.05, "r_R": 0.05, "b": 0.3}}'


@pytest.mark.parametrize("content, options, fragments", [
    (None, NOMINAL_OPTION, ["missing.json", "no such file"]),
    ('{"params": {"r_L": 1' + "0" * 400 + ', "r_R": 0.05, "b": 0.3}}', NOMINAL_OPTION,
     ["result.json: params.r_L must be a positive length in meters, got Infinity"]),
    ("[" * 100_000 + "]" * 100_000, NOMINAL_OPTION, ["result.json: not valid JSON: nested too "
                                                     "deeply"]),
    ("{not json", NOMINAL_OPTION, ["result.json:1", "not valid JSON"]),
    ("[1, 2]", NOMINAL_OPTION, ["result.json", "JSON object"]),
    ('{"sensor_pose": null}', NOMINAL_OPTION, ["result.json", "params"]),
    ('{"params": {"r_L": 0.05, "r_R": 0.05}}', NOMINAL_OPTION, ["result.json", "params.b"]),
    ('{"params": {"r_L": -0.05, "r_R": 0.05, "b": 0.3}}', NOMINAL_OPTION,
     ["result.json", "params.r_L", "positive"]),
    ('{"params": {"r_L": 0.05, "r_R": 0.05, "b": 0.3}, "sensor_pose": {"x": 0}}',
     NOMINAL_OPTION, ["result.json", "sensor_pose.y"]),
    ('{"params": {"r_L": 0.05, "r_R": 0.05, "b": 0.3}, "nominal": {"r_L": 0}}', [],
     ["result.json", "nominal.r_L"]),
    (GOOD, [], ["result.json", "--nominal"]),
    (GOOD, ["--nominal", "0.05,0.05"], ["--nominal"]),
    (GOOD, [*NOMINAL_OPTION, "--nominal-sensor-pose", "1,x,0"], ["--nominal-sensor-pose"]),
])
def test_bad_params_are_one_line_errors(capsys, tmp_path, log_files, content, options,
                                        fragments):
    path = tmp_path / ("missing.json" if content is None else "result.json")
    if content is not None:
        path.write_text(content)
    code, _, err = run_cli(capsys, "validate", *log_files, "--params", path, *options)
    assert_one_line_error(code, err, *fragments)


def test_segment_file_and_missing_log_are_one_line_errors(capsys, tmp_path, params_file,
                                                          noisy_log):
    segments = tmp_path / "segments.csv"
    save_segments(segments, segment_timeseries(noisy_log.series).segments)
    code, _, err = run_cli(capsys, "validate", segments, "--params", params_file, "--nominal",
                           "0.05,0.05,0.3")
    assert_one_line_error(code, err, "segments.csv", "segment file")
    code, _, err = run_cli(capsys, "validate", tmp_path / "nope.csv", "--params", params_file,
                           "--nominal", "0.05,0.05,0.3")
    assert_one_line_error(code, err, "nope.csv", "no such file")
    code, _, err = run_cli(capsys, "validate", tmp_path / "nope.csv")
    assert_one_line_error(code, err, "--params")


def test_log_without_poses_in_encoder_range_is_an_error(capsys, tmp_path, noisy_log,
                                                        params_file):
    files = write_log(tmp_path, "log", noisy_log.series)
    code, _, err = run_cli(capsys, "validate", *files, "--params", params_file, "--nominal",
                           "0.05,0.05,0.3", "--time-offset", "1000")
    assert_one_line_error(code, err, "log.enc.csv+", "encoder time range")


@pytest.mark.parametrize("fault, fragment", [
    ("counter", "log.enc.csv:{line}: the wheel angles jump (1 time(s) in the log; the first "
                "here), so dead reckoning across it means nothing: a counter that overflows"),
    ("relocalised", "log.pose.csv:{line}: the pose jumps (1 time(s) in the log; the first "
                    "here), so dead reckoning across it means nothing: a relocalisation"),
])
def test_a_log_that_jumps_is_not_dead_reckoned(capsys, tmp_path, noisy_log, params_file, fault,
                                               fragment):
    """A wheel counter that wraps, or a pose source that relocalises, mid-log: dead reckoning
    across the jump gave end-point errors of metres and a ratio near 1 (calibration looked
    useless), exit 0. Now a one-line error at the first jump."""
    series = noisy_log.series
    if fault == "counter":
        k = int(np.searchsorted(series.t_enc, series.t_enc[0] + 20.0))
        phi_L = series.phi_L.copy()
        phi_L[k:] -= 65536 * 2 * np.pi / 4096  # an unsigned 16-bit counter wraps
        series = TimeSeries(series.t_enc, phi_L, series.phi_R, series.t_pose, series.x,
                            series.y, series.theta)
    else:
        k = int(np.searchsorted(series.t_pose, series.t_pose[0] + 20.0))
        x = series.x.copy()
        x[k:] += 0.5
        series = TimeSeries(series.t_enc, series.phi_L, series.phi_R, series.t_pose, x,
                            series.y, series.theta)
    files = write_log(tmp_path, "log", series)
    code, _, err = run_cli(capsys, "validate", *files, "--params", params_file, "--nominal",
                           "0.05,0.05,0.3")
    assert_one_line_error(code, err, fragment.format(line=k + 2))


def test_a_log_against_the_models_conventions_is_not_dead_reckoned(capsys, tmp_path,
                                                                   noisy_log, params_file):
    """A held-out log whose right wheel runs backwards (a motor mounted mirrored): both robots
    dead-reckoned it into nonsense and validate said "no better x1.01", exit 0. Now the
    wiring check calibrate makes, as a one-line error."""
    series = noisy_log.series
    mirrored = TimeSeries(series.t_enc, series.phi_L, -series.phi_R, series.t_pose, series.x,
                          series.y, series.theta)
    files = write_log(tmp_path, "log", mirrored)
    code, _, err = run_cli(capsys, "validate", *files, "--params", params_file, "--nominal",
                           "0.05,0.05,0.3")
    assert_one_line_error(code, err, "log.enc.csv+", "the right wheel's angle runs backwards")


def test_pose_samples_off_the_track_are_left_out_of_dead_reckoning(capsys, tmp_path,
                                                                   noisy_log, params_file):
    """A marker swap (two samples 0.5 m off, then back on the track) is no relocalisation:
    the samples are left out with a note and the log is validated, the line of a later real
    jump still named right."""
    series = noisy_log.series
    k = int(np.searchsorted(series.t_pose, series.t_pose[0] + 10.0))
    x = series.x.copy()
    x[k:k + 2] += 0.5
    swapped = TimeSeries(series.t_enc, series.phi_L, series.phi_R, series.t_pose, x,
                         series.y, series.theta)
    files = write_log(tmp_path, "log", swapped)
    code, out, err = run_cli(capsys, "validate", *files, "--params", params_file, "--nominal",
                             "0.05,0.05,0.3")
    assert code in (0, 7), err
    assert "2 pose sample(s) off the track" in err and "verdict" in out
    j = int(np.searchsorted(series.t_pose, series.t_pose[0] + 20.0))
    x[j:] += 0.5  # and a relocalisation later on
    files = write_log(tmp_path, "log2", TimeSeries(series.t_enc, series.phi_L, series.phi_R,
                                                   series.t_pose, x, series.y, series.theta))
    code, _, err = run_cli(capsys, "validate", *files, "--params", params_file, "--nominal",
                           "0.05,0.05,0.3")
    assert code == 2 and f"log2.pose.csv:{j + 2}: the pose jumps" in err


def test_a_counter_that_overflows_is_unwrapped_and_said_so(capsys, tmp_path, params_file):
    """validate follows a 16-bit tick counter through its overflows (as calibrate does) and says
    so on stderr, since it prints no segmentation report."""
    from tests.unit.logs.test_timeseries import write_16_bit_counters

    series = synthetic_log(np.random.default_rng(12), 40.0, TRUTH, SENSOR,
                           pose_noise=(0.002, 0.002), ticks_per_rev=16384).series
    path = tmp_path / "counters.csv"
    write_16_bit_counters(path, series, 16384, signed=False)
    code, out, err = run_cli(capsys, "validate", path, "--params", params_file, "--nominal",
                             "0.05,0.05,0.3", "--ticks-per-rev", "16384", "--time-offset", "0")
    assert code == 0 and "excite validation" in out
    assert err == (f"excite: note: {path}: ticks_L (16-bit counter), ticks_R (16-bit counter) "
                   "overflowed, unwrapped\n")


def test_a_log_with_an_encoder_gap_is_dead_reckoned_in_parts(capsys, tmp_path, noisy_log,
                                                             params_file):
    """Five seconds of both streams missing: across the gap the wheels' path is unknown (one
    straight arc between two encoder samples 5 s apart took the calibrated robot metres off
    and the verdict flipped to "no better"); each part is dead-reckoned from its own first
    pose, with a note naming the gap."""
    series = noisy_log.series
    keep_enc = (series.t_enc < 20.0) | (series.t_enc > 25.0)
    keep_pose = (series.t_pose < 20.0) | (series.t_pose > 25.0)
    holed = TimeSeries(series.t_enc[keep_enc], series.phi_L[keep_enc], series.phi_R[keep_enc],
                       series.t_pose[keep_pose], series.x[keep_pose], series.y[keep_pose],
                       series.theta[keep_pose])
    files = write_log(tmp_path, "holed", holed)
    code, out, err = run_cli(capsys, "validate", *files, "--params", params_file, "--nominal",
                             "0.05,0.05,0.3", "--json")
    assert code == 0
    [note] = err.splitlines()
    assert note.startswith(f"excite: note: {'+'.join(files)}: cut at 1 encoder gap(s) longer "
                           "than the window (1 s), the longest 5.0")
    assert note.endswith("each of its 2 parts is dead-reckoned from its own first pose")
    logs = json.loads(out)["logs"]
    assert [e["file"] for e in logs] == [f"{'+'.join(files)} (part {k} of 2)" for k in (1, 2)]
    for entry in logs:
        assert entry["calibrated"]["rms_path_error"] < 0.02 and entry["verdict"] == "better"
