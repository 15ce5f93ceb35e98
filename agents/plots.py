"""The plots of a comparison: errors, sigma_min and ANEES against segments, trajectories,
and with a target the survival curves of the time to target.

:func:`plot_comparison` draws the segment record (:mod:`agents.segment_record`) as PNG files.
matplotlib is imported when plotting, not with this module.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from agents.segment_record import by_episode, max_abs_error, oracle_median, pair_mask, pairs_of
from agents.target_record import stops_of
from excite.stats.consistency import anees_bounds

ORACLE_LABEL = "oracle (E-optimal, true params)"
DPI = 110


def pair_labels(pairs: list[tuple[str, str]]) -> dict[tuple[str, str], str]:
    """Display names of (protocol, estimator) pairs: the protocol's label (with its
    settings), followed by " | estimator" when more than one estimator ran."""
    several = len({estimator for _, estimator in pairs}) > 1
    return {(p, e): f"{p} | {e}" if several else p for p, e in pairs}


def plot_comparison(
    columns: dict[str, np.ndarray], out_dir: str | Path, arena_size: float = 4.0
) -> list[Path]:
    """Write the comparison plots as PNG files into `out_dir` (created if missing).

    Figures: ``errors_vs_segment.png`` (max relative error, %, median and 25-75% band over
    episodes, log scale), ``sigma_min_vs_segment.png`` (median and band, with the median
    oracle as a dashed line), ``anees_vs_segment.png`` (each estimator's ANEES, the mean NEES
    over episodes, log scale, with the 95% chi-square bounds of a consistent estimator
    dashed) and ``trajectories.png`` (the first episode's true path per protocol, with the
    first estimator that ran, in the square arena of side `arena_size` (m) centred at the
    origin, collisions as red x); with the target columns (``excite compare --target``)
    also ``target_survival.png`` (:func:`_plot_survival`). One line per (protocol,
    estimator), named by the labels with their settings (:func:`pair_labels`), in one color
    across the figures.

    Returns:
        The paths of the files written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pairs = pairs_of(columns)
    labels = pair_labels(pairs)
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colors = {pair: cycle[i % len(cycle)] for i, pair in enumerate(pairs)}
    paths = []

    figures = [
        (100.0 * max_abs_error(columns), "errors_vs_segment.png",
         "max relative error of r_L, r_R, b (%)",
         "Estimate error vs segments (median, 25-75% band over episodes)", "median"),
        (np.asarray(columns["sigma_min"], float), "sigma_min_vs_segment.png",
         "sigma_min (dimensionless, larger is better)",
         "Information sigma_min vs segments (median, 25-75% band over episodes)", "median"),
        (np.asarray(columns["nees"], float), "anees_vs_segment.png",
         "ANEES (mean NEES over episodes)",
         "Estimator consistency vs segments (dashed: 95% bounds of a consistent estimator)",
         "mean"),
    ]
    for values, name, ylabel, title, centre in figures:
        fig, ax = plt.subplots(figsize=(9.0, 4.8))
        bounds = set()
        for pair in pairs:
            mask = pair_mask(columns, *pair)
            _, seg, matrix = by_episode(columns, mask, values)
            if centre == "mean":
                ax.plot(seg, matrix.mean(axis=0), marker=".", color=colors[pair],
                        label=labels[pair])
                dof = int(np.max(np.asarray(columns["nees_dof"])[mask]))
                bounds.add(anees_bounds(matrix.shape[0], dof))
                continue
            with np.errstate(invalid="ignore"):
                q25, q50, q75 = np.nanpercentile(matrix, [25, 50, 75], axis=0)
            ax.plot(seg, q50, marker=".", color=colors[pair], label=labels[pair])
            ax.fill_between(seg, q25, q75, color=colors[pair], alpha=0.2, linewidth=0)
        if name == "sigma_min_vs_segment.png":
            ax.axhline(oracle_median(columns), color="black", linestyle="--",
                       label=ORACLE_LABEL)
        else:
            ax.set_yscale("log", nonpositive="mask")
        for low, high in sorted(bounds):
            for bound in (low, high):
                ax.axhline(bound, color="black", linestyle="--", linewidth=1)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("segment (motion intervals so far)")
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
        fig.tight_layout()
        paths.append(out / name)
        fig.savefig(paths[-1], dpi=DPI)
        plt.close(fig)

    first = {}  # each protocol's first pair
    for pair in pairs:
        first.setdefault(pair[0], pair)
    paths.append(_plot_trajectories(columns, list(first.values()),
                                    {pair[0]: colors[pair] for pair in first.values()},
                                    out, arena_size))
    if "stop" in columns:
        paths.append(_plot_survival(columns, pairs, labels, colors, out))
    return paths


def _plot_survival(columns: dict[str, np.ndarray], pairs: list[tuple[str, str]],
                   labels: dict[tuple[str, str], str], colors: dict[tuple[str, str], str],
                   out: Path) -> Path:
    """``target_survival.png``: per pair the share of robots (episodes) the stopping rule has
    not yet said done for, against the segments (left) and the seconds (right) driven; a
    curve that ends above 0 ends at the budget (those robots are censored, not done within
    it; the legend gives their number, as curves at 1 can hide each other). Call only after
    `plot_comparison` has selected the Agg backend."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11.0, 4.4), sharey=True)
    for pair in pairs:
        stops = stops_of(columns, *pair)
        for ax, driven in zip(axes, (stops.segments, stops.seconds), strict=True):
            done = np.sort(driven[stops.stopped])
            x = np.concatenate([[0.0], done, [driven.max()]])
            share = 1.0 - np.arange(done.size + 1) / driven.size
            ax.step(x, np.append(share, share[-1]), where="post", color=colors[pair],
                    label=f"{labels[pair]} ({driven.size - done.size} of {driven.size} "
                    "not done)")
    for ax, unit in zip(axes, ("segments", "seconds (s)"), strict=True):
        ax.set_xlabel(f"{unit} driven")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("share of robots not done yet")
    axes[1].legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.suptitle("Time to target: robots the stopping rule has not said done for")
    fig.tight_layout()
    path = out / "target_survival.png"
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _plot_trajectories(
    columns: dict[str, np.ndarray], pairs: list[tuple[str, str]], colors: dict[str, str],
    out: Path, arena_size: float,
) -> Path:
    """Grid of arena panels with the first episode path of each (protocol, estimator) pair
    given (colors by protocol); returns the PNG path.

    The path joins the true positions (m) at the segment ends, in segment order; the start
    marker is the first recorded point (the end of segment 1). Short ticks show the heading.
    Call only after `plot_comparison` has selected the Agg backend.
    """
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    start = {"marker": "o", "color": "green", "linestyle": "none"}
    crash = {"marker": "x", "color": "red", "markersize": 8, "markeredgewidth": 2,
             "linestyle": "none"}
    ncols = min(4, len(pairs))
    nrows = math.ceil(len(pairs) / ncols)
    legend_height = 0.5  # inches below the panels
    height = 3.2 * nrows + legend_height + 0.4
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.2 * ncols, height), squeeze=False)
    half = arena_size / 2.0
    episode = np.asarray(columns["episode"])
    for ax, (p, estimator) in zip(axes.flat, pairs, strict=False):
        mask = pair_mask(columns, p, estimator)
        rows = np.flatnonzero(mask & (episode == episode[mask].min()))
        rows = rows[np.argsort(np.asarray(columns["segment"])[rows])]
        x, y, th = (np.asarray(columns[c], float)[rows] for c in ("x", "y", "theta"))
        hit = np.asarray(columns["collision"])[rows] > 0
        ax.plot([-half, half, half, -half, -half], [-half, -half, half, half, -half],
                color="black", linewidth=2)
        ax.plot(x, y, color=colors[p], marker=".", markersize=4)
        tick = 0.06 * arena_size
        ax.quiver(x, y, tick * np.cos(th), tick * np.sin(th), color=colors[p], angles="xy",
                  scale_units="xy", scale=1, width=0.006, alpha=0.6)
        ax.plot(x[:1], y[:1], **start)
        ax.plot(x[hit], y[hit], **crash)
        margin = 0.05 * arena_size
        ax.set_xlim(-half - margin, half + margin)
        ax.set_ylim(-half - margin, half + margin)
        ax.set_aspect("equal")
        ax.set_title(f"{p} (episode {episode[rows[0]]})", color=colors[p], fontsize="medium")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    for ax in axes.flat[len(pairs):]:
        ax.set_axis_off()
    handles = [
        Line2D([], [], color="black", linewidth=2, label="walls"),
        Line2D([], [], color="gray", marker=".", label="path (segment ends), heading ticks"),
        Line2D([], [], **start, label="start (segment 1 end)"),
        Line2D([], [], **crash, label="collision"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize="small")
    fig.suptitle("Trajectories of the first episode (true pose at segment ends)")
    fig.tight_layout(rect=(0, legend_height / height, 1, 1))
    path = out / "trajectories.png"
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path
