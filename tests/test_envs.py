"""The Gymnasium environment: the API contract (check_env, the vector API), the run it makes (the
same as ``simulate`` for a controller's actions), an observation without the plant's truth, seeds
that select the rig, and the task suite's paths."""

from __future__ import annotations

import dataclasses
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import capsule_mpc.envs as envs
from capsule_mpc.envs import ENV_IDS, CapsuleEnv, controller_policy, task_path
from capsule_mpc.envs.observation import OBSERVATION_FIELDS
from capsule_mpc.envs.tasks import EVAL_SEED_BASE, TASKS, eval_seeds, task_scenario
from capsule_mpc.errors import ConfigError
from capsule_mpc.experiments.benchmark import run_episode
from capsule_mpc.path_reach import check_epm_workspace
from capsule_mpc.sim import draw_plant_truth, simulate
from capsule_mpc.sim import loop as sim_loop

#: Metrics that time this machine (wall clock) or that the controller reports in its step's stats,
#: which the agent's seat does not pass on (solves, rejected measurements, its phase).
#: What a run through the env cannot give as the direct run does: the controller's own statistics
#: (its phase, placement moves, rejected frames; a policy behind the env reports none) and wall times.
_NOT_COMPARED = {
    "end_phase",
    "placement_moves",
    "step_ms_max",
    "solve_ms_median",
    "solve_ms_p99",
    "solve_ms_max",
    "deadline_misses",
    "measurements_rejected",
}
#: Index of the first measurement column and of the columns the camera fills.
_MEAS = [OBSERVATION_FIELDS.index(f) for f in ("meas_x_m", "meas_y_m", "meas_valid", "meas_capture_t_s")]


def _same_metrics(a: dict, b: dict) -> list[str]:
    """Names of the metrics (those of :data:`_NOT_COMPARED` aside) that differ between two runs."""
    differ = []
    for key in sorted(set(a) | set(b)):
        if key in _NOT_COMPARED:
            continue
        x, y = a.get(key), b.get(key)
        both_nan = isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y)
        if x != y and not both_nan:
            differ.append(key)
    return differ


def test_every_task_and_preset_is_registered():
    assert len(ENV_IDS) == len(TASKS) * 2
    for env_id in ENV_IDS:
        assert env_id in gym.registry
    envs.register_envs()  # again: harmless


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_passes_without_a_warning(env_id):
    """The checker's seeds (123, 456 and the ones drawn after them) are rigs shared by every task of
    a preset: their force maps are computed once (tens of seconds each on a cold cache)."""
    env = gym.make(env_id)
    env.reset(seed=123)  # else its first reset() draws a rig from the OS's entropy: a new force map
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    env.close()
    assert [str(w.message) for w in caught] == []


def test_the_vector_api_runs_the_envs_on_their_own_seeds():
    vec = gym.make_vec("CapsuleMPC/pipe_fast-lab-v0", num_envs=2, vectorization_mode="sync")
    obs, info = vec.reset(seed=[3, 4])
    assert obs.shape == (2, len(OBSERVATION_FIELDS))
    assert list(info["seed"]) == [3, 4]
    for _ in range(3):
        obs, reward, terminated, truncated, info = vec.step(np.zeros((2, 3)))
    assert obs.shape == (2, len(OBSERVATION_FIELDS)) and reward.shape == (2,)
    assert not np.any(terminated) and not np.any(truncated)
    vec.close()


def test_a_seed_selects_the_plant_draw():
    env = CapsuleEnv("pipe_fast", "lab")
    env.reset(seed=3)
    truth = env._driver.loop.truth
    assert truth.seed == 3
    assert truth.values == draw_plant_truth(task_scenario("pipe_fast", "lab"), 3).values
    env.reset(seed=4)
    assert env._driver.loop.truth.values != truth.values
    env.close()


def test_reset_without_a_seed_never_draws_an_evaluation_or_test_seed():
    env = CapsuleEnv("pipe_fast", "lab")
    env.reset(seed=3)
    _, info = env.reset()  # drawn from the generator seeded by 3: one rig, cached after the first run
    env.close()
    assert info["seed"] >= envs.env.TRAINING_SEED_BASE > EVAL_SEED_BASE + 10_000


def test_follow_through_the_env_gives_the_simulate_run():
    env = CapsuleEnv("pipe_fast", "lab")
    info = run_episode(env, controller_policy("follow"), 3)
    direct = simulate(env.scenario, "follow", env.path, 3)
    assert _same_metrics(info["metrics"], direct.metrics) == []
    assert info["metrics"]["tracking_rms_mm"] == direct.metrics["tracking_rms_mm"]
    np.testing.assert_array_equal(env.result.log["capsule_x_m"], direct.log["capsule_x_m"])
    # the return is the negative integral of the tracking error (plus the final-error term)
    assert info["return"] < -envs.FINAL_ERROR_WEIGHT_S * info["metrics"]["final_error_mm"]


@pytest.mark.slow
def test_the_mpc_through_the_env_gives_the_simulate_run():
    env = CapsuleEnv("pipe_fast", "lab")
    info = run_episode(env, controller_policy("mpc"), 3)
    direct = simulate(env.scenario, "mpc", env.path, 3)
    assert _same_metrics(info["metrics"], direct.metrics) == []
    assert info["success"] == bool(direct.metrics["completed"])


def _settle_observations(monkeypatch, perturb) -> tuple[np.ndarray, dict]:
    """The observations of the settle phase (zero actions) on seed 3's rig, its truth perturbed."""
    real = sim_loop.draw_plant_truth
    monkeypatch.setattr(sim_loop, "draw_plant_truth", lambda sc, seed: perturb(real(sc, seed)))
    env = CapsuleEnv("rectangle", "lab")
    obs = [env.reset(seed=3)[0]]
    while obs[-1][0] < -env.frame_s:
        obs.append(env.step(np.zeros(3))[0])
    log = env._driver.loop.log.arrays()
    truth = env._driver.loop.truth
    env.close()
    return np.array(obs), {"log": log, "bias": (truth.camera_bias_x_m, truth.camera_bias_y_m)}


def test_the_observation_carries_nothing_of_the_truth_but_what_the_camera_sees(monkeypatch):
    def perturb(truth):
        values = dict(truth.values)
        values.update(mu0_scale=1.4, mass_scale=1.1, camera_bias_x_m=4e-4, camera_bias_y_m=-3e-4)
        values.update({k: v * 1.05 for k, v in values.items() if k.endswith("remanence_scale")})
        return dataclasses.replace(truth, values=values)

    base, truth_a = _settle_observations(monkeypatch, lambda t: t)
    other, truth_b = _settle_observations(monkeypatch, perturb)
    assert truth_a["bias"] != truth_b["bias"]
    np.testing.assert_array_equal(base[0], other[0])  # no frame has arrived yet: nothing differs
    rest = [i for i in range(len(OBSERVATION_FIELDS)) if i not in _MEAS]
    np.testing.assert_array_equal(base[:, rest], other[:, rest])
    # the camera: the capture one frame earlier, plus the bias (the noise is the seed's, the same)
    for obs, truth in ((base, truth_a), (other, truth_b)):
        log = truth["log"]
        seen = obs[1:, 1:3] - np.column_stack([log["capsule_x_m"], log["capsule_y_m"]])[: len(obs) - 1]
        seen -= np.asarray(truth["bias"])
        truth["noise"] = seen
    np.testing.assert_allclose(truth_a["noise"], truth_b["noise"], atol=1e-15)


def test_bad_actions_and_tasks_are_refused():
    env = CapsuleEnv("pipe_fast", "lab")
    env.reset(seed=3)
    with pytest.raises(ValueError, match=r"action: each of \(vx, vy, vz\) must be in \+-0.08 m/s"):
        env.step(np.array([0.5, 0.0, 0.0]))
    with pytest.raises(ValueError, match="action: must be 3 finite values"):
        env.step(np.array([np.nan, 0.0, 0.0]))
    env.close()
    with pytest.raises(ConfigError, match="task: must be one of"):
        CapsuleEnv("spiral", "lab")
    with pytest.raises(ConfigError, match="preset: must be one of"):
        CapsuleEnv("pipe", "ideal")


def test_evaluation_seeds_are_apart_from_the_tests_and_tuning():
    seeds = eval_seeds(200)
    assert min(seeds) == EVAL_SEED_BASE and min(seeds) > 1199
    with pytest.raises(ConfigError, match="draws: must be >= 1"):
        eval_seeds(0)


@pytest.mark.parametrize("task", ["unseen", "place"])
def test_drawn_paths_are_reproducible_and_within_the_epm_workspace(task):
    scenario = task_scenario(task, "hard")
    for seed in eval_seeds(30):
        path = task_path(task, seed)
        np.testing.assert_array_equal(path.waypoints_m, task_path(task, seed).waypoints_m)
        check_epm_workspace(scenario, path)
    assert not np.array_equal(task_path(task, 5000).waypoints_m, task_path(task, 5001).waypoints_m)
