"""A core-only install (numpy, scipy) runs excite calibrate, segment and validate on CSVs,
lists the protocols and plans with them (no simulator: a planner can drive a real robot).

Run by ``make test-core`` in its own virtual environment with ``pip install .`` (no extras);
not collected by pytest. Exits non-zero on the first failure.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import tempfile
from contextlib import redirect_stdout
from io import StringIO
from pathlib import Path

import numpy as np

from excite.cli import main
from excite.core.kinematics import Params
from excite.core.models import SensorPose
from excite.logs.synthetic import synthetic_log
from excite.logs.timeseries_csv import write_timeseries


def check(condition: bool, what: str) -> None:
    if not condition:
        sys.exit(f"core-only check failed: {what}")
    print(f"ok: {what}")


def run(*argv: str) -> tuple[int, str]:
    out = StringIO()
    with redirect_stdout(out):
        code = main(list(argv))
    return code, out.getvalue()


def core_only() -> None:
    for extra in ("gymnasium", "pymunk", "matplotlib", "rosbags", "stable_baselines3"):
        check(importlib.util.find_spec(extra) is None, f"{extra} is not installed")
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        truth = Params(0.050, 0.051, 0.300)
        for seed in range(2):
            log = synthetic_log(np.random.default_rng(seed), 60, truth, SensorPose(0.1, 0, 0.3),
                                pose_noise=(0.002, 0.002))
            write_timeseries(directory / f"log{seed}.csv", log.series)
        code, out = run("calibrate", str(directory / "log0.csv"), "--json")
        check(code == 0, "excite calibrate on a time-series CSV")
        (directory / "result.json").write_text(out)
        code, _ = run("segment", str(directory / "log0.csv"), "--out",
                      str(directory / "segments.csv"))
        check(code == 0, "excite segment")
        code, _ = run("calibrate", str(directory / "segments.csv"))
        check(code == 0, "excite calibrate on a segment CSV")
        code, out = run("validate", str(directory / "log1.csv"), "--params",
                        str(directory / "result.json"), "--nominal", "0.052,0.049,0.31",
                        "--json")
        check(code == 0 and json.loads(out)["overall"]["ratio"]["end_position_error"] < 1,
              "excite validate")
        code, _ = run("simulate", "--protocol", "spin", "--segments", "3", "--out",
                      str(directory / "sim.csv"))
        check(code == 2, "excite simulate says which extra it needs (exit 2)")
    code, out = run("protocols")
    check(code == 0 and "umbmark" in out and "speed" in out, "excite protocols")
    check(plans_without_simulator(), "every registered protocol but learned plans from "
          "RobotKnowledge alone")


def plans_without_simulator() -> bool:
    """Every protocol that needs no policy builds and acts on a hand-made RobotKnowledge."""
    from agents.catalog import PROTOCOLS, make_protocol
    from excite.contracts import RobotKnowledge, Traction

    nominal = Params(0.05, 0.05, 0.3)
    knowledge = RobotKnowledge(
        observation=np.zeros(16), estimate=nominal, information=np.eye(3), log=np.zeros((1, 5)),
        pose=np.zeros(3), nominal=nominal, sigma=np.array([2e-3, 2e-3, 1e-3]),
        max_wheel_speed=10.0, segment_duration=1.0, arena_size=4.0, budget=30,
        traction=Traction(motor_tau=0.05, grip=6.3, spin_inertia=0.56))
    actions = []
    for name in PROTOCOLS:
        if name != "learned":
            protocol = make_protocol(name)
            protocol.reset(np.random.default_rng(0))
            actions.append(protocol.act(knowledge))
    return all(a.shape == (2,) and np.all(np.abs(a) <= 1) for a in actions)


if __name__ == "__main__":
    core_only()
