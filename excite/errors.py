"""excite's exceptions: one base class, so callers can catch everything excite raises on
purpose (bad data, bad settings) apart from programming errors."""

from __future__ import annotations

__all__ = ["ExciteError", "DataError", "EstimatorError", "MetricError", "one_line_repr"]


class ExciteError(Exception):
    """Base class of every error excite raises for bad input or settings."""


class DataError(ExciteError, ValueError):
    """Malformed or insufficient data; the message names the file and line (or topic) where
    known."""


class EstimatorError(ExciteError, ValueError):
    """Bad estimator settings: an unknown estimator name, a ``module:factory`` that does not
    import, or an invalid option (prior, window size, ...)."""


class MetricError(ExciteError, ValueError):
    """Arrays a metric cannot be computed from (shapes, thresholds, confidence levels)."""


def one_line_repr(value: object, width: int = 80) -> str:
    """``repr(value)`` on one line, cut to ``width`` characters: how error messages show a
    value a user's code returned."""
    text = " ".join(repr(value).split())
    return text if len(text) <= width else text[:width - 3] + "..."
