"""Summaries, a text table and plots of an `excite compare` run.

The input is the per-segment record of a comparison, as columns (equal-length numpy arrays)
loaded from ``DIR/segments.csv``: one row per (protocol, episode, segment), with the signed
relative errors ``r_L_err, r_R_err, b_err`` of the online estimate against the hidden truth,
the information measure ``sigma_min`` (dimensionless, see DESIGN.md), the per-episode ceiling
``oracle_sigma_min``, the Cramér–Rao relative stds ``rel_std_r_L, rel_std_r_R, rel_std_b``,
``collision`` (0/1), the true end pose ``x, y`` (m), ``theta`` (rad) and the cumulative
``distance`` (m).

`summarize` reduces each episode to its last segment and gives medians with percentile
bootstrap 95% intervals over episodes; `format_table` prints that summary; `plot_comparison`
draws errors and sigma_min against the segment count, and the trajectories of episode 0.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

PARAMETERS = ("r_L", "r_R", "b")
UNDETERMINED_REL_STD = 0.1  # a parameter whose median final relative std exceeds this is flagged
ORACLE_LABEL = "oracle (E-optimal, true params)"
DPI = 110
MAX_WIDTH = 100  # characters per table line


def _json_float(value: float) -> float | None:
    """A plain Python float, or None for inf / nan (so `json.dumps(allow_nan=False)` works)."""
    value = float(value)
    return value if math.isfinite(value) else None


def _protocols(columns: dict[str, np.ndarray]) -> list[str]:
    """Protocol names in the order of their first appearance in the rows."""
    names = np.asarray(columns["protocol"]).astype(str)
    _, first = np.unique(names, return_index=True)
    return [str(names[i]) for i in np.sort(first)]


def _last_rows(columns: dict[str, np.ndarray], protocol: str) -> np.ndarray:
    """Row indices of each episode's last segment for one protocol, ordered by episode."""
    rows = np.flatnonzero(np.asarray(columns["protocol"]).astype(str) == protocol)
    episode = np.asarray(columns["episode"])[rows]
    order = np.lexsort((np.asarray(columns["segment"])[rows], episode))
    rows, episode = rows[order], episode[order]
    is_last = np.append(episode[1:] != episode[:-1], True)
    return rows[is_last]


def _oracle_median(columns: dict[str, np.ndarray]) -> float:
    """Median over episodes of the per-episode oracle sigma_min (dimensionless)."""
    _, first = np.unique(np.asarray(columns["episode"]), return_index=True)
    return float(np.median(np.asarray(columns["oracle_sigma_min"], float)[first]))


def _max_abs_error(columns: dict[str, np.ndarray]) -> np.ndarray:
    """Per-row max(|r_L_err|, |r_R_err|, |b_err|) (relative, dimensionless)."""
    errors = np.column_stack([np.asarray(columns[f"{p}_err"], float) for p in PARAMETERS])
    return np.max(np.abs(errors), axis=1)


def final_max_errors(columns: dict[str, np.ndarray], protocol: str) -> np.ndarray:
    """One protocol's final max relative error (the last segment's max of |r_L_err|,
    |r_R_err|, |b_err|) per episode, ordered by episode."""
    return _max_abs_error(columns)[_last_rows(columns, protocol)]


def _median_ci(values: np.ndarray, resample: np.ndarray) -> dict[str, float | list | None]:
    """Median of `values` and the 95% percentile bootstrap interval of the median.

    resample: (n_boot, n) indices into `values`, one bootstrap sample per row.
    """
    with np.errstate(invalid="ignore"):
        boot = np.median(values[resample], axis=1)
        lo, hi = np.percentile(boot, [2.5, 97.5])
    return {"median": _json_float(np.median(values)), "ci95": [_json_float(lo), _json_float(hi)]}


def _summarize_protocol(
    columns: dict[str, np.ndarray], protocol: str, rng: np.random.Generator, n_boot: int
) -> dict:
    """Summary of one protocol over its episodes' last segments (see `summarize`)."""
    last = _last_rows(columns, protocol)
    n = last.size
    resample = rng.integers(0, n, size=(n_boot, n))
    sigma = np.asarray(columns["sigma_min"], float)[last]
    oracle = np.asarray(columns["oracle_sigma_min"], float)[last]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = sigma / oracle
    collisions = np.asarray(columns["collision"], float)
    rows = np.asarray(columns["protocol"]).astype(str) == protocol
    episodes = np.asarray(columns["episode"])[rows]
    per_episode = np.bincount(np.unique(episodes, return_inverse=True)[1], collisions[rows])
    rel_std = {p: np.median(np.asarray(columns[f"rel_std_{p}"], float)[last]) for p in PARAMETERS}
    return {
        "episodes": int(n),
        "segments": int(np.max(np.asarray(columns["segment"])[rows])),
        "final_max_error": _median_ci(final_max_errors(columns, protocol), resample),
        "final_error": {
            p: _json_float(np.median(np.abs(np.asarray(columns[f"{p}_err"], float)[last])))
            for p in PARAMETERS
        },
        "sigma_min": _median_ci(sigma, resample),
        "ratio_to_oracle": _median_ci(ratio, resample),
        "distance_m": _json_float(np.median(np.asarray(columns["distance"], float)[last])),
        "collisions": {
            "total": int(round(collisions[rows].sum())),
            "per_episode": float(per_episode.mean()),
        },
        "undetermined": [
            p for p in PARAMETERS if not rel_std[p] <= UNDETERMINED_REL_STD  # nan counts too
        ],
    }


def summarize(columns: dict[str, np.ndarray], seed: int = 0, n_boot: int = 2000) -> dict:
    """Per-protocol summary of a comparison, from each episode's last segment.

    Args:
        columns: the segment record (see the module docstring), equal-length arrays.
        seed: seed of the numpy Generator drawing the bootstrap resamples.
        n_boot: number of bootstrap resamples of the episodes.

    Returns:
        ``{"protocols": {name: {...}}, "oracle_sigma_min": {"median"}, "bootstrap": {...}}``,
        protocols in order of first appearance. Per protocol: ``episodes``, ``segments`` (K),
        ``final_max_error`` (relative, ``{"median", "ci95": [lo, hi]}``), ``final_error``
        (median |relative error| per parameter), ``sigma_min`` and ``ratio_to_oracle``
        (dimensionless, median and ci95), ``distance_m`` (median path length, m),
        ``collisions`` (``{"total", "per_episode"}``) and ``undetermined`` (parameters whose
        median final Cramér–Rao relative std exceeds 10%). The ci95 are percentile bootstrap
        intervals of the median over episodes (episodes resampled jointly for all metrics of
        a protocol). Only plain ints, floats, lists, dicts and None (for inf / nan) appear.
    """
    rng = np.random.default_rng(seed)
    protocols = {p: _summarize_protocol(columns, p, rng, n_boot) for p in _protocols(columns)}
    return {
        "protocols": protocols,
        "oracle_sigma_min": {"median": _json_float(_oracle_median(columns))},
        "bootstrap": {"seed": int(seed), "n_boot": int(n_boot), "confidence": 0.95},
    }


def _num(value: float | None, digits: int = 3) -> str:
    """`value` with `digits` significant digits (no exponent above 10**digits); "n/a" for None."""
    if value is None:
        return "n/a"
    if abs(value) >= 10**digits:
        return f"{value:.0f}"
    return f"{value:.{digits}g}"


def _pct(value: float | None, digits: int = 3) -> str:
    """A relative value (0.01 = 1%) as a percentage with `digits` significant digits."""
    return _num(None if value is None else 100.0 * value, digits)


def format_table(summary: dict) -> str:
    """Fixed-width text table of a `summarize` result, best protocol (lowest error) first.

    Errors are medians over episodes of the final |relative error|, in %; the 95% interval is
    that of the median max error. smin is the median sigma_min (dimensionless), /oracle the
    median ratio to the per-episode oracle, dist the median path length (m), coll the total
    number of segments ending in a collision. Lines fit in 100 columns for realistic values
    and labels up to about 16 characters (columns are separated by one space instead of two
    when needed); longer labels (protocols with settings) widen the table.
    """
    headers = ["protocol", "maxerr%", "95% CI", "r_L%", "r_R%", "b%", "smin", "/oracle",
               "dist m", "coll", "undetermined"]
    left = {0, len(headers) - 1}

    def sort_key(item: tuple[str, dict]) -> float:
        median = item[1]["final_max_error"]["median"]
        return math.inf if median is None else median

    rows = []
    for name, s in sorted(summary["protocols"].items(), key=sort_key):
        lo, hi = s["final_max_error"]["ci95"]
        rows.append([
            name,
            _pct(s["final_max_error"]["median"]),
            f"[{_pct(lo, 2)}, {_pct(hi, 2)}]",
            *(_pct(s["final_error"][p]) for p in PARAMETERS),
            _num(s["sigma_min"]["median"]),
            _num(s["ratio_to_oracle"]["median"], 2),
            _num(s["distance_m"], 2),
            str(s["collisions"]["total"]),
            ",".join(s["undetermined"]) or "-",
        ])
    widths = [max(len(r[i]) for r in [headers, *rows]) for i in range(len(headers))]
    gap = "  " if sum(widths) + 2 * (len(widths) - 1) <= MAX_WIDTH else " "

    def line(cells: list[str]) -> str:
        pairs = enumerate(zip(cells, widths, strict=True))
        return gap.join(c.ljust(w) if i in left else c.rjust(w) for i, (c, w) in pairs).rstrip()

    body = [line(headers), "-" * len(line(headers)), *(line(r) for r in rows)]
    oracle = summary["oracle_sigma_min"]["median"]
    body.append(f"oracle sigma_min (E-optimal design, true params): median {_num(oracle)}")
    body.append("errors: median |relative error| of the final estimate over episodes; "
                "95% CI: bootstrap of maxerr%")
    return "\n".join(body)


def format_tuning(document: dict) -> str:
    """Text table of a tuned-settings document (``excite tune``): per protocol the winning
    settings (the protocol written with them), its median final max error (%) over the tuning
    episodes and that at the declared defaults."""
    headers = ["protocol", "tuned", "maxerr%", "at defaults", "candidates"]
    rows = [[label, entry["label"],
             _pct(entry["final_max_error"]), _pct(entry["default_final_max_error"]),
             str(len(entry["candidates"]))]
            for label, entry in document["protocols"].items()]
    widths = [max(len(r[i]) for r in [headers, *rows]) for i in range(len(headers))]

    def line(cells: list[str]) -> str:
        return "  ".join(c.ljust(w) if i < 2 else c.rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    return "\n".join([
        line(headers), "-" * len(line(headers)), *(line(r) for r in rows),
        f"{document['episodes']} tuning episodes of {document['segments']} segments on "
        f"{document['env_id']} ({document['robot']} robot); maxerr%: {document['criterion']}",
    ])


def _by_segment(
    columns: dict[str, np.ndarray], protocol: str, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Segment numbers 1..K and the (episodes, K) matrix of `values` for one protocol.

    Missing (episode, segment) cells are nan.
    """
    rows = np.asarray(columns["protocol"]).astype(str) == protocol
    _, ep_index = np.unique(np.asarray(columns["episode"])[rows], return_inverse=True)
    segment = np.asarray(columns["segment"], int)[rows]
    matrix = np.full((ep_index.max() + 1, segment.max()), np.nan)
    matrix[ep_index, segment - 1] = values[rows]
    return np.arange(1, segment.max() + 1), matrix


def plot_comparison(
    columns: dict[str, np.ndarray], out_dir: str | Path, arena_size: float = 4.0
) -> list[Path]:
    """Write the comparison plots as PNG files into `out_dir` (created if missing).

    Figures: ``errors_vs_segment.png`` (max relative error, %, median and 25-75% band over
    episodes, log scale), ``sigma_min_vs_segment.png`` (median and band, with the median
    oracle as a dashed line) and ``trajectories.png`` (episode 0's true path per protocol in
    the square arena of side `arena_size` (m) centred at the origin, collisions as red x).
    Each protocol keeps one color across the figures.

    Returns:
        The paths of the three files written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    protocols = _protocols(columns)
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colors = {p: cycle[i % len(cycle)] for i, p in enumerate(protocols)}
    paths = []

    figures = [
        (100.0 * _max_abs_error(columns), "errors_vs_segment.png",
         "max relative error of r_L, r_R, b (%)",
         "Estimate error vs segments (median, 25-75% band over episodes)", None),
        (np.asarray(columns["sigma_min"], float), "sigma_min_vs_segment.png",
         "sigma_min (dimensionless, larger is better)",
         "Information sigma_min vs segments (median, 25-75% band over episodes)",
         _oracle_median(columns)),
    ]
    for values, name, ylabel, title, ceiling in figures:
        fig, ax = plt.subplots(figsize=(9.0, 4.8))
        for p in protocols:
            seg, matrix = _by_segment(columns, p, values)
            with np.errstate(invalid="ignore"):
                q25, q50, q75 = np.nanpercentile(matrix, [25, 50, 75], axis=0)
            ax.plot(seg, q50, marker=".", color=colors[p], label=p)
            ax.fill_between(seg, q25, q75, color=colors[p], alpha=0.2, linewidth=0)
        if ceiling is None:
            ax.set_yscale("log", nonpositive="mask")
        else:
            ax.axhline(ceiling, color="black", linestyle="--", label=ORACLE_LABEL)
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

    paths.append(_plot_trajectories(columns, protocols, colors, out, arena_size))
    return paths


def _plot_trajectories(
    columns: dict[str, np.ndarray], protocols: list[str], colors: dict[str, str], out: Path,
    arena_size: float,
) -> Path:
    """Grid of arena panels with each protocol's first episode path; returns the PNG path.

    The path joins the true positions (m) at the segment ends, in segment order; the start
    marker is the first recorded point (the end of segment 1). Short ticks show the heading.
    Call only after `plot_comparison` has selected the Agg backend.
    """
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    start = {"marker": "o", "color": "green", "linestyle": "none"}
    crash = {"marker": "x", "color": "red", "markersize": 8, "markeredgewidth": 2,
             "linestyle": "none"}
    ncols = min(4, len(protocols))
    nrows = math.ceil(len(protocols) / ncols)
    legend_height = 0.5  # inches below the panels
    height = 3.2 * nrows + legend_height + 0.4
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.2 * ncols, height), squeeze=False)
    half = arena_size / 2.0
    names = np.asarray(columns["protocol"]).astype(str)
    episode = np.asarray(columns["episode"])
    for ax, p in zip(axes.flat, protocols, strict=False):
        rows = np.flatnonzero((names == p) & (episode == episode[names == p].min()))
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
    for ax in axes.flat[len(protocols):]:
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
