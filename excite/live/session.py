"""A live calibration session: drive a robot with a protocol's maneuvers until the stopping
rule says the calibration is done. Transport-agnostic and light (numpy, scipy and the
protocol contracts: no ROS, no simulator).

Feed it the wheel angles and the external poses as they arrive, with their stamps; ask it for
the command to send now; read its status; finish it::

    session = LiveSession(settings, protocol)
    while not session.ended:
        for t, phi_L, phi_R in new_wheel_angles():
            session.add_wheels(t, phi_L, phi_R)
        for t, x, y, theta in new_poses():
            session.add_pose(t, x, y, theta)
        send(session.command(now()))
    result = session.finish()

A transport that has to leave a stream's messages out (unreadable, stamped ahead of its clock)
tells the session why (:meth:`LiveSession.left_out`): when that stream goes silent, the
session's reason says so.

Each call of :meth:`LiveSession.command` is one pass of a pipeline of named stages:

1. **watch**: the streams' silence (stop the robot after ``silence_timeout``, resume when
   they return, abort after ``abort_timeout``: :func:`excite.live.log.silence_text` says
   why), the time limit, and whether the wheels follow the command
   (:mod:`excite.live.watch`);
2. **segment end**, once per ``segment_duration``: the data so far are cut into segments
   with the offline code (:func:`excite.logs.segmentation.segment_timeseries`, fixed windows
   of ``segment_duration``), the stopping rule decides on them
   (:class:`excite.stopping.StoppingRule`: the batch calibration), and the protocol is asked
   for the next command through the simulator's contract
   (:class:`excite.contracts.RobotKnowledge` built from live data: the body's pose in the
   area, the latest estimate and its information, the nominal traction). When the rule's
   batch calibration finds that the model does not fit (the wheels slip, most often), the
   session slows down to half its speed (at most twice, to ``MIN_SPEED_SCALE``) and
   calibrates on the data from then on only;
3. **ramp**: the protocol's wheel speeds, scaled down to what the robot can stop from
   before its footprint leaves the area (the stopping guard, whatever the protocol:
   :mod:`excite.live.braking`), are approached at most at ``max_wheel_acceleration``.

A decision computed on the executor saw the log up to an earlier segment's end: when it
says done, the session is *confirming*: the robot stops, and the rule decides again on the
whole log (done ends the session; otherwise it drives on). A session ends *done* (the rule
said so on everything it recorded), *out_of_time* (``max_time``) or *aborted* (a
silence too long, wheels that do not follow, or :meth:`LiveSession.abort`); from then on the
command is zero. :meth:`LiveSession.finish` runs the full offline calibration of the whole
session since its last slowdown (:func:`excite.calibrate` on the session's log cut as
``excite calibrate --window segment_duration --split-at-gaps --start T`` cuts it): the answer
is the batch one, with its fit tests.

Frames and units: stamps in s on one clock for both streams; poses of the external sensor in
its world frame (x, y in m, theta in rad); wheel angles in rad (cumulative); commands in rad/s
per wheel, and as (v in m/s, omega in rad/s) with the nominal geometry.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from concurrent.futures import BrokenExecutor, Executor, Future
from dataclasses import replace

import numpy as np

from excite.calibration.pipeline import calibrate
from excite.calibration.result import CalibrationResult
from excite.contracts import RobotKnowledge
from excite.core import se2
from excite.core.information import information_matrix
from excite.core.models import AXLE, SENSOR_POSE, SegmentModel, SensorPose
from excite.errors import DataError, ExciteError
from excite.live.area import Area
from excite.live.braking import within_reach
from excite.live.log import (
    Stream,
    better_offset,
    clock_offset,
    cut,
    decide_log,
    increment_noise,
    pose_age,
    silence_text,
)
from excite.live.result import OUTCOMES, Command, LiveResult, LiveStatus
from excite.live.settings import LiveSettings
from excite.live.watch import MotionWatch
from excite.logs.segments import Segments
from excite.logs.timeseries import TimeSeries, during
from excite.stopping import StopDecision, StoppingRule

__all__ = ["MIN_SPEED_SCALE", "LiveSession"]

#: The lowest share of the speed limit a session slows down to when the model does not fit.
MIN_SPEED_SCALE = 0.25


class LiveSession:
    """Drives a robot with ``protocol`` until calibrated (see the module docstring).

    settings: :class:`excite.live.settings.LiveSettings`. protocol: an object with
    ``reset(rng)`` and ``act(knowledge) -> [-1, 1]^2`` (every protocol of ``agents``; an
    action that is not two finite numbers is a ValueError, never a command).
    seed: the protocol's random generator's seed. observe: builds the observation vector a
    learned policy reads from the knowledge and the last action (None: an empty one).
    executor: where the stopping rule's batch calibration runs (e.g. a one-thread
    ThreadPoolExecutor, so a transport's command loop never waits for it; the decision is
    then taken up as soon as it is ready, and a "done" ends the session at once); None: in
    the caller's thread.
    """

    def __init__(self, settings: LiveSettings, protocol, seed: int | None = None,
                 observe: Callable[[RobotKnowledge, np.ndarray], np.ndarray] | None = None,
                 executor: Executor | None = None) -> None:
        self.settings = settings
        self.protocol = protocol
        self.protocol.reset(np.random.default_rng(seed))
        self.rule = StoppingRule(target=settings.target, confidence=settings.confidence,
                                 sensor_pose=settings.sensor_pose)
        self._observe = observe
        self.executor = executor
        self._pending: Future | None = None
        self._wheels = Stream(2)
        self._poses = Stream(3)
        self._watch = MotionWatch(settings.motion_window, settings.response_time,
                                  settings.command_speed)
        self._state = "waiting"
        self._reason = "waiting for the wheel angles and the poses"
        self._start: float | None = None
        self._now: float | None = None
        self._segment_start: float | None = None
        self._segment_end: float | None = None
        self._segments = 0
        self._action = np.zeros(2)
        self._target = np.zeros(2)
        self._sent = np.zeros(2)
        self._sent_at: float | None = None
        self._rows = np.zeros((0, 5))
        self._decision: StopDecision | None = None
        # the clock offset (s) the accepted decisions' log was cut with
        self._offset: float | None = None
        self._area: Area | None = None
        self._statuses: list[LiveStatus] = []
        self._silent_since: float | None = None
        self._speed_scale = 1.0
        self._epoch: float | None = None
        self._pending_epoch: float | None = None
        self._slowdowns: list[tuple[float, float]] = []
        self._confirm_at = math.inf
        self._confirming: StopDecision | None = None

    # -- input --------------------------------------------------------------------------------
    def add_wheels(self, t: float, phi_L: float, phi_R: float,
                   received: float | None = None) -> None:
        """The wheel angles (rad, cumulative) at stamp ``t`` (s), which arrived at
        ``received`` (s, the commands' clock; None: not known)."""
        self._wheels.add(t, (phi_L, phi_R), received)

    def add_pose(self, t: float, x: float, y: float, theta: float,
                 received: float | None = None) -> None:
        """The external sensor's pose (x, y in m, theta in rad) at stamp ``t`` (s), which
        arrived at ``received`` (s; None: not known)."""
        self._poses.add(t, (x, y, theta), received)

    def left_out(self, stream: str, reason: str) -> None:
        """Why the latest messages of ``stream`` ("wheels" or "poses") could not be used
        (a transport's words, e.g. "the JointState messages no longer name ..."): what the
        session says when that stream goes silent. A sample used again clears it."""
        streams = {"wheels": self._wheels, "poses": self._poses}
        if stream not in streams:
            raise ValueError(f"stream must be 'wheels' or 'poses', got {stream!r}")
        streams[stream].left_out = reason

    def abort(self, reason: str) -> None:
        """End the session now as *aborted* (e.g. interrupted); the command becomes zero."""
        if not self.ended:
            self._end("aborted", reason)

    # -- the loop -----------------------------------------------------------------------------
    def command(self, now: float) -> Command:
        """The command to send at time ``now`` (s, the streams' clock). DataError, before
        the session starts, when the robot's footprint is outside the area."""
        self._now = now
        if not self.ended:
            self._watch_streams(now)
        if self._state == "running" and now >= self._segment_end:
            self._end_segment(now)
        elif self._state == "running" and self._pending is not None and self._pending.done():
            self._take_decision()  # a decision that says done stops the robot now
            if self._decision is not None and self._decision.done:
                self._done(now)
        elif self._state == "confirming":
            self._confirm(now)
        if self._state != "running":
            self._target[:] = 0.0
        return self._ramp(now)

    def _watch_streams(self, now: float) -> None:
        """Stage 1: start, silence, time limit, and the wheels against the command."""
        if self._wheels.last is None or self._poses.last is None:
            return
        age = max(now - self._wheels.last, pose_age(self._poses, self._wheels, now))
        if age > self.settings.silence_timeout:
            self._silent_since = self._silent_since or now - age
            if now - self._silent_since > self.settings.abort_timeout:
                self._end("aborted", silence_text(
                    self._wheels, self._poses, now, self.settings.silence_timeout,
                    f" for longer than {self.settings.abort_timeout:g} s"))
            elif self._state == "running":
                self._state, self._reason = "paused", silence_text(
                    self._wheels, self._poses, now, self.settings.silence_timeout)
            return
        self._silent_since = None
        if self._state in ("waiting", "paused"):
            self._begin(now)
            return
        if self._start is not None and now - self._start >= self.settings.max_time:
            self._end("out_of_time", f"the time limit of {self.settings.max_time:g} s ran out "
                      "before the target was reached")
            return
        fault = self._watch.check(min(now, self._wheels.last), self._wheels.at)
        if fault is not None:
            self._end("aborted", str(fault))
            return
        self._check_area()

    def _check_area(self) -> None:
        """Abort when the footprint (at the measured pose) reaches outside the area: the
        guard kept the plan inside, so the robot does not move as planned (or started
        outside)."""
        clearance = self._area.clearance(self._body_pose(), self.settings.chassis)
        if clearance < 0:
            self._end("aborted", f"the robot's footprint is {-clearance:.2f} m outside the "
                      f"safe area {self._area.to_text()} (m, pose frame): stopped")

    def _begin(self, now: float) -> None:
        """Start (or resume after a silence): a new segment from now. DataError when the
        robot's footprint is outside the area at the start (an area or radius that does not
        hold the robot: bad input, never a command)."""
        if self._start is None:
            body = self._body_pose()
            area = self.settings.area_at(body)
            clearance = area.clearance(body, self.settings.chassis)
            if clearance < 0:
                raise DataError(f"the robot's footprint reaches {-clearance:.2f} m outside the "
                                f"safe area {area.to_text()} (m, pose frame) at the start: "
                                "give an area that holds it (--area, --radius)")
            self._start, self._area = now, area
        self._state, self._reason = "running", "driving"
        self._check_area()
        if self._state == "running":
            self._next_action(now)

    def _end_segment(self, now: float) -> None:
        """Stage 2: the segment's row for the planner, the decision on the log so far, the
        protocol's next command."""
        row = self._row(self._segment_start, now)
        if row is not None:
            self._rows = np.vstack([self._rows, row])
        self._take_decision()
        self._start_decision()
        if self._decision is not None:
            self._reason = self._decision.reason
        self._slow_down(now)
        if self._decision is not None and self._decision.done:
            self._done(now)
            return
        self._statuses.append(self.status)
        self._next_action(now)

    def _done(self, now: float) -> None:
        """The rule said done. On the data up to now (no executor) the session ends; a
        decision from the executor saw the log up to an earlier segment's end, so the robot
        stops and the rule decides again on all of it (:meth:`_confirm`): the session's
        answer is the batch calibration of everything it recorded, which the rule must
        have judged."""
        self._statuses.append(self.status)
        if self.executor is None:
            self._end("done", self._decision.reason)
            return
        self._state = "confirming"
        self._reason = (f"{self._decision.reason}, decided on {self._decision.n_segments} "
                        "segments: robot stopped, deciding again on the whole log")
        self._confirm_at, self._confirming = now + self.settings.response_time, None

    def _confirm(self, now: float) -> None:
        """Stage 2 while confirming: once the robot has had ``response_time`` to stop and no
        other decision is pending, the rule decides on the whole log (the batch calibration,
        without the screen). *Done* ends the session; anything else drives on (slower when
        the model does not fit the data)."""
        self._take_decision()
        if self.ended or self._pending is not None or now < self._confirm_at:
            return
        if self._confirming is None:
            self._confirming = self._decision
            self._start_decision(screen=False)
            if self._pending is not None:
                return
        d, stale, self._confirming = self._decision, self._confirming, None
        if d is not stale and d is not None and d.done:
            self._end("done", d.reason)
            return
        self._state = "running"
        self._reason = d.reason if d is not stale and d is not None else "driving"
        self._slow_down(now)
        self._statuses.append(self.status)
        self._next_action(now)

    def _row(self, start: float, end: float) -> np.ndarray | None:
        """The planner's row (dphi_L, dphi_R, dx, dy, dtheta) of the command held over
        [start, end] (s): between the last pose samples at or before each time, the wheel
        angles interpolated there (rad) and the sensor's motion in its frame at the first
        (m, m, rad), as excite.logs.segmentation forms a segment."""
        t = self._poses.t
        a, b = bisect.bisect_right(t, start) - 1, bisect.bisect_right(t, end) - 1
        if a < 0 or b <= a:
            return None
        wheels_a, wheels_b = self._wheels.at(t[a]), self._wheels.at(t[b])
        if wheels_a is None or wheels_b is None:
            return None
        increment = se2.between(np.array(self._poses.values[a]),
                                np.array(self._poses.values[b]))
        return np.concatenate([wheels_b - wheels_a, increment])

    def _next_action(self, now: float) -> None:
        knowledge = self.knowledge()
        action = np.asarray(self.protocol.act(knowledge), dtype=float)
        if action.shape != (2,) or not np.isfinite(action).all():  # never sent to a robot
            raise ValueError(f"the protocol's action must be two finite wheel-speed "
                             f"fractions, got {action!r}")
        action = np.clip(action, -1.0, 1.0)
        self._action = action
        self._target = action * self.settings.command_speed * self._speed_scale
        self._segment_start, self._segment_end = now, now + self.settings.segment_duration
        self._segments += 1

    def _ramp(self, now: float) -> Command:
        """Stage 3: the wheel speeds sent: zero at once unless running, else the protocol's
        scaled down to what the robot can stop from inside the area
        (:func:`excite.live.braking.within_reach`),
        at most max_wheel_acceleration from the last."""
        if self._state != "running":
            sent = np.zeros(2)
        else:
            clearance = self._area.clearance(self._body_pose(), self.settings.chassis)
            target = self._target * within_reach(self.settings, self._target, clearance)
            if self._sent_at is None or not math.isfinite(self.settings.max_wheel_acceleration):
                sent = target
            else:
                step = self.settings.max_wheel_acceleration * max(now - self._sent_at, 0.0)
                sent = self._sent + np.clip(target - self._sent, -step, step)
        self._sent, self._sent_at = sent, now
        self._watch.commanded(now, float(sent[0]), float(sent[1]))
        v, omega = self.settings.twist(float(sent[0]), float(sent[1]))
        return Command(float(sent[0]), float(sent[1]), v, omega)

    def _end(self, outcome: str, reason: str) -> None:
        self._state, self._reason = outcome, reason
        self._target[:] = 0.0

    # -- what the robot knows ---------------------------------------------------------------
    def _series(self, start: float | None = None) -> TimeSeries | None:
        """The session's wheel angles and poses (from ``start``, s; None: all); None while
        too few."""
        t_enc, wheels = self._wheels.arrays()
        t_pose, poses = self._poses.arrays()
        if len(t_enc) < 2 or len(t_pose) < 2:
            return None
        series = TimeSeries(t_enc, wheels[:, 0], wheels[:, 1], t_pose, *poses.T,
                            source=("wheel angles", "poses"))
        try:
            return during(series, start)
        except DataError:  # fewer than 2 samples of a stream since ``start``
            return None

    def _segmented(self) -> tuple[Segments, float]:
        """The session's log since the last slowdown cut into segments as ``excite calibrate
        --start`` cuts it, and the clock offset it was cut with (s): the one the last accepted
        decision's log was cut with (that decision's calibration is then this one's), else
        :func:`clock_offset`'s; raises ExciteError when it cannot be cut, e.g. too few
        segments."""
        series = self._series(self._epoch)
        if series is None:
            raise ExciteError("no wheel angles and poses yet")
        offset = (self._offset if self._offset is not None
                  else clock_offset(series, self.settings.time_offset))
        return cut(series, self.settings.segment_duration, offset), offset

    def _start_decision(self, screen: bool = True) -> None:
        """The stopping rule on the log so far (:func:`decide_log`; ``screen``: passing the
        last decision, so most looks skip the batch calibration), in the caller's thread or
        on the executor (one at a time: this segment's data wait for the next end)."""
        if self._pending is not None:
            return
        series = self._series(self._epoch)
        if series is None:
            return
        args = (self.rule, series, self.settings.segment_duration, self.settings.nominal,
                self._decision if screen else None, self.settings.time_offset)
        self._pending_epoch = self._epoch
        if self.executor is None:
            try:
                self._accept(decide_log(*args))
            except np.linalg.LinAlgError as exc:
                self._look_failed(exc)
        else:
            self._pending = self.executor.submit(decide_log, *args)

    def _take_decision(self, wait: bool = False) -> None:
        """The executor's decision when it has come back, or ``wait`` for it. A decisions'
        process that died (killed, out of memory) aborts the session, which keeps its
        report; a look whose linear algebra failed is skipped (:meth:`_look_failed`); any
        other failure of the decision is raised (once)."""
        if self._pending is not None and (wait or self._pending.done()):
            pending, self._pending = self._pending, None
            try:
                decision = pending.result()
            except (BrokenExecutor, OSError) as exc:
                self.abort(f"the stopping rule's process failed ({type(exc).__name__}: "
                           f"{exc})")
                return
            except np.linalg.LinAlgError as exc:
                self._look_failed(exc)
                return
            self._accept(decision)

    def _look_failed(self, exc: np.linalg.LinAlgError) -> None:
        """A look of the stopping rule whose batch calibration failed numerically on the log
        so far (a singular matrix: seen in about one session in 20-50 of the rehearsals,
        near the end, not reproduced): no decision from it, the session drives on and the
        rule looks again at the next segment's end; the reason says so."""
        self._reason = (f"the stopping rule's calibration failed on the log so far "
                        f"({type(exc).__name__}: {exc}); it decides again at the next "
                        "segment's end")

    def _accept(self, look: tuple[StopDecision | None, float | None]) -> None:
        """Take a decision on the data since the current slowdown (an older one is stale),
        and the clock offset its log was cut with (:func:`decide_log`)."""
        decision, offset = look
        if decision is not None and self._pending_epoch == self._epoch:
            self._decision = decision
            if offset is not None:
                self._offset = offset

    def _slow_down(self, now: float) -> None:
        """The model does not fit the data since the last slowdown (the wheels slip, most
        often): drive gentler, at half the speed (down to MIN_SPEED_SCALE), and calibrate on
        the data from now on only."""
        d = self._decision
        if d is None or d.result is None or d.result.fit.ok:
            return
        if self._speed_scale <= MIN_SPEED_SCALE:
            self._reason = f"{d.reason}; already at the lowest speed"
            return
        self._speed_scale = max(0.5 * self._speed_scale, MIN_SPEED_SCALE)
        # the clock offset too: one the faster driving showed may be its slip's lag
        self._epoch, self._decision, self._offset = now, None, None
        self._slowdowns.append((now, self._speed_scale))
        self._reason = (f"{d.reason}: driving at {self._speed_scale:.0%} of the speed from "
                        "now on, calibrating on the data from here")

    def _calibration(self) -> CalibrationResult | None:
        d = self._decision
        return None if d is None or d.result is None or not d.result.identifiable else d.result

    def _mount(self) -> np.ndarray:
        """The sensor's pose on the body (x, y, theta): given, estimated, or on the axle."""
        if isinstance(self.settings.sensor_pose, SensorPose):
            return self.settings.sensor_pose.as_array()
        result = self._calibration()
        if result is not None and result.sensor_pose is not None:
            return result.sensor_pose.as_array()
        return np.zeros(3)

    def _body_pose(self) -> np.ndarray:
        """The body's (axle midpoint's) latest pose in the pose frame."""
        sensor = np.array(self._poses.values[-1])
        return se2.compose(sensor, se2.inverse(self._mount()))

    def _planned(self, estimate) -> tuple[SegmentModel, np.ndarray, np.ndarray]:
        """The model a planner plans for, its current and its nominal parameters: the
        sensor-pose model while the mounting is estimated (the stopping rule's target then
        covers it: ``--sensor-pose estimate``, or ``auto`` until its calibration chooses the
        axle model; the mounting's nominal is the axle), else the axle model."""
        s = self.settings
        wheels, nominal = estimate.as_array(), s.nominal.as_array()
        result = self._calibration()
        if (isinstance(s.sensor_pose, SensorPose) or s.sensor_pose == "axle"
                or (s.sensor_pose == "auto" and result is not None
                    and result.sensor_pose_std is None)):
            return AXLE, wheels, nominal
        return SENSOR_POSE, np.append(wheels, self._mount()), np.append(nominal, np.zeros(3))

    def knowledge(self) -> RobotKnowledge:
        """What a planner may use now (the simulator's contract, from live data)."""
        s = self.settings
        result = self._calibration()
        estimate = result.params if result is not None else s.nominal
        sigma = (np.array(s.sigma) if result is None
                 else increment_noise(result, s.segment_duration))
        sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, s.sigma)
        rows = self._rows
        model, theta, nominal_theta = self._planned(estimate)
        information = (information_matrix(rows[:, 0], rows[:, 1], theta, sigma,
                                          scale=nominal_theta, model=model) if len(rows)
                       else np.zeros((model.size, model.size)))
        extent = self._area.extent
        budget = max(int(s.max_time / s.segment_duration), 1)
        knowledge = RobotKnowledge(
            observation=np.zeros(0, dtype=np.float32), estimate=estimate,
            information=information, log=rows.copy(),
            pose=self._area.to_local(self._body_pose()), nominal=s.nominal, sigma=sigma,
            max_wheel_speed=s.command_speed * self._speed_scale,
            segment_duration=s.segment_duration,
            arena_size=min(extent), budget=budget, chassis=s.chassis, traction=s.traction,
            arena_extent=extent, model=model, theta=theta, nominal_theta=nominal_theta)
        if self._observe is not None:
            knowledge = replace(knowledge, observation=self._observe(knowledge, self._action))
        return knowledge

    # -- status and result --------------------------------------------------------------------
    @property
    def ended(self) -> bool:
        return self._state in OUTCOMES

    @property
    def started(self) -> bool:
        """Whether the session has started driving (both streams came)."""
        return self._start is not None

    @property
    def state(self) -> str:
        return self._state

    @property
    def reason(self) -> str:
        return self._reason

    @property
    def area(self) -> Area | None:
        return self._area

    @property
    def decision(self) -> StopDecision | None:
        return self._decision

    @property
    def statuses(self) -> tuple[LiveStatus, ...]:
        """The status after every segment so far."""
        return tuple(self._statuses)

    @property
    def status(self) -> LiveStatus:
        """Where the session stands now."""
        d = self._decision
        result = self._calibration()
        nominal = tuple(map(float, self.settings.nominal.as_array()))
        clearance = None
        if self._area is not None and self._poses.t:
            clearance = self._area.clearance(self._body_pose(), self.settings.chassis)
        now = self._now if self._now is not None else 0.0
        return LiveStatus(
            state=self._state,
            elapsed=0.0 if self._start is None else now - self._start,
            segments=self._segments,
            calibrated_segments=0 if d is None else d.n_segments,
            estimate=nominal if result is None else tuple(map(float, result.params.as_array())),
            std=None if result is None else tuple(map(float, result.std)),
            statistic=math.inf if d is None else d.statistic,
            seconds_to_go=None if d is None else d.seconds_to_go,
            clearance=clearance, reason=self._reason)

    def finish(self) -> LiveResult:
        """End the session (as *aborted* if it is still running) and run the full offline
        calibration of everything it recorded."""
        if not self.ended:
            self._end("aborted", "the session was finished before it ended")
        if self._pending is not None:
            self._take_decision(wait=True)
        calibration, error, offset = None, None, None
        try:
            segments, offset = self._segmented()
            calibration = calibrate(segments, initial=self.settings.nominal,
                                    sensor_pose=self.settings.sensor_pose)
        except ExciteError as exc:
            error = str(exc)
        duration = 0.0 if self._start is None or self._now is None else self._now - self._start
        suggested = (None if self._state == "done" or offset is None
                     or self.settings.time_offset == "estimate"
                     else better_offset(self.rule, self._series(), self.settings.segment_duration,
                                        self.settings.nominal, offset))
        return LiveResult(outcome=self._state, reason=self._reason, calibration=calibration,
                          calibration_error=error, decision=self._decision,
                          series=self._series(), area=self._area,
                          statuses=tuple(self._statuses), duration=duration,
                          calibrated_from=self._epoch, slowdowns=tuple(self._slowdowns),
                          time_offset=offset, suggested_time_offset=suggested)
