"""CSV files as real exports write them (docs/formats.md, "CSV exports"): semicolons and tabs,
decimal commas, units and other names in the header, columns excite does not read, for
time-series CSVs and segment CSVs alike. Each export is written from the same numbers as a
plain CSV, and must read back as those numbers (bit for bit when no unit is converted, to
rounding when one is), with the notes the user is told; anything ambiguous is a one-line
error naming the file, line and column."""

import math

import numpy as np
import pytest

from excite import DataError, load_segments
from excite.core.kinematics import Params
from excite.core.models import SensorPose
from excite.logs.inputs import LogOptions, group_inputs, segment_inputs
from excite.logs.segments import load_segment_files
from excite.logs.synthetic import synthetic_log
from excite.logs.timeseries_csv import read_timeseries, write_timeseries
from excite.logs.timeseries_header import header_hint, timeseries_streams

STREAMS = ("t_enc", "phi_L", "phi_R", "t_pose", "x", "y", "theta")


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """A plain time-series CSV t,phi_L,phi_R,x,y,theta (10 s, encoders at 100 Hz, poses at
    50 Hz: rows with empty pose cells) and its cells: (path, header, rows)."""
    series = synthetic_log(np.random.default_rng(7), 10.0, Params(0.05, 0.051, 0.3),
                           SensorPose(0.1, 0.02, 0.3), pose_noise=(0.002, 0.002)).series
    path = tmp_path_factory.mktemp("plain") / "plain.csv"
    write_timeseries(path, series)
    header, *rows = [line.split(",") for line in path.read_text().splitlines()]
    assert header == ["t", "phi_L", "phi_R", "x", "y", "theta"]
    assert any(row[3] == "" for row in rows) and all(row[0] for row in rows)
    return path, header, rows


def export(path, header, rows, sep=",", decimal_comma=False):
    """Write a table: fields joined by ``sep``, a decimal comma for a point when asked."""
    def line(cells):
        return sep.join(c.replace(".", ",") if decimal_comma else c for c in cells)
    path.write_text("\n".join([sep.join(header)] + [line(row) for row in rows]) + "\n")
    return path


def read(path, **kwargs):
    notes = []
    series = read_timeseries(path, on_note=notes.append, **kwargs)
    return series, notes


def assert_same(series, reference, rtol=0.0):
    for name in STREAMS:
        a, b = getattr(series, name), getattr(reference, name)
        if rtol:
            np.testing.assert_allclose(a, b, rtol=rtol, atol=1e-12, err_msg=name)
        else:
            np.testing.assert_array_equal(a, b, err_msg=name)


@pytest.mark.parametrize("sep, decimal_comma", [
    (";", False), (";", True), ("\t", False), ("\t", True), (", ", False), (",\t", False),
    (" ; ", True),
])
def test_separators_and_decimal_commas_read_the_same_numbers(tmp_path, plain, sep,
                                                             decimal_comma):
    path, header, rows = plain
    reference = read_timeseries(path)
    series, notes = read(export(tmp_path / "log.csv", header, rows, sep, decimal_comma))
    assert_same(series, reference)
    assert notes == []


@pytest.mark.parametrize("sep", [";", "\t", ","])
def test_a_spreadsheets_separator_line_is_skipped(tmp_path, plain, sep):
    path, header, rows = plain
    out = export(tmp_path / "log.csv", header, rows, sep, decimal_comma=sep != ",")
    out.write_text(f"sep={sep}\n" + out.read_text())
    assert timeseries_streams(out) == {"encoder", "pose"}
    assert_same(read_timeseries(out), read_timeseries(path))
    segments = export(tmp_path / "s.csv", SEGMENT_HEADER, SEGMENT_ROWS, sep)
    segments.write_text(f"SEP={sep}\n" + segments.read_text())
    plain_segments = export(tmp_path / "p.csv", SEGMENT_HEADER, SEGMENT_ROWS)
    np.testing.assert_array_equal(load_segments(segments).as_array(),
                                  load_segments(plain_segments).as_array())


@pytest.mark.parametrize("header", [
    ["t [s]", "phi_L [rad]", "phi_R(rad)", "x (m)", "y [ m ]", "theta[rad]"],
    ["time", "phi_left", "phi_right", "pos_x", "pos_y", "yaw"],
    ["timestamp", "left_angle", "right_angle", "position_x", "Position Y", "heading"],
    ["Stamp", "Left-Wheel-Angle", "right_wheel_angle", "pose.x", "pose_y", "Yaw"],
    ["t_s", "angle_l", "angle_r", "x_m", "y_m", "theta_rad"],
    ['"time [s]"', '"phi_L"', '"phi_R"', '"x"', '"y"', '"yaw"'],
    ["TIME (S)", "PHI_L (RAD)", "PHI_R (RAD)", "X (M)", "Y (M)", "YAW (RAD)"],
])
def test_other_names_and_base_units_read_the_same_numbers_without_a_note(tmp_path, plain,
                                                                         header):
    path, _, rows = plain
    for sep in (",", ";"):
        series, notes = read(export(tmp_path / "log.csv", header, rows, sep))
        assert_same(series, read_timeseries(path))
        assert notes == []


def test_columns_not_read_are_named_in_a_note_and_never_parsed(tmp_path, plain):
    """z, qw, battery, a frame id holding the separator (quoted), a date: not read, even where
    they are not numbers; a separator closing every line makes an unnamed column."""
    path, header, rows = plain
    extra = ["z", "frame", "qw", "battery", "date"]
    cells = ["0.1", '"map;base"', "1.0", "12.5", "2026-11-26 10:00:00"]
    table = [header[:3] + extra[:2] + header[3:] + extra[2:]]
    table += [row[:3] + cells[:2] + row[3:] + cells[2:] for row in rows]
    path_out = tmp_path / "extra.csv"
    path_out.write_text("\n".join(";".join(r) for r in table) + "\n")
    series, notes = read(path_out)
    assert_same(series, read_timeseries(path))
    assert notes == [f"{path_out}: columns not read: z, frame, qw, battery, date"]
    trailing = export(tmp_path / "trailing.csv", header + [""], [row + [""] for row in rows],
                      "\t")
    series, notes = read(trailing)
    assert_same(series, read_timeseries(path))
    assert notes == [f"{trailing}: columns not read: (unnamed column 7)"]


def test_rows_of_the_columns_not_read_alone_are_left_out_with_a_note(tmp_path, plain):
    """A merged export of several topics: a battery sample on a row of its own (only a time
    and the battery) is left out, and a note counts them; without columns not read, a row
    with only a time is still an error naming its line."""
    path, header, rows = plain
    table = [header + ["battery"]]
    for k, row in enumerate(rows):
        table.append(row + [""])
        if k % 3 == 0:
            table.append([f"{float(row[0]) + 1e-4:.6f}"] + [""] * (len(header) - 1) + ["12.3"])
    merged = tmp_path / "merged.csv"
    merged.write_text("\n".join(",".join(r) for r in table) + "\n")
    series, notes = read(merged)
    assert_same(series, read_timeseries(path))
    skipped = len(table) - 1 - len(rows)
    assert notes == [f"{merged}: columns not read: battery",
                     f"{merged}: {skipped} rows without encoder or pose values left out (a "
                     "merged export's other columns)"]


@pytest.mark.parametrize("spelling", ["nan", "NaN"])
def test_nan_cells_are_samples_not_measured_like_empty_cells(tmp_path, plain, spelling):
    """A motion-capture body out of view, written as NaN (numpy's savetxt, some bridges):
    those pose samples are missing, as if their cells were empty; a row left with only a
    time is dropped; a note counts the rows and names their lines."""
    path, header, rows = plain
    pose_rows = [k for k, row in enumerate(rows) if row[3]]
    lost = set(pose_rows[100:140])  # about 1.6 s of poses
    with_nan = [row[:3] + [spelling] * 3 if k in lost else row for k, row in enumerate(rows)]
    without = [row[:3] + [""] * 3 if k in lost else row for k, row in enumerate(rows)]
    without = [row for row in without if any(row[1:])]
    series, notes = read(export(tmp_path / "nan.csv", header, with_nan))
    assert_same(series, read_timeseries(export(tmp_path / "empty.csv", header, without)))
    lines = sorted(k + 2 for k in lost)
    assert notes == [f"{tmp_path / 'nan.csv'}: 40 rows with NaN cells (lines {lines[0]}-"
                     f"{lines[-1]}) read as samples not measured, like empty cells (a "
                     "motion-capture body not tracked?)"]
    assert series.t_pose.size == sum(bool(row[3]) for row in rows) - 40


@pytest.mark.parametrize("names, planar, length", [
    (("qx", "qy", "qz", "qw"), False, 1.0),
    (("orientation.x", "orientation.y", "orientation.z", "orientation.w"), False, 2.5),
    (("quat_z", "quat_w"), True, 1.0),
])
def test_a_quaternion_gives_the_heading(tmp_path, plain, names, planar, length):
    """Quaternion columns instead of theta: its yaw, equal to theta to rounding whatever the
    quaternion's length, with a note; a few degrees of roll and pitch (a ramp) change
    nothing."""
    path, header, rows = plain
    out_rows = []
    for k, row in enumerate(rows):
        if not row[5]:
            out_rows.append(row[:5] + [""] * len(names))
            continue
        half = 0.5 * float(row[5])
        roll = 0.0 if planar else 0.05 * math.sin(k)  # rad, about the body x axis
        cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
        q = (sr * math.cos(half), sr * math.sin(half), cr * math.sin(half), cr * math.cos(half))
        out_rows.append(row[:5] + [repr(length * v) for v in (q[2:] if planar else q)])
    out = export(tmp_path / "quaternion.csv", header[:5] + list(names), out_rows, ";")
    series, notes = read(out)
    reference = read_timeseries(path)
    assert_same(series, reference, rtol=1e-12)
    labels = ", ".join(("qz", "qw") if planar else ("qx", "qy", "qz", "qw"))
    assert notes == [f"{out}: theta is the yaw of the quaternion {labels}"]
    assert timeseries_streams(out) == {"encoder", "pose"}


def test_theta_is_read_and_a_quaternion_beside_it_is_not(tmp_path, plain):
    path, header, rows = plain
    out = export(tmp_path / "both.csv", header + ["qz", "qw"],
                 [row + (["nonsense", "1"] if row[5] else ["", ""]) for row in rows], ";")
    series, notes = read(out)
    assert_same(series, read_timeseries(path))
    assert notes == [f"{out}: columns not read: qz, qw"]


def scaled(rows, factors):
    """The rows with each filled cell multiplied by its column's factor (written as the
    shortest text of the product)."""
    return [[repr(float(c) * f) if c else "" for c, f in zip(row, factors, strict=True)]
            for row in rows]


@pytest.mark.parametrize("header, factors, converted", [
    (["t [ms]", "phi_L", "phi_R", "x [mm]", "y (cm)", "theta [deg]"],
     [1e3, 1, 1, 1e3, 1e2, 180 / math.pi],
     "t from ms to s, x from mm to m, y from cm to m, theta from deg to rad"),
    (["time_ns", "phi_L_deg", "phi_R (degrees)", "x", "y", "yaw_deg"],
     [1e9, 180 / math.pi, 180 / math.pi, 1, 1, 180 / math.pi],
     "t from ns to s, phi_L from deg to rad, phi_R from degrees to rad, theta from deg to rad"),
    (["stamp (µs)", "phi_L", "phi_R", "x", "y", "heading (°)"],
     [1e6, 1, 1, 1, 1, 180 / math.pi], "t from µs to s, theta from ° to rad"),
])
def test_units_are_converted_to_s_m_rad_with_a_note(tmp_path, plain, header, factors,
                                                    converted):
    path, _, rows = plain
    out = export(tmp_path / "units.csv", header, scaled(rows, factors), ";", True)
    series, notes = read(out)
    assert_same(series, read_timeseries(path), rtol=1e-12)
    assert notes == [f"{out}: units converted: {converted}"]


def test_ticks_with_a_count_unit_and_a_pair_of_exported_stream_files(tmp_path, plain):
    """An encoder file (semicolons, decimal commas, ms, tick counts) and a pose file (tabs,
    mm, degrees) given together: one log, equal to the plain file's, a note for each file."""
    _, header, rows = plain
    ticks = [[row[0], str(round(float(row[1]) * 2048 / math.pi)),
              str(round(float(row[2]) * 2048 / math.pi))] for row in rows]
    reference = tmp_path / "ticks.csv"
    export(reference, ["t", "ticks_L", "ticks_R"], ticks)
    enc = export(tmp_path / "enc.csv", ["time [ms]", "left_ticks [ticks]", "right_ticks"],
                 scaled(ticks, [1e3, 1, 1]), ";", True)
    pose_rows = [[row[0], *row[3:]] for row in rows if row[3]]
    poses = export(tmp_path / "poses.csv", ["t", "x [mm]", "y [mm]", "yaw [deg]", "qw"],
                   [r + ["1"] for r in scaled(pose_rows, [1, 1e3, 1e3, 180 / math.pi])], "\t")
    export(tmp_path / "pose_ref.csv", ["t", "x", "y", "theta"], pose_rows)
    assert timeseries_streams(enc) == {"encoder"} and timeseries_streams(poses) == {"pose"}
    (log,) = group_inputs([str(poses), str(enc)])
    assert log.kind == "timeseries" and log.paths == (str(poses), str(enc))
    series, notes = read([poses, enc], ticks_per_rev=4096)
    expected = read_timeseries([reference, tmp_path / "pose_ref.csv"], ticks_per_rev=4096)
    assert_same(series, expected, rtol=1e-12)
    assert notes == [f"{poses}: columns not read: qw",
                     f"{poses}: units converted: x from mm to m, y from mm to m, "
                     "theta from deg to rad",
                     f"{enc}: units converted: t from ms to s"]


@pytest.mark.parametrize("sep", [" ", "   "])
def test_whitespace_separated_stream_files_and_a_tum_trajectory(tmp_path, plain, sep):
    """Files separated by spaces (runs of them: a printf log): each stream in a file of its
    own, since spaces cannot leave a cell empty; and the poses as a TUM trajectory (evo's
    format: timestamp tx ty tz qx qy qz qw, no header or a comment), read as the pose
    stream with a note. Each equals the plain file."""
    _, _, rows = plain
    enc_rows = [row[:3] for row in rows if row[1]]
    pose_rows = [[row[0], *row[3:]] for row in rows if row[3]]
    reference = read_timeseries([export(tmp_path / "enc_ref.csv", ["t", "phi_L", "phi_R"],
                                        enc_rows),
                                 export(tmp_path / "pose_ref.csv", ["t", "x", "y", "theta"],
                                        pose_rows)])
    enc = export(tmp_path / "enc.txt", ["t", "phi_L", "phi_R"], enc_rows, sep)
    poses = export(tmp_path / "poses.txt", ["t", "x", "y", "theta"], pose_rows, sep)
    assert timeseries_streams(enc) == {"encoder"} and timeseries_streams(poses) == {"pose"}
    assert_same(read_timeseries([enc, poses]), reference)
    with_units = export(tmp_path / "units.txt", ["t [s]", "phi_L (rad)", "phi_R [rad]"],
                        enc_rows, sep)  # a unit stays with its name
    assert_same(read_timeseries([with_units, poses]), reference)
    tum = [[t, x, y, "0.1", "0", "0", repr(math.sin(0.5 * float(theta))),
            repr(math.cos(0.5 * float(theta)))] for t, x, y, theta in pose_rows]
    for comment in ("", "# timestamp tx ty tz qx qy qz qw\n"):
        path = tmp_path / "poses.tum"
        path.write_text(comment + "\n".join(sep.join(row) for row in tum) + "\n")
        assert timeseries_streams(path) == {"pose"}
        series, notes = read([enc, path])
        assert_same(series, reference, rtol=1e-12)
        assert notes[0] == (f"{path}: read as a TUM trajectory (t x y z qx qy qz qw: s, m, "
                            "the orientation quaternion)")


def test_held_values_of_a_filled_export_are_read_as_no_sample(tmp_path, plain):
    """PlotJuggler's "fill with previous value": every row full, each stream repeating its
    last sample in the other stream's rows. Read so, a 10 Hz stream's values sat up to a
    period late (the wheel angles 'jumped'; b 1.9% off); now the repeats are no samples and
    the log equals the export with empty cells. A full-row log whose streams are sampled
    together, standing still for a while (its wheels repeat, its noisy poses do not), is read
    as it is."""
    path, header, rows = plain
    filled, last = [], [""] * len(header)
    for row in rows:
        last = [new or old for new, old in zip(row, last, strict=True)]
        filled.append(last)
    series, notes = read(export(tmp_path / "filled.csv", header, filled))
    assert_same(series, read_timeseries(path))
    assert len(notes) == 1 and "the phi_L/phi_R cells repeat the row before them" not in notes[0]
    assert notes[0].startswith(f"{tmp_path / 'filled.csv'}: the x/y/theta cells repeat the row "
                               "before them in ")
    together = [list(row) for row in rows if row[3]]
    for row in together[100:200]:  # 2 s standing still: the wheels repeat
        row[1], row[2] = together[99][1], together[99][2]
    series, notes = read(export(tmp_path / "together.csv", header, together))
    assert notes == [] and series.t_enc.size == len(together)


PLOTJUGGLER = ["__time", "/joint_states/wheel_left_joint/position",
               "/joint_states/wheel_right_joint/position", "/mocap/pose/pose/position/x",
               "/mocap/pose/pose/position/y", "/mocap/pose/pose/orientation/z",
               "/mocap/pose/pose/orientation/w", "/battery/voltage"]


def _quaternion_rows(rows):
    """The plain rows with the heading as (qz, qw) and a battery column."""
    out = []
    for t, left, right, x, y, theta in rows:
        q = ([repr(math.sin(0.5 * float(theta))), repr(math.cos(0.5 * float(theta)))]
             if theta else ["", ""])
        out.append([t, left, right, x, y, *q, "12.1"])
    return out


def test_ros_exports_are_read_by_their_column_names(tmp_path, plain):
    """PlotJuggler's CSV export (``__time``, topic paths) and ``rostopic echo -p``'s pose
    file (``field.header.stamp`` in ns, ``field.pose.position.x``): the columns read as
    the time-series columns they hold, with a note; the same log as the plain file."""
    path, _, rows = plain
    reference = read_timeseries(path)
    export_path = export(tmp_path / "pj.csv", PLOTJUGGLER, _quaternion_rows(rows))
    series, notes = read(export_path)
    assert_same(series, reference, rtol=1e-12)
    assert notes[0] == (f"{export_path}: the column names of a ROS export (PlotJuggler, "
                        "rostopic) read: __time as t, /joint_states/wheel_left_joint/position "
                        "as phi_L, /joint_states/wheel_right_joint/position as phi_R, "
                        "/mocap/pose/pose/position/x as x, /mocap/pose/pose/position/y as y, "
                        "/mocap/pose/pose/orientation/z as qz, /mocap/pose/pose/orientation/w "
                        "as qw")
    enc = export(tmp_path / "enc.csv", ["t", "phi_L", "phi_R"], [r[:3] for r in rows if r[1]])
    header = ["%time", "field.header.seq", "field.header.stamp", "field.header.frame_id",
              "field.pose.position.x", "field.pose.position.y", "field.pose.orientation.z",
              "field.pose.orientation.w"]
    poses = [[str(round(float(r[0]) * 1e9) + 1234), "0", str(round(float(r[0]) * 1e9)),
              "map", r[3], r[4], *r[5:7]] for r in _quaternion_rows(rows) if r[3]]
    rostopic = export(tmp_path / "pose.csv", header, poses)
    assert timeseries_streams(rostopic) == {"pose"}
    series, _ = read([enc, rostopic])
    assert_same(series, reference, rtol=1e-9)
    renamed = export(tmp_path / "renamed.csv", [h if h != "field.header.stamp" else "t [ns]"
                                                for h in header], poses)
    assert_same(read([enc, renamed])[0], reference, rtol=1e-9)  # %time not read beside t
    joints = tmp_path / "js.csv"
    joints.write_text("%time,field.header.stamp,field.name0,field.name1,field.position0,"
                      "field.position1\n1,1,left_wheel,right_wheel,0.0,0.0\n")
    with pytest.raises(DataError, match="a JointState of rostopic echo -p: name the wheels' "
                                        r"field.position<i> columns phi_L and phi_R"):
        group_inputs([str(joints), str(rostopic)])
    two = [*PLOTJUGGLER, "/vicon/robot/pose/position/x"]
    path_two = export(tmp_path / "two.csv", two, [r + [r[3]] for r in _quaternion_rows(rows)])
    skid = export(tmp_path / "skid.csv", ["__time", "/joint_states/front_left_wheel/position",
                                          "/joint_states/rear_left_wheel/position"], [])
    with pytest.raises(DataError, match="skid.csv:1: columns '/joint_states/front_left_wheel/"
                                        "position', '/joint_states/rear_left_wheel/position' "
                                        "are all phi_L: joints of one side"):
        read(skid)
    with pytest.raises(DataError, match="two.csv:1: columns '/mocap/pose/pose/position/x', "
                                        "'/vicon/robot/pose/position/x' are all x: an export "
                                        "of several topics of one kind; export one"):
        read(path_two)


def test_wheel_speeds_are_integrated_into_angles(tmp_path, plain):
    """Wheel speeds instead of angles (a driver's velocity state interface, a motor
    controller's rpm): read under their names and units, integrated by the trapezoidal rule
    with a note; the same log to the integral's error. A PlotJuggler export of a JointState's
    velocity is read so when no joint's position is exported, and not beside positions."""
    path, _, rows = plain
    reference = read_timeseries(path)
    enc = [r for r in rows if r[1]]
    t = np.array([float(r[0]) for r in enc])
    speeds = [np.gradient(np.array([float(r[k]) for r in enc]), t) for k in (1, 2)]
    rpm = [[r[0], repr(float(left) * 30 / math.pi), repr(float(right) * 30 / math.pi)]
           for r, left, right in zip(enc, *speeds, strict=True)]
    poses = [[r[0], *r[3:6]] for r in rows if r[3]]
    speeds_path = export(tmp_path / "speeds.csv",
                         ["time", "left_wheel_speed [rpm]", "right_wheel_speed [rpm]"], rpm)
    pose_path = export(tmp_path / "poses.csv", ["t", "x", "y", "theta"], poses)
    assert timeseries_streams(speeds_path) == {"encoder"}
    series, notes = read([speeds_path, pose_path])
    assert f"{speeds_path}: wheel speeds (rad/s) integrated into angles by the trapezoidal " \
           "rule; their errors add up over time, which the noise model's slip level takes" in notes
    for name in ("t_enc", "t_pose", "x", "y", "theta"):
        np.testing.assert_allclose(getattr(series, name), getattr(reference, name), rtol=1e-12)
    for name in ("phi_L", "phi_R"):  # angles from 0: the increments are the log's
        increments = np.diff(getattr(series, name))
        np.testing.assert_allclose(increments, np.diff(getattr(reference, name)), atol=2e-3)
    with pytest.raises(DataError, match="speeds.csv:1: ticks_per_rev given, but the encoder "
                                        "columns are omega_L, omega_R, not ticks"):
        read([speeds_path, pose_path], ticks_per_rev=1024)
    header = ["__time", "/joint_states/wheel_left_joint/velocity",
              "/joint_states/wheel_right_joint/velocity"]
    pj = export(tmp_path / "pj.csv", header, [[r[0], repr(float(a)), repr(float(b))]
                                              for r, a, b in zip(enc, *speeds, strict=True)])
    assert timeseries_streams(pj) == {"encoder"}
    series, notes = read([pj, pose_path])
    np.testing.assert_allclose(np.diff(series.phi_L), np.diff(reference.phi_L), atol=2e-3)
    assert any("velocity as omega_L" in note for note in notes)
    both = export(tmp_path / "both.csv", [*header, "/joint_states/wheel_left_joint/position",
                                          "/joint_states/wheel_right_joint/position"],
                  [[r[0], repr(float(a)), repr(float(b)), r[1], r[2]]
                   for r, a, b in zip(enc, *speeds, strict=True)])
    series, notes = read([both, pose_path])
    assert_same(series, reference, rtol=1e-12)
    assert not any("integrated" in note for note in notes)
    # positions beside the velocities that a velocity-only driver never fills (NaN, as
    # joint_state_broadcaster writes them; empty), or fills with one value: velocities read
    for position in ("nan", "", "0"):
        unfilled = export(tmp_path / "unfilled.csv",
                          [*header, "/joint_states/wheel_left_joint/position",
                           "/joint_states/wheel_right_joint/position"],
                          [[r[0], repr(float(a)), repr(float(b)), position, position]
                           for r, a, b in zip(enc, *speeds, strict=True)])
        series, notes = read([unfilled, pose_path])
        np.testing.assert_allclose(np.diff(series.phi_R), np.diff(reference.phi_R), atol=2e-3)
        assert f"{unfilled}: the wheel joints' position columns are never filled or never " \
               "change (a driver that reports velocities only): their velocity columns " \
               "read instead" in notes
        assert not any("velocity" in note and "not read" in note for note in notes)


def test_a_separator_ending_every_data_row_but_not_the_header(tmp_path, plain):
    path, header, rows = plain
    ended = tmp_path / "ended.csv"
    ended.write_text(",".join(header) + "\n" + "".join(",".join(row) + ",\n" for row in rows))
    assert_same(read(ended)[0], read_timeseries(path))


def test_a_y_up_motion_capture_export_is_turned_z_up(tmp_path, plain):
    """A motion-capture export in its Y-up world (x, y the height, z; the rigid body's y axis
    up): read with z as the Z-up log, with a note (it was refused as tilted 90 degrees)."""
    path, _, rows = plain
    enc = export(tmp_path / "enc.csv", ["t", "phi_L", "phi_R"], [r[:3] for r in rows if r[1]])
    poses = []
    for t, _, _, x, y, theta in (r for r in rows if r[3]):
        half = 0.5 * float(theta)  # yaw about the world y axis in the Y-up world
        poses.append([t, x, "0.3", repr(-float(y)), "0", repr(math.sin(half)), "0",
                      repr(math.cos(half))])
    mocap = export(tmp_path / "mocap.csv", ["t", "x", "y", "z", "qx", "qy", "qz", "qw"], poses)
    series, notes = read([enc, mocap])
    assert_same(series, read_timeseries(path), rtol=1e-9)
    assert f"{mocap}: the poses are Y-up (the world's y axis up, as motion capture streams by " \
        "default; the body its y axis up, turned z-up): turned Z-up, positions (x, y, z) read " \
        "as (x, -z, y)" in notes


MOTIVE_BLOCK = "\n".join([
    "Format Version,1.23,Take Name,run,Capture Frame Rate,50.000000,Rotation Type,Quaternion,"
    "Length Units,Millimeters,Coordinate Space,Global",
    "",
    ",Type" + ",Rigid Body" * 8 + ",Rigid Body Marker",
    ",Name" + ",{body}" * 8 + ",{body}:Marker1",
    ",ID" + ",1" * 8 + ",2",
    ",,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,"
    "Position",
    "Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,X",
    ""])


def test_an_optitrack_motive_export_is_read_by_its_header_block(tmp_path, plain):
    """Motive's CSV: the take's settings, rows Type, Name, ID and the columns' kinds above
    Frame,Time (Seconds),X,Y,Z,...; Y-up (its default), lengths in mm. The rigid body's
    rotation and position are read (a marker's are not), turned Z-up; the same log as the
    plain file. Two rigid bodies are an error naming them."""
    path, _, rows = plain
    enc = export(tmp_path / "enc.csv", ["t", "phi_L", "phi_R"], [r[:3] for r in rows if r[1]])
    lines = []
    for frame, (t, _, _, x, y, theta) in enumerate(r for r in rows if r[3]):
        half = 0.5 * float(theta)
        lines.append(",".join([str(frame), t, "0", repr(math.sin(half)), "0",
                               repr(math.cos(half)), repr(1e3 * float(x)), "300.0",
                               repr(-1e3 * float(y)), "0.0002", "1.0"]))
    motive = tmp_path / "motive.csv"
    motive.write_text(MOTIVE_BLOCK.format(body="robot") + "\n".join(lines) + "\n")
    series, notes = read([enc, motive])
    assert_same(series, read_timeseries(path), rtol=1e-9)
    assert notes[0] == (f"{motive}: read as an OptiTrack Motive export (rigid body 'robot', "
                        "lengths in mm)")
    euler = MOTIVE_BLOCK.format(body="robot").replace("Quaternion", "XYZ")
    motive.write_text(euler + "\n".join(lines) + "\n")
    with pytest.raises(DataError, match="missing column theta .* 'Rigid Body robot rotation "
                                        "X'.* not read: give the heading as theta"):
        group_inputs([str(enc), str(motive)])
    two = MOTIVE_BLOCK.format(body="robot").replace(",robot:Marker1", ",box")
    two = two.replace("Rigid Body Marker", "Rigid Body")
    motive.write_text(two + "\n".join(lines) + "\n")
    with pytest.raises(DataError, match="an OptiTrack Motive export of several rigid bodies "
                                        r"\(box, robot\); export the robot's alone"):
        read([enc, motive])


def test_a_file_after_a_lone_stream_that_is_no_stream_file_is_named(tmp_path, plain):
    """An encoder file followed by an export excite does not read (here a Motive CSV with
    its header block): the error is about that export, not "give the file with the other
    stream" (it was given)."""
    _, _, rows = plain
    enc = export(tmp_path / "enc.csv", ["t", "phi_L", "phi_R"], [r[:3] for r in rows if r[1]])
    motive = tmp_path / "motive.csv"
    motive.write_text("Format Version,1.23,Take Name,run\n,,Type,Rigid Body\n0,0.0,1,2\n")
    with pytest.raises(DataError) as info:
        group_inputs([str(enc), str(motive)])
    message = str(info.value)
    assert message.startswith(f"{motive}: no header of a time-series stream")
    assert message.endswith(f"(given after {enc}, which has only the encoder stream: this "
                            "file should hold the pose stream)")


GOOD_ROWS = "0;0;0;0;0;0\n0.1;1;1;0.05;0;0\n0.2;2;2;0.1;0;0\n"


@pytest.mark.parametrize("text, message", [
    ("t [m],phi_L,phi_R,x,y,theta\n", "log.csv:1: column 't [m]': unit 'm' is not a unit of "
     "time (s, sec, secs, second, seconds, ms, us, µs, μs, ns)"),
    ("t,phi_L,phi_R,x [ft],y,theta\n", "log.csv:1: column 'x [ft]': unit 'ft' is not a unit "
     "of length (m, cm, mm)"),
    ("t,phi_L,phi_R,x,y,theta [rad/s]\n", "column 'theta [rad/s]': unit 'rad/s' is not a unit "
     "of angle"),
    ("t,ticks_L [rad],ticks_R,x,y,theta\n", "column 'ticks_L [rad]': unit 'rad' is not a unit "
     "of count"),
    ("t,time,phi_L,phi_R,x,y,theta\n", "log.csv:1: columns 't' and 'time' are both t; keep one"),
    ("t;phi_L;phi_R;x;y;theta;yaw\n", "columns 'theta' and 'yaw' are both theta; keep one"),
    ("t,phi_L,phi_R,x,y,theta,T\n", "log.csv:1: column t appears twice"),
    ("t;phi_L;phi_R;x;y;theta\n0;0;0;0;0;0\n0,1;1;1;0.05;0;0\n",
     "log.csv:3: x has a decimal point ('0.05') but other numbers have decimal commas"),
    ("t;phi_L;phi_R;x;y;theta\n0,0,0,0,0,0\n", "log.csv:2: expected 6 columns separated by "
     "semicolons, found 1"),
    ("t\tphi_L\tphi_R\tx\ty\ttheta\n0\t0\t0\t0\t0\n", "log.csv:2: expected 6 columns "
     "separated by tabs, found 5"),
    ("t;phi_L;phi_R;x;y;theta\n" + GOOD_ROWS + "0.3;3;abc;0.15;0;0\n",
     "log.csv:5: phi_R is not a number: 'abc'"),
    ("t;phi_L;phi_R;x;y;theta;z\n" + "0.3;3;3;nan;0;0;0\n",
     "log.csv:2: x is empty (or NaN) but other x/y/theta cells are not"),
    ("time;left;right;x;y;yaw\n0;0;0;0;0;0\n", "log.csv: only pose columns; give the other "
     "stream too (a second file with t,phi_L,phi_R, or all columns in one file); 'left', "
     "'right' not read: wheel columns are named phi_L, phi_R (rad), ticks_L, ticks_R or "
     "omega_L, omega_R (rad/s"),
    ("time,enc_left,enc_right,x,y,qz,qw\n", "log.csv: only pose columns; give the other "
     "stream too (a second file with t,phi_L,phi_R, or all columns in one file); 'enc_left', "
     "'enc_right' not read: wheel columns are named phi_L, phi_R (rad), ticks_L, ticks_R or "
     "omega_L, omega_R (rad/s"),
    ("time,phi_L,phi_R,x,y,rotation_z,rotation_w\n", "log.csv:1: missing column theta "
     "(expected t,phi_L,phi_R,x,y,theta in one file, or t,phi_L,phi_R and t,x,y,theta in two); "
     "the header names 'time', 'phi_L', 'phi_R', 'x', 'y', 'rotation_z', 'rotation_w'"),
    ("time,phi_L,phi_R,x,y,q_x,q_y,q_w\n", "log.csv:1: the quaternion has no column qz (the "
     "heading is the yaw of qx, qy, qz, qw; qx and qy may both be left out)"),
    ("time,phi_L,phi_R,x,y,qx,qz,qw\n", "log.csv:1: the quaternion has no column qy"),
    ("t,phi_L,phi_R,x,y,qz,qw\n0,0,0,0,0,0,1\n0.1,1,1,0.1,0,,1\n", "log.csv:3: qz is empty "
     "(or NaN) but other quaternion cells are not"),
    ("t,phi_L,phi_R,x,y,qz,qw\n0,0,0,0,0,0,1\n0.1,1,1,0.1,0,0,0\n", "log.csv:3: the "
     "orientation quaternion (x, y, z, w) = (0.0, 0.0, 0.0, 0.0) is not a rotation"),
    ("t,phi_L,phi_R,x,y,qx,qy,qz,qw\n0,0,0,0,0,0,0,0,1\n0.1,1,1,0.1,0,0.7071,0,0,0.7071\n",
     "log.csv:3: the pose's z axis is tilted 90.0 degrees from the world z axis"),
    ("t,phi_L,phi_R,x,y,qz,qw [deg]\n", "log.csv:1: column 'qw [deg]': unit 'deg' is not a "
     "unit of number (it has none)"),
    ("Zeit;X;Y;Gier\n", "log.csv:1: no time column t (s); the header names 'Zeit', 'X', 'Y', "
     "'Gier' (expected t,phi_L,phi_R,x,y,theta in one file"),
    ("t,phi_L,phi_R,omega_L,omega_R,x,y,theta\n", "log.csv:1: wheel columns of two kinds "
     "(phi_L, phi_R and omega_L, omega_R); give one kind"),
    ("t,left_wheel_speed [m/s],right_wheel_speed [m/s],x,y,theta\n", "log.csv:1: column "
     "'left_wheel_speed [m/s]': unit 'm/s' is not a unit of angular speed (rad/s, rad/sec, "
     "deg/s, °/s, rpm, rev/s)"),
    ("t,left_wheel_speed,right_wheel_speed [rpm],x,y,theta\n", "log.csv:1: column "
     "'left_wheel_speed' has no unit: wheel speeds may be in rad/s, deg/s, rpm or rev/s; say "
     "which, e.g. 'left_wheel_speed [rpm]' or 'left_wheel_speed [rad/s]'"),
    ("t,omega_L,omega_R,x,y,theta\n0,1,1,0,0,0\n0.1,1,inf,0,0,0\n", "log.csv:3: omega_R is "
     "not finite"),
    ("time;battery\n", "log.csv:1: neither encoder (phi_L, phi_R) nor pose (x, y, theta) "
     "columns (expected t,phi_L,phi_R,x,y,theta in one file, or t,phi_L,phi_R and t,x,y,theta "
     "in two); the header names 'time', 'battery'"),
])
def test_what_cannot_be_read_safely_is_a_one_line_error(tmp_path, text, message):
    path = tmp_path / "log.csv"
    path.write_text(text)
    with pytest.raises(DataError) as info:
        read_timeseries(path)
    assert str(info.value).startswith(str(path)) and message in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("header, streams", [
    ("time;x (m);y (m);yaw [deg];z", {"pose"}),
    ("time;x;y;qx;qy;qz;qw", {"pose"}),
    ("time;x;y;orientation.z;orientation.w", {"pose"}),
    ("stamp\tleft_ticks\tright_ticks\tbattery", {"encoder"}),
    ('"Time [s]","Phi_L","Phi_R"', {"encoder"}),
    ("time;left;right;x;y;yaw", {"pose"}),
    ("x;y;yaw", {"encoder", "pose"}),  # no time: read alone, the error names it
    ("t,x,y,theta,phi_L", {"encoder", "pose"}),  # a partial wheel group: likewise
    ("t,x [ft],y,theta", {"encoder", "pose"}),  # a bad unit: likewise
    ("time;phi_L;phi_R;x;y;yaw;qw", {"encoder", "pose"}),
    ("dphi_L;dphi_R;dx_gt [mm];dy_gt;dtheta_gt", set()),
    ("1;1;0,05;0;0", set()),
    ("foo;bar", set()),
])
def test_what_kind_of_file_a_real_header_is(tmp_path, header, streams):
    path = tmp_path / "log.csv"
    path.write_text(header + "\n")
    assert timeseries_streams(path) == streams


def test_a_lone_pose_file_with_wheel_like_columns_hints_at_their_names(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text("time;left;right;x;y;yaw\n")
    assert header_hint(path) == ("; 'left', 'right' not read: wheel columns are named phi_L, "
                                 "phi_R (rad), ticks_L, ticks_R or omega_L, omega_R (rad/s; "
                                 "see docs/formats.md)")
    with pytest.raises(DataError, match="has only the pose stream; give the file with the other "
                       "stream right after it; 'left', 'right' not read"):
        group_inputs([str(path)])
    path.write_text("t,phi_L,phi_R,left_current\n")
    assert header_hint(path) == ""  # the wheels are there: nothing is missing


# --------------------------------------------------------------------------- segment CSVs

SEGMENT_HEADER = ["dphi_L", "dphi_R", "dx_gt", "dy_gt", "dtheta_gt"]
SEGMENT_ROWS = [["1.5", "1.25", "0.075", "0.0012", "-0.0425"],
                ["2", "1", "0.07", "0.01", "-0.17"],
                ["-1", "1", "0", "0", "0.33"],
                ["0.5", "0.75", "0.031", "-0.002", "0.05"]]


def load(path):
    notes = []
    return load_segments(path, on_note=notes.append), notes


@pytest.fixture
def segment_reference(tmp_path):
    return load_segments(export(tmp_path / "plain.csv", SEGMENT_HEADER, SEGMENT_ROWS)).as_array()


@pytest.mark.parametrize("sep, decimal_comma, with_header", [
    (";", False, True), (";", True, True), ("\t", True, True), ("\t", False, False),
    (";", True, False), ("; ", True, False),
])
def test_segment_csv_separators_and_decimal_commas(tmp_path, segment_reference, sep,
                                                   decimal_comma, with_header):
    path = export(tmp_path / "s.csv", SEGMENT_HEADER if with_header else [], SEGMENT_ROWS, sep,
                  decimal_comma)
    if not with_header:
        path.write_text(path.read_text().lstrip("\n"))
    segments, notes = load(path)
    np.testing.assert_array_equal(segments.as_array(), segment_reference)
    assert notes == []


def test_segment_csv_with_units_any_order_and_columns_not_read(tmp_path, segment_reference):
    """A header in another order, with units (converted) and columns not read: the same
    segments to rounding, and notes naming what was done."""
    header = ["index", "dtheta_gt [deg]", "dx_gt (mm)", "dy_gt [m]", "dphi_L [rad]",
              "dphi_R (deg)", "note"]
    rows = [[str(i), repr(math.degrees(float(r[4]))), repr(float(r[2]) * 1e3), r[3], r[0],
             repr(math.degrees(float(r[1]))), '"a; b"'] for i, r in enumerate(SEGMENT_ROWS)]
    path = export(tmp_path / "s.csv", header, rows, ";")
    segments, notes = load(path)
    np.testing.assert_allclose(segments.as_array(), segment_reference, rtol=1e-14, atol=1e-17)
    assert notes == [f"{path}: columns not read: index, note",
                     f"{path}: units converted: dtheta_gt from deg to rad, dx_gt from mm to "
                     "m, dphi_R from deg to rad"]
    many = []
    load_segment_files([path, path], on_note=many.append)
    assert many == notes + notes


def test_segment_csv_time_columns_with_units(tmp_path):
    rows = [r + [repr(i * 1000.0), repr((i + 1) * 1000.0)] for i, r in enumerate(SEGMENT_ROWS)]
    path = export(tmp_path / "s.csv", SEGMENT_HEADER + ["t_end [ms]", "t_start_ms"],
                  [r[:5] + [r[6], r[5]] for r in rows], "\t")
    segments, notes = load(path)
    np.testing.assert_array_equal(segments.t_start, np.arange(4.0))
    np.testing.assert_array_equal(segments.t_end, np.arange(1.0, 5.0))
    assert segments.chained[1:].all()
    assert notes == [f"{path}: units converted: t_end from ms to s, t_start from ms to s"]


@pytest.mark.parametrize("header, message", [
    ("foo;bar", ":1: the header names 'foo', 'bar': neither a segment CSV "
     "(dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt) nor a time-series CSV (t with phi_L,phi_R or "
     "ticks_L,ticks_R, and x,y,theta; names and units: docs/formats.md)"),
    ("dphi_L;dphi_R;dx_gt;dtheta_gt;z", ":1: missing column dy_gt (a segment CSV's columns: "
     "dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt); the header names 'dphi_L', 'dphi_R', 'dx_gt', "
     "'dtheta_gt', 'z'"),
    ("dphi_L;dphi_R;dx_gt;dy_gt;dtheta_gt;t_start", ":1: the time columns t_start and t_end "
     "go together"),
    ("dphi_L;dphi_R;dx_gt [deg];dy_gt;dtheta_gt", ":1: column 'dx_gt [deg]': unit 'deg' is "
     "not a unit of length (m, cm, mm)"),
])
def test_segment_csv_headers_that_cannot_be_read(tmp_path, header, message):
    path = tmp_path / "s.csv"
    path.write_text(header + "\n1;1;0;0;0;0\n")
    with pytest.raises(DataError) as info:
        load_segments(path)
    assert str(info.value) == f"{path}{message}"


def test_notes_of_segment_files_and_logs_reach_on_note(tmp_path, plain):
    """Through the inputs of excite calibrate: a segment CSV's and a log's notes, in order."""
    _, header, rows = plain
    segments = export(tmp_path / "s.csv", SEGMENT_HEADER + ["quality"],
                      [r + ["1"] for r in SEGMENT_ROWS], ";")
    log = export(tmp_path / "log.csv", header + ["battery"], [r + ["12"] for r in rows], "\t")
    notes = []
    parts = segment_inputs(group_inputs([str(segments), str(log)]), LogOptions(),
                           on_note=notes.append)
    assert len(parts) == 2
    assert notes[:2] == [f"{segments}: columns not read: quality",
                         f"{log}: columns not read: battery"]
    assert parts[1].log is not None and parts[1].log.notes[0] == notes[1]
