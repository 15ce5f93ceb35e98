"""Training over several robots at once: one SB3 VecEnv made of several, side by side.

Each part is a vector env of one robot distribution (a preset, or a preset with overrides),
with its own nominal robot, motor limit and arena; the policy sees them all through the same
robot-relative observations (estimate / nominal, positions / arena half-size, commands /
motor limit), so one policy can learn them all. Env i of the concatenation is env i - offset
of its part; seeds follow SB3's convention across the whole (``seed(s)`` gives env i the seed
s + i).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn


class ConcatVecEnv(VecEnv):
    """The envs of ``parts`` (VecEnvs with identical spaces) as one VecEnv, in order."""

    def __init__(self, parts: Sequence[VecEnv]):
        if not parts:
            raise ValueError("ConcatVecEnv needs at least one part")
        first = parts[0]
        for part in parts[1:]:
            if (part.observation_space != first.observation_space
                    or part.action_space != first.action_space):
                raise ValueError("ConcatVecEnv: every part must have the same spaces")
        self.parts = list(parts)
        self.offsets = np.cumsum([0] + [part.num_envs for part in self.parts])
        self.slices = [slice(int(a), int(b)) for a, b in zip(self.offsets[:-1],
                                                             self.offsets[1:], strict=True)]
        super().__init__(int(self.offsets[-1]), first.observation_space, first.action_space)

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        for part, start in zip(self.parts, self.offsets, strict=False):
            part.seed(None if seed is None else seed + int(start))
        return super().seed(seed)

    def set_options(self, options: list[dict] | dict | None = None) -> None:
        super().set_options(options)
        for part, where in zip(self.parts, self.slices, strict=True):
            part.set_options(self._options[where])

    def reset(self) -> np.ndarray:
        observations = [part.reset() for part in self.parts]
        self.reset_infos = [info for part in self.parts for info in part.reset_infos]
        self._reset_seeds()
        self._reset_options()
        return np.concatenate(observations)

    def step_async(self, actions: np.ndarray) -> None:
        for part, where in zip(self.parts, self.slices, strict=True):
            part.step_async(actions[where])

    def step_wait(self) -> VecEnvStepReturn:
        results = [part.step_wait() for part in self.parts]
        obs, rewards, dones, infos = zip(*results, strict=True)
        return (np.concatenate(obs), np.concatenate(rewards), np.concatenate(dones),
                [info for part_infos in infos for info in part_infos])

    def close(self) -> None:
        for part in self.parts:
            part.close()

    def _locate(self, indices: VecEnvIndices) -> list[tuple[VecEnv, int]]:
        """(part, index within it) of each of ``indices``."""
        out = []
        for i in self._get_indices(indices):
            k = int(np.searchsorted(self.offsets, i, side="right")) - 1
            out.append((self.parts[k], i - int(self.offsets[k])))
        return out

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [part.get_attr(attr_name, [j])[0] for part, j in self._locate(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for part, j in self._locate(indices):
            part.set_attr(attr_name, value, [j])

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None,
                   **method_kwargs) -> list[Any]:
        return [part.env_method(method_name, *method_args, indices=[j], **method_kwargs)[0]
                for part, j in self._locate(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper],
                       indices: VecEnvIndices = None) -> list[bool]:
        return [part.env_is_wrapped(wrapper_class, [j])[0] for part, j in self._locate(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [image for part in self.parts for image in part.get_images()]
