"""A real robot's log as a regression test: a Clearpath Jackal J100 (skid-steer) driven by hand
for 330 s, wheel speeds and lidar odometry (MAD-ICP). excite's default calibration must agree
with the authors' own fit (LeoBrizi/jackass-calibrator's config.json; no uncertainty published)
within 2.5 of excite's std on all six parameters. Fixture and licence: tests/data/jackal_j100."""

import json
from pathlib import Path

import pytest

from tests.conftest import run_cli

DATA = Path(__file__).resolve().parents[1] / "data" / "jackal_j100"
#: The authors' calibration of this recording (config.json): r_L, r_R, b in m; the lidar's
#: pose in the body frame (m, m, rad).
AUTHORS = {"r_L": 0.09206977407707143, "r_R": 0.0924379711241535, "b": 0.5372927964043419}
AUTHORS_LIDAR = {"x": -0.16705944914964835, "y": -0.002813190970535312,
                 "theta": 0.008070034871175746}


@pytest.mark.slow
def test_default_calibration_agrees_with_the_authors_fit(capsys):
    code, out, err = run_cli(capsys, "calibrate", DATA / "encoders.csv", DATA / "poses.csv",
                             "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["model"] == "sensor_pose"
    for name, value in AUTHORS.items():
        z = (report["params"][name] - value) / report["std"][name]
        assert abs(z) <= 2.5, (name, z)
    for name, value in AUTHORS_LIDAR.items():
        z = (report["sensor_pose"][name] - value) / report["sensor_pose_std"][name]
        assert abs(z) <= 2.5, (name, z)
