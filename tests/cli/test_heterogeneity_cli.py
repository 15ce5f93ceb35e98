"""excite calibrate with several inputs that disagree: the report says so and names the file,
--json carries the per-file estimates, --common-params fails the fit."""

import json
from pathlib import Path

import numpy as np
import pytest

from excite import Params, save_segments
from excite.logs.synthetic import lesson_dataset
from tests.conftest import TRUTH, run_cli

OTHER = Params(TRUTH.r_L, TRUTH.r_R, 0.311)  # another robot: a wider track


@pytest.fixture
def two_robots(tmp_path):
    paths = []
    for name, params, seed in (("robot_a.csv", TRUTH, 1), ("robot_b.csv", OTHER, 2)):
        path = tmp_path / name
        save_segments(path, lesson_dataset(np.random.default_rng(seed), 150, params))
        paths.append(str(path))
    return paths


def test_two_files_that_disagree_are_said_so_with_exit_zero(capsys, two_robots):
    code, out, err = run_cli(capsys, "calibrate", *two_robots)
    assert code == 0
    lines = out.splitlines()
    disagreement = next(line for line in lines if line.lstrip().startswith("disagreement"))
    assert "b from " in disagreement and "their std cover the spread" in disagreement
    assert two_robots[0] in disagreement and two_robots[1] in disagreement
    agreement = next(line for line in lines if "agreement       = NO" in line)
    assert "most different" in agreement and "2 logs" in agreement
    assert sum(line.startswith(f"    {path}: r_L ") for path in two_robots
               for line in lines) == 2
    fit = next(line for line in lines if line.lstrip().startswith("fit "))
    assert "fit             = ok: each of the 2 logs fits alone" in fit


def test_json_gives_each_file_and_the_pool(capsys, two_robots):
    code, out, _ = run_cli(capsys, "calibrate", *two_robots, "--json")
    assert code == 0
    report = json.loads(out)
    h = report["heterogeneity"]
    assert h["detected"] and h["by"] == "logs" and h["pooling"] == "random effects"
    assert h["p_value"] < h["level"] and h["statistic"] > 0
    assert [g["name"] for g in h["groups"]] == two_robots
    assert [g["n_segments"] for g in h["groups"]] == [150, 150]
    b = [g["params"]["b"] for g in h["groups"]]
    assert abs(b[0] - TRUTH.b) < 5 * h["groups"][0]["std"]["b"]
    assert abs(b[1] - OTHER.b) < 5 * h["groups"][1]["std"]["b"]
    # the pooled b lies between the two robots' and its std covers the spread
    assert min(b) < report["params"]["b"] < max(b)
    assert report["std"]["b"] > 0.25 * abs(b[1] - b[0])


def test_common_params_fail_the_fit(capsys, two_robots):
    code, out, _ = run_cli(capsys, "calibrate", *two_robots, "--common-params")
    assert code == 4
    fit = next(line for line in out.splitlines() if line.lstrip().startswith("fit "))
    assert "fit             = NO: r_L, r_R, b differ between the 2 logs" in fit
    assert "--common-params" in fit


def test_one_file_of_one_robot_is_tested_between_kinds_of_motion(capsys, two_robots):
    code, out, _ = run_cli(capsys, "calibrate", two_robots[0], "--json")
    assert code == 0
    h = json.loads(out)["heterogeneity"]
    assert h["by"] == "motion" and len(h["groups"]) >= 2


def test_files_whose_sensor_mountings_differ_fail_the_fit(capsys, tmp_path):
    """One robot, the sensor mounted anew between two files: exit 4 naming both mountings,
    and no static-transform command for a mounting that fits neither."""
    from excite.core.models import SENSOR_POSE

    paths = []
    for name, mounting, seed in (("a.csv", (0.10, -0.03, 0.40), 1),
                                 ("b.csv", (0.07, 0.0, 0.10), 2)):
        rng = np.random.default_rng(seed)
        dphi_L, dphi_R = rng.normal(0.0, 2.0, 150), rng.normal(0.0, 2.0, 150)
        truth, _ = SENSOR_POSE.evaluate(dphi_L, dphi_R, np.r_[TRUTH.as_array(), mounting],
                                        jacobian=False)
        rows = np.column_stack([dphi_L, dphi_R, truth.T + rng.normal(0.0, 2e-3, (150, 3))])
        path = tmp_path / name
        np.savetxt(path, rows, delimiter=",", header="dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt",
                   comments="")
        paths.append(str(path))
    code, out, _ = run_cli(capsys, "calibrate", *paths)
    assert code == 4
    assert "fit             = NO: the sensor mounting differs between the logs (" in out
    assert "sensor transform" not in out
    code, out, _ = run_cli(capsys, "calibrate", *paths, "--json")
    mounting = json.loads(out)["heterogeneity"]["mounting"]
    assert code == 4 and mounting["differ"] and mounting["dof"] == 3
    assert mounting["p_value"] < mounting["level"] == 0.001


def test_the_same_data_twice_is_a_one_line_error_naming_both(capsys, tmp_path, two_robots):
    """A file given twice, or a copy of it beside it, would pool every segment twice (every
    std 1/sqrt(2) of what the data say, the agreement test blind): refused."""
    copy = tmp_path / "copy_of_a.csv"
    copy.write_bytes(Path(two_robots[0]).read_bytes())
    for files in ([two_robots[0], two_robots[0]], [two_robots[0], two_robots[1], str(copy)]):
        code, out, err = run_cli(capsys, "calibrate", *files)
        assert code == 2 and out == "" and err.count("\n") == 1
        assert err == (f"excite: error: {files[0]} and {files[-1]} hold the same data: give "
                       "each log once (pooled twice, every std would be 1/sqrt(2) of what the "
                       "data say)\n")
