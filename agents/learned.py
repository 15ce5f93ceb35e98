"""A trained policy as a calibration protocol (``learned``).

A policy file is a stable-baselines3 zip plus its observation normalization
(``NAME.vecnormalize.pkl``, written by ``excite train``). Both are pickled code: load only
files you trust.
"""

from __future__ import annotations

import hashlib
import pickle
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np

from agents.protocols import WALL_MARGIN, Parameter, Protocol, ProtocolError, Value
from excite.contracts import RobotKnowledge

#: The policy file shipped with excite (the default of the ``policy`` setting).
SHIPPED_POLICY = Path(__file__).parent / "policies" / "excite_ppo.zip"


class LearnedPolicy(Protocol):
    """Acts with a trained SB3 policy (deterministic) on the env's observation, through the
    wall guard of every protocol (a safety shield). The policy drives smoothly (steady
    commands, little lag or slip to allow for), so its guard asks by default for less
    clearance per unit of speed than that of the abrupt scripted maneuvers."""

    parameters = (
        Parameter("policy", str, "", "stable-baselines3 policy file (empty: the shipped "
                  "policy); its NAME.vecnormalize.pkl beside it"),
        replace(WALL_MARGIN, default=0.1, high=0.5, grid=6),
    )
    policy: str

    @classmethod
    def policy_path(cls, settings: Mapping[str, Value]) -> Path:
        """The policy file these settings name (the shipped one when empty)."""
        return Path(settings["policy"]) if settings["policy"] else SHIPPED_POLICY

    @classmethod
    def unavailable(cls, settings: Mapping[str, Value]) -> str | None:
        path = cls.policy_path(settings)
        if path.exists():
            return None
        where = "" if settings["policy"] else " (no policy is shipped; train one with excite train)"
        return f"learned policy file not found: {path}{where}"

    @classmethod
    def fingerprint(cls, settings: Mapping[str, Value]) -> str | None:
        """sha256 of the policy file and its observation normalization (missing: none)."""
        from agents.train import normalization_path

        path = cls.policy_path(settings)
        digest = hashlib.sha256()
        for part in (path, normalization_path(path)):
            digest.update(part.read_bytes() if part.is_file() else b"")
            digest.update(b"\0")  # the two contents stay apart
        return digest.hexdigest()

    def __init__(self, **settings: Value):
        super().__init__(**settings)
        path = self.policy_path(self.settings)
        if reason := self.unavailable(self.settings):
            raise ProtocolError(reason)
        import torch
        from gymnasium.spaces import Box
        from stable_baselines3 import PPO, SAC
        from stable_baselines3.common.vec_env import VecNormalize

        from agents.train import normalization_path

        torch.set_num_threads(1)  # one small forward pass per segment
        errors = []
        for algo in (PPO, SAC):
            try:
                self.model = algo.load(str(path), device="cpu")
                break
            except Exception as exc:  # noqa: BLE001 (SB3 raises many kinds on a bad file)
                errors.append(f"{algo.__name__}: {exc}")
        else:
            raise ProtocolError(f"{path}: not a stable-baselines3 policy ({errors[0][:200]})")
        space = self.model.action_space
        if not (isinstance(space, Box) and space.shape == (2,)):
            raise ProtocolError(f"{path}: the policy's actions are {space}, not two wheel-speed "
                                "commands (a Box of shape (2,)): it was not trained on excite's "
                                "environments")
        if not all(bool(torch.isfinite(p).all()) for p in self.model.policy.parameters()):
            raise ProtocolError(f"{path}: the policy's weights are not finite (NaN or inf): "
                                "its training diverged")
        norm_path = normalization_path(path)
        try:
            with open(norm_path, "rb") as handle:
                normalization = pickle.load(handle)
        except Exception as exc:  # noqa: BLE001 (unpickling raises any kind on a bad file)
            raise ProtocolError(f"{norm_path}: cannot load the observation normalization "
                                f"saved with the policy ({type(exc).__name__}: "
                                f"{str(exc)[:200]})") from None
        rms = getattr(normalization, "obs_rms", None)
        if not isinstance(normalization, VecNormalize) or np.shape(
                getattr(rms, "mean", None)) != tuple(self.model.observation_space.shape):
            raise ProtocolError(f"{norm_path}: not the observation normalization of this "
                                "policy (a VecNormalize of its observations' shape "
                                f"{tuple(self.model.observation_space.shape)})")
        self.normalization: VecNormalize = normalization
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

