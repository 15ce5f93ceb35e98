"""Gymnasium ids of excite's environments, registered without importing gymnasium early.

``import excite`` must stay light (no gymnasium, pymunk or torch), yet
``import excite; gymnasium.make("excite/DiffDriveCalib-v0")`` must work. So ``import excite``
registers the ids at once if gymnasium is already imported, and otherwise right after
gymnasium's own import finishes (a one-shot import hook). Entry points are strings, so
pymunk is imported only by ``gymnasium.make``.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys

ENTRY_POINT = "envs.env:DiffDriveCalibEnv"
VECTOR_ENTRY_POINT = "envs.vector_env:DiffDriveCalibVectorEnv"
DEFAULT_BUDGET = 30  # segments per episode
DEFAULT_ENV_ID = "excite/DiffDriveCalib-v0"
#: The hidden sensor mounting of the Sensor id, drawn per episode: around 10 cm ahead of the
#: axle, turned by up to 0.8 rad (uniform spreads whose std matches the default estimator's
#: prior: 0.1 b for offsets, 0.5 rad for the angle).
SENSOR_MOUNTING = {"x": (0.05, 0.15), "y": (-0.05, 0.05), "theta": (-0.8, 0.8)}
ENV_IDS = {
    DEFAULT_ENV_ID: {"ideal": False},
    "excite/DiffDriveCalibIdeal-v0": {"ideal": True},
    "excite/DiffDriveCalibSensor-v0": {"ideal": False, "sensor_pose": SENSOR_MOUNTING},
}


def register_envs() -> None:
    """Register excite's ids with gymnasium (idempotent)."""
    import gymnasium

    for env_id, kwargs in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            # No max_episode_steps: the env owns its budget (config "budget").
            gymnasium.register(id=env_id, entry_point=ENTRY_POINT, kwargs=dict(kwargs),
                               vector_entry_point=VECTOR_ENTRY_POINT)


class _RegisterAfterGymnasiumImport(importlib.abc.MetaPathFinder):
    """Finds gymnasium like the normal machinery, and registers the ids once it is loaded."""

    def find_spec(self, name, path=None, target=None):
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        exec_module = spec.loader.exec_module

        def exec_then_register(module):
            exec_module(module)
            register_envs()

        spec.loader.exec_module = exec_then_register  # type: ignore[method-assign]
        return spec


def install() -> None:
    """Register now if gymnasium is loaded, else as soon as it is."""
    if "gymnasium" in sys.modules:
        register_envs()
    elif not any(isinstance(f, _RegisterAfterGymnasiumImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _RegisterAfterGymnasiumImport())
