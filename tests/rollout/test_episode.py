"""The evaluation harness: any environment of this package, raw or wrapped; summaries over seeds."""

import math
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

from microg_env.analysis.summary import summarise
from microg_env.compiled import mj_step
from microg_env.controllers import make_controller
from microg_env.controllers.pid import PID
from microg_env.envs.core import LandingCore
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.imperfections import Imperfections
from microg_env.rollout.episode import evaluate, run_episode, run_with_metrics
from microg_env.scenarios import CONDITIONS
from microg_env.trajectory import CHANNELS

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
    trajectory = run_episode(env, make_controller("pid", env.settings.control_period_s), seed=0, duration_s=40.0)
    drawn = env.active_scenario.duration_s
    assert drawn < 30.0
    assert trajectory.time_s[-1] == pytest.approx(drawn, abs=env.settings.control_period_s)


#: Conditions 2 and 3 to past their first collision and lift-off (condition 2: 3.4 and 4.6 s;
#: condition 3 under pid-dom: the second weight at 8.7 s, the collision at 10.1 s, lift-off at
#: 11.4 s). The later bounces of the 30 s run the same code paths again.
CONDITION_2, CONDITION_3 = replace(CONDITIONS[2], duration_s=5.0), replace(CONDITIONS[3], duration_s=12.0)


def _both_loops(settings: dict, controller: str = "pid", seed: int = 0, pid=None, **kwargs):
    """The episode run by the compiled PID loop and by the environment's own steps (an on_step
    callback keeps run_episode on them), with each run's progress reports, environment, PID and
    the compiled loop's calls (none for the environment's steps)."""
    runs = []
    for python_loop in (False, True):
        env = MicroGravityLandingEnv(**settings)
        each = make_controller(controller, env.settings.control_period_s, **kwargs) if pid is None else pid()
        reports, calls = [], []
        env.core.run_pid = lambda *args, calls=calls, run=env.core.run_pid: calls.append(args[1]) or run(*args)
        on_step = (lambda env, info: None) if python_loop else None
        try:
            trajectory = run_episode(env, each, seed, on_progress=reports.append, on_step=on_step)
        except ValueError as error:
            trajectory = error
        runs.append((trajectory, reports, env, each, calls))
    assert runs[0][4], "the compiled loop did not run"
    assert not runs[1][4]
    return runs


def _same_state(fast_env, slow_env, fast_pid, slow_pid):
    """The environments, their generators and the PIDs are where each other's are, to the last bit."""
    fields = ("observation", "steps", "previous_action", "placed_load_kg", "reward_x", "reward", "descent")
    for field in (*fields, "last_readings"):
        np.testing.assert_array_equal(getattr(fast_env.core, field), getattr(slow_env.core, field), err_msg=field)
    for field in ("qpos", "qvel", "act", "ctrl"):
        np.testing.assert_array_equal(getattr(fast_env.data, field), getattr(slow_env.data, field), err_msg=field)
    assert fast_env.np_random.bit_generator.state == slow_env.np_random.bit_generator.state
    np.testing.assert_array_equal(fast_env.core._noise.used, slow_env.core._noise.used)
    assert fast_env.core._noise.exhausted == slow_env.core._noise.exhausted
    for name in PID.STATE:
        np.testing.assert_array_equal(getattr(fast_pid, name), getattr(slow_pid, name), err_msg=name)


@pytest.mark.parametrize(
    ("settings", "controller", "seed"),
    [
        # noise blocks run out
        ({"condition": 1, "scenario": replace(CONDITIONS[1], duration_s=2.5)}, "pid", 0),
        # weights placed in flight, a period finished outside the loop
        ({"scenario": CONDITION_3}, "pid-dom", 3),
        # the descent term, two windows
        ({"scenario": CONDITION_3, "reward_descent_weight": 0.5}, "pid-dom", 3),
        # a drawn plant
        ({"scenario_sampler": "training", "domain_randomization": "full"}, "pid", 7),
        # MuJoCo's own stepping: nstep per period
        ({"scenario": CONDITION_3, "drive_scheme": "mujoco"}, "pid-dom", 3),
        # the ideal drive, exact sensors
        ({"scenario": CONDITION_2, "imperfections": Imperfections.none()}, "pid", 1),
        # sensors missing, 5 physics steps a period
        ({"scenario": CONDITION_2, "sensor_set": "paper", "control_period_s": 5e-4}, "pid", 2),
    ],
)
def test_the_compiled_pid_loop_runs_the_environments_episode_bit_for_bit(settings, controller, seed):
    (fast, fast_reports, fast_env, fast_pid, _), (slow, slow_reports, slow_env, slow_pid, _) = _both_loops(
        settings, controller, seed
    )
    assert len(fast) == len(slow) > 1000
    for name in CHANNELS:
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
    assert fast.termination_reason == slow.termination_reason
    assert fast_reports == slow_reports
    assert sum(fast_reports) == len(fast) - 1
    _same_state(fast_env, slow_env, fast_pid, slow_pid)


def test_the_compiled_pid_loop_ends_where_the_environment_terminates():
    """A PID with no gains lets the loaded lander take x to the guide's end: both loops stop there."""
    runs = _both_loops({"condition": 3}, gains={"kp_per_s": 0, "ki_per_s2": 0.0, "kd": 0.0})
    (fast, fast_reports, fast_env, fast_pid, _), (slow, slow_reports, slow_env, slow_pid, _) = runs
    assert fast.termination_reason == slow.termination_reason == "guide_stroke_limit"
    assert len(fast) == len(slow) < CONDITIONS[3].duration_s / 1e-3
    np.testing.assert_array_equal(fast.x_m, slow.x_m)
    np.testing.assert_array_equal(fast.reward, slow.reward)
    assert fast_reports == slow_reports
    _same_state(fast_env, slow_env, fast_pid, slow_pid)


def test_the_compiled_pid_loop_refuses_a_non_finite_action_as_the_environment_does():
    """Its first action is NaN, when the sensors' first noise draws are still to be made: both loops
    raise the environment's error before drawing them."""

    def nan_pid():
        pid = make_controller("pid", 1e-3)
        pid.constants = (math.nan, *pid.constants[1:])  # kp: every command NaN
        return pid

    (fast, _, fast_env, fast_pid, _), (slow, _, slow_env, slow_pid, _) = _both_loops({"condition": 1}, pid=nan_pid)
    assert isinstance(fast, ValueError)
    assert str(fast) == str(slow) == "action must be finite, got nan"
    _same_state(fast_env, slow_env, fast_pid, slow_pid)


def test_only_a_pid_on_the_raw_single_environment_takes_the_compiled_loop(monkeypatch):
    taken = []
    monkeypatch.setattr(LandingCore, "run_pid", lambda self, *args: taken.append(args) or (1, 0))

    class Tuned(PID):  # a subclass may act otherwise: stepped through the environment
        pass

    class Logged(MicroGravityLandingEnv):  # a subclass may step otherwise
        pass

    pid = make_controller("pid", 1e-3)
    tuned = Tuned(pid.gains, 1e-3)
    short = {"scenario": replace(CONDITIONS[1], duration_s=0.01)}
    run_episode(gym.make(ENV_ID, **short), pid, 0)  # wrapped
    run_episode(Logged(**short), pid, 0)
    run_episode(MicroGravityLandingEnv(**short), tuned, 0)
    run_episode(MicroGravityLandingEnv(**short), make_controller("feedforward", 1e-3), 0)
    run_episode(MicroGravityLandingEnv(**short, decision_period=2), pid, 0)
    run_episode(MicroGravityLandingEnv(**short, action_mode="residual"), pid, 0)
    run_episode(MicroGravityLandingEnv(**short), pid, 0, on_step=lambda env, info: None)
    assert not taken
    run_episode(MicroGravityLandingEnv(**short), pid, 0)
    assert len(taken) == 1


def test_kernels_find_mujocos_step_beside_the_bindings():
    """Without it the compiled PID loop silently falls back to the environment's steps."""
    assert mj_step is not None
    assert LandingCore(1).can_run_pid(make_controller("pid", 1e-3))


def test_the_compiled_pid_loop_steps_the_midpoint_drive_as_the_environment_does():
    """With ``drive_scheme="midpoint"`` the PID's compiled loop sets the drive's speed input every
    physics step as the environment's own steps do, bit for bit; the scheme changes x."""
    settings = {"condition": 3, "drive_scheme": "midpoint"}
    pid = make_controller("pid", 1e-3)
    compiled = run_episode(MicroGravityLandingEnv(**settings), pid, 5, duration_s=0.3)
    stepped = run_episode(MicroGravityLandingEnv(**settings), pid, 5, duration_s=0.3, on_step=lambda env, info: None)
    np.testing.assert_array_equal(compiled.x_m, stepped.x_m)
    mujocos = run_episode(MicroGravityLandingEnv(condition=3, drive_scheme="mujoco"), pid, 5, duration_s=0.3)
    assert np.abs(compiled.x_m - mujocos.x_m).max() > 1e-9


def test_every_runner_shows_a_controller_what_the_environment_shows():
    """With ``hidden_observations`` the PID reads 0 for x whichever loop runs it: the compiled loop
    (which reads the whole observation, so it steps aside), the environment's own steps and a batch
    (these gave x 39 um apart in 0.3 s before)."""
    from microg_env.rollout.batch import EpisodeSpec, run_batch

    settings = {"condition": 3, "hidden_observations": ("x",)}
    pid = make_controller("pid", 1e-3)
    compiled = run_episode(MicroGravityLandingEnv(**settings), pid, 5, duration_s=0.3)
    stepped = run_episode(MicroGravityLandingEnv(**settings), pid, 5, duration_s=0.3, on_step=lambda env, info: None)
    (batched, _, error), *_ = run_batch([EpisodeSpec("pid", None, 5)], settings | {"scenario": None}, 1)
    assert error is None
    shown = run_episode(MicroGravityLandingEnv(condition=3), pid, 5, duration_s=0.3)
    np.testing.assert_array_equal(compiled.x_m, stepped.x_m)
    np.testing.assert_array_equal(compiled.x_m, batched.x_m[: len(compiled)])
    assert np.abs(compiled.x_m - shown.x_m).max() > 1e-6  # blind to x, the PID lets x go
