"""One harness for every controller: run episodes on given seeds and summarise their metrics.

It accepts any environment of this package as users have it, raw or wrapped (``gym.make`` adds
``TimeLimit``, ``OrderEnforcing`` and the checker): it steps through the wrappers and reads the
rig's settings from ``env.unwrapped``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import gymnasium as gym
import numpy as np

from microg_env import validate
from microg_env.analysis.metrics import RunMetrics, compute_metrics
from microg_env.analysis.summary import failure_rate
from microg_env.controllers.base import Controller, tell_plants
from microg_env.controllers.pid import PID
from microg_env.envs.core import STATE_KEYS, TERMINATION_REASONS
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.scenarios import MAX_DURATION_S
from microg_env.sim.reference import simulate_reference
from microg_env.trajectory import CHANNELS, Trajectory, TrajectoryRecorder

#: Control steps between progress reports.
PROGRESS_EVERY = 1000


def _rig_env(env: gym.Env) -> MicroGravityLandingEnv:
    rig_env = env.unwrapped
    if not isinstance(rig_env, MicroGravityLandingEnv):
        raise ValueError(f"env must be a microg environment (raw or wrapped), got {type(rig_env).__name__}")
    return rig_env


def run_episode(
    env: gym.Env,
    controller: Controller,
    seed: int | None = None,
    duration_s: float | None = None,
    on_progress: Callable[[int], None] | None = None,
    on_step: Callable[[gym.Env, dict], None] | None = None,
) -> Trajectory:
    """Reset ``env`` with ``seed`` and let ``controller`` drive it for ``duration_s`` (default and
    at most: the scenario's). Stops early when the episode terminates or is truncated.

    ``on_progress(steps)`` reports the steps run, every 1000 and, at the end, the rest of the
    planned steps (so a progress bar ends full). ``on_step(env, info)`` sees the environment after
    the reset and after every step (e.g. to render a video).
    """
    rig_env = _rig_env(env)
    if duration_s is not None:  # a drawn schedule's duration is known only after the reset: it caps
        if rig_env.settings.scenario_sampler is not None:
            validate.positive("duration_s", duration_s, "s", MAX_DURATION_S, "the longest run")
        else:
            validate.positive("duration_s", duration_s, "s", rig_env.scenario.duration_s, "the scenario's duration")
    obs, info = env.reset(seed=seed)
    scenario_duration = rig_env.active_scenario.duration_s
    steps = round(min(scenario_duration, duration_s or scenario_duration) / rig_env.settings.control_period_s)
    controller.reset()
    tell_plants(controller, np.zeros(1, dtype=np.int64), [rig_env.params], ideal_drive=rig_env.core.rig.ideal_drive)
    raw = env is rig_env and type(env) is MicroGravityLandingEnv  # nothing overrides its step
    if raw and on_step is None and env.render_mode != "human" and rig_env.core.can_run_pid(controller):
        return _run_pid(rig_env, controller, steps, on_progress)  # the same steps, one compiled loop
    recorder = TrajectoryRecorder()
    recorder.append(info)
    if on_step is not None:
        on_step(env, info)
    reason, reported = None, 0
    for k in range(steps):
        obs, reward, terminated, truncated, info = env.step(controller(obs, info))
        recorder.append(info, reward)
        if on_step is not None:
            on_step(env, info)
        if on_progress is not None and (k + 1) % PROGRESS_EVERY == 0:
            on_progress(PROGRESS_EVERY)
            reported += PROGRESS_EVERY
        if terminated or truncated:
            reason = info["termination_reason"]
            break
    if on_progress is not None:
        on_progress(steps - reported)
    return recorder.finish(rig_env.active_scenario, rig_env.params.gravity_m_s2, rig_env.params.lander.mass_kg, reason)


def _run_pid(rig_env: MicroGravityLandingEnv, pid: PID, steps: int, on_progress) -> Trajectory:
    """:func:`run_episode`'s loop after the reset for a :class:`PID` on the raw single environment,
    compiled (:meth:`~microg_env.envs.core.LandingCore.run_pid`): the same trajectory, bit for bit
    (tests/rollout/test_episode.py), at close to the physics' own speed."""
    core, rngs = rig_env.core, [rig_env.np_random]
    states, rewards = np.empty((steps + 1, len(STATE_KEYS))), np.zeros(steps + 1)
    states[0] = core.state(np.zeros(1, dtype=np.int64))[0]  # the reset's
    done, code, reported = 0, None, 0
    while done < steps and code is None:
        ran, code = core.run_pid(pid, min(PROGRESS_EVERY - done % PROGRESS_EVERY, steps - done), rngs, states,
                                 rewards, done + 1)  # fmt: skip
        done += ran
        if on_progress is not None and done % PROGRESS_EVERY == 0:
            on_progress(PROGRESS_EVERY)
            reported += PROGRESS_EVERY
    if on_progress is not None:
        on_progress(steps - reported)
    rows = states[: done + 1, [STATE_KEYS.index(name) for name in CHANNELS[:-1]]]
    reason = None if code is None else TERMINATION_REASONS[code]
    params = rig_env.params
    return Trajectory.from_rows(
        rig_env.active_scenario, params.gravity_m_s2, params.lander.mass_kg, rows, rewards[: done + 1], reason
    )


def plant_of(env: gym.Env) -> tuple:
    """What the ideal reference of the episode ``env`` just ran depends on: the first four arguments
    of :func:`~microg_env.sim.reference.simulate_reference` (the scenario and parameters of its reset
    and its steps)."""
    rig_env = _rig_env(env)
    return rig_env.active_scenario, rig_env.params, rig_env.settings.control_period_s, rig_env.settings.physics_step_s


def reference_for(env: gym.Env, trajectory: Trajectory) -> Trajectory:
    """The ideal-microgravity landing of the episode ``env`` just ran, as long as ``trajectory``."""
    return simulate_reference(*plant_of(env), float(trajectory.time_s[-1]))


def run_with_metrics(
    env: gym.Env,
    controller: Controller,
    seed: int | None = None,
    duration_s: float | None = None,
    on_step: Callable[[gym.Env, dict], None] | None = None,
    on_progress: Callable[[int], None] | None = None,
) -> tuple[Trajectory, Trajectory, RunMetrics]:
    """One episode, its ideal-microgravity reference (same lander, pad and loads) and its metrics."""
    trajectory = run_episode(env, controller, seed, duration_s, on_progress=on_progress, on_step=on_step)
    reference = reference_for(env, trajectory)
    return trajectory, reference, compute_metrics(trajectory, reference)


def evaluate(
    make_env: Callable[[], gym.Env], controller: Controller, seeds: Iterable[int]
) -> tuple[list[RunMetrics], float]:
    """Metrics of ``controller`` on each seed, and the failure rate (episodes ended at a limit)."""
    env = make_env()
    try:
        runs = [run_with_metrics(env, controller, seed)[2] for seed in seeds]
    finally:
        env.close()
    return runs, failure_rate(runs)
