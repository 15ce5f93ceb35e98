"""excite calibrate on CSV files as real exports write them (docs/formats.md, "CSV exports"):
the same log as a plain CSV and as a spreadsheet's export gives the same calibration, with
notes on stderr for what was not read and what was converted."""

import json
import math

import numpy as np
import pytest

from excite.core.kinematics import Params
from excite.core.models import SensorPose
from excite.logs.synthetic import synthetic_log
from excite.logs.timeseries_csv import write_timeseries
from tests.conftest import run_cli


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    series = synthetic_log(np.random.default_rng(11), 60.0, Params(0.050, 0.051, 0.300),
                           SensorPose(0.1, -0.03, 0.4), pose_noise=(0.002, 0.002)).series
    path = tmp_path_factory.mktemp("exports") / "plain.csv"
    write_timeseries(path, series)
    return path


def export(plain, path, header, factors, extras):
    """The plain log's cells times ``factors``, separated by semicolons with decimal commas,
    under ``header``, with the ``extras`` cells appended to every row."""
    _, *rows = [line.split(",") for line in plain.read_text().splitlines()]
    lines = [";".join(header)]
    for row in rows:
        cells = [repr(float(c) * f) if c and f != 1 else c for c, f in zip(row, factors,
                                                                             strict=True)]
        lines.append(";".join([*cells, *extras]).replace(".", ","))
    path.write_text("\n".join(lines) + "\n")
    return path


def notes_of(err):
    return [line for line in err.splitlines() if line.startswith("excite: note:")]


@pytest.mark.slow
def test_a_semicolon_export_with_units_and_extra_columns_calibrates_as_the_plain_csv(
        capsys, plain, tmp_path):
    """Units already in s, m, rad: the numbers are the plain file's bit for bit, and one note
    names the columns not read. In ms, mm and degrees: converted (a note says so), the same
    calibration to the conversions' rounding (well under a thousandth of a std)."""
    code, out, err = run_cli(capsys, "calibrate", plain, "--json")
    assert code == 0 and notes_of(err) == []
    reference = json.loads(out)
    header = ["time [s]", "phi_L (rad)", "phi_R (rad)", "x (m)", "y (m)", "yaw[rad]", "z",
              "qw", "battery"]
    base = export(plain, tmp_path / "export.csv", header, [1] * 6, ["0.0", "1.0", "12.6"])
    code, out, err = run_cli(capsys, "calibrate", base, "--json")
    assert code == 0
    assert notes_of(err) == [f"excite: note: {base}: columns not read: z, qw, battery"]
    report = json.loads(out)
    for key in ("params", "std", "sensor_pose", "model", "noise"):
        assert report.get(key) == reference.get(key), key

    header[:6] = ["t [ms]", "phi_L [deg]", "phi_R [deg]", "x [mm]", "y [mm]", "yaw [deg]"]
    degrees = 180 / math.pi
    scaled = export(plain, tmp_path / "scaled.csv", header,
                    [1e3, degrees, degrees, 1e3, 1e3, degrees], ["0.0", "1.0", "12.6"])
    code, out, err = run_cli(capsys, "calibrate", scaled, "--json")
    assert code == 0
    assert notes_of(err) == [
        f"excite: note: {scaled}: columns not read: z, qw, battery",
        f"excite: note: {scaled}: units converted: t from ms to s, phi_L from deg to rad, "
        "phi_R from deg to rad, x from mm to m, y from mm to m, theta from deg to rad"]
    report = json.loads(out)
    for name in ("r_L", "r_R", "b"):  # the conversions' rounding, far below the std
        std = reference["std"][name]
        assert abs(report["params"][name] - reference["params"][name]) < 1e-3 * std
        assert report["std"][name] == pytest.approx(std, rel=1e-3)


def test_a_header_of_neither_format_is_a_one_line_error_naming_both(capsys, tmp_path):
    path = tmp_path / "odd.csv"
    path.write_text("Zeit;Links;Rechts\n0;0;0\n")
    code, out, err = run_cli(capsys, "calibrate", path)
    assert code == 2 and out == "" and err.count("\n") == 1
    assert err.startswith(f"excite: error: {path}:1: the header names 'Zeit', 'Links', "
                          "'Rechts': neither a segment CSV (dphi_L,dphi_R,dx_gt,dy_gt,"
                          "dtheta_gt) nor a time-series CSV")
    path.write_text("t [s];x [ft];y;theta\n0;0;0;0\n")
    code, _, err = run_cli(capsys, "calibrate", path)
    assert code == 2 and err == (f"excite: error: {path}:1: column 'x [ft]': unit 'ft' is not "
                                 "a unit of length (m, cm, mm)\n")


def _motion_capture_export(plain, tmp_path, rotation_header):
    """The plain log as two files: the encoders, and a motion-capture export of the poses
    (Motive / Vicon style: frame, time, X, Y, Z, a rotation) with the heading as a quaternion
    about z."""
    _, *rows = [line.split(",") for line in plain.read_text().splitlines()]
    encoders = ["t,phi_L,phi_R"] + [",".join(r[:3]) for r in rows if r[1]]
    poses = [",".join(["Frame", "Time (Seconds)", "X", "Y", "Z", *rotation_header])]
    for frame, r in enumerate(row for row in rows if row[3]):
        half = 0.5 * float(r[5])
        rotation = [0.0, 0.0, math.sin(half), math.cos(half)][:len(rotation_header)]
        poses.append(",".join([str(frame), r[0], r[3], r[4], "0.0", *map(repr, rotation)]))
    (tmp_path / "enc.csv").write_text("\n".join(encoders) + "\n")
    (tmp_path / "mocap.csv").write_text("\n".join(poses) + "\n")
    return tmp_path / "enc.csv", tmp_path / "mocap.csv"


@pytest.mark.slow
def test_a_motion_capture_export_with_rx_to_rw_reads_its_quaternion(capsys, plain, tmp_path):
    """RX, RY, RZ, RW (a motion-capture export's rotation) are the quaternion when RW is
    there: the same calibration as the plain file's to the quaternion's rounding. Without RW
    they are Euler angles, not read: the error says theta is missing and names them."""
    _, out, _ = run_cli(capsys, "calibrate", plain, "--json")
    reference = json.loads(out)
    enc, mocap = _motion_capture_export(plain, tmp_path, ["RX", "RY", "RZ", "RW"])
    code, out, err = run_cli(capsys, "calibrate", enc, mocap, "--json")
    assert code == 0, err
    assert f"excite: note: {mocap}: theta is the yaw of the quaternion qx, qy, qz, qw" in err
    report = json.loads(out)
    for name, value in reference["params"].items():
        assert report["params"][name] == pytest.approx(value, abs=1e-3 * reference["std"][name])
    enc, euler = _motion_capture_export(plain, tmp_path, ["RX", "RY", "RZ"])
    code, _, err = run_cli(capsys, "calibrate", euler)
    assert code == 2 and "missing column theta" in err and "'RZ'" in err


@pytest.mark.slow
def test_positions_in_mm_without_a_unit_name_the_log_and_the_unit_to_write(capsys, plain,
                                                                           tmp_path):
    """A pose file in mm whose header has no unit: the error names the log, the time, and the
    header unit that converts it (x (mm)), not a segment CSV's column."""
    _, *rows = [line.split(",") for line in plain.read_text().splitlines()]
    lines = ["t,phi_L,phi_R,x,y,theta"]
    for r in rows:
        x, y = (repr(1000 * float(v)) if v else v for v in r[3:5])
        lines.append(",".join([*r[:3], x, y, r[5]]))
    path = tmp_path / "mm.csv"
    path.write_text("\n".join(lines) + "\n")
    code, _, err = run_cli(capsys, "calibrate", path)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"excite: error: {path}: the segment from t = ")
    assert "segments are: values in other units?" in err and "x (mm)" in err
