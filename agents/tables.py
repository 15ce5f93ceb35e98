"""Fixed-width text tables of a comparison's summary and of tuned settings.

:func:`format_table` prints the summary of ``excite compare``
(:func:`agents.summary.summarize`, with the target section of
:func:`agents.target_summary.add_target` when there is one), :func:`format_tuning` a
tuned-settings document (``excite tune``).
"""

from __future__ import annotations

import math

from agents.summary import RATIO_THRESHOLD, THRESHOLDS

MAX_WIDTH = 100  # characters per table line


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
    """Fixed-width text of a :func:`agents.summary.summarize` result: one row per (protocol,
    estimator), best (lowest error) first; then, when the reference ran, its paired ratios
    over each baseline; then, with a target (:func:`agents.target_summary.add_target`), the
    time to target section: per pair the median segments, seconds and metres until the
    stopping rule said done (with bootstrap 95% intervals; ">b" a lower bound when half the
    episodes or more did not stop within the budget, "(n)" the episodes that did not), the
    false stops over the stops with a Wilson 95% interval (%), the median max relative error
    at the stop (%), and the reference's paired ratio of segments to target over each
    baseline.

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
    if any("target" in s for _, _, s in entries):
        body += ["", *_target_lines([(p, e, s) for p, e, s in sorted(entries, key=sort_key)],
                                    several, reference)]
    return "\n".join(body)


def _driven_cell(entry: dict, censored: int, digits: int = 3) -> str:
    """A median time to target with its interval: "m [lo, hi]"; ">b" (a lower bound) when
    the median is censored; an interval's end beyond the budget is inf; "(n)" the censored
    episodes."""
    lo, hi = (_num(v, 2) if v is not None else "inf" for v in entry["ci95"])
    cell = (f">{_num(entry['at_least'], digits)}" if entry["median"] is None
            else f"{_num(entry['median'], digits)} [{lo}, {hi}]")
    return cell + (f"({censored})" if censored else "")


def _target_lines(entries: list[tuple[str, str, dict]], several: bool,
                  reference: str | None) -> list[str]:
    """The target section of :func:`format_table`: per pair the time to target (segments,
    s, m), the false stops and the error at the stop; then, when the reference ran, its
    paired ratio of time to target over each baseline."""
    first = next(s["target"] for _, _, s in entries if "target" in s)
    headers = ["protocol", *(["estimator"] if several else []), "segments", "seconds",
               "metres", "false stops", "err@stop%"]
    rows = []
    for protocol, estimator, s in entries:
        t = s.get("target")
        if t is None:
            continue
        time, false, error = t["time_to_target"], t["false_stop_rate"], t["error_at_stop"]
        lo, hi = false["ci95"]
        err_lo, err_hi = error["ci95"]
        rows.append([
            protocol, *([estimator] if several else []),
            *(_driven_cell(time[key], time["censored"]) for key in ("segments", "seconds",
                                                                    "metres")),
            f"{false['false_stops']}/{false['stops']} [{_pct(lo, 2)}, {_pct(hi, 2)}]%",
            "n/a" if error["median"] is None else
            f"{_pct(error['median'])} [{_pct(err_lo, 2)}, {_pct(err_hi, 2)}]",
        ])
    lines = [f"time to target: the stopping rule says every parameter is within "
             f"{_pct(first['value'])}% at {first['confidence']:.0%} (budget "
             f"{first['budget']} segments)",
             "median [bootstrap 95% CI]; >b: half the robots or more not done (b a lower "
             "bound); (n): not done",
             "false stops: stopped with the truth outside the target / stops [Wilson 95% CI]",
             "err@stop%: median max |relative error| of r_L, r_R, b at the stop [95% CI]",
             *_render(headers, rows, {0, 1} if several else {0})]
    ratios = [(p, e, s["target"]["vs_reference"]) for p, e, s in entries
              if "vs_reference" in s.get("target", {})]
    if reference and ratios:
        headers = ["baseline", *(["estimator"] if several else []), "time to target"]
        rows = [[p, *([e] if several else []), _ratio_cell(r["time_to_target"])]
                for p, e, r in ratios]
        lines += ["", f"reference: {reference}",
                  "reference / baseline: median segments to target over the same episodes "
                  "[paired bootstrap 95% CI]",
                  *_render(headers, rows, {0, 1} if several else {0})]
    return lines


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
