"""A trained policy as a calibration protocol (``learned``).

A policy file is a stable-baselines3 zip plus its observation normalization
(``NAME.vecnormalize.pkl``, written by ``excite train``). Both are pickled code: load only
files you trust.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

from agents.catalog import ProtocolError
from agents.protocols import Protocol
from excite.contracts import RobotKnowledge


class LearnedPolicy(Protocol):
    """Acts with a trained SB3 policy (deterministic) on the env's observation, through the
    wall guard of every protocol (a safety shield). The policy drives smoothly (steady
    commands, little lag or slip to allow for), so the guard asks for less clearance per unit
    of speed than for the abrupt scripted maneuvers."""

    name = "learned"
    speed_margin = 0.1

    def __init__(self, path: str | Path):
        import torch
        from stable_baselines3 import PPO, SAC
        from stable_baselines3.common.vec_env import VecNormalize

        from agents.train import normalization_path

        torch.set_num_threads(1)  # one small forward pass per segment

        path = Path(path)
        errors = []
        for algo in (PPO, SAC):
            try:
                self.model = algo.load(str(path), device="cpu")
                break
            except Exception as exc:  # noqa: BLE001 (SB3 raises many kinds on a bad file)
                errors.append(f"{algo.__name__}: {exc}")
        else:
            raise ProtocolError(f"{path}: not a stable-baselines3 policy ({errors[0][:200]})")
        norm_path = normalization_path(path)
        try:
            with open(norm_path, "rb") as handle:
                self.normalization: VecNormalize = pickle.load(handle)
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError) as exc:
            raise ProtocolError(f"{norm_path}: cannot load the observation normalization "
                                f"saved with the policy ({exc})") from None
        self.path = path
        self.observation_shape = tuple(self.model.observation_space.shape)

    def incompatibility(self, observation_shape: tuple[int, ...]) -> str | None:
        if tuple(observation_shape) == self.observation_shape:
            return None
        return (f"{self.path.name} was trained for observations of shape "
                f"{self.observation_shape}, this environment gives {tuple(observation_shape)} "
                "(another observation layout)")

    def plan(self, knowledge: RobotKnowledge) -> np.ndarray:
        reason = self.incompatibility(knowledge.observation.shape)
        if reason:
            raise ProtocolError(reason)
        obs = self.normalization.normalize_obs(knowledge.observation[None, :])
        action, _ = self.model.predict(obs, deterministic=True)
        return np.asarray(action, dtype=float).reshape(2)

