"""Live calibration: drive a robot with a protocol's maneuvers until the stopping rule says
done (:class:`~excite.live.session.LiveSession`, transport-agnostic), and its ROS 2 node
(``excite live``, the ``ros2`` extra)."""

from excite.live.area import Area
from excite.live.result import Command, LiveResult, LiveStatus
from excite.live.session import LiveSession
from excite.live.settings import LiveSettings

__all__ = ["Area", "Command", "LiveResult", "LiveSession", "LiveSettings", "LiveStatus"]
