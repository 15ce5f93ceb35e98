"""``excite simulate``: drive a simulated robot with a protocol and write its log, with the
hidden truth beside it."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from excite.commands.args import UsageError, env_id, positive_int, robot_preset
from excite.registration import DEFAULT_ENV_ID


def add_parser(sub: argparse._SubParsersAction) -> None:
    sim = sub.add_parser("simulate", help="drive a simulated robot with a protocol, write its log")
    sim.add_argument("--protocol", required=True, metavar="NAME")
    sim.add_argument("--segments", type=positive_int, required=True, metavar="N")
    sim.add_argument("--seed", type=int, default=0, metavar="S")
    sim.add_argument("--env", default=DEFAULT_ENV_ID, metavar="ID")
    sim.add_argument("--policy", metavar="PATH", help="policy file for --protocol learned")
    sim.add_argument("--robot", default="default", metavar="PRESET",
                     help="robot preset: default, turtlebot3, jackal, husky")
    sim.add_argument("--out", required=True, metavar="FILE.csv",
                     help="segment CSV; the hidden truth goes to FILE.truth.json")
    sim.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from agents.catalog import make_protocol
    from agents.compare import make_env, run_protocol_episode
    from excite.data import save_segments

    env = env_id(args.env)
    robot = robot_preset(args.robot)
    protocol = make_protocol(args.protocol, args.policy)
    out = Path(args.out)
    if not out.parent.is_dir():
        raise UsageError(f"cannot write {out}: no such directory {out.parent}")
    env_ = make_env(env, args.segments, robot)
    records = run_protocol_episode(env_, protocol, args.seed)
    base = env_.unwrapped
    save_segments(out, base.segments)
    truth = {**dict(zip(("r_L", "r_R", "b"), base.true_params.as_array().tolist(), strict=True)),
             "robot": {k: float(v) for k, v in vars(base.robot).items()},
             "sigma": dict(zip(("x", "y", "theta"), base.sigma.tolist(), strict=True)),
             "env": env, "protocol": args.protocol, "seed": args.seed,
             "segments": len(records),
             "collisions": int(np.sum([r["collision"] for r in records]))}
    truth_path = out.with_name(out.stem + ".truth.json") if out.suffix == ".csv" else Path(
        f"{out}.truth.json")
    truth_path.write_text(json.dumps(truth, indent=2) + "\n")
    print(f"wrote {len(records)} segments to {out} and the hidden truth to {truth_path}")
    return 0
