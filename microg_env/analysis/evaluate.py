"""One harness for every controller: run episodes on given seeds and summarise their metrics."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from microg_env.analysis.metrics import RunMetrics, compute_metrics
from microg_env.analysis.trajectory import Trajectory, TrajectoryRecorder
from microg_env.controllers import Controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.sim.reference import simulate_reference


def run_episode(
    env: MicroGravityLandingEnv,
    controller: Controller,
    seed: int | None = None,
    duration_s: float | None = None,
    on_progress: Callable[[int], None] | None = None,
) -> Trajectory:
    """Reset ``env`` with ``seed`` and let ``controller`` drive it for ``duration_s`` (default: the scenario's).

    Stops early if the episode terminates. ``on_progress(steps)`` reports the steps run, every
    1000 and, at the end, the rest of the planned steps (so a progress bar ends full).
    """
    obs, info = env.reset(seed=seed)
    controller.reset()
    duration_s = env.active_scenario.duration_s if duration_s is None else duration_s
    steps = round(duration_s / env.control_period_s)
    recorder = TrajectoryRecorder(steps + 1)
    recorder.append(info)
    reason, reported = None, 0
    for k in range(steps):
        obs, reward, terminated, _, info = env.step(controller(obs, info))
        recorder.append(info, reward)
        if terminated:
            reason = info["termination_reason"]
            break
        if on_progress is not None and (k + 1) % 1000 == 0:
            on_progress(1000)
            reported += 1000
    if on_progress is not None:
        on_progress(steps - reported)
    return recorder.finish(env.active_scenario, env.params.gravity_m_s2, env.params.lander.mass_kg, reason)


def run_with_metrics(
    env: MicroGravityLandingEnv, controller: Controller, seed: int | None = None, duration_s: float | None = None
) -> tuple[Trajectory, Trajectory, RunMetrics]:
    """One episode, its ideal-microgravity reference (same lander, pad and loads) and its metrics."""
    trajectory = run_episode(env, controller, seed, duration_s)
    reference = simulate_reference(env.active_scenario, env.base_params, env.control_period_s, trajectory.time_s[-1])
    return trajectory, reference, compute_metrics(trajectory, reference)


@dataclass(frozen=True)
class Summary:
    """A metric over several seeds: mean, standard deviation and worst case."""

    mean: float
    std: float
    worst: float


def summarise(runs: Iterable[RunMetrics], quantity: Callable[[RunMetrics], float], worst: Callable = max) -> Summary:
    """Summary of ``quantity(run)`` over ``runs``, leaving out runs that never reached it (NaN)."""
    values = np.array([quantity(run) for run in runs], dtype=float)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return Summary(math.nan, math.nan, math.nan)
    return Summary(float(finite.mean()), float(finite.std()), float(worst(finite)))


def evaluate(
    make_env: Callable[[], MicroGravityLandingEnv], controller: Controller, seeds: Iterable[int]
) -> tuple[list[RunMetrics], float]:
    """Metrics of ``controller`` on each seed, and the failure rate (episodes ended at a stroke limit)."""
    env = make_env()
    runs = [run_with_metrics(env, controller, seed)[2] for seed in seeds]
    env.close()
    failures = sum(run.termination_reason is not None for run in runs)
    return runs, failures / max(len(runs), 1)
