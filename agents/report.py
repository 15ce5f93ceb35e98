"""Summaries, a text table and plots of an `excite compare` run.

The input is the per-segment record of a comparison, as columns (equal-length numpy arrays)
loaded from ``DIR/segments.csv``: one row per (protocol, estimator, episode, segment), with
the signed relative errors ``r_L_err, r_R_err, b_err`` of the estimate against the hidden
truth, the information measure ``sigma_min`` (dimensionless, see docs/conventions.md), the
per-episode
ceiling ``oracle_sigma_min``, the Cramér–Rao relative stds ``rel_std_r_L, rel_std_r_R,
rel_std_b``, the estimator's ``nees`` against the truth over ``nees_dof`` parameters,
``collision`` (0/1), the true end pose ``x, y`` (m), ``theta`` (rad), the cumulative
``distance`` (m) and ``time`` (s) driven.

Computation: `summarize` reduces each (protocol, estimator) pair's episodes to medians with
percentile bootstrap 95% intervals and the decision metrics of :mod:`agents.metrics` and
:mod:`excite.stats.consistency`. Presentation: `format_table` prints that summary;
`plot_comparison` draws errors, sigma_min and ANEES against the segment count, and the
trajectories of the first episode.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from agents.metrics import N_BOOT, error_time_area, paired_ratio, time_to_accuracy
from excite.core.models import AXLE
from excite.estimators import DEFAULT_ESTIMATOR
from excite.stats.consistency import CONFIDENCE, anees_bounds, verdict

PARAMETERS = AXLE.names
UNDETERMINED_REL_STD = 0.1  # a parameter whose median final relative std exceeds this is flagged
#: Accuracy thresholds of the time to accuracy (max relative error; keys of the summary).
THRESHOLDS = {"0.5%": 0.005, "0.2%": 0.002}
#: The threshold of the paired time ratio (a key of THRESHOLDS).
RATIO_THRESHOLD = "0.2%"
#: The protocol the paired ratios put over each baseline (its label, or its name with
#: settings: ``learned:margin=0.1``).
REFERENCE = "learned"
ORACLE_LABEL = "oracle (E-optimal, true params)"
DPI = 110
MAX_WIDTH = 100  # characters per table line


def _json_float(value: float) -> float | None:
    """A plain Python float, or None for inf / nan (so `json.dumps(allow_nan=False)` works)."""
    value = float(value)
    return value if math.isfinite(value) else None


def _pairs(columns: dict[str, np.ndarray]) -> list[tuple[str, str]]:
    """(protocol, estimator) pairs in the order of their first appearance in the rows."""
    protocol = np.asarray(columns["protocol"]).astype(str).tolist()
    estimator = np.asarray(columns["estimator"]).astype(str).tolist()
    return list(dict.fromkeys(zip(protocol, estimator, strict=True)))


def _pair_mask(columns: dict[str, np.ndarray], protocol: str,
               estimator: str = DEFAULT_ESTIMATOR) -> np.ndarray:
    """Boolean mask of one (protocol, estimator) pair's rows."""
    return ((np.asarray(columns["protocol"]).astype(str) == protocol)
            & (np.asarray(columns["estimator"]).astype(str) == estimator))


def _last_rows(columns: dict[str, np.ndarray], protocol: str,
               estimator: str = DEFAULT_ESTIMATOR) -> np.ndarray:
    """Row indices of each episode's last segment for one pair, ordered by episode."""
    rows = np.flatnonzero(_pair_mask(columns, protocol, estimator))
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


def final_max_errors(columns: dict[str, np.ndarray], protocol: str,
                     estimator: str = DEFAULT_ESTIMATOR) -> np.ndarray:
    """One pair's final max relative error (the last segment's max of |r_L_err|, |r_R_err|,
    |b_err|) per episode, ordered by episode."""
    return _max_abs_error(columns)[_last_rows(columns, protocol, estimator)]


def _median_ci(values: np.ndarray, resample: np.ndarray) -> dict[str, float | list | None]:
    """Median of `values` and the percentile bootstrap interval (CONFIDENCE) of the median.

    resample: (n_boot, n) indices into `values`, one bootstrap sample per row.
    """
    tail = 50.0 * (1.0 - CONFIDENCE)
    with np.errstate(invalid="ignore"):
        boot = np.median(values[resample], axis=1)
        lo, hi = np.percentile(boot, [tail, 100.0 - tail], method="inverted_cdf")
    return {"median": _json_float(np.median(values)), "ci95": [_json_float(lo), _json_float(hi)]}


def _by_episode(columns: dict[str, np.ndarray], mask: np.ndarray,
                values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Episode numbers, segment numbers 1..K and the (episodes, K) matrix of `values` over
    the rows of `mask` (one pair, or one protocol). Missing (episode, segment) cells are
    nan."""
    episodes, ep_index = np.unique(np.asarray(columns["episode"])[mask], return_inverse=True)
    segment = np.asarray(columns["segment"], int)[mask]
    matrix = np.full((episodes.size, segment.max()), np.nan)
    matrix[ep_index, segment - 1] = np.asarray(values, float)[mask]
    return episodes, np.arange(1, segment.max() + 1), matrix


def _time_to_accuracy(max_error: np.ndarray, time: np.ndarray, distance: np.ndarray,
                      resample: np.ndarray) -> tuple[dict, dict[str, np.ndarray]]:
    """Per threshold: medians with intervals of the segments, seconds and metres to
    accuracy, and the censored count; and the per-episode segments (inf: censored)."""
    out, segments = {}, {}
    for key, threshold in THRESHOLDS.items():
        reached = time_to_accuracy(max_error, threshold, time, distance)
        out[key] = {
            "threshold": threshold,
            "segments": _median_ci(reached.segments, resample),
            "seconds": _median_ci(reached.seconds, resample),
            "metres": _median_ci(reached.metres, resample),
            "censored": int(reached.censored.sum()),
        }
        segments[key] = reached.segments
    return out, segments


def _consistency(nees: np.ndarray, dof: np.ndarray) -> dict:
    """ANEES (episodes' mean NEES) at the last segment and per segment against the bounds
    of a consistent estimator (nees: (M, K) matrix; dof: the pair's nees_dof values)."""
    parameters = int(np.max(dof))
    bounds = anees_bounds(nees.shape[0], parameters)
    per_segment = nees.mean(axis=0)
    with np.errstate(invalid="ignore"):
        inside = (per_segment >= bounds[0]) & (per_segment <= bounds[1])
    final = float(per_segment[-1])
    return {
        "final": _json_float(final),
        "bounds": list(bounds),
        "verdict": verdict(final, bounds),
        "parameters": parameters,
        "segments_inside": float(inside.mean()),
    }


def _summarize_pair(columns: dict[str, np.ndarray], protocol: str, estimator: str,
                    rng: np.random.Generator, n_boot: int) -> tuple[dict, dict[str, np.ndarray]]:
    """Summary of one (protocol, estimator) pair (see `summarize`), and its per-episode
    values the paired ratios compare: ``final_max_error`` and the segments to each
    threshold, ordered by episode, with ``episode`` the episode numbers."""
    last = _last_rows(columns, protocol, estimator)
    mask = _pair_mask(columns, protocol, estimator)
    n = last.size
    resample = rng.integers(0, n, size=(n_boot, n))
    sigma = np.asarray(columns["sigma_min"], float)[last]
    oracle = np.asarray(columns["oracle_sigma_min"], float)[last]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = sigma / oracle
    collisions = np.asarray(columns["collision"], float)
    episodes = np.asarray(columns["episode"])[mask]
    per_episode = np.bincount(np.unique(episodes, return_inverse=True)[1], collisions[mask])
    rel_std = {p: np.median(np.asarray(columns[f"rel_std_{p}"], float)[last]) for p in PARAMETERS}
    episode, _, max_error = _by_episode(columns, mask, _max_abs_error(columns))
    time = _by_episode(columns, mask, columns["time"])[2]
    distance = _by_episode(columns, mask, columns["distance"])[2]
    nees = _by_episode(columns, mask, columns["nees"])[2]
    accuracy, to_accuracy = _time_to_accuracy(max_error, time, distance, resample)
    final = final_max_errors(columns, protocol, estimator)
    summary = {
        "episodes": int(n),
        "segments": int(np.max(np.asarray(columns["segment"])[mask])),
        "final_max_error": _median_ci(final, resample),
        "final_error": {
            p: _json_float(np.median(np.abs(np.asarray(columns[f"{p}_err"], float)[last])))
            for p in PARAMETERS
        },
        "sigma_min": _median_ci(sigma, resample),
        "ratio_to_oracle": _median_ci(ratio, resample),
        "distance_m": _json_float(np.median(np.asarray(columns["distance"], float)[last])),
        "collisions": {
            "total": int(round(collisions[mask].sum())),
            "per_episode": float(per_episode.mean()),
        },
        "undetermined": [
            p for p in PARAMETERS if not rel_std[p] <= UNDETERMINED_REL_STD  # nan counts too
        ],
        "time_to_accuracy": accuracy,
        "error_time_area": _median_ci(error_time_area(max_error, time), resample),
        "anees": _consistency(nees, np.asarray(columns["nees_dof"])[mask]),
    }
    return summary, {"episode": episode, "final_max_error": final, **to_accuracy}


def reference_protocol(protocols: list[str], reference: str = REFERENCE) -> str | None:
    """The first protocol label that is ``reference`` or ``reference`` with settings
    (``learned:margin=0.1``); None when there is none."""
    return next((p for p in protocols if p == reference or p.startswith(reference + ":")),
                None)


def _censored_bound(reference: np.ndarray, baseline: np.ndarray,
                    segments: int) -> dict[str, float]:
    """What a ratio of medians of times to accuracy still says when a median is censored
    (not reached within ``segments``, so beyond it): ``{"at_most": r}`` when only the
    baseline's is, ``{"at_least": r}`` when only the reference's is, else nothing."""
    ours, theirs = float(np.median(reference)), float(np.median(baseline))
    if math.isfinite(ours) and not math.isfinite(theirs):
        return {"at_most": ours / segments}
    if math.isfinite(theirs) and not math.isfinite(ours):
        return {"at_least": segments / theirs}
    return {}


def _paired(reference: dict[str, np.ndarray], baseline: dict[str, np.ndarray],
            segments: int, rng: np.random.Generator, n_boot: int) -> dict:
    """reference / baseline ratios of medians over their common episodes, with paired
    bootstrap intervals: the final max error and the segments to RATIO_THRESHOLD (a ratio
    with a censored median is None, with the bound it still gives, see _censored_bound)."""
    common, ours, theirs = np.intersect1d(reference["episode"], baseline["episode"],
                                          return_indices=True)
    out: dict = {"episodes": int(common.size)}
    for key, name in (("final_max_error", "final_max_error"),
                      (RATIO_THRESHOLD, f"time_to_{RATIO_THRESHOLD}")):
        if not common.size:
            out[name] = {"ratio": None, "ci95": [None, None]}
            continue
        num, den = reference[key][ours], baseline[key][theirs]
        result = paired_ratio(num, den, rng, n_boot)
        bound = _censored_bound(num, den, segments) if key == RATIO_THRESHOLD else {}
        ci = [None, None] if bound else [_json_float(result.ci[0]), _json_float(result.ci[1])]
        out[name] = {"ratio": None if bound else _json_float(result.ratio), "ci95": ci, **bound}
    return out


def summarize(columns: dict[str, np.ndarray], seed: int = 0, n_boot: int = N_BOOT,
              reference: str = REFERENCE) -> dict:
    """Per-(protocol, estimator) summary of a comparison.

    Args:
        columns: the segment record (see the module docstring), equal-length arrays.
        seed: seed of the numpy Generator drawing the bootstrap resamples.
        n_boot: number of bootstrap resamples of the episodes.
        reference: the protocol the paired ratios put over each baseline (a label, or a
            name whose labels with settings count too); no ratios when it did not run.

    Returns:
        ``{"protocols": {protocol: {estimator: {...}}}, "oracle_sigma_min": {"median"},
        "reference": label or None, "thresholds": THRESHOLDS, "bootstrap": {...}}``,
        protocols and estimators in order of first appearance. Per pair:

        - ``episodes``, ``segments`` (K);
        - ``final_max_error`` (relative, ``{"median", "ci95": [lo, hi]}``), ``final_error``
          (median |relative error| per parameter);
        - ``sigma_min`` and ``ratio_to_oracle`` (dimensionless, median and ci95),
          ``distance_m`` (median path length, m), ``collisions`` (``{"total",
          "per_episode"}``), ``undetermined`` (parameters whose median final Cramér–Rao
          relative std exceeds 10%);
        - ``time_to_accuracy``: per threshold key (``"0.5%"``, ``"0.2%"``) ``threshold``
          (relative), ``segments``, ``seconds`` (s) and ``metres`` (m) driven until the max
          relative error stays below it (median and ci95; an episode that does not end below
          is censored, counted as later than all others, so a median or bound beyond the
          reached episodes is None: "not reached within K segments"), and ``censored`` (the
          number of such episodes);
        - ``error_time_area``: the area under the max relative error over time from the end
          of segment 1 to the end of the last (relative error x s; median and ci95);
        - ``anees``: ``final`` (the mean over episodes of the last segment's NEES, None when
          a covariance says nothing), ``bounds`` ([lo, hi], the two-sided 95% chi-square
          interval of a consistent estimator for these episodes and ``parameters``),
          ``verdict`` ("consistent", "over-confident", "under-confident", "undefined") and
          ``segments_inside`` (the share of segments 1..K whose ANEES is inside the bounds);
        - ``vs_reference`` (baselines only, when the reference ran with the same estimator):
          ``episodes`` (paired), ``final_max_error`` and ``time_to_0.2%`` (segments), each
          ``{"ratio", "ci95"}``: the reference's median over the baseline's (below 1: the
          reference is better), with a paired percentile bootstrap interval over episodes
          (:func:`agents.metrics.paired_ratio`; None where undefined). When only one median
          time is censored (beyond K segments) the ratio and its interval are None and the
          entry says what is known: ``at_most`` (reference median / K, the baseline's censored) or
          ``at_least`` (K / baseline median, the reference's censored).

        The ci95 of medians are percentile bootstrap intervals over episodes (resampled
        jointly for all metrics of a pair). Only plain ints, floats, str, lists, dicts and
        None (for inf / nan) appear.
    """
    rng = np.random.default_rng(seed)
    pairs = _pairs(columns)
    protocols: dict[str, dict[str, dict]] = {}
    per_episode: dict[tuple[str, str], dict[str, np.ndarray]] = {}
    for protocol, estimator in pairs:
        entry, per_episode[protocol, estimator] = _summarize_pair(
            columns, protocol, estimator, rng, n_boot)
        protocols.setdefault(protocol, {})[estimator] = entry
    ref = reference_protocol(list(protocols), reference)
    if ref is not None:
        for protocol, estimator in pairs:
            if protocol != ref and (ref, estimator) in per_episode:
                protocols[protocol][estimator]["vs_reference"] = _paired(
                    per_episode[ref, estimator], per_episode[protocol, estimator],
                    protocols[protocol][estimator]["segments"], rng, n_boot)
    return {
        "protocols": protocols,
        "oracle_sigma_min": {"median": _json_float(_oracle_median(columns))},
        "reference": ref,
        "thresholds": dict(THRESHOLDS),
        "bootstrap": {"seed": int(seed), "n_boot": int(n_boot), "confidence": CONFIDENCE},
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


def _render(headers: list[str], rows: list[list[str]], left: set[int]) -> list[str]:
    """Fixed-width lines (header, rule, rows): columns in `left` left-aligned, the others
    right-aligned, separated by two spaces, or one when two would exceed MAX_WIDTH."""
    widths = [max(len(r[i]) for r in [headers, *rows]) for i in range(len(headers))]
    gap = "  " if sum(widths) + 2 * (len(widths) - 1) <= MAX_WIDTH else " "

    def line(cells: list[str]) -> str:
        pairs = enumerate(zip(cells, widths, strict=True))
        return gap.join(c.ljust(w) if i in left else c.rjust(w) for i, (c, w) in pairs).rstrip()

    return [line(headers), "-" * len(line(headers)), *(line(r) for r in rows)]


def _time_cell(entry: dict, segments: int) -> str:
    """Median segments to accuracy; ">K" when not reached in most episodes; "(n)" the
    censored episodes."""
    median = entry["segments"]["median"]
    cell = f">{segments}" if median is None else _num(median)
    return cell + (f"({entry['censored']})" if entry["censored"] else "")


#: The ANEES cell's mark per verdict.
_VERDICT_MARK = {"consistent": "", "over-confident": "+", "under-confident": "-",
                 "undefined": ""}


def _ratio_cell(entry: dict) -> str:
    """A paired ratio with its interval; "<r" / ">r" for the bound of a censored median."""
    lo, hi = entry["ci95"]
    if "at_most" in entry:
        return f"<{_num(entry['at_most'], 2)}"
    if "at_least" in entry:
        return f">{_num(entry['at_least'], 2)}"
    return f"{_num(entry['ratio'], 2)} [{_num(lo, 2)}, {_num(hi, 2)}]"


def format_table(summary: dict) -> str:
    """Fixed-width text of a `summarize` result: one row per (protocol, estimator), best
    (lowest error) first; then, when the reference ran, its paired ratios over each baseline.

    maxerr% is the median over episodes of the final max |relative error| (%), with the 95%
    interval of that median; t<0.5%, t<0.2% the median segments until the max error stays
    below 0.5% and 0.2% (">K": not reached in most episodes; "(n)": n episodes censored);
    smin the median sigma_min (dimensionless), /oracle the median ratio to the per-episode
    oracle, dist the median path length (m), coll the number of segments ending in a
    collision, ANEES the estimator's final ANEES ("+" above its 95% chi-square bounds:
    over-confident, "-" below), undetermined the parameters the data leave open. The
    estimator column appears when more than one ran. Labels show each protocol's settings
    (tuned or given). Lines fit in 100 columns for realistic values and labels up to about
    16 characters; longer labels widen the table. The seconds and metres to accuracy and
    the error-time area are in summary.json.
    """
    entries = [(p, e, s) for p, by_estimator in summary["protocols"].items()
               for e, s in by_estimator.items()]
    several = len({e for _, e, _ in entries}) > 1

    def error(entry: dict) -> float:
        median = entry["final_max_error"]["median"]
        return math.inf if median is None else median

    best = {p: min(error(s) for s in by_estimator.values())
            for p, by_estimator in summary["protocols"].items()}
    order = {e: i for i, e in enumerate(dict.fromkeys(e for _, e, _ in entries))}

    def sort_key(item: tuple[str, str, dict]) -> tuple[float, int]:
        """Protocols by their best estimator's error, each protocol's estimators together."""
        return best[item[0]], order[item[1]]

    headers = ["protocol", *(["estimator"] if several else []), "maxerr%", "95% CI",
               "t<0.5%", "t<0.2%", "smin", "/oracle", "dist m", "coll", "ANEES",
               "undetermined"]
    rows = []
    for protocol, estimator, s in sorted(entries, key=sort_key):
        lo, hi = s["final_max_error"]["ci95"]
        anees = s["anees"]
        rows.append([
            protocol, *([estimator] if several else []),
            _pct(s["final_max_error"]["median"]),
            f"[{_pct(lo, 2)}, {_pct(hi, 2)}]",
            *(_time_cell(s["time_to_accuracy"][key], s["segments"]) for key in THRESHOLDS),
            _num(s["sigma_min"]["median"]),
            _num(s["ratio_to_oracle"]["median"], 2),
            _num(s["distance_m"], 2),
            str(s["collisions"]["total"]),
            _num(anees["final"]) + _VERDICT_MARK[anees["verdict"]],
            ",".join(s["undetermined"]) or "-",
        ])
    body = _render(headers, rows, {0, 1, len(headers) - 1} if several else {0, len(headers) - 1})
    oracle = summary["oracle_sigma_min"]["median"]
    body.append(f"oracle sigma_min (E-optimal design, true params): median {_num(oracle)}")
    body.append("maxerr%: median final max |relative error| [95% bootstrap CI]; t<x%: median "
                "segments until below x%")
    bounds = {(s["episodes"], s["anees"]["parameters"]): s["anees"]["bounds"]
              for _, _, s in entries}
    body.append("ANEES 95% bounds: " + "; ".join(
        f"[{_num(lo)}, {_num(hi)}] ({m} episodes x {p} parameters)"
        for (m, p), (lo, hi) in bounds.items()) + "; + over-, - under-confident")
    reference = summary.get("reference")
    ratios = [(p, e, s["vs_reference"]) for p, e, s in sorted(entries, key=sort_key)
              if "vs_reference" in s]
    if reference and ratios:
        key = f"time_to_{RATIO_THRESHOLD}"
        headers = ["baseline", *(["estimator"] if several else []), "final maxerr",
                   f"time to {RATIO_THRESHOLD}"]
        rows = [[p, *([e] if several else []), _ratio_cell(r["final_max_error"]),
                 _ratio_cell(r[key])] for p, e, r in ratios]
        body += ["", f"reference: {reference}",
                 "reference / baseline: ratio of medians over the same episodes [paired "
                 "bootstrap 95% CI]",
                 "below 1: the reference is better; <r: the baseline's median time is beyond "
                 "the budget", *_render(headers, rows, {0, 1} if several else {0})]
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
    return "\n".join([
        *_render(headers, rows, {0, 1}),
        f"{document['episodes']} tuning episodes of {document['segments']} segments on "
        f"{document['env_id']} ({document['robot']} robot); maxerr%: {document['criterion']}",
    ])


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
    origin, collisions as red x). One line per (protocol, estimator), named by the labels
    with their settings (:func:`pair_labels`), in one color across the figures.

    Returns:
        The paths of the four files written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pairs = _pairs(columns)
    labels = pair_labels(pairs)
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colors = {pair: cycle[i % len(cycle)] for i, pair in enumerate(pairs)}
    paths = []

    figures = [
        (100.0 * _max_abs_error(columns), "errors_vs_segment.png",
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
            mask = _pair_mask(columns, *pair)
            _, seg, matrix = _by_episode(columns, mask, values)
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
            ax.axhline(_oracle_median(columns), color="black", linestyle="--",
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
    return paths


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
        mask = _pair_mask(columns, p, estimator)
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
