"""The packaged recipes learn: each trained from scratch at a short budget beats its zero action (its
base controller alone), paired on test seeds. Minutes of training each (about 18 CPU-minutes
together), so they carry the ``recipe`` marker, which the default suite leaves out (pyproject's
addopts): run them with ``python -m pytest -m recipe`` when a recipe, a task or the training code
changes, and before a release."""

import dataclasses
import importlib
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
REPO = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.recipe, pytest.mark.slow]


def _standard_error(differences: np.ndarray) -> float:
    """The standard error of the mean of paired differences."""
    return float(differences.std(ddof=1) / math.sqrt(differences.size))


def _train_briefly(tmp_path, **settings):
    """A run of ``settings`` (TrainSettings' fields) evaluated once, at the end: its exported policy
    folder is the last model."""
    from microg_env.learning.train import TrainSettings, train

    run = TrainSettings(
        log_folder=str(tmp_path / "logs"), eval_freq=10**9, eval_episodes=1, checkpoint_freq=10**9, command="pytest"
    )
    return train(dataclasses.replace(run, **settings)) / "policy"


def _beats_its_base_at_the_collision(folder, seeds=range(1000, 1040)):
    """The deployed policy of ``folder`` against its base alone on the task's own draws ``seeds``,
    paired: x at the collision at least 5 % lower and more than two standard errors of the paired
    difference below. Returns the deployed policy."""
    from microg_env.controllers.registry import load_policy, policy_card
    from microg_env.rollout.batch import evaluate_batch
    from microg_env.task import ACTING_KEYS, TaskSettings

    task = policy_card(folder)["env_kwargs"]
    episodes = {key: value for key, value in task.items() if key not in ACTING_KEYS}  # the deployed policy acts
    learned = load_policy(folder, TaskSettings(**episodes).control_period_s)
    x = {
        name: np.array([run.flexible_unit_excursion_collision_m for run in evaluate_batch(episodes, c, seeds)[0]])
        for name, c in (("learned", learned), ("zero", task["base_controller"]))
    }
    differences = x["learned"] - x["zero"]
    assert x["learned"].mean() < 0.95 * x["zero"].mean(), (x["learned"].mean(), x["zero"].mean())
    assert differences.mean() < -2.0 * _standard_error(differences), differences
    return learned


def test_the_working_ids_recipe_beats_its_zero_residual_at_the_collision_after_a_short_budget(tmp_path):
    """sac.yml's MicroGravityLanding-Residual-v6 entry (the recipe of the shipped
    ``residual-sac-setpoint``, seed 5), 40 000 steps (about four minutes on one core; the shipped policy
    took 2 x 10^5, and each of the recipe's five seeds was 11-17 % below the base on its validation
    episodes by then): its exported policy holds x at the collision lower than the zero residual
    (``adaptive-dither`` alone) on 40 test episodes of the task's own draws, seeds 1000-1039, paired,
    by at least 5 % and by more than two standard errors of the paired difference. v6's return
    cannot tell them apart (it scores x in every period, the long rest on the pad included: the
    shipped policy's paired return over seeds 1000-1019 is the zero residual's, -0.13 +- 0.96), so
    the test reads what the recipe is chosen by."""
    from microg_env.controllers.registry import policy_card

    folder = _train_briefly(tmp_path, algo="sac", env_id="MicroGravityLanding-Residual-v6", seed=5, timesteps=40_000)
    task = policy_card(folder)["env_kwargs"]
    assert task["residual_gate_on"] == "setpoint"
    assert task["base_controller"] == "adaptive-dither"
    _beats_its_base_at_the_collision(folder)


def test_the_gain_scheduling_recipe_improves_return_and_collision_after_a_short_budget(tmp_path, monkeypatch):
    """ppo.yml's MicroGravityLanding-GainScheduling-v1 entry (stable-baselines3's PPO defaults but
    8 environments, VecNormalize and [64, 64] networks), seed 0, 40 960 steps (under a minute on two
    cores): on the task's own draws, paired with the zero action (``pid-dom`` as tuned), its exported
    policy earns more return on seeds 1000-1019 and holds x at the collision lower on seeds
    1000-1039, each by more than two standard errors of the paired difference, x by at least 5 %."""
    import gymnasium as gym

    monkeypatch.syspath_prepend(str(REPO / "training"))
    episode_return = importlib.import_module("returns_table").episode_return
    env_id = "MicroGravityLanding-GainScheduling-v1"
    learned = _beats_its_base_at_the_collision(_train_briefly(tmp_path, env_id=env_id, timesteps=40_000))
    env, policy, seeds = gym.make(env_id), learned.policy, range(1000, 1020)
    returns = {
        "learned": [episode_return(env, lambda o: policy.predict(o)[0].reshape(-1), s) for s in seeds],
        "zero": [episode_return(env, lambda o: np.zeros(3, dtype=np.float32), s) for s in seeds],
    }
    gain = np.array(returns["learned"]) - np.array(returns["zero"])
    assert gain.mean() > 2.0 * _standard_error(gain), gain


def test_the_command_recipe_follows_the_lander_after_a_short_budget(tmp_path, monkeypatch):
    """ppo.yml's MicroGravityLanding-Command-v1 entry (stable-baselines3's PPO defaults but 8
    environments and an action spread of e^-2), seed 0, 10^5 steps (about two minutes alone; the
    shipped policy took 3 x 10^5): the untrained network's action is about 0 (stable-baselines3
    starts its action layer at 1/100 of the others' scale), and the support held still ends every
    episode at the guide's end. On 20 of the task's own draws (seeds 1000-1019) the trained policy
    ends none there, earns more return than the zero action by more than two standard errors of
    the paired difference, and holds x at the collision within three times the paper's PID's mean."""
    import gymnasium as gym

    from microg_env.controllers.registry import load_policy, policy_card
    from microg_env.rollout.batch import evaluate_batch
    from microg_env.task import ACTING_KEYS, TaskSettings

    monkeypatch.syspath_prepend(str(REPO / "training"))
    episode_return = importlib.import_module("returns_table").episode_return
    env_id, seeds = "MicroGravityLanding-Command-v1", range(1000, 1020)
    folder = _train_briefly(tmp_path, env_id=env_id, timesteps=100_000)
    task = policy_card(folder)["env_kwargs"]
    episodes = {key: value for key, value in task.items() if key not in ACTING_KEYS}
    learned = load_policy(folder, TaskSettings(**episodes).control_period_s)
    runs, failures = evaluate_batch(episodes, learned, seeds)
    assert failures == 0.0
    pid_runs, _ = evaluate_batch(episodes, "pid", seeds)
    x = [np.mean([run.flexible_unit_excursion_collision_m for run in each]) for each in (runs, pid_runs)]
    assert x[0] < 3.0 * x[1], x
    env, policy = gym.make(env_id), learned.policy
    gain = np.array(
        [
            episode_return(env, lambda o: policy.predict(o)[0].reshape(-1), s)
            - episode_return(env, lambda o: np.zeros(1, dtype=np.float32), s)
            for s in seeds
        ]
    )
    assert gain.mean() > 2.0 * _standard_error(gain), gain
