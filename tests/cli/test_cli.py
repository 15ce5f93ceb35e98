import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

from excite import save_segments
from excite.errors import DataError
from excite.logs.synthetic import lesson_dataset
from tests.conftest import TRUTH, assert_one_line_error, run_cli, spin_segments, straight_segments


@pytest.fixture
def good_csv(tmp_path, rng):
    path = tmp_path / "log.csv"
    save_segments(path, lesson_dataset(rng, 200, TRUTH))
    return path




def test_report_and_exit_zero(capsys, good_csv):
    code, out, err = run_cli(capsys, "calibrate", good_csv)
    assert code == 0 and err == ""
    assert out.splitlines()[2].startswith("verdict: calibrated: use these values")
    for word in ("r_L", "r_R", "b ", "sigma_min", "condition number", "identifiable    = yes",
                 "residual RMS", "outliers"):
        assert word in out


def test_json_object(capsys, good_csv):
    code, out, _ = run_cli(capsys, "calibrate", good_csv, "--json", "--sigma", "2e-3,2e-3,1e-3",
                           "--loss", "huber", "--init", "0.1,0.1,0.6")
    assert code == 0
    d = json.loads(out)
    assert set(d["params"]) == {"r_L", "r_R", "b"}
    assert d["sigma"] == {"x": 2e-3, "y": 2e-3, "theta": 1e-3}
    assert d["converged"] and d["identifiable"] and d["loss"] == "huber"
    np.testing.assert_allclose([d["params"][k] for k in ("r_L", "r_R", "b")],
                               TRUTH.as_array(), rtol=0.03)


@pytest.mark.slow
def test_ros2_yaml(capsys, good_csv, tmp_path):
    out_yaml = tmp_path / "ddc.yaml"
    code, out, _ = run_cli(capsys, "calibrate", good_csv, "--init", "0.05,0.05,0.3",
                           "--ros2-yaml", out_yaml)
    assert code == 0 and str(out_yaml) in out
    text = out_yaml.read_text().splitlines()
    assert text[:2] == ["diff_drive_controller:", "  ros__parameters:"]
    values = dict(line.strip().split(": ") for line in text[2:])
    assert float(values["wheel_radius"]) == 0.05 and float(values["wheel_separation"]) == 0.3
    d = json.loads(subprocess.run([sys.executable, "-m", "excite.cli", "calibrate",
                                   str(good_csv), "--json", "--init", "0.05,0.05,0.3"],
                                  capture_output=True, text=True, check=True).stdout)
    assert float(values["left_wheel_radius_multiplier"]) == pytest.approx(
        d["params"]["r_L"] / 0.05, rel=1e-8)
    assert float(values["wheel_separation_multiplier"]) == pytest.approx(
        d["params"]["b"] / 0.3, rel=1e-8)


@pytest.mark.parametrize(
    "segments, words",
    [(straight_segments, "b: no segment turns"),
     (spin_segments, "the common scale of r_L, r_R and b: no segment translates")],
)
def test_degenerate_data_exit_3_and_name_the_direction(capsys, tmp_path, rng, segments, words):
    path = tmp_path / "d.csv"
    save_segments(path, segments(rng))
    code, out, _ = run_cli(capsys, "calibrate", path)
    assert code == 3 and words in out
    code, out, _ = run_cli(capsys, "calibrate", path, "--json")
    d = json.loads(out)
    assert code == 3 and d["identifiable"] is False and d["unidentifiable_direction"] == words


BAD_FILES = {
    "empty": ("", "no segments"),
    "header only": ("dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt\n", "no segments"),
    "text": ("1,1,0,0,0\n1,2,x,0,0\n1,1,0,0,0\n", ":2: dx_gt is not a number"),
    "nan": ("1,1,0,0,0\n1,2,0,0,0\n1,1,nan,0,0\n", ":3: dx_gt is not finite"),
    "inf": ("1,1,0,0,0\ninf,2,0,0,0\n1,1,0,0,0\n", ":2: dphi_L is not finite"),
    "columns": ("1,1,0,0,0\n1,1,0,0\n1,1,0,0,0\n", ":2: expected 5 columns, found 4"),
    "too few": ("1,1,0,0,0\n1,1,0,0,0\n", "at least 3"),
    "binary": (b"\x7fELF\x02\x01\x01\x00\x00\x00", "binary data"),
}


@pytest.mark.parametrize("name", BAD_FILES)
def test_bad_files_are_one_line_errors(capsys, tmp_path, name):
    content, fragment = BAD_FILES[name]
    path = tmp_path / "bad.csv"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    code, out, err = run_cli(capsys, "calibrate", path)
    assert_one_line_error(code, err, str(path), fragment)
    assert out == ""


@pytest.mark.parametrize(
    "extra, fragment",
    [
        (["--sigma", "1e-3,1e-3"], "--sigma needs 3"),
        (["--sigma", "1e-3,-1e-3,1e-3"], "SY must be positive"),
        (["--sigma", "a,b,c"], "SX is not a number"),
        (["--sigma", "1e-3,1e-3,nan"], "STH must be positive"),
        (["--init=-0.05,0.05,0.3"], "RL must be positive"),
        (["--init", "-0.05,0.05,0.3"], "--init: RL must be positive and finite, got '-0.05'"),
        (["--sensor-pose", "0,0.1,90"], "--sensor-pose 0,0.1,90: the angle 90 rad is beyond pi "
                                        "(degrees? 90 deg = 1.571 rad)"),
        (["--init", "0.05,0.05,0"], "B must be positive"),
        (["--init", "0.05,0.05,inf"], "B must be positive"),
        (["--loss", "cauchy"], "invalid choice: 'cauchy'"),
        (["--bogus"], "unrecognized arguments: --bogus"),
        (["--ros2-yaml", "/nonexistent/dir/x.yaml"], "cannot write /nonexistent/dir/x.yaml"),
    ],
)
def test_bad_options_are_one_line_errors(capsys, good_csv, extra, fragment):
    code, _, err = run_cli(capsys, "calibrate", good_csv, *extra)
    assert_one_line_error(code, err, fragment)


def test_usage_errors(capsys, tmp_path):
    assert_one_line_error(*run_cli(capsys)[::2], "a command is required")
    assert_one_line_error(*run_cli(capsys, "frobnicate")[::2], "invalid choice")
    assert_one_line_error(*run_cli(capsys, "calibrate")[::2], "required")
    assert_one_line_error(*run_cli(capsys, "calibrate", tmp_path / "none.csv")[::2],
                          "no such file")
    assert_one_line_error(*run_cli(capsys, "calibrate", tmp_path)[::2], "is a directory")


@pytest.mark.slow
def test_console_script_has_no_traceback_and_version(tmp_path):
    exe = [sys.executable, "-m", "excite.cli"]
    bad = tmp_path / "bad.csv"
    bad.write_text("1,2,3\n")
    proc = subprocess.run([*exe, "calibrate", str(bad)], capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1
    proc = subprocess.run([*exe, "--version"], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.startswith("excite ")


def test_import_excite_stays_light():
    code = ("import sys, excite, gymnasium; "
            "heavy = {'pymunk', 'numba', 'torch', 'stable_baselines3', 'matplotlib'} "
            "& set(sys.modules); "
            "print(sorted(heavy))")
    # gymnasium itself may be imported by the user; excite must not pull the others.
    proc = subprocess.run([sys.executable, "-c", code.replace(", gymnasium", "")],
                          capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "[]"
    proc = subprocess.run([sys.executable, "-c", "import sys, excite; "
                           "print('gymnasium' in sys.modules)"],
                          capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "False"
    # scipy.stats alone took ~2 s to import: excite imports no scipy at all (its time is in
    # benchmarks/bench_import.py).
    proc = subprocess.run([sys.executable, "-c", "import sys, excite; "
                           "print(sorted(m for m in sys.modules if m.startswith('scipy')))"],
                          capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "[]"


# -- the sensor pose, misfit exit status, several files, closed stdout -------------------------
def off_axle_csv(tmp_path, rng, name="off.csv", n=200):
    from excite import Segments
    from excite.core.models import SENSOR_POSE

    phi = rng.normal(0.0, 2.0, (2, n))
    theta = np.append(TRUTH.as_array(), [0.05, -0.03, 1.8])
    measured = SENSOR_POSE.predict(*phi, theta) + rng.normal(size=(n, 3)) * [2e-3, 2e-3, 1e-3]
    path = tmp_path / name
    save_segments(path, Segments(*phi, *measured.T))
    return path


def test_off_axle_sensor_is_estimated_by_default(capsys, tmp_path, rng):
    code, out, _ = run_cli(capsys, "calibrate", off_axle_csv(tmp_path, rng), "--json")
    d = json.loads(out)
    assert code == 0 and d["model"] == "sensor_pose" and d["fit"]["ok"]
    assert abs(d["sensor_pose"]["theta"] - 1.8) < 5 * d["sensor_pose_std"]["theta"]
    assert len(d["full_covariance"]) == 6 and d["parameters"][3:] == ["l_x", "l_y", "l_theta"]


def test_forced_axle_on_off_axle_data_is_exit_4_with_the_reason(capsys, tmp_path, rng):
    code, out, err = run_cli(capsys, "calibrate", off_axle_csv(tmp_path, rng),
                             "--sensor-pose", "axle")
    assert code == 4 and err == ""
    assert "fit             = NO" in out and "the sensor is not on the axle" in out
    assert "try --sensor-pose estimate" in out


def test_given_sensor_pose_and_static_transform_export(capsys, tmp_path, rng):
    path = off_axle_csv(tmp_path, rng)
    code, out, _ = run_cli(capsys, "calibrate", path, "--sensor-pose", "0.05,-0.03,1.8")
    assert code == 0 and "sensor theta = +1.800000 rad" in out and "(given)" in out
    out_yaml = tmp_path / "ddc.yaml"
    code, out, _ = run_cli(capsys, "calibrate", path, "--sensor-pose", "estimate",
                           "--ros2-yaml", out_yaml)
    text = out_yaml.read_text()
    assert code == 0 and "static_transform_publisher --x 0.0" in text
    assert "--frame-id base_link --child-frame-id sensor" in text
    assert "sensor transform: ros2 run tf2_ros static_transform_publisher" in out


def test_several_files_are_one_data_set(capsys, tmp_path, rng):
    a, b = off_axle_csv(tmp_path, rng, "a.csv", 100), off_axle_csv(tmp_path, rng, "b.csv", 100)
    code, out, _ = run_cli(capsys, "calibrate", a, b, "--json")
    assert code == 0 and json.loads(out)["n_segments"] == 200


@pytest.mark.parametrize("extra, fragment", [
    (["--sensor-pose", "somewhere"], "--sensor-pose must be auto, axle, estimate or X,Y,THETA"),
    (["--sensor-pose", "0,0,nan"], "--sensor-pose: X,Y,THETA must be finite"),
    (["--sensor-pose", "0,a,0"], "--sensor-pose: X,Y,THETA must be finite"),
    (["--trim", "0.7"], "must be a fraction in [0, 0.5)"),
    (["--trim", "x"], "not a number"),
])
def test_bad_sensor_options_are_one_line_errors(capsys, good_csv, extra, fragment):
    assert_one_line_error(*run_cli(capsys, "calibrate", good_csv, *extra)[::2], fragment)


def test_all_zero_log_is_a_one_line_error(capsys, tmp_path):
    path = tmp_path / "zeros.csv"
    path.write_text("0,0,0,0,0\n" * 10)
    assert_one_line_error(*run_cli(capsys, "calibrate", path)[::2], "no segment moves")


@pytest.mark.slow
def test_noise_free_log_gives_the_exact_parameters_without_warnings(tmp_path, rng):
    from tests.conftest import exact_segments

    path = tmp_path / "exact.csv"
    save_segments(path, exact_segments(rng.normal(0, 0.4, 60), rng.normal(0, 0.4, 60)))
    proc = subprocess.run([sys.executable, "-W", "error", "-m", "excite.cli", "calibrate",
                           str(path), "--json"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    params = json.loads(proc.stdout)["params"]
    np.testing.assert_allclose([params[k] for k in ("r_L", "r_R", "b")], TRUTH.as_array(),
                               rtol=1e-9)


def test_closed_stdout_is_a_normal_end(good_csv):
    """As `excite calibrate log.csv | head -3`, with the reader gone before the first write."""
    proc = subprocess.Popen([sys.executable, "-m", "excite.cli", "calibrate", str(good_csv)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # the reader leaves before excite has written anything
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0 and err == b"", err


def test_numpy_warnings_on_the_way_to_an_error_stay_off_stderr(capsys, monkeypatch, tmp_path):
    """An error is one line even when numpy warned before it (overflow in a rejected trial
    step, say); EXCITE_DEBUG=1 shows the warnings."""
    from excite.commands import calibrate as command

    def overflowing(args):
        np.exp(np.array([1000.0]))  # RuntimeWarning: overflow
        raise DataError("bad.csv:3: a bad row")

    monkeypatch.setattr(command, "run", overflowing)
    monkeypatch.delenv("EXCITE_DEBUG", raising=False)
    with warnings.catch_warnings(record=True) as shown:
        warnings.simplefilter("always")
        code, _, err = run_cli(capsys, "calibrate", tmp_path / "bad.csv")
    assert_one_line_error(code, err, "bad.csv:3")
    assert not [w for w in shown if issubclass(w.category, RuntimeWarning)]
    monkeypatch.setenv("EXCITE_DEBUG", "1")
    with pytest.warns(RuntimeWarning, match="overflow"):
        run_cli(capsys, "calibrate", tmp_path / "bad.csv")


def test_utf16_files_are_named(capsys, tmp_path):
    """A CSV saved by Windows PowerShell (UTF-16 with a byte-order mark): one line saying so,
    from calibrate and from segment (which called it 'a segment file')."""
    path = tmp_path / "log.csv"
    path.write_text("t,phi_L,phi_R,x,y,theta\n0,0,0,0,0,0\n", encoding="utf-16")
    message = f"{path}: UTF-16 text (as Windows PowerShell writes it); save it as UTF-8"
    assert_one_line_error(*run_cli(capsys, "calibrate", path)[::2], message)
    assert_one_line_error(*run_cli(capsys, "segment", path, "--out", tmp_path / "s.csv")[::2],
                          message)


@pytest.mark.parametrize("argv, name, value", [
    (["calibrate", "x.csv", "--sensor-pose", "-0.05,0.01,0"], "sensor_pose", "-0.05,0.01,0"),
    (["calibrate", "x.csv", "--time-offset", "-1e-3"], "time_offset", "-0.001"),
    (["live", "--left-wheel", "l", "--right-wheel", "r", "--pose-topic", "/p", "--area",
      "-2,-2.5,2,2.5"], "area", "-2,-2.5,2,2.5"),
])
def test_values_of_numbers_with_a_leading_minus_are_values(argv, name, value):
    """A sensor behind the axle, an area around the origin: a value that starts with a minus
    sign is read as the option's value (argparse took it for an unknown option)."""
    from excite.cli import build_parser

    assert str(getattr(build_parser().parse_args(argv), name)) == value
