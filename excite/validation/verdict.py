"""The verdict of a validation: does the calibrated robot dead-reckon better than the nominal
one, no better, or worse?

Rule (one log, or overall)
--------------------------
The verdict compares the RMS path error (m) of the calibrated robot with the nominal robot's
(:class:`excite.validation.dead_reckoning.PathErrors`): it uses every pose sample, where an
end-point error is one sample that can be small by chance (drift that happens to return near
the measured path). With ratio = calibrated / nominal:

* ``better`` when ratio <= 1 / MARGIN;
* ``worse`` when ratio >= MARGIN;
* ``no better`` in between (a difference within the margin does not matter for use).

MARGIN (1.1: 10% either way) is fixed by what a user cares about, not fitted to data. A nominal
error of 0 makes the calibrated robot ``no better`` when its error is 0 too, else ``worse``.
Overall, the ratio is that of the means over the logs (as the validation reports it).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Literal

__all__ = ["MARGIN", "METRIC", "VERDICTS", "Verdict", "judge", "tally"]

Verdict = Literal["better", "no better", "worse"]
#: Every verdict, best first.
VERDICTS: tuple[Verdict, ...] = ("better", "no better", "worse")
#: The metric the verdict compares (a field of PathErrors, m).
METRIC = "rms_path_error"
#: Calibrated errors within this factor of the nominal ones either way are "no better".
MARGIN = 1.1


def judge(nominal: float, calibrated: float) -> Verdict:
    """The verdict on one metric value (>= 0) of the nominal and the calibrated robot."""
    if nominal <= 0.0:
        return "no better" if calibrated <= 0.0 else "worse"
    ratio = calibrated / nominal
    if ratio <= 1.0 / MARGIN:
        return "better"
    return "worse" if ratio >= MARGIN else "no better"


def tally(verdicts: Sequence[Verdict]) -> str:
    """How many logs got each verdict, in words: 'better on 2, worse on 1 of 3 logs'."""
    counts = Counter(verdicts)
    parts = [f"{verdict} on {counts[verdict]}" for verdict in VERDICTS if counts[verdict]]
    return f"{', '.join(parts)} of {len(verdicts)} log{'s' if len(verdicts) != 1 else ''}"
