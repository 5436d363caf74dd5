"""A Gymnasium environment over the simulated rig: one episode is one closed-loop run of a task.

Each :meth:`CapsuleEnv.step` is one camera frame of a :class:`~capsule_mpc.sim.loop.ClosedLoop`
(:mod:`.seat`): the agent sees what a real controller gets (:mod:`.observation`) and its action is
the EPM velocity command of the frame.

Action: the EPM's velocity (vx, vy, vz), m/s, each within ``+-limits.speed_mps`` (vz moves its
height). It is the frame's command as every controller's is: applied ``plant.compute_delay_s``
after the frame, through the arm's own guard (the speed clip and the workspace braking),
Ruckig's jerk-limited setpoints and the UR5's inverse kinematics (``sim.actuator: robot``), with
the draw's servo lag; zero during the settle phase (t < 0, the arm held still). An action
outside the space is refused (ValueError; wrap the env in ``gymnasium.wrappers.ClipAction`` to
clip instead).

Reward per step, in mm s (the negative time integral of the tracking error): ``-e * dt`` with ``e``
the true capsule's distance to the time-parameterised reference at the next frame, mm, and ``dt``
the frame period, s, for frames at t >= 0. On the last step also: ``-FINAL_ERROR_WEIGHT_S *
final_error_mm`` (the distance at rest to the path's end), and ``-FAILURE_PENALTY`` if the capsule
decoupled from the magnet or dropped off the plate. The reward reads the plant's truth; the
observation never does.

Termination: ``terminated`` when the run ends: the capsule at rest after the path's nominal end
(and the agent :attr:`~CapsuleEnv.policy_finished`), or decoupled or dropped; ``truncated`` when it
reaches the run's cut-off (``1.25 x`` the nominal duration ``+ sim.tail_s``) first. The last step's
observation repeats the last frame's; its ``info`` carries ``metrics`` (the run's metrics, as
:func:`capsule_mpc.sim.simulate` scores them), ``outcome``, ``success`` (:func:`.tasks.task_success`)
and ``seed``. Every step's ``info`` has ``t_s``.

Seeds: ``reset(seed=s)`` runs the rig drawn from ``s`` (plant, start offset, camera noise, and the
path of the ``unseen`` and ``place`` tasks), the run :func:`~capsule_mpc.sim.simulate` makes with
``seed=s``; ``reset()`` takes the next seed from the environment's generator, in
``[TRAINING_SEED_BASE, 2**31 - 1)``: training never meets the evaluation seeds (5000 on) nor the
tests' (below 1200).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

from ..config import Scenario
from ..errors import ConfigError
from ..paths import ReferencePath
from ..sim import ClosedLoop, RunResult
from .observation import action_space, observation, observation_space
from .seat import AgentFrame, AgentSeat, LoopDriver
from .tasks import get_task, task_path, task_scenario, task_success

__all__ = ["FAILURE_PENALTY", "FINAL_ERROR_WEIGHT_S", "TRAINING_SEED_BASE", "CapsuleEnv"]

#: Weight of the final error in the last step's reward, s: resting 1 mm off costs as much as
#: trailing 1 mm behind for this long.
FINAL_ERROR_WEIGHT_S = 10.0
#: Reward lost when the capsule decouples or drops, mm s: trailing 50 mm (beyond the decoupling
#: lead) for 20 s.
FAILURE_PENALTY = 1000.0
#: Seeds ``reset()`` draws without one: from here to ``2**31 - 1``, apart from the tests' seeds and
#: the evaluation seeds (:data:`~.tasks.EVAL_SEED_BASE` on, far fewer than this many).
TRAINING_SEED_BASE = 1_000_000
_SEED_END = 2**31 - 1


class CapsuleEnv(gym.Env[np.ndarray, np.ndarray]):
    """One task of the suite on one plant preset (module docstring).

    Parameters
    ----------
    task : str
        A task of :data:`capsule_mpc.envs.tasks.TASKS` (default ``rectangle``).
    preset : str
        The plant preset the rigs are drawn from: ``lab`` (default) or ``hard``.
    render_mode : None
        No rendering (the run's log is in ``info["metrics"]``; plot it with :mod:`capsule_mpc.plots`).

    Attributes
    ----------
    scenario : Scenario
        The nominal rig (what a controller may know).
    path : ReferencePath
        The current episode's reference (after :meth:`reset`).
    policy_finished : bool
        Set by an agent that runs a final approach of its own: while False the run does not end at
        rest (the cut-off still applies). Default True.
    result : RunResult or None
        The finished episode's run (log, metrics), None while it runs.
    seed_used : int or None
        The current episode's seed.
    epm_start_m : numpy.ndarray (3,)
        Where the operator put the EPM for the episode (the nominal model's rest pose over the
        path's start), m: what a controller's ``reset`` is given.
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 (declared so by gymnasium.Env)

    def __init__(self, task: str = "rectangle", preset: str = "lab", render_mode: str | None = None) -> None:
        if render_mode is not None:
            raise ConfigError(f"render_mode: must be None (no rendering), got {render_mode!r}")
        self.task = get_task(task)
        self.preset = preset
        self.scenario: Scenario = task_scenario(task, preset)
        if self.scenario.plant.compute_delay_mode != "fixed":
            raise ConfigError("plant.compute_delay_mode: must be 'fixed' for the environment")
        self.action_space = action_space(self.scenario)
        self.observation_space = observation_space(self.scenario)
        self.frame_s = 1.0 / float(self.scenario.camera.rate_hz)
        self.path: ReferencePath = task_path(task, 0)
        self.policy_finished = True
        self.result: RunResult | None = None
        self.seed_used: int | None = None
        self.epm_start_m = np.zeros(3)
        self._driver: LoopDriver | None = None
        self._last_obs = np.zeros(self.observation_space.shape)
        self._cmd = np.zeros(3)

    # -- the episode ------------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start the run of the rig drawn from ``seed`` (None: the next seed of the environment's
        generator); returns the first frame's observation and ``{"t_s", "seed", "epm_start_m"}``."""
        super().reset(seed=seed)
        if seed is not None and seed < 0:
            raise ValueError(f"seed: must be >= 0, got {seed}")
        drawn = int(self.np_random.integers(TRAINING_SEED_BASE, _SEED_END))
        run_seed = int(seed) if seed is not None else drawn
        self.close()
        self.seed_used, self.result, self.policy_finished = run_seed, None, True
        self.path = task_path(self.task.name, run_seed)
        loop = ClosedLoop(self.scenario, AgentSeat(), self.path, run_seed, meta={"task": self.task.name})
        self._driver = LoopDriver(loop)
        self._cmd = np.zeros(3)
        first = self._driver.start()
        self.epm_start_m = self._driver.seat.epm_start_m.copy()
        if not isinstance(first, AgentFrame):
            raise RuntimeError(f"the run ended before its first frame: {first.outcome_text()}")
        self._last_obs = self._observe(first)
        info = {"t_s": first.t_s, "seed": run_seed, "epm_start_m": self.epm_start_m.copy()}
        return self._last_obs.copy(), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Send ``action`` (vx, vy, vz in m/s) as the frame's command and run to the next frame."""
        if self._driver is None:
            raise RuntimeError("CapsuleEnv.step: call reset() first (or after the episode ended)")
        act = self._check_action(action)
        t_now = float(self._last_obs[0])
        self._cmd = act if t_now >= 0 else np.zeros(3)
        out = self._driver.send(act, self.policy_finished)
        if isinstance(out, AgentFrame):
            self._last_obs = self._observe(out)
            reward = self._tracking_reward(out.truth_row)
            return self._last_obs.copy(), reward, False, False, {"t_s": out.t_s}
        return self._end(out)

    def _check_action(self, action: Any) -> np.ndarray:
        act = np.asarray(action, dtype=float).ravel()
        if act.shape != (3,) or not np.all(np.isfinite(act)):
            raise ValueError(f"action: must be 3 finite values (vx, vy, vz), m/s, got {action!r}")
        speed = float(self.scenario.limits.speed_mps)
        if np.any(np.abs(act) > speed):
            raise ValueError(f"action: each of (vx, vy, vz) must be in +-{speed:g} m/s, got {act.tolist()}")
        return act

    def _observe(self, frame: AgentFrame) -> np.ndarray:
        return observation(frame.t_s, frame.measurement, frame.epm_position_m, self._cmd, self.path)

    def _tracking_reward(self, row: dict[str, Any]) -> float:
        """``-e * dt`` at a frame at t >= 0 (e: true tracking error, mm); 0 before."""
        if float(row["t_s"]) < 0:
            return 0.0
        err_mm = 1e3 * math.hypot(row["capsule_x_m"] - row["ref_x_m"], row["capsule_y_m"] - row["ref_y_m"])
        return -err_mm * self.frame_s

    def _end(self, result: RunResult) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """The last step: the final error, and on a failure its row's tracking term and the penalty."""
        self.result, self._driver = result, None
        log = result.log
        last = {k: float(log[k][-1]) for k in ("t_s", "capsule_x_m", "capsule_y_m", "ref_x_m", "ref_y_m")}
        metrics = dict(result.metrics)
        reward = -FINAL_ERROR_WEIGHT_S * float(metrics["final_error_mm"])
        if result.flags.decoupled or result.flags.dropped:  # the failure row is a frame the agent never saw
            reward += self._tracking_reward(last) - FAILURE_PENALTY
        info = {
            "t_s": last["t_s"],
            "metrics": metrics,
            "outcome": result.outcome_text(),
            "success": task_success(self.task.name, metrics),
            "seed": self.seed_used,
        }
        truncated = bool(result.flags.timed_out)
        return self._last_obs.copy(), reward, not truncated, truncated, info

    def close(self) -> None:
        """Drop the run in progress, if any."""
        if self._driver is not None:
            self._driver.close()
            self._driver = None
