"""The Gymnasium environment: plan calibration maneuvers for a robot with hidden wheels."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from envs.robot import RobotDistribution, RobotSpec
from envs.simulation import Simulation, SimulationConfig
from excite.data import Segments
from excite.information import eigen_3x3, information_matrix
from excite.kinematics import Params
from excite.online import OnlineEstimator
from excite.registration import DEFAULT_BUDGET


class Estimator(Protocol):
    """What the environment needs of an online estimator (OnlineEstimator implements it)."""

    def update(self, dphi_L: float, dphi_R: float, dx: float, dy: float,
               dtheta: float) -> None: ...

    @property
    def params(self) -> Params: ...

    @property
    def covariance(self) -> np.ndarray: ...


#: estimator_factory(nominal robot, sensor sigma (sx, sy, sth)) -> a fresh estimator.
EstimatorFactory = Callable[[Params, np.ndarray], Estimator]


def default_estimator(nominal: Params, sigma: np.ndarray) -> OnlineEstimator:
    """OnlineEstimator started at the nominal robot, with the sensor's noise levels."""
    return OnlineEstimator(nominal, sigma=sigma)


OBS_SIZE = 16


@dataclass(frozen=True)
class RobotKnowledge:
    """What the robot knows after n segments: everything a planner may use, never the truth.

    observation: the env's observation vector. estimate: current estimate (m). information:
    relative Fisher information of the log at the estimate (3x3). log: (n, 5) calibration rows.
    pose: measured world pose (x, y, theta). nominal: the nominal robot. sigma: sensor noise
    (m, m, rad). max_wheel_speed: motor limit (rad/s); segment_duration (s); arena_size (m);
    budget (segments).
    """

    observation: np.ndarray
    estimate: Params
    information: np.ndarray
    log: np.ndarray
    pose: np.ndarray
    nominal: Params
    sigma: np.ndarray
    max_wheel_speed: float
    segment_duration: float
    arena_size: float
    budget: int

    @property
    def n_segments(self) -> int:
        return int(self.log.shape[0])


class DiffDriveCalibEnv(gym.Env):
    """Excite a differential-drive robot so its wheel parameters become identifiable fast.

    A robot with hidden effective wheel radii r_L, r_R and wheel separation b (drawn per
    episode around the nominal robot) drives in a walled arena. Each step is one motion
    segment: the action holds two wheel-speed commands for ``segment_duration`` seconds
    (optionally followed by ``settle_time`` seconds of stop command: stop-and-go segments start
    and end at rest, which keeps the wheel-speed ratio, hence the curvature, constant); the
    encoders and an external pose sensor then give one calibration row
    (dphi_L, dphi_R, dx, dy, dtheta), which updates an online estimator. The reward is the
    information the segment added.

    On the slip id the robot drives continuously: the motors lag (first order) and the wheels
    push through friction-capped traction, so abrupt or fast maneuvers slip and curve
    differently from the constant-curvature model, while smooth, gentle ones follow it: the
    information a maneuver buys is traded against the bias it brings. The Ideal id rolls
    exactly along the model.

    ## Action space
    ``Box(-1, 1, (2,), float32)``: (left, right) wheel-speed commands as fractions of the
    motor limit (``robot["max_wheel_speed"]``, rad/s). Out-of-range actions are clipped;
    non-finite actions raise ``ValueError``.

    ## Observation space
    ``Box(float32, (16,))``, only what a real robot could know (never the hidden truth):

    | index | meaning |
    |-------|---------|
    | 0-2   | estimate / nominal - 1 for (r_L, r_R, b), clipped to [-1, 1] |
    | 3-5   | log1p of the eigenvalues (ascending) of the information matrix F, / 10 |
    | 6-8   | eigenvector of F's smallest eigenvalue (the worst-known direction) |
    | 9-10  | measured position x, y divided by the arena half-size |
    | 11-12 | cos, sin of the measured heading |
    | 13-14 | the previous action |
    | 15    | fraction of the segment budget used |

    F is the whitened, relatively scaled Fisher information of all segments so far at the
    current estimate (DESIGN.md); sigma_min = sqrt(lambda_min(F)).

    ## Reward
    A sum of named terms, each reported in ``info["reward_terms"]``:

    - ``information``: (sigma_min_t - sigma_min_{t-1}) / ``information_scale``; the episode's
      sum telescopes to the final sigma_min / information_scale;
    - ``collision``: -``collision_penalty`` when the chassis touched a wall;
    - ``effort``: -``effort_cost`` * mean(action^2); ``time``: -``time_cost`` per segment;
    - ``accuracy`` (privileged, for training in simulation only; 0 by default):
      -``accuracy_weight`` * 100 * (e_t - e_{t-1}), e the max relative error of the estimate
      against the hidden truth; the episode's sum telescopes to -accuracy_weight * 100 *
      (final error - nominal's error). The observation never contains the truth.

    ## Episode end
    Truncated after ``budget`` segments (the registered ids also set ``max_episode_steps``;
    pass ``max_episode_steps`` to ``gymnasium.make`` when you change the budget). Terminated
    when ``target_sigma_min`` (if set) is reached.

    ## Configuration
    ``DiffDriveCalibEnv.default_config()`` documents every key; override with
    ``config={...}`` or keyword arguments, e.g.
    ``gymnasium.make("excite/DiffDriveCalib-v0", budget=50, max_episode_steps=50)``.
    ``estimator_factory(nominal, sigma)`` plugs in another estimator (default:
    :class:`excite.OnlineEstimator` at the nominal robot).

    ## Evaluation
    ``env.unwrapped.true_params`` (hidden truth), ``env.unwrapped.segments`` (the episode's
    calibration log), ``env.unwrapped.estimator``.

    ``reset(options={"robot": RobotSpec, "pose": (x, y, theta)})`` fixes the hidden robot
    and/or start pose.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 4}

    @staticmethod
    def default_config() -> dict[str, Any]:
        return {
            "ideal": False,  # True: roll without slip or lag (the kinematic model is exact)
            "budget": DEFAULT_BUDGET,  # segments per episode
            "segment_duration": 1.0,  # s the command is held (a multiple of 1 / physics_hz)
            "settle_time": 0.0,  # s of zero command after it (> 0: stop-and-go segments)
            "arena_size": 4.0,  # m, square arena side
            "physics_hz": 50.0,  # physics tick rate
            "ticks_per_rev": 4096,  # encoder resolution
            "sigma_xy": 2e-3,  # m, pose sensor noise (per segment increment)
            "sigma_theta": 1e-3,  # rad
            "robot": {},  # RobotDistribution overrides, e.g. {"radius_rel": 0.05}
            "information_scale": 100.0,  # reward unit of sigma_min
            "collision_penalty": 1.0,
            "effort_cost": 0.0,
            "time_cost": 0.0,
            "accuracy_weight": 0.0,  # privileged term (uses the hidden truth)
            "target_sigma_min": None,  # terminate once sigma_min reaches it
        }

    def __init__(
        self,
        render_mode: str | None = None,
        config: dict[str, Any] | None = None,
        estimator_factory: EstimatorFactory | None = None,
        **overrides: Any,
    ):
        cfg = self.default_config()
        for key, value in {**(config or {}), **overrides}.items():
            if key not in cfg:
                raise ValueError(f"unknown config key {key!r}; known: {', '.join(cfg)}")
            cfg[key] = value
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}")
        if int(cfg["budget"]) < 1:
            raise ValueError(f"budget must be at least 1 segment, got {cfg['budget']}")
        self.config = cfg
        self.render_mode = render_mode
        self.distribution = RobotDistribution(**cfg["robot"])
        nominal = self.distribution.nominal()
        self.nominal = Params(*nominal.kinematic_params())
        self.max_wheel_speed = nominal.max_wheel_speed
        self.sim = Simulation(SimulationConfig(
            arena_width=cfg["arena_size"], arena_height=cfg["arena_size"],
            physics_hz=cfg["physics_hz"], ideal=bool(cfg["ideal"]),
            ticks_per_rev=cfg["ticks_per_rev"], sigma_xy=cfg["sigma_xy"],
            sigma_theta=cfg["sigma_theta"]))
        self.sigma = self.sim.pose_sensor.sigma
        self.segment_duration = float(cfg["segment_duration"])
        self.budget = int(cfg["budget"])
        self.estimator_factory = estimator_factory or default_estimator

        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        low = np.array([-1] * 3 + [0] * 3 + [-1] * 3 + [-1.5] * 2 + [-1] * 4 + [0], np.float32)
        high = np.array([1] * 3 + [5] * 3 + [1] * 3 + [1.5] * 2 + [1] * 4 + [1], np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._renderer = None
        self._robot: RobotSpec | None = None

    # -- episode ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = options or {}
        robot = options.get("robot") or self.distribution.sample(self.np_random)
        sim_rng = np.random.default_rng(self.np_random.integers(2**63))
        self.sim.reset(robot, sim_rng, pose=options.get("pose"))
        self._robot = robot
        self._sensor_rng = np.random.default_rng(self.np_random.integers(2**63))
        self.estimator = self.estimator_factory(self.nominal, self.sigma.copy())
        self._log = np.empty((self.budget, 5))  # calibration rows; grows if stepped past budget
        self._n = 0
        self._paths: list[np.ndarray] = [self.sim.pose[None, :]]
        self._last_action = (0.0, 0.0)
        self._sigma_min = 0.0
        self._estimate = self.nominal
        self._information = np.zeros((3, 3))
        self._eigen = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0))  # eigenvalues, weakest direction
        self._measured_pose = self.sim.pose_sensor.absolute(self.sim.pose, self._sensor_rng)
        self._error = self.max_relative_error
        if self.render_mode == "human":
            self.render()
        return self._observation(), {"sigma_min": 0.0, "n_segments": 0}

    def step(self, action):
        if self._robot is None:
            raise RuntimeError("call reset() before step()")
        values = np.asarray(action, dtype=float).reshape(-1).tolist()
        if len(values) != 2 or not all(map(math.isfinite, values)):
            raise ValueError(f"action must be 2 finite numbers (left, right), got {action!r}")
        left, right = (min(max(v, -1.0), 1.0) for v in values)
        outcome = self.sim.run_segment(left * self.max_wheel_speed, right * self.max_wheel_speed,
                                       self.segment_duration, self.config["settle_time"])
        row = outcome.measurement
        self.estimator.update(*row.tolist())
        if self._n == len(self._log):
            self._log = np.concatenate([self._log, np.empty_like(self._log)])
        self._log[self._n] = row
        self._n += 1
        self._paths.append(outcome.path[1:])
        self._last_action = (left, right)
        self._measured_pose = self.sim.pose_sensor.absolute(outcome.pose_end, self._sensor_rng)

        previous, previous_error = self._sigma_min, self._error
        self._estimate = self._read_estimate()
        self._information = self.information_at(self._estimate)
        self._eigen = eigen_3x3(self._information)
        self._sigma_min = math.sqrt(max(self._eigen[0][0], 0.0))
        n = self._n
        config = self.config
        target = config["target_sigma_min"]
        terminated = target is not None and self._sigma_min >= target
        truncated = n >= self.budget and not terminated
        terms = {
            "information": (self._sigma_min - previous) / config["information_scale"],
            "collision": -float(config["collision_penalty"]) if outcome.collision else 0.0,
            "effort": -float(config["effort_cost"]) * 0.5 * (left * left + right * right),
            "time": -float(config["time_cost"]),
            "accuracy": 0.0,
        }
        if config["accuracy_weight"]:
            self._error = self.max_relative_error
            terms["accuracy"] = (-config["accuracy_weight"] * 100.0
                                 * (self._error - previous_error))
        info = {
            "reward_terms": terms,
            "sigma_min": self._sigma_min,
            "collision": bool(outcome.collision),
            "measurement": row,
            "estimate": self._estimate.as_array(),
            "n_segments": n,
        }
        if self.render_mode == "human":
            self.render()
        return self._observation(), float(sum(terms.values())), terminated, truncated, info

    # -- what the robot knows ------------------------------------------------------------------
    def _read_estimate(self) -> Params:
        p = self.estimator.params
        return p if isinstance(p, Params) else Params.from_array(p)

    @property
    def estimate(self) -> Params:
        """The estimator's estimate after the last segment."""
        return self._estimate

    @property
    def segments(self) -> Segments:
        """The calibration log of this episode so far."""
        return Segments.from_array(self._log[: self._n])

    def information_at(self, params: Params) -> np.ndarray:
        """Relative Fisher information of this episode's segments evaluated at ``params``."""
        if not self._n:
            return np.zeros((3, 3))
        log = self._log[: self._n]
        return information_matrix(log[:, 0], log[:, 1], params, self.sigma, scale=self.nominal)

    @property
    def sigma_min(self) -> float:
        return self._sigma_min

    def knowledge(self) -> RobotKnowledge:
        """What the robot knows now (for planners and scripted protocols)."""
        return RobotKnowledge(
            observation=self._observation(), estimate=self.estimate,
            information=self._information.copy(), log=self._log[: self._n].copy(),
            pose=self._measured_pose.copy(), nominal=self.nominal, sigma=self.sigma.copy(),
            max_wheel_speed=self.max_wheel_speed, segment_duration=self.segment_duration,
            arena_size=float(self.config["arena_size"]), budget=self.budget)

    def _observation(self) -> np.ndarray:
        (lam0, lam1, lam2), weakest = self._eigen
        sign = 1.0 if max(weakest, key=abs) >= 0 else -1.0  # a unique sign for the direction
        estimate, nominal = self._estimate, self.nominal
        x, y, theta = self._measured_pose.tolist()
        to_unit = 2.0 / self.config["arena_size"]
        obs = np.array([
            estimate.r_L / nominal.r_L - 1.0, estimate.r_R / nominal.r_R - 1.0,
            estimate.b / nominal.b - 1.0,
            0.1 * math.log1p(max(lam0, 0.0)), 0.1 * math.log1p(max(lam1, 0.0)),
            0.1 * math.log1p(max(lam2, 0.0)),
            sign * weakest[0], sign * weakest[1], sign * weakest[2],
            x * to_unit, y * to_unit, math.cos(theta), math.sin(theta),
            *self._last_action,
            self._n / self.budget,
        ], dtype=np.float32)
        space = self.observation_space
        return np.minimum(np.maximum(obs, space.low, out=obs), space.high, out=obs)

    # -- evaluation only -------------------------------------------------------------------------
    @property
    def true_params(self) -> Params:
        """The hidden truth (for evaluation; never part of the observation)."""
        if self._robot is None:
            raise RuntimeError("call reset() first")
        return Params(*self._robot.kinematic_params())

    @property
    def robot(self) -> RobotSpec:
        if self._robot is None:
            raise RuntimeError("call reset() first")
        return self._robot

    @property
    def path(self) -> np.ndarray:
        """The true world poses (x, y, theta) of this episode at the physics rate (M, 3)."""
        return np.concatenate(self._paths)

    @property
    def last_segment_distance(self) -> float:
        """Path length (m) the robot travelled in the last segment (evaluation only)."""
        steps = self._paths[-1][:, :2] if len(self._paths) > 1 else np.zeros((1, 2))
        start = self._paths[-2][-1, :2] if len(self._paths) > 1 else steps[0]
        points = np.vstack([start, steps])
        return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))

    @property
    def max_relative_error(self) -> float:
        return float(np.max(np.abs(self.estimate.as_array() / self.true_params.as_array() - 1)))

    # -- rendering ---------------------------------------------------------------------------
    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode=...")
            return None
        if self._renderer is None:
            from envs.rendering import ArenaRenderer

            self._renderer = ArenaRenderer(self.config["arena_size"],
                                           human=self.render_mode == "human")
        frame = self._renderer.draw(
            path=self.path, pose=self.sim.pose, robot=self.robot,
            estimate=self.estimate, sigma_min=self._sigma_min, n_segments=self._n,
            budget=self.budget)
        return None if self.render_mode == "human" else frame

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self):
        state = copy.copy(self.__dict__)
        state["_renderer"] = None  # figures do not pickle; a new one is made on demand
        return state
