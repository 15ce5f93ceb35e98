"""``excite segment``: cut time-series logs and bags into the segment CSV (the lesson's columns
plus each segment's time span)."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from excite.commands.args import UsageError
from excite.commands.logs import add_log_options


def add_parser(sub: argparse._SubParsersAction) -> None:
    seg = sub.add_parser("segment", help="cut time-series logs or bags into a segment CSV")
    seg.add_argument("logs", nargs="+", metavar="LOG",
                     help="time-series CSV (or a pair of stream CSVs) or ROS bag")
    seg.add_argument("--out", required=True, metavar="FILE.csv",
                     help="segment CSV: dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt,t_start,t_end")
    add_log_options(seg)
    seg.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from excite.calibration.starts import initial_estimate
    from excite.commands.logs import group_inputs, segment_inputs
    from excite.core.models import single_arc_error
    from excite.logs.segments import Segments, save_segments

    inputs = group_inputs(args.logs)
    if any(source.kind == "segments" for source in inputs):
        bad = next(source for source in inputs if source.kind == "segments")
        raise UsageError(f"{bad.name}: a segment file, not a time-series log or bag")
    parts = segment_inputs(args, inputs)
    segments = Segments.concatenate([part.segments for part in parts])
    try:
        save_segments(args.out, segments)
    except OSError as exc:
        raise UsageError(f"cannot write {args.out}: {exc.strerror}") from None
    for part in parts:
        print(part.describe())
    error = single_arc_error(segments.sub_dphi_L, segments.sub_dphi_R,
                             initial_estimate(segments))
    worst, typical = float(error.max()), float(np.median(error))
    print(f"wrote {len(segments)} segments to {args.out}")
    print(f"each row is one arc: within the segments the curvature changes, and one arc per "
          f"segment misses the motion by up to {worst:.2e} m (median {typical:.2e} m); "
          "excite calibrate on the log itself composes the sub-steps", file=sys.stderr)
    return 0
