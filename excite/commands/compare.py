"""``excite compare``: run calibration protocols on the same hidden robots and report."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from excite.commands.args import UsageError, env_id, positive_int, robot_preset
from excite.registration import DEFAULT_BUDGET, DEFAULT_ENV_ID


def add_parser(sub: argparse._SubParsersAction) -> None:
    cmp_ = sub.add_parser("compare", help="compare calibration protocols on the same robots")
    cmp_.add_argument("--protocols", metavar="A,B,...",
                      help="default: every protocol available (learned if a policy exists)")
    cmp_.add_argument("--episodes", type=positive_int, default=20, metavar="N")
    cmp_.add_argument("--segments", type=positive_int, default=DEFAULT_BUDGET, metavar="K")
    cmp_.add_argument("--seed", type=int, default=0, metavar="S")
    cmp_.add_argument("--env", default=DEFAULT_ENV_ID, metavar="ID")
    cmp_.add_argument("--workers", type=positive_int, default=None, metavar="W",
                      help="worker processes (default: all cores)")
    cmp_.add_argument("--out", default="excite_compare", metavar="DIR")
    cmp_.add_argument("--policy", metavar="PATH", help="policy file for the learned protocol")
    cmp_.add_argument("--robot", default="default", metavar="PRESET",
                      help="robot preset: default, turtlebot3, jackal, husky")
    cmp_.set_defaults(handler=run)


def _protocol_names(text: str | None, policy: str | None) -> list[str]:
    from agents.catalog import PROTOCOL_NAMES, default_protocols

    if text is None:
        return default_protocols(policy)
    names = [n.strip() for n in text.split(",") if n.strip()]
    for name in names:
        if name not in PROTOCOL_NAMES:
            raise UsageError(f"unknown protocol {name!r}; choose from {', '.join(PROTOCOL_NAMES)}")
    if not names or len(set(names)) != len(names):
        raise UsageError(f"--protocols needs distinct comma-separated names, got {text!r}")
    return names


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from agents.compare import (
        COLUMNS,
        CompareSettings,
        incompatible_protocols,
        make_env,
        run_comparison,
    )
    from agents.report import format_table, plot_comparison, summarize

    env = env_id(args.env)
    if args.policy and not Path(args.policy).is_file():
        raise UsageError(f"--policy: no such file {args.policy}")
    protocols = _protocol_names(args.protocols, args.policy)
    settings = CompareSettings(env_id=env, segments=args.segments, seed=args.seed,
                               robot=robot_preset(args.robot))
    probe = make_env(env, args.segments, settings.robot)
    shape, arena_size = probe.observation_space.shape, float(probe.unwrapped.config["arena_size"])
    probe.close()
    skipped = incompatible_protocols(protocols, shape, args.policy)
    for name, reason in skipped.items():
        print(f"excite: skipping {name}: {reason}", file=sys.stderr)
    protocols = [name for name in protocols if name not in skipped]
    if not protocols:
        raise UsageError("no protocol can run on this environment")
    try:
        rows = run_comparison(args.out, protocols, args.episodes, settings, args.workers,
                              args.policy)
    except OSError as exc:
        raise UsageError(f"cannot write to {args.out}: {exc.strerror}") from None
    columns = {k: np.array([r[k] for r in rows]) for k in COLUMNS}
    summary = summarize(columns, seed=args.seed)
    summary["settings"] = {"env": env, "segments": args.segments, "seed": args.seed,
                           "episodes": args.episodes, "protocols": protocols,
                           "robot": settings.robot}
    out = Path(args.out)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    plots = plot_comparison(columns, out, arena_size=arena_size)
    print(format_table(summary))
    print(f"\nresults: {out / 'segments.csv'}, {out / 'summary.json'}")
    print("plots:   " + ", ".join(str(p) for p in plots))
    return 0
