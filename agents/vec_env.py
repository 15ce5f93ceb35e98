"""stable-baselines3's VecEnv interface over excite's native vector env.

SB3 resets an ended episode in the same step and hands its last observation over in
``info["terminal_observation"]``; time-limit ends are marked ``info["TimeLimit.truncated"]``
(SB3 bootstraps their value). :class:`NativeVecEnv` runs
:class:`envs.vector_env.DiffDriveCalibVectorEnv` in gymnasium's SAME_STEP autoreset mode and
translates its vector infos into SB3's list of per-env dicts, adding the episode statistics
SB3's Monitor would (``info["episode"]``: return, length, time).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

import excite  # noqa: F401  (registers the environment ids)


class NativeVecEnv(VecEnv):
    """An SB3 VecEnv of ``num_envs`` robots stepped in one process.

    env_id: an excite id (its ``vector_entry_point`` is the native vector env); env_kwargs:
    its configuration. Seeds follow SB3's convention (``seed(s)`` gives env i the seed s + i),
    which is the vector env's own: robot i then behaves as the single env seeded s + i.
    """

    def __init__(self, env_id: str, num_envs: int, env_kwargs: dict[str, Any] | None = None):
        self.venv = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
                                 autoreset_mode=AutoresetMode.SAME_STEP, **(env_kwargs or {}))
        super().__init__(num_envs, self.venv.single_observation_space,
                         self.venv.single_action_space)
        self._actions: np.ndarray | None = None
        self._returns = np.zeros(num_envs)
        self._lengths = np.zeros(num_envs, dtype=int)
        self._started = time.time()

    def reset(self) -> np.ndarray:
        seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
        obs, info = self.venv.reset(seed=seeds)
        self.reset_infos = self._split(info)
        self._returns[:] = 0.0
        self._lengths[:] = 0
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        obs, reward, terminated, truncated, info = self.venv.step(self._actions)
        dones = terminated | truncated
        infos = self._split(info)
        self._returns += reward
        self._lengths += 1
        for i in np.flatnonzero(dones):
            infos[i]["terminal_observation"] = info["final_obs"][i]
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            infos[i]["episode"] = {"r": float(self._returns[i]), "l": int(self._lengths[i]),
                                   "t": round(time.time() - self._started, 6)}
        self._returns[dones] = 0.0
        self._lengths[dones] = 0
        return obs, reward.astype(np.float32), dones, infos

    def _split(self, info: dict[str, Any]) -> list[dict[str, Any]]:
        """The vector env's info (arrays over robots, fresh each step) as one dict per robot:
        Python numbers for (N,) arrays, row views for (N, k) arrays, a dict of numbers for a
        dict of (N,) arrays (one ``tolist`` per array, not one conversion per robot)."""
        out: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for key, value in info.items():
            if key.startswith("_") or key.startswith("final_"):
                continue
            if isinstance(value, dict):
                names = list(value)
                items = [dict(zip(names, row, strict=True)) for row in
                         zip(*(value[name].tolist() for name in names), strict=True)]
            else:
                items = value.tolist() if value.ndim == 1 else list(value)
            for entry, item in zip(out, items, strict=True):
                entry[key] = item
        return out

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.venv.unwrapped, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.venv.unwrapped, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None,
                   **method_kwargs) -> list[Any]:
        method = getattr(self.venv.unwrapped, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper],
                       indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.num_envs
