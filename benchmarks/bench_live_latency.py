"""Live sessions whose poses arrive late: the clock offset given, zero or estimated.

The made-up robot of ``examples/live_session.py`` (kinematic, motion capture with 1 mm /
2 mrad noise at 50 Hz, wheels within 3% of the nominal (0.05, 0.05, 0.30) m) with its poses
stamped on arrival, ``--latency`` s after they were taken (pose time = true time + latency),
driven by slip_aware until the stopping rule says done at 0.5% (95%) or 120 s pass,
the commands every 20 ms. The same robots and seeds for each ``time_offset`` (a number, s, or
"estimate"). Per setting: sessions done, the median and 90th percentile of the seconds driven,
the final calibration's truth inside its 95% ellipse (r_L, r_R, b) and within the target, the
false stops (done with the truth outside the target), and the offsets the log was cut with.

Usage: python benchmarks/bench_live_latency.py [--latency 0.03] [--sessions 40]
       [--offsets 0,-0.03,estimate] [--wheels-every K (wheel angles at 50/K Hz)]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from agents.catalog import make_protocol
from excite import Params
from excite.contracts import Traction
from excite.live import LiveSession, LiveSettings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import live_session as EXAMPLE  # noqa: E402  (the made-up robot and the transport's loop)

NOMINAL = Params(0.05, 0.05, 0.30)
TRACTION = Traction(motor_tau=0.05, grip=5.0)



def session(truth: Params, seed: int, latency: float, time_offset, wheels_every: int = 1
            ) -> tuple:
    """One session: (outcome, seconds driven, truth in the 95% ellipse, within the target,
    the offset the log was cut with)."""
    robot = EXAMPLE.ToyRobot(truth, seed=100 + seed, latency=latency)
    settings = LiveSettings(nominal=NOMINAL, max_wheel_speed=20.0, target=0.005,
                            sensor_pose="axle", max_time=120.0, traction=TRACTION,
                            time_offset=time_offset)
    result = EXAMPLE.run(LiveSession(settings, make_protocol("slip_aware"), seed=seed), robot,
                         wheels_every=wheels_every)
    c = result.calibration
    if c is None:
        return result.outcome, robot.t, False, False, math.nan
    error = c.params.as_array() - truth.as_array()
    inside = bool(error @ np.linalg.solve(c.covariance, error) <= chi2.ppf(0.95, 3))
    within = bool(np.all(np.abs(error / truth.as_array()) <= settings.target))
    return result.outcome, robot.t, inside, within, result.time_offset


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latency", type=float, default=0.03)
    parser.add_argument("--sessions", type=int, default=40)
    parser.add_argument("--wheels-every", type=int, default=1,
                        help="wheel angles every K-th 20 ms tick (50/K Hz; default 1)")
    parser.add_argument("--offsets", default=None,
                        help="comma-separated: numbers (s) or estimate (default 0, the "
                        "negated latency, estimate)")
    args = parser.parse_args(argv)
    offsets = ([0.0, -args.latency, "estimate"] if args.offsets is None else
               [o if o == "estimate" else float(o) for o in args.offsets.split(",")])
    rng = np.random.default_rng(2026)
    truths = [Params(*(NOMINAL.as_array() * rng.uniform(0.97, 1.03, 3)))
              for _ in range(args.sessions)]
    out = {}
    for offset in offsets:
        rows = [session(truth, k, args.latency, offset, args.wheels_every)
                for k, truth in enumerate(truths)]
        seconds = np.array([r[1] for r in rows])
        cut = np.array([r[4] for r in rows], dtype=float)
        out[str(offset)] = row = {
            "done": sum(r[0] == "done" for r in rows), "sessions": len(rows),
            "median_s": float(np.median(seconds)), "p90_s": float(np.percentile(seconds, 90)),
            "inside_95": sum(r[2] for r in rows), "within_target": sum(r[3] for r in rows),
            "false_stops": sum(r[0] == "done" and not r[3] for r in rows),
            "offset_range": [float(np.nanmin(cut)), float(np.nanmax(cut))]}
        print(f"latency {args.latency:g} s, wheels at {50 / args.wheels_every:g} Hz, "
              f"time_offset {offset}: done {row['done']}/"
              f"{row['sessions']}, {row['median_s']:.1f} s median ({row['p90_s']:.1f} s 90th "
              f"percentile), truth in the 95% ellipse {row['inside_95']}/{row['sessions']}, "
              f"within the target {row['within_target']}/{row['sessions']}, false stops "
              f"{row['false_stops']}/{row['done']}, cut with "
              f"{row['offset_range'][0]:+.4f} to {row['offset_range'][1]:+.4f} s", flush=True)
    return out


if __name__ == "__main__":
    main()
