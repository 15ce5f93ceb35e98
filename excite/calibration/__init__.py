"""Batch calibration of a differential drive's wheel radii and separation, and of its pose
sensor's mounting, from segments: :func:`calibrate` returns a :class:`CalibrationResult`
(with its :class:`FitTest`). The stages are listed in :mod:`excite.calibration.pipeline`;
:mod:`excite.calibration.export` writes a result for ROS 2.
"""

from excite.calibration.pipeline import calibrate
from excite.calibration.result import CalibrationResult, FitTest

__all__ = ["CalibrationResult", "FitTest", "calibrate"]
