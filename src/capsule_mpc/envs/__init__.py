"""Gymnasium environments of the simulated rig and the benchmark's task suite.

Importing this package registers one environment per task and plant preset, e.g.::

    import gymnasium as gym
    import capsule_mpc.envs  # registers CapsuleMPC/<task>-<preset>-v0

    env = gym.make("CapsuleMPC/rectangle-lab-v0")
    obs, info = env.reset(seed=5000)

The tasks are in :mod:`.tasks`, the observation in :mod:`.observation`, the action, reward and
termination in :mod:`.env`, the policies (the package's controllers, a random one, a user's
``module:function``) in :mod:`.policies`.
"""

from __future__ import annotations

import gymnasium as gym

from .env import FAILURE_PENALTY, FINAL_ERROR_WEIGHT_S, CapsuleEnv
from .observation import OBSERVATION_FIELDS, measurement_from_observation
from .policies import ControllerPolicy, controller_policy, load_policy, random_policy
from .tasks import EVAL_SEED_BASE, PRESETS, TASKS, Task, env_id, eval_seeds, get_task, task_path

__all__ = [
    "ENV_IDS",
    "EVAL_SEED_BASE",
    "FAILURE_PENALTY",
    "FINAL_ERROR_WEIGHT_S",
    "OBSERVATION_FIELDS",
    "PRESETS",
    "TASKS",
    "CapsuleEnv",
    "ControllerPolicy",
    "Task",
    "controller_policy",
    "env_id",
    "eval_seeds",
    "get_task",
    "load_policy",
    "measurement_from_observation",
    "random_policy",
    "register_envs",
    "task_path",
]

#: Every registered id, task by task, ``lab`` before ``hard``.
ENV_IDS: tuple[str, ...] = tuple(env_id(t.name, p) for t in TASKS for p in PRESETS)


def register_envs() -> None:
    """Register :data:`ENV_IDS` with Gymnasium (done on import; repeating it is harmless)."""
    for task in TASKS:
        for preset in PRESETS:
            name = env_id(task.name, preset)
            if name not in gym.registry:
                gym.register(
                    id=name,
                    entry_point="capsule_mpc.envs.env:CapsuleEnv",
                    kwargs={"task": task.name, "preset": preset},
                )


register_envs()
