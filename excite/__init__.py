"""excite: calibrate a differential-drive robot's wheel radii and separation, and plan the
maneuvers that identify them fastest.

Core API (numpy/scipy only; importing excite never imports gymnasium, pymunk or torch, yet
registers the environment ids ``excite/DiffDriveCalib-v0`` and ``excite/DiffDriveCalibIdeal-v0``
with gymnasium, see :mod:`excite.registration`)::

    from excite import Params, Segments, predict_increment, increment_jacobian
    from excite import load_segments, save_segments, calibrate, OnlineEstimator
"""

from excite.calibration import CalibrationResult, calibrate
from excite.core.kinematics import Params, predict_increment
from excite.core.models import SensorPose, increment_jacobian
from excite.errors import DataError, ExciteError
from excite.estimators.online import OnlineEstimator
from excite.logs.segments import Segments, load_segment_files, load_segments, save_segments
from excite.registration import install as _install_gymnasium_ids

_install_gymnasium_ids()

__version__ = "0.1.0"

__all__ = [
    "CalibrationResult",
    "DataError",
    "ExciteError",
    "OnlineEstimator",
    "Params",
    "Segments",
    "SensorPose",
    "calibrate",
    "increment_jacobian",
    "load_segment_files",
    "load_segments",
    "predict_increment",
    "save_segments",
    "__version__",
]
