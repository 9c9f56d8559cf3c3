"""The evaluation harness: any environment of this package, raw or wrapped; summaries over seeds."""

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

from microg_env.analysis.summary import summarise
from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.rollout.episode import evaluate, run_episode, run_with_metrics
from microg_env.scenarios import CONDITIONS

ENV_ID = "microg_env:MicroGravityLanding-v1"


def test_the_harness_runs_the_env_users_have():
    """gym.make wraps the env (TimeLimit, OrderEnforcing, checker): the harness used to fail on it."""
    made = gym.make(ENV_ID, condition=2)
    raw = MicroGravityLandingEnv(condition=2)
    controller = make_controller("pid", 1e-3)
    wrapped_run = run_episode(made, controller, seed=4, duration_s=1.0)
    raw_run = run_episode(raw, controller, seed=4, duration_s=1.0)
    assert len(wrapped_run) == len(raw_run) == 1001
    np.testing.assert_array_equal(wrapped_run.x_m, raw_run.x_m)
    _, _, metrics = run_with_metrics(gym.make(ENV_ID, condition=2), controller, seed=4, duration_s=2.0)
    assert metrics.termination_reason is None


def test_the_harness_rejects_other_envs_and_durations_beyond_the_scenario():
    controller = make_controller("pid", 1e-3)
    with pytest.raises(ValueError, match="microg environment"):
        run_episode(gym.make("CartPole-v1"), controller)
    with pytest.raises(ValueError, match="duration_s"):
        run_episode(MicroGravityLandingEnv(condition=1), controller, duration_s=31.0)


def test_evaluation_harness_over_seeds():
    scenario = replace(CONDITIONS[2], duration_s=2.0)  # the free fall only
    runs, failure_rate = evaluate(
        lambda: gym.make(ENV_ID, scenario=scenario), make_controller("pid", 1e-3), seeds=[0, 1, 2]
    )
    assert len(runs) == 3
    assert failure_rate == 0.0
    errors = [abs(run.compensation_error_pct[0]) for run in runs]
    summary = summarise(runs, lambda run: abs(run.compensation_error_pct[0]))
    assert summary.mean == pytest.approx(np.mean(errors))
    assert summary.worst == max(errors)
    assert len(set(errors)) > 1  # the seeds change the noise


def test_a_drawn_schedule_runs_to_its_own_duration():
    """With a scenario sampler the duration is drawn at reset (here a few seconds): a longer cap
    than condition 1's 30 s is accepted and the run ends at the drawn schedule's end."""
    env = MicroGravityLandingEnv(scenario_sampler="training")
    trajectory = run_episode(env, make_controller("pid", env.control_period_s), seed=0, duration_s=40.0)
    drawn = env.active_scenario.duration_s
    assert drawn < 30.0
    assert trajectory.time_s[-1] == pytest.approx(drawn, abs=env.control_period_s)
