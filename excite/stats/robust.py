"""Robust scale: the normal distribution's constant for the median absolute deviation."""

from __future__ import annotations

__all__ = ["MEDIAN_ABS_NORMAL"]

#: The median of |N(0, 1)|: a robust std is the median absolute value / this (MAD).
MEDIAN_ABS_NORMAL = 0.6744897501960817
