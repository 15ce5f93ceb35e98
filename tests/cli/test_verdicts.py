"""Results a user can act on safely: no controller file from a failed calibration unless
forced (and then marked unsafe), implausible nominal values refused with the likely unit, a
calibrate report that leads with what to do, and validate's verdict with its exit status."""

import json
import math

import numpy as np
import pytest

from excite import save_segments
from excite.commands.args import plausible_params
from excite.commands.exit_status import EXIT_WORSE
from excite.errors import ExciteError
from excite.logs.synthetic import lesson_dataset, synthetic_log
from excite.validation.verdict import MARGIN, judge, tally
from tests.cli.test_cli import off_axle_csv
from tests.cli.test_validate import NOMINAL, SENSOR, TRUTH, write_log, write_params
from tests.conftest import TRUTH as LESSON_TRUTH
from tests.conftest import assert_one_line_error, run_cli, straight_segments

INIT = ["--init", "0.05,0.05,0.3"]


def misfit_args(tmp_path, rng):
    """A calibration that ends with exit status 4: the axle model forced on off-axle data."""
    return [off_axle_csv(tmp_path, rng), "--sensor-pose", "axle"]


def undetermined_args(tmp_path, rng):
    """A calibration that ends with exit status 3: no segment turns."""
    path = tmp_path / "straight.csv"
    save_segments(path, straight_segments(rng))
    return [path]


def too_few_args(tmp_path, rng):
    """A calibration that ends with exit status 3: three segments, the noise levels
    estimated (with the parameters, they would fit the data exactly)."""
    path = tmp_path / "three.csv"
    save_segments(path, lesson_dataset(rng, 3, dphi_std=2.0))
    return [path]


# --------------------------------------------------------------------------- --ros2-yaml


@pytest.mark.parametrize("make, status, why", [
    (misfit_args, 4, "the model does not fit the data"),
    (undetermined_args, 3, "the data do not determine every parameter: b: no segment turns"),
    (too_few_args, 3, "the data do not determine every parameter: 3 segments cannot "
     "determine 3 parameters and the noise levels"),
])
@pytest.mark.parametrize("json_out", [False, True])
def test_no_controller_file_from_a_failed_calibration(capsys, tmp_path, rng, make, status,
                                                      why, json_out):
    out_yaml = tmp_path / "ddc.yaml"
    extra = ["--json"] if json_out else []
    code, out, err = run_cli(capsys, "calibrate", *make(tmp_path, rng), *INIT, *extra,
                             "--ros2-yaml", out_yaml)
    assert code == status and not out_yaml.exists()
    [note] = err.splitlines()
    assert note.startswith(f"excite: note: {out_yaml} not written (exit status {status}): "
                           f"{why}") and note.endswith("--force-yaml writes it anyway, "
                                                       "marked unsafe")
    if json_out:
        assert json.loads(out)["identifiable"] == (status != 3)
    else:
        assert "wrote ROS 2" not in out


@pytest.mark.parametrize("make, status, why", [
    (misfit_args, 4, "the model does not fit the data: "),
    (undetermined_args, 3, "the data do not determine every parameter: "),
])
def test_a_forced_controller_file_says_it_is_unsafe_and_why(capsys, tmp_path, rng, make,
                                                            status, why):
    out_yaml = tmp_path / "ddc.yaml"
    code, out, err = run_cli(capsys, "calibrate", *make(tmp_path, rng), *INIT, "--ros2-yaml",
                             out_yaml, "--force-yaml")
    assert code == status and err == ""
    assert f"wrote ROS 2 diff_drive_controller parameters to {out_yaml}, marked unsafe" in out
    lines = out_yaml.read_text().splitlines()
    assert lines[0].startswith("# UNSAFE: do not load these parameters into a controller")
    assert lines[1].startswith(f"# Why: {why}")
    assert f"(exit status {status}; written only because of --force-yaml)" in lines[1]
    body = [line for line in lines if not line.startswith("#")]
    assert body[:2] == ["diff_drive_controller:", "  ros__parameters:"]


def test_a_successful_calibration_writes_an_unmarked_file_with_the_report_s_multipliers(
        capsys, tmp_path, rng):
    path = tmp_path / "log.csv"
    save_segments(path, lesson_dataset(rng, 200, LESSON_TRUTH))
    out_yaml = tmp_path / "ddc.yaml"
    code, out, err = run_cli(capsys, "calibrate", path, *INIT, "--ros2-yaml", out_yaml,
                             "--force-yaml")
    assert code == 0 and err == "" and "marked unsafe" not in out
    text = out_yaml.read_text()
    assert not text.startswith("#")
    lines = out.splitlines()
    assert lines[2] == "verdict: calibrated: set these diff_drive_controller multipliers"
    [multipliers] = [line for line in lines if line.startswith("  multipliers")]
    for key in ("left_wheel_radius_multiplier", "right_wheel_radius_multiplier",
                "wheel_separation_multiplier"):
        in_file = float(text.split(f"{key}: ")[1].split()[0])
        in_report = float(multipliers.split(f"{key} ")[1].split()[0].rstrip(","))
        assert in_report == pytest.approx(in_file, rel=1e-5)


def test_force_yaml_needs_ros2_yaml(capsys, tmp_path, rng):
    code, _, err = run_cli(capsys, "calibrate", *undetermined_args(tmp_path, rng),
                           "--force-yaml")
    assert_one_line_error(code, err, "--force-yaml needs --ros2-yaml")


# --------------------------------------------------------------------------- nominal values


@pytest.mark.parametrize("values, fragment", [
    ("5,5,30", "a wheel radius of 5 m is implausible (centimetres given as metres? "
               "5 cm = 0.05)"),
    ("165,165,555", "a wheel radius of 165 m is implausible (millimetres given as metres? "
                    "165 mm = 0.165)"),
    ("65,65,300", "(centimetres or millimetres given as metres? 65 cm = 0.65, "
                  "65 mm = 0.065)"),
    ("2500,2500,10", "a wheel radius of 2500 m is implausible (wheel radii are 5 mm to 2 m)"),
    ("0.0005,0.0005,0.003", "a wheel radius of 0.0005 m is implausible (wheel radii are "
                            "5 mm to 2 m; RL,RR,B are in metres)"),
    ("0.05,0.004,0.3", "a wheel radius of 0.004 m is implausible"),
    ("0.05,0.5,0.3", "wheel radii of 0.05 m and 0.5 m are implausible (they differ by a "
                     "factor 10;"),
    ("0.05,0.05,30", "a wheel separation of 30 m is implausible (centimetres given as "
                     "metres? 30 cm = 0.3)"),
    ("0.05,0.05,0.04", "a wheel separation of 0.04 m, no longer than the wheel radius "
                       "0.05 m, is implausible"),
    ("0.3,0.3,0.3", "a wheel separation of 0.3 m, no longer than the wheel radius 0.3 m"),
])
def test_implausible_nominal_values_are_one_line_errors_with_the_likely_unit(
        capsys, tmp_path, values, fragment):
    code, out, err = run_cli(capsys, "calibrate", tmp_path / "never_read.csv", "--init",
                             values)
    assert out == ""
    assert_one_line_error(code, err, f"--init {values}: ", fragment)
    params = write_params(tmp_path / "result.json", TRUTH)
    code, _, err = run_cli(capsys, "validate", tmp_path / "never_read.csv", "--params",
                           params, "--nominal", values)
    assert_one_line_error(code, err, f"--nominal {values}: ", fragment)


@pytest.mark.parametrize("values", [
    (0.0205, 0.0205, 0.053),   # e-puck
    (0.033, 0.033, 0.16),      # TurtleBot3 Burger
    (0.1651, 0.1651, 0.555),   # Husky
    (0.005, 0.005, 0.0051),    # at the lower bounds
    (2.0, 1.0, 20.0),          # at the upper bounds
])
def test_real_robots_and_the_bounds_themselves_are_plausible(values):
    plausible_params(values, "", "--init")


@pytest.mark.parametrize("values", [(0.0049, 0.005, 0.3), (2.01, 2.0, 5.0),
                                    (0.05, 0.1001, 0.3), (0.05, 0.05, 20.01)])
def test_just_outside_the_bounds_is_implausible(values):
    with pytest.raises(ExciteError, match="implausible"):
        plausible_params(values, "", "--init")


@pytest.mark.parametrize("scale, fragments", [
    ((1.0, 1.0, 100.0, 100.0, 1.0), ("the calibration gives a wheel radius of",
                                     "which no real robot has: positions in centimetres read "
                                     "as metres? (a robot with r_L 0.05")),
    ((180 / math.pi, 180 / math.pi, 1.0, 1.0, 1.0), (
        "which no real robot has: wheel angles in degrees read as radians? (a robot with "
        "r_L 0.05",)),
    # beyond any robot row by row: refused as the file is read
    ((1.0, 1.0, 1000.0, 1000.0, 1.0), (":2: the sensor moved ", "rows are: values in other "
                                       "units? (excite reads m and rad")),
])
def test_a_log_in_other_units_is_a_one_line_error_naming_them(capsys, tmp_path, scale,
                                                               fragments):
    """Positions in mm or cm, or wheel angles in degrees, calibrate to wheel parameters no
    real robot has: refused, never 'use these values' (nor a controller file)."""
    seg = lesson_dataset(np.random.default_rng(4), 100, sigma=(1e-3, 1e-3, 1e-3))
    path = tmp_path / "units.csv"
    save_segments(path, type(seg)(*(seg.as_array() * np.array(scale)).T))
    code, out, err = run_cli(capsys, "calibrate", path, "--ros2-yaml", tmp_path / "c.yaml")
    assert out == "" and not (tmp_path / "c.yaml").exists()
    assert_one_line_error(code, err, str(path), *fragments)


@pytest.mark.parametrize("scale, fragment", [
    (30 / math.pi, "0.105 and 0.107 times the nominal 0.05 m and 0.05 m (no calibration "
                   "moves a radius so far): wheel speeds in rpm read as rad/s? check the "
                   "wheel columns and --init"),
    (4.0, ": motor angles before a gearbox read as wheel angles (a gear ratio of about "
          "3.94)? check the wheel columns and --init"),
])
def test_wheel_radii_far_from_the_nominal_ones_are_a_one_line_error_naming_the_cause(
        capsys, tmp_path, scale, fragment):
    """Wheel angles in other units than rad (or a motor's, before its gearbox) calibrate to
    radii no calibration moves so far from the nominal ones (--init): refused with the likely
    cause, never 'set these multipliers' (nor a controller file); within the factor they
    are a calibration."""
    seg = lesson_dataset(np.random.default_rng(4), 100, sigma=(1e-3, 1e-3, 1e-3))
    path = tmp_path / "wheels.csv"
    save_segments(path, type(seg)(*(seg.as_array() * np.array([scale, scale, 1, 1, 1])).T))
    code, out, err = run_cli(capsys, "calibrate", path, "--init", "0.05,0.05,0.3",
                             "--ros2-yaml", tmp_path / "c.yaml")
    assert out == "" and not (tmp_path / "c.yaml").exists()
    assert_one_line_error(code, err, f"{path}: the calibration gives ", fragment)
    save_segments(path, type(seg)(*(seg.as_array() * np.array([2.2, 2.2, 1, 1, 1])).T))
    code, out, err = run_cli(capsys, "calibrate", path, "--init", "0.05,0.05,0.3")
    assert code == 0 and "set these diff_drive_controller multipliers" in out, err


def test_radii_of_one_metre_name_wheel_travel_in_metres(capsys, tmp_path):
    """Wheel travel in m (or surface speeds in m/s) read as rad calibrates to radii of 1 m
    whatever the robot: with --init, the one-line error names it; without, a note; a radius
    within the factor is no error."""
    from excite import Params
    from excite.core.plausible import NOMINAL_FACTOR, far_from_nominal
    from excite.logs.timeseries import TimeSeries
    from excite.logs.timeseries_csv import write_timeseries

    s = synthetic_log(np.random.default_rng(3), 60.0, Params(0.3, 0.302, 1.2),
                      pose_noise=(1e-3, 1e-3)).series
    path = tmp_path / "metres.csv"
    write_timeseries(path, TimeSeries(s.t_enc, s.phi_L * 0.3, s.phi_R * 0.302, s.t_pose, s.x,
                                      s.y, s.theta))
    code, out, err = run_cli(capsys, "calibrate", path, "--init", "0.3,0.3,1.2")
    assert_one_line_error(code, err, "wheel radii of 1 m and 1 m, 3.33 and 3.33 times the "
                          "nominal 0.3 m and 0.3 m", "wheel travel in metres (or surface "
                          "speeds in m/s) read as radians (rad/s), which gives radii of 1 m? "
                          "check the wheel columns and --init")
    code, out, err = run_cli(capsys, "calibrate", path)
    assert code == 0
    assert (f"excite: note: {path}: both wheel radii come out 1 m (1 and 1 m), what wheel "
            "travel in metres (or surface speeds in m/s) read as radians (rad/s), which gives "
            "radii of 1 m: if the wheel columns hold those, these radii scale them (give the "
            "robot's nominal values, --init, to check)") in err
    assert far_from_nominal((1.0004, 0.9991), (0.3, 0.3)) == (
        "wheel radii of 1 m and 0.9991 m, 3.33 and 3.33 times the nominal 0.3 m and 0.3 m "
        "(no calibration moves a radius so far): wheel travel in metres (or surface speeds "
        "in m/s) read as radians (rad/s), which gives radii of 1 m? check the wheel columns "
        "and --init")
    assert far_from_nominal((0.3 * NOMINAL_FACTOR, 0.3 / NOMINAL_FACTOR), (0.3, 0.3)) is None
    assert "3 times slower than the wheels" in far_from_nominal((0.9, 0.9), (0.3, 0.3))


@pytest.mark.parametrize("row, fragment", [
    ((6.0, 5.7, 0.27, -0.1, -9999.0), ":5: dtheta_gt -9999 rad, more than any robot turns on "
                                      "wheel increments of 6 and 5.7 rad (at most 24.3 rad): "
                                      "a corrupt row or a missing-value sentinel?"),
    ((6.0, 5.7, 1e300, -0.1, 0.2), ":5: the sensor moved 1e+300 m"),
    ((1e200, 5.7, 0.27, -0.1, 0.2), ":5: dphi_L 1e+200 rad, more than any segment turns a "
                                    "wheel (1e+06 rad)"),
])
def test_a_row_no_robot_drives_is_a_one_line_error_naming_its_line(capsys, tmp_path, rng,
                                                                   row, fragment):
    """One corrupt row decides a least-squares fit before any test of gross errors sees it
    (it crashed the solver, or came back 'not determined' or 'use these values' with a std of
    1e20 %): refused as the file is read, naming its line; the library's calibrate() says the
    same of the segment."""
    from excite import calibrate

    rows = lesson_dataset(rng, 40).as_array()
    rows[3] = row
    path = tmp_path / "corrupt.csv"
    save_segments(path, type(lesson_dataset(rng, 3))(*rows.T))
    code, out, err = run_cli(capsys, "calibrate", path)
    assert out == ""
    assert_one_line_error(code, err, f"{path}{fragment}")
    with pytest.raises(ExciteError, match="^segment 3: "):
        calibrate(rows)


# --------------------------------------------------------------------------- validate


def test_the_verdict_rule_and_its_margin():
    assert judge(1.0, 1.0 / MARGIN) == "better" and judge(1.0, 0.5) == "better"
    assert judge(1.0, 0.95) == judge(1.0, 1.0) == judge(1.0, 1.05) == "no better"
    assert judge(1.0, MARGIN) == "worse" and judge(1.0, 2.6) == "worse"
    assert judge(0.0, 0.0) == "no better" and judge(0.0, 1e-3) == "worse"
    assert tally(["worse", "better", "better"]) == "better on 2, worse on 1 of 3 logs"
    assert tally(["no better"]) == "no better on 1 of 1 log"


@pytest.fixture(scope="module")
def held_out(tmp_path_factory):
    """Two held-out logs of the robot TRUTH (5% off NOMINAL)."""
    folder = tmp_path_factory.mktemp("held_out")
    rng = np.random.default_rng(7)
    return [path for name in ("a", "b") for path in write_log(
        folder, name, synthetic_log(rng, 30.0, TRUTH, SENSOR, pose_noise=(0.002, 0.001),
                                    step=0.002).series)]


def nominal_option(params) -> list[str]:
    return ["--nominal", ",".join(f"{v:.9g}" for v in params.as_array())]


@pytest.mark.parametrize("calibrated, nominal, verdict, status", [
    (TRUTH, NOMINAL, "better", 0),
    (TRUTH, TRUTH, "no better", 0),
    (NOMINAL, TRUTH, "worse", EXIT_WORSE),
])
def test_validate_ends_with_a_verdict_and_its_exit_status(capsys, tmp_path, held_out,
                                                          calibrated, nominal, verdict,
                                                          status):
    params = write_params(tmp_path / "result.json", calibrated)
    code, out, err = run_cli(capsys, "validate", *held_out, "--params", params,
                             *nominal_option(nominal))
    assert code == status and err == ""
    last = out.splitlines()[-1]
    assert last.startswith(f"verdict: the calibrated robot dead-reckons {verdict} than the "
                           f"nominal one (RMS path error x")
    assert f"; {verdict} on 2 of 2 logs)" in last
    assert out.count(f"  verdict     {verdict} than nominal (RMS path error x") == 2
    code, out, _ = run_cli(capsys, "validate", *held_out, "--params", params,
                           *nominal_option(nominal), "--json")
    d = json.loads(out)
    assert code == status and d["overall"]["verdict"] == verdict
    assert [log["verdict"] for log in d["logs"]] == [verdict, verdict]


def test_validate_help_documents_the_verdict_and_its_exit_status(capsys):
    with pytest.raises(SystemExit):
        run_cli(capsys, "validate", "--help")
    text = " ".join(capsys.readouterr().out.split())
    assert f"at least {MARGIN:g} worse" in text and f"{EXIT_WORSE} when it is worse" in text


# --------------------------------------------------------------------------- --target


def test_calibrate_says_whether_the_target_is_reached_and_how_much_more_driving(capsys,
                                                                                 tmp_path):
    """--target: the stopping rule's decision on the calibration of a recorded log, done or
    not yet with the segments and seconds still needed, in the report and the JSON; the
    exit status is the calibration's."""
    log = write_log(tmp_path, "log", synthetic_log(np.random.default_rng(3), 60.0, TRUTH,
                                                   SENSOR, pose_noise=(2e-3, 2e-3)).series)
    code, out, _ = run_cli(capsys, "calibrate", *log, "--target", "0.01")
    assert code == 0
    assert out.splitlines()[-1].startswith("target 0.01 at 95%: done: every parameter within "
                                           "its tolerance at 95%")
    code, out, _ = run_cli(capsys, "calibrate", *log, "--target", "0.0001", "--json",
                           "--target-confidence", "0.9")
    target = json.loads(out)["target"]
    decision = target["decision"]
    assert code == 0 and target["value"] == 0.0001 and target["confidence"] == 0.9
    assert not decision["done"] and decision["statistic"] > 1
    n = decision["n_segments"]
    assert decision["segments_to_go"] == math.ceil(n * decision["statistic"] ** 2) - n
    assert decision["seconds_to_go"] == pytest.approx(decision["segments_to_go"], rel=0.2)
    code, out, _ = run_cli(capsys, "calibrate", *log, "--target", "0.0001",
                           "--target-confidence", "0.9")
    assert out.splitlines()[-1] == (
        f"target 0.0001 at 90%: not yet: {decision['reason']}; about "
        f"{decision['segments_to_go']:.0f} more segments (about "
        f"{decision['seconds_to_go']:.0f} s) of driving like this would get there")


@pytest.mark.parametrize("args, message", [
    (["--target", "2"], "argument --target: must be a relative error strictly between 0 and "
     "1, got '2'"),
    (["--target", "x"], "argument --target: not a number: 'x'"),
    (["--target-confidence", "0.9"], "--target-confidence needs --target"),
    (["--target", "0.01", "--target-confidence", "1"], "argument --target-confidence: must "
     "be a confidence strictly between 0 and 1, got '1'"),
])
def test_bad_targets_of_calibrate_are_one_line_errors(capsys, tmp_path, rng, args, message):
    path = tmp_path / "s.csv"
    save_segments(path, lesson_dataset(rng, 30))
    assert_one_line_error(*run_cli(capsys, "calibrate", path, *args)[::2], message)
