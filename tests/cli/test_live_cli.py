"""Every bad input of ``excite live`` and ``excite sim-robot`` is one line and exit status 2,
found before anything talks to ROS (these run without the ros2 extra)."""

import pytest

from tests.conftest import assert_one_line_error, run_cli

TOPICS = ["--left-wheel", "l", "--right-wheel", "r", "--pose-topic", "/pose"]


@pytest.mark.parametrize("args, words", [
    ([], "--nominal RL,RR,B"),
    (["--nominal", "0.05,0.05,0.3"], "--max-wheel-speed"),
    (["--nominal", "0.05,0.05,0.3", "--robot", "default"], "give --nominal or --robot, not both"),
    (["--nominal", "5,5,30", "--max-wheel-speed", "20"], "--nominal"),
    (["--robot", "default", "--area", "0,0,1"], "--area"),
    (["--robot", "default", "--area", "1,0,0,1"], "X0 < X1"),
    (["--robot", "default", "--area", "0,0,1,1", "--radius", "1"], "--area or --radius"),
    (["--robot", "default", "--rate", "10"], "--rate must be 20 to 1000 Hz, got 10"),
    (["--robot", "default", "--rate", "1e9"], "--rate must be 20 to 1000 Hz, got 1e+09"),
    (["--robot", "default", "--sensor-pose", "0.05,0.02,100"],
     "--sensor-pose 0.05,0.02,100: the angle 100 rad is beyond pi (degrees? 100 deg = "
     "1.745 rad)"),
    (["--robot", "default", "--response-time", "100"],
     "--response-time (100 s) must be shorter than --abort-timeout (10 s)"),
    (["--robot", "default", "--segment-duration", "0.001"],
     "--segment-duration must be at least 0.1 s (a maneuver the robot can follow)"),
    (["--robot", "default", "--speed-fraction", "1.5"], "--speed-fraction must be in (0, 1]"),
    (["--robot", "default", "--target", "2"], "target"),
    (["--robot", "default", "--target", "0"], "--target"),
    (["--nominal", "0.05,0.05,0.3", "--max-wheel-speed", "20"], "slip_aware needs"),
    (["--nominal", "0.05,0.05,0.3", "--max-wheel-speed", "20", "--motor-tau", "0.05"],
     "go together"),
    (["--robot", "default", "--protocol", "nosuch"], "nosuch"),
    (["--robot", "nosuch"], "unknown robot preset"),
    (["--robot", "default", "--force-yaml"], "--force-yaml needs --ros2-yaml"),
    (["--robot", "default", "--sensor-pose", "1,2"], "--sensor-pose"),
    (["--robot", "default", "--silence-timeout", "5", "--abort-timeout", "1"],
     "--abort-timeout must be at least --silence-timeout"),
    (["--robot", "default", "--target-confidence", "1"], "--target-confidence must be in (0, 1)"),
    (["--robot", "default", "--segment-duration", "1e300"],
     "--segment-duration (1e+300 s) must be at most --max-time (600 s)"),
    (["--robot", "default", "--time-offset", "nan"], "--time-offset: must be finite, got 'nan'"),
    (["--robot", "default", "--time-offset", "soon"],
     "--time-offset: must be a number of seconds or 'estimate', got 'soon'"),
])
def test_bad_live_input(capsys, args, words):
    code, _, err = run_cli(capsys, "live", *TOPICS, *args)
    assert_one_line_error(code, err, words)


def test_live_refuses_to_record_over_a_bag(capsys, tmp_path):
    (tmp_path / "s.mcap").mkdir()
    code, _, err = run_cli(capsys, "live", *TOPICS, "--robot", "default", "--record",
                           tmp_path / "s.mcap")
    assert_one_line_error(code, err, "exists")


@pytest.mark.parametrize("option", ["--out", "--record"])
def test_live_refuses_an_output_in_a_missing_folder(capsys, tmp_path, option):
    code, _, err = run_cli(capsys, "live", *TOPICS, "--robot", "default", option,
                           tmp_path / "no" / "r.json")
    assert_one_line_error(code, err, "no such directory")
    assert not (tmp_path / "no").exists()


def test_live_refuses_an_output_it_cannot_write_before_the_robot_moves(capsys, tmp_path):
    """The result files are written after the drive: one the system refuses (here /proc) is
    an error before the session, not an internal error after it with the report lost. An
    output that can be written is left as it was (nothing created by the check)."""
    code, _, err = run_cli(capsys, "live", *TOPICS, "--robot", "default", "--out",
                           "/proc/excite-live.json")
    assert_one_line_error(code, err, "cannot write /proc/excite-live.json")
    code, _, err = run_cli(capsys, "live", *TOPICS, "--robot", "default", "--ros2-yaml",
                           "/proc/excite-live.yaml")
    assert_one_line_error(code, err, "cannot write /proc/excite-live.yaml")
    run_cli(capsys, "live", *TOPICS, "--robot", "default", "--out", tmp_path / "r.json")
    assert not (tmp_path / "r.json").exists()


#: Bad sim-robot options and the words of their error.
BAD_SIM_ROBOT = {
    "--cut pose:1": "--cut",
    "--cut wheels:1:2": "--cut",
    "--cut pose:-1:2": "START >= 0",
    "--mount 1,2": "--mount",
    "--pose-noise -1,0": "--pose-noise",
    "--speed 0": "--speed",
    "--robot nosuch": "unknown robot preset",
}


@pytest.mark.parametrize("args", BAD_SIM_ROBOT)
def test_bad_sim_robot_input(capsys, args):
    code, _, err = run_cli(capsys, "sim-robot", *args.split())
    assert_one_line_error(code, err, BAD_SIM_ROBOT[args])
