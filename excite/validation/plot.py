"""The image of ``excite validate --plot`` (PNG, PDF, SVG or JPEG by its suffix): per log, the
measured sensor path (ground truth) and the paths dead-reckoned with the nominal and the
calibrated robot, in the world frame (m).

matplotlib (the ``sim`` extra) is imported when a plot is drawn, never with this module; the
figure is rendered by the Agg canvas directly (no pyplot, no global backend switch).
"""

from __future__ import annotations

import math
import os

from excite.validation.dead_reckoning import ValidationResult

__all__ = ["plot_validation"]

#: Most points drawn per path (longer paths are thinned evenly; the last point is kept).
MAX_POINTS = 5000


def plot_validation(result: ValidationResult, path: str | os.PathLike[str]) -> None:
    """Write an image (its format by the suffix) with one panel per log: measured, nominal and
    calibrated sensor paths (x, y in m, equal axes), the start marked, the end-point errors in
    the legend. Raises OSError when the file cannot be written, ModuleNotFoundError without
    matplotlib."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = len(result.logs)
    columns = min(n, 3)
    rows = math.ceil(n / columns)
    figure = Figure(figsize=(5.0 * columns, 4.6 * rows), layout="constrained")
    FigureCanvasAgg(figure)
    for i, log in enumerate(result.logs):
        axes = figure.add_subplot(rows, columns, i + 1)
        step = max(1, math.ceil(log.t.size / MAX_POINTS))
        keep = list(range(0, log.t.size - 1, step)) + [log.t.size - 1]
        for poses, label, style in (
                (log.measured, "measured (ground truth)", dict(color="black", lw=2.0)),
                (log.nominal_path, f"nominal (end {log.nominal.end_position_error:.3g} m)",
                 dict(color="tab:red", lw=1.2, ls="--")),
                (log.calibrated_path,
                 f"calibrated (end {log.calibrated.end_position_error:.3g} m)",
                 dict(color="tab:blue", lw=1.2))):
            axes.plot(poses[keep, 0], poses[keep, 1], label=label, **style)
        axes.plot(*log.measured[0, :2], "o", color="black", ms=5, label="start")
        axes.set_aspect("equal", adjustable="datalim")
        axes.set_xlabel("x [m]")
        axes.set_ylabel("y [m]")
        axes.set_title("+".join(map(os.path.basename, log.file.split("+"))), fontsize=10)
        axes.grid(alpha=0.3)
        axes.legend(fontsize=8, loc="best")
    figure.savefig(path, dpi=110)  # the format of its suffix
