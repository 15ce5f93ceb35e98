"""``excite segment``: cut time-series logs and bags into the segment CSV (the lesson's columns
plus each segment's time span)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from excite.commands.args import UsageError, check_not_an_input, check_output_file
from excite.commands.exit_status import EXIT_OK
from excite.commands.logs import LOG_FILES, add_log_options

#: What ``excite segment --help`` says the command does.
DESCRIPTION = """Cut time-series logs and ROS bags into segments (fixed windows, or keyframes by
distance and angle) and write them as one segment CSV, with a line per input on the segments kept
and dropped. excite calibrate also reads the logs themselves, which is more exact."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    seg = sub.add_parser("segment", help="cut time-series logs or bags into a segment CSV",
                         description=DESCRIPTION)
    seg.add_argument("logs", nargs="+", metavar="LOG", help=LOG_FILES)
    seg.add_argument("--out", required=True, metavar="FILE.csv",
                     help="the segment CSV (required), columns dphi_L,dphi_R,dx_gt,dy_gt,"
                     "dtheta_gt,t_start,t_end (rad, rad, m, m, rad, s, s)")
    add_log_options(seg)
    seg.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from excite.calibration.starts import initial_estimate
    from excite.commands.logs import log_options, print_note
    from excite.core.models import single_arc_error
    from excite.logs.inputs import segment_logs
    from excite.logs.segments import Segments, save_segments

    check_output_file(Path(args.out))
    check_not_an_input(args.out, args.logs, "--out")
    parts = segment_logs(args.logs, log_options(args), on_note=print_note)
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
    print_note(f"each row is one arc: within the segments the curvature changes, and one arc "
               f"per segment misses the motion by up to {worst:.2e} m (median {typical:.2e} "
               "m); excite calibrate on the log itself composes the sub-steps")
    return EXIT_OK
