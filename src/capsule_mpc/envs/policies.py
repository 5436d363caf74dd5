"""Policies for the environment: the package's controllers as policies, a random policy, and
loading a user's policy from ``module:function``.

A *policy factory* is a callable ``factory(env) -> policy``, called once per episode after
``env.reset`` with the unwrapped :class:`~.env.CapsuleEnv` (its ``task``, ``preset``, nominal
``scenario``, the episode's ``path`` and ``seed_used``: what a real controller may know); the
policy is a callable ``policy(observation) -> action``. A policy may carry a ``finished``
attribute (bool): the benchmark copies it to :attr:`CapsuleEnv.policy_finished` after each action.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..interfaces import Controller, make_controller
from .env import CapsuleEnv
from .observation import action_space, measurement_from_observation

__all__ = ["ControllerPolicy", "Policy", "PolicyFactory", "controller_policy", "load_policy", "random_policy"]

#: A policy: observation -> action (m/s).
Policy = Callable[[np.ndarray], np.ndarray]
#: Makes an episode's policy from the reset environment.
PolicyFactory = Callable[[CapsuleEnv], Policy]


class ControllerPolicy:
    """A :class:`~capsule_mpc.interfaces.Controller` driven through the environment's observations.

    The controller is reset with the environment's nominal scenario, the episode's path and the
    EPM's start pose (:attr:`CapsuleEnv.epm_start_m`), and stepped with the time, measurement and
    EPM pose each observation carries, as the loop would step it.

    Parameters
    ----------
    controller : Controller
        The controller (a new instance per episode).
    env : CapsuleEnv
        The reset environment.
    """

    def __init__(self, controller: Controller, env: CapsuleEnv) -> None:
        self.controller = controller
        self.env = env
        self._reset = False

    @property
    def finished(self) -> bool:
        """The controller's :attr:`~capsule_mpc.interfaces.Controller.finished`."""
        return self.controller.finished

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """The controller's command (vx, vy, vz), m/s, for this observation."""
        t, meas, epm = measurement_from_observation(obs)
        if not self._reset:
            self.controller.reset(self.env.scenario, self.env.path, self.env.epm_start_m.copy())
            self._reset = True
        cmd = self.controller.step(t, meas, epm)
        return np.asarray(cmd.epm_velocity_mps, dtype=float)[:3].copy()


def controller_policy(name: str) -> PolicyFactory:
    """A factory of :class:`ControllerPolicy` for the registered controller ``name``."""

    def factory(env: CapsuleEnv) -> Policy:
        return ControllerPolicy(make_controller(name), env)

    return factory


def random_policy(env: CapsuleEnv) -> Policy:
    """Actions uniform in the action space, from a generator seeded with the episode's seed."""
    space = action_space(env.scenario)
    rng = np.random.default_rng(env.seed_used)

    def act(obs: np.ndarray) -> np.ndarray:
        return np.asarray(rng.uniform(space.low, space.high))

    return act


def load_policy(spec: str) -> PolicyFactory:
    """The policy factory named ``module:function`` (module docstring).

    Raises
    ------
    ConfigError
        ``--policy: ...`` when the text is not ``module:function``, the module cannot be imported
        or has no such callable.
    """
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise ConfigError(f"--policy: must be module:function, got {spec!r}")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"--policy: cannot import {module_name!r}: {exc}") from exc
    factory: Any = module
    for part in attr.split("."):
        factory = getattr(factory, part, None)
    if not callable(factory):
        raise ConfigError(f"--policy: {spec!r} is not a callable")
    return factory
