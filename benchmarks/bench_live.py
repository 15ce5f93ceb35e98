"""Time to target of live sessions against the simulated robot, beside `excite compare --target`
for the same protocol and robot preset (issue 28, acceptance 3).

Each session: `excite sim-robot --robot PRESET --seed S --speed X --mount 0,0,0 --pose-noise
SXY,STH` and `excite live --robot PRESET --sensor-pose axle --target T --use-sim-time` over
real DDS (envs.rehearsal), one after the other. The mounting is on the axle and the pose
noise per sample is the env's increment noise over sqrt(2) (a segment's increment is the
difference of two samples), so the live sessions estimate what the env estimates from data
of the same size. The comparison: `excite compare --target T --protocols PROTOCOL --robot
PRESET` on the slip env (independent increments, the online estimator for the planner), its
median segments to target.

Needs the sim and ros2 extras (`make bench-live` runs it in .venv-ros):

    python benchmarks/bench_live.py --sessions 10 --speed 3
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from envs.rehearsal import EXCITE, rehearse

#: The env's per-increment pose noise (m, rad): envs.config's sigma_xy, sigma_theta.
ENV_SIGMA = (2e-3, 1e-3)


def _median_ci(values: np.ndarray, rng: np.random.Generator, n: int = 2000
               ) -> tuple[float, float, float]:
    boot = np.median(rng.choice(values, (n, values.size)), axis=1)
    return float(np.median(values)), float(np.quantile(boot, 0.025)), float(
        np.quantile(boot, 0.975))


def live_sessions(args: argparse.Namespace, work: Path) -> list[dict]:
    noise = f"{ENV_SIGMA[0] / math.sqrt(2):.6f},{ENV_SIGMA[1] / math.sqrt(2):.6f}"
    rows = []
    for k in range(args.sessions):
        seed = args.seed + k
        folder = work / f"session{seed}"
        folder.mkdir()
        start = time.monotonic()
        s = rehearse(folder, ["--left-wheel", "left_wheel_joint", "--right-wheel",
                              "right_wheel_joint", "--pose-topic", "/pose", "--robot",
                              args.robot, "--sensor-pose", "axle", "--target",
                              str(args.target), "--protocol", args.protocol, "--max-time",
                              str(args.max_time), "--seed", str(seed),
                              *([] if args.time_offset is None
                                else ["--time-offset", args.time_offset])],
                     ["--robot", args.robot, "--seed", str(seed), "--mount", "0,0,0",
                      "--pose-noise", noise], speed=args.speed,
                     timeout=args.max_time / args.speed * 4 + 120)
        live = s.result["live"] if s.result else {}
        params = (s.result or {}).get("params") or {}
        std = (s.result or {}).get("std") or {}
        z = [(params[n] - s.truth[n]) / std[n] for n in ("r_L", "r_R", "b")
             if params.get(n) is not None and std.get(n)]
        error = max((abs(params[n] / s.truth[n] - 1) for n in ("r_L", "r_R", "b")
                     if params.get(n) is not None), default=math.nan)
        row = {"seed": seed, "code": s.code, "outcome": live.get("outcome"),
               "seconds": live.get("duration"), "segments": live.get("segments"),
               "slowdowns": len(live.get("slowdowns") or []),
               "max_abs_z": max(map(abs, z)) if z else None, "error": error,
               "wall": time.monotonic() - start}
        rows.append(row)
        why = "" if row["outcome"] == "done" else f" ({live.get('reason')})"
        print(f"session seed {seed}: {row['outcome']}{why} after {row['seconds']} s "
              f"({row['segments']} segments, {row['slowdowns']} slowdowns), max |z| "
              f"{row['max_abs_z']}, error {100 * error:.3f}%, {row['wall']:.0f} s wall",
              flush=True)
    return rows


def compare_sessions(args: argparse.Namespace, work: Path) -> dict:
    out = work / "compare"
    cmd = [*EXCITE, "compare", "--target", str(args.target), "--protocols", args.protocol,
           "--robot", args.robot, "--episodes", str(args.episodes), "--workers",
           str(args.workers), "--out", str(out), "--seed", str(args.seed)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    summary = json.loads((out / "summary.json").read_text())
    return summary


def _compare_target(summary: dict, protocol: str) -> dict:
    """The ``target`` entry of ``protocol`` (its first estimator) in compare's summary."""
    return next(iter(summary["protocols"][protocol].values()))["target"]


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=10)
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--speed", type=float, default=3.0)
    parser.add_argument("--target", type=float, default=0.005)
    parser.add_argument("--robot", default="default")
    parser.add_argument("--protocol", default="slip_aware")
    parser.add_argument("--max-time", type=float, default=150.0)
    parser.add_argument("--seed", type=int, default=7000)
    parser.add_argument("--time-offset", default=None,
                        help="passed to excite live (default: live's own)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args(argv)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python "
          f"{platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M')}; {' '.join(sys.argv)}")
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        rows = live_sessions(args, work)
        summary = compare_sessions(args, work)
    done = [r for r in rows if r["outcome"] == "done"]
    seconds = np.array([r["seconds"] if r["outcome"] == "done" else math.inf for r in rows])
    print(f"\nlive: {len(done)}/{len(rows)} done; median seconds to target (censored at "
          f"--max-time as inf) {np.median(seconds):.1f}")
    if done:
        print("  median, 95% CI over the done sessions: "
              f"{_median_ci(np.array([r['seconds'] for r in done]), rng)}")
        print(f"  truth within 3 std: {sum(r['max_abs_z'] < 3 for r in done)}/{len(done)}")
    target = _compare_target(summary, args.protocol)
    ttt = target["time_to_target"]
    print(f"compare --target {args.target} ({args.episodes} episodes): median seconds "
          f"{ttt['seconds']['median']} {ttt['seconds']['ci95']}, segments "
          f"{ttt['segments']['median']}, censored {ttt['censored']}; false stops "
          f"{target['false_stop_rate']}")
    if done and ttt["seconds"]["median"]:
        ratio = np.median(seconds) / ttt["seconds"]["median"]
        print(f"live / compare, median seconds: {ratio:.2f}")
    return {"live": rows, "compare": summary}


if __name__ == "__main__":
    main()
