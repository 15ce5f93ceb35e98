"""The text of a validation (``excite validate``, ``excite calibrate --holdout``): a table per
log and overall of the nominal and calibrated errors and their ratio, and verdict lines
(:mod:`excite.validation.verdict`), per log and overall. Presentation only."""

from __future__ import annotations

from excite.validation.dead_reckoning import PathErrors, ValidationResult
from excite.validation.verdict import MARGIN, METRIC, Verdict, tally

__all__ = ["summary", "verdict_line"]

_WORDS = {"better": "better than", "no better": "no better than", "worse": "worse than"}
_ADVICE = {"better": "use the calibration",
           "no better": f"the difference is within the margin (x{MARGIN:g} either way); the "
                        "nominal values do as well on these logs",
           "worse": "do not use the calibration; check that these logs are of the same robot "
                    "and sensor mounting, and calibrate on more varied driving"}


def _number(value: float | None) -> str:
    return f"{'-' if value is None else f'{value:.4g}':>15}"


def _rows(label: str, nominal: PathErrors, calibrated: PathErrors) -> list[str]:
    ratio = calibrated.ratio(nominal)
    return [label,
            *(f"  {what:<12}" + "".join(_number(value) for value in values.values())
              for what, values in (("nominal", nominal.to_dict()),
                                   ("calibrated", calibrated.to_dict()),
                                   ("ratio", ratio)))]


def _ratio_words(ratio: float | None) -> str:
    return "nominal error 0" if ratio is None else f"x{ratio:.3g}"


def verdict_line(result: ValidationResult) -> str:
    """The overall verdict in one line, with the per-log tally and what to do."""
    verdict: Verdict = result.verdict
    return (f"verdict: the calibrated robot dead-reckons {_WORDS[verdict]} the nominal one "
            f"(RMS path error {_ratio_words(result.ratio[METRIC])} overall; "
            f"{tally([log.verdict for log in result.logs])}): {_ADVICE[verdict]}")


def summary(result: ValidationResult) -> str:
    """A table per log (with its verdict) and overall, then the overall verdict line."""
    header = (f"  {'':<12}{'end pos [m]':>15}{'end head [rad]':>15}"
              f"{'RMS path [m]':>15}")
    lines = [f"excite validation: {len(result.logs)} log(s), dead reckoning from each "
             "log's first external pose", header]
    for log in result.logs:
        lines += _rows(log.file, log.nominal, log.calibrated)
        if log.umbmark is not None:
            u = log.umbmark
            lines.append(
                f"  UMBmark E_max,syst [m] ({u.count('cw')} cw, {u.count('ccw')} ccw "
                f"loops): nominal {u.nominal.e_max_syst:.4g}, calibrated "
                f"{u.calibrated.e_max_syst:.4g}, ratio {_number(u.ratio).strip()}")
        lines.append(f"  {'verdict':<12}{log.verdict} than nominal (RMS path error "
                     f"{_ratio_words(log.ratio[METRIC])})")
    lines += _rows("overall (mean over logs; ratio of the means)", result.nominal,
                   result.calibrated)
    lines.append(verdict_line(result))
    return "\n".join(lines)
