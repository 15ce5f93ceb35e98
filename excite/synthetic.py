"""Synthetic segment datasets of the lesson's kind, for demos, tests and benchmarks."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from excite.data import Segments
from excite.information import DEFAULT_SIGMA, as_sigma
from excite.kinematics import Params, predict_increment

__all__ = ["LESSON_TRUTH", "lesson_dataset"]

#: The robot of the lesson's synthetic example (m).
LESSON_TRUTH = Params(0.050, 0.051, 0.300)


def lesson_dataset(
    rng: np.random.Generator,
    n: int = 200,
    params: Params = LESSON_TRUTH,
    sigma: ArrayLike = DEFAULT_SIGMA,
    dphi_std: float = 0.4,
) -> Segments:
    """The lesson's synthetic experiment: wheel increments ~ N(0, dphi_std^2) rad, exact
    kinematics at ``params``, plus Gaussian noise of std ``sigma`` = (sx [m], sy [m], sth [rad])
    on the measured increment."""
    s = as_sigma(sigma)
    dphi_L = rng.normal(0.0, dphi_std, n)
    dphi_R = rng.normal(0.0, dphi_std, n)
    truth = np.column_stack(predict_increment(dphi_L, dphi_R, params))
    measured = truth + rng.normal(size=(n, 3)) * s
    return Segments(dphi_L, dphi_R, *measured.T)
