"""Outputs a user asks for that cannot be written, or would destroy an input, and inputs that
hold values no robot has: one-line errors (exit status 2), checked before anything is
written, never a traceback (exit status 1) or a half-written result."""

import json

import numpy as np
import pytest

from excite import Params, save_segments
from excite.core.models import SensorPose
from excite.logs.synthetic import lesson_dataset, synthetic_log
from excite.logs.timeseries_csv import write_timeseries
from tests.cli.test_validate import write_params
from tests.conftest import assert_one_line_error, run_cli

TRUTH = Params(0.05, 0.051, 0.3)


@pytest.fixture
def log_csv(tmp_path):
    path = tmp_path / "run.csv"
    write_timeseries(path, synthetic_log(np.random.default_rng(3), 40.0, TRUTH,
                                         pose_noise=(1e-3, 1e-3)).series)
    return path


def test_segment_never_overwrites_its_input(capsys, log_csv):
    before = log_csv.read_bytes()
    code, out, err = run_cli(capsys, "segment", log_csv, "--out", log_csv)
    assert out == ""
    assert_one_line_error(code, err, f"--out {log_csv} is the input {log_csv}: writing it "
                          "would overwrite the input")
    assert log_csv.read_bytes() == before


def test_calibrate_never_writes_its_controller_file_over_an_input(capsys, tmp_path, rng):
    path = tmp_path / "seg.csv"
    save_segments(path, lesson_dataset(rng, 60))
    before = path.read_bytes()
    code, _, err = run_cli(capsys, "calibrate", path, "--ros2-yaml", tmp_path / "." / "seg.csv")
    assert_one_line_error(code, err, "--ros2-yaml", "is the input")
    assert path.read_bytes() == before


@pytest.mark.parametrize("where, words", [("folder", "it is a folder; give a file name"),
                                           ("missing", "no such directory")])
def test_calibrate_checks_its_controller_file_before_calibrating(capsys, tmp_path, rng, where,
                                                                 words):
    """A --ros2-yaml that is a folder or in no folder: refused before the calibration (it
    printed the whole report, then the error)."""
    path = tmp_path / "seg.csv"
    save_segments(path, lesson_dataset(rng, 60))
    out = tmp_path if where == "folder" else tmp_path / "none" / "ddc.yaml"
    code, stdout, err = run_cli(capsys, "calibrate", path, "--ros2-yaml", out)
    assert stdout == ""
    assert_one_line_error(code, err, f"cannot write {out}: {words}")


def test_simulate_checks_the_truth_file_before_writing_the_log(capsys, tmp_path):
    (tmp_path / "run.truth.json").mkdir()
    code, _, err = run_cli(capsys, "simulate", "--protocol", "arcs", "--segments", "3",
                           "--out", tmp_path / "run.csv")
    assert_one_line_error(code, err, "run.truth.json: it is a folder")
    assert not (tmp_path / "run.csv").exists()


@pytest.mark.parametrize("out", ["/proc/excite-test.csv", "a" * 300 + ".csv"])
def test_a_path_the_system_refuses_is_a_one_line_error(capsys, tmp_path, monkeypatch, out):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "simulate", "--protocol", "arcs", "--segments", "3",
                           "--out", out)
    assert_one_line_error(code, err, out)


def test_validate_checks_the_values_of_its_params_file(capsys, tmp_path, log_csv):
    params = write_params(tmp_path / "cm.json", TRUTH, None,
                          nominal={"r_L": 5, "r_R": 5, "b": 30})
    code, _, err = run_cli(capsys, "validate", log_csv, "--params", params)
    assert_one_line_error(code, err, 'cm.json: "nominal" 5,5,30: a wheel radius of 5 m is '
                          "implausible (centimetres given as metres?")
    far = write_params(tmp_path / "far.json", TRUTH, SensorPose(1e300, 0.0, 0.0),
                       nominal={"r_L": 0.05, "r_R": 0.05, "b": 0.3})
    code, _, err = run_cli(capsys, "validate", log_csv, "--params", far)
    assert_one_line_error(code, err, 'far.json: "sensor_pose": a sensor 1e+300 m from the '
                          "axle midpoint (at most 20 m) is implausible")
    good = write_params(tmp_path / "good.svg", TRUTH, None,  # a name --plot could write
                        nominal={"r_L": 0.05, "r_R": 0.05, "b": 0.3})
    code, _, err = run_cli(capsys, "validate", log_csv, "--params", good, "--plot", good)
    assert_one_line_error(code, err, "--plot", "is the input")
    json.loads(good.read_text())  # untouched


def test_an_implausible_sensor_mounting_option_is_a_one_line_error(capsys, tmp_path, rng):
    path = tmp_path / "seg.csv"
    save_segments(path, lesson_dataset(rng, 60))
    code, _, err = run_cli(capsys, "calibrate", path, "--sensor-pose", "100,0,0")
    assert_one_line_error(code, err, "--sensor-pose 100,0,0: a sensor 100 m from the axle "
                          "midpoint (at most 20 m) is implausible")


@pytest.mark.parametrize("command", [["train"], ["sweep", "sweep.yaml"]])
def test_an_empty_run_folder_is_a_one_line_error(capsys, command):
    """Path('') is the working folder: a sweep wrote its whole folder there (found by
    fuzzing); compare already refused an empty --out."""
    code, _, err = run_cli(capsys, *command, "--out", "")
    assert_one_line_error(code, err, "--out is empty; give a folder")


def test_protocols_with_settings_names_the_syntax(capsys):
    code, _, err = run_cli(capsys, "protocols", "arcs:speed=0.2")
    assert_one_line_error(code, err, "arcs:speed=0.2: excite protocols takes a name (arcs)")


@pytest.mark.parametrize("name", ["run.tuple", "run.bag", "run.mcap"])
def test_simulate_refuses_a_name_of_another_format(capsys, tmp_path, name):
    """A segment CSV written as run.tuple was read back as a tuple file (found by fuzzing)."""
    code, _, err = run_cli(capsys, "simulate", "--protocol", "arcs", "--segments", "3",
                           "--out", tmp_path / name)
    assert_one_line_error(code, err, "writes a CSV; a ", "name it .csv")
    assert not any(tmp_path.iterdir())
