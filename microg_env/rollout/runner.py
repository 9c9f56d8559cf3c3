"""The one runner: :func:`run` runs a :class:`~microg_env.rollout.spec.RunSpec`, :func:`run_many`
runs many, as rigs of ``mujoco.batch`` batches where they share a compiled model (specs that differ
only in controller, gains, seed, schedule and the parameters an episode sets:
:attr:`~microg_env.rollout.spec.RunSpec.batch_key`), and both return :class:`RunResult`: the
metrics and what produced them.

:func:`run` steps the single Gymnasium environment (it can render a video as it goes);
:func:`run_many` steps the vector core (:func:`microg_env.rollout.batch.run_batches`). A spec gives
the same trajectory either way, bit for bit (tests/envs/test_vector.py, tests/rollout/test_batch.py,
tests/experiments/test_experiments.py).
"""

from __future__ import annotations

import contextlib
import math
import platform
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from functools import cache
from importlib import metadata
from typing import Any

import gymnasium as gym

from microg_env import validate
from microg_env.analysis.metrics import RunMetrics, compute_metrics
from microg_env.controllers.registry import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.imperfections import apply_imperfections
from microg_env.rollout.batch import EpisodeSpec, run_batches
from microg_env.rollout.episode import plant_of, run_episode
from microg_env.rollout.spec import RETUNED_PID, RunSpec
from microg_env.scenarios import Scenario
from microg_env.sim.reference import cut_reference, reference_key, simulate_reference
from microg_env.trajectory import Trajectory
from microg_env.workers import process_pool, usable_cores

#: A reference's cost per simulated second as a share of a run's (0.45 s against 1.7 s for a 30 s
#: condition), to start the longest tasks first.
REFERENCE_COST = 0.25


@cache
def versions() -> dict[str, str]:
    """The versions a result was produced with."""
    out = {"python": platform.python_version()}
    for package in ("microg-env", "mujoco", "numpy", "gymnasium"):
        try:
            out[package] = metadata.version(package)
        except metadata.PackageNotFoundError:  # pragma: no cover - a source tree not installed
            out[package] = "unknown"
    return out


@dataclass(frozen=True)
class RunResult:
    """A run's metrics (None if it raised, with ``error``), its spec, the PID gains a re-tuned
    controller used (set by :func:`microg_env.experiments.tuning.run_with_retuning`), the wall time
    and versions; the trajectories only while in memory."""

    spec: RunSpec
    metrics: RunMetrics | None
    error: str | None = None
    tuned_gains: dict[str, float] = field(default_factory=dict)
    wall_s: float = math.nan
    versions: dict[str, str] = field(default_factory=versions)
    trajectory: Trajectory | None = field(default=None, repr=False, compare=False)
    reference: Trajectory | None = field(default=None, repr=False, compare=False)

    @property
    def ok(self) -> bool:
        return self.error is None


def run(
    spec: RunSpec,
    on_step: Callable[[gym.Env, dict], None] | None = None,
    on_progress: Callable[[int], None] | None = None,
    render: dict[str, Any] | None = None,
) -> RunResult:
    """Run ``spec`` on the single environment (``render``: its render keyword arguments;
    ``on_step(env, info)`` after the reset and every step; ``on_progress(steps)``). Raises on a bad
    spec; the result keeps both trajectories."""
    start = time.perf_counter()
    trajectory, plant = _episode(spec, on_step, on_progress, render)
    reference = simulate_reference(*plant, float(trajectory.time_s[-1]))
    return _scored(spec, trajectory, reference, time.perf_counter() - start)


def _episode(
    spec: RunSpec, on_step=None, on_progress=None, render: dict[str, Any] | None = None
) -> tuple[Trajectory, tuple]:
    """``spec``'s episode on the single environment, and its plant: the first four arguments of
    :func:`~microg_env.sim.reference.simulate_reference` (the scenario and parameters of its reset)."""
    env = MicroGravityLandingEnv(**spec.env_kwargs(), **(render or {}))
    try:
        trajectory = run_episode(env, _controller(spec), spec.seed, on_step=on_step, on_progress=on_progress)
        return trajectory, plant_of(env)
    finally:
        env.close()


def _scored(spec: RunSpec, trajectory: Trajectory, reference: Trajectory, wall_s: float) -> RunResult:
    """The result of ``spec``'s episode ``trajectory``, scored against ``reference``."""
    return RunResult(spec, compute_metrics(trajectory, reference), None, {}, wall_s, versions(), trajectory, reference)


def run_each(
    specs: Sequence[RunSpec], workers: int | None = None, progress: Callable[[int], None] | None = None
) -> list[RunResult]:
    """:func:`run` of each of ``specs`` (with its trajectories), in order; independent runs on
    ``workers`` processes at once (default: every usable core; 1: here, one after another), beside each
    ideal reference they need, simulated once as long as the longest run that needs it: a run cuts
    its own from it once both have ended (:func:`_shared_references`). ``progress(steps)``: a run's
    control steps as it ends. Raises on the first bad spec."""
    workers = min(workers or usable_cores(), len(specs))
    if workers <= 1:  # one process: its kept references are shared already
        results = []
        for spec in specs:
            results.append(run(spec))
            if progress is not None:
                progress(len(results[-1].trajectory) - 1)
        return results
    planned = [_planned_reference(spec) for spec in specs]
    jobs = _shared_references(planned)
    tasks = [(_reference, (job,), REFERENCE_COST * job[-1]) for job in jobs.values()]
    for spec, plan in zip(specs, planned, strict=True):
        length = spec.duration_s or spec.scenario_schedule().duration_s
        tasks.append((_timed_episode, (spec, plan is None), length * (1 if plan else 1 + REFERENCE_COST)))
    outcomes: list = [None] * len(tasks)
    with process_pool(workers) as pool:
        futures = {}
        for t in sorted(range(len(tasks)), key=lambda t: -tasks[t][2]):  # the longest first
            futures[pool.submit(tasks[t][0], *tasks[t][1])] = t
        for future in as_completed(futures):
            t = futures[future]
            outcomes[t] = future.result()
            if progress is not None and t >= len(jobs):
                progress(len(outcomes[t][0]) - 1)
    references = dict(zip(jobs, outcomes, strict=False))
    results = []
    for spec, (trajectory, plant, reference, wall_s) in zip(specs, outcomes[len(jobs) :], strict=True):
        if reference is None:  # cut from the shared one (or, were the plant not the one planned, its own)
            shared = references.get(reference_key(*plant))
            if shared is None:
                reference = simulate_reference(*plant, float(trajectory.time_s[-1]))
            else:
                reference = cut_reference(shared, len(trajectory), plant[0])
        results.append(_scored(spec, trajectory, reference, wall_s))
    return results


def _planned_reference(spec: RunSpec) -> tuple[tuple, list] | None:
    """The :func:`~microg_env.sim.reference.reference_key` of ``spec``'s reference and the
    :func:`_reference` job that simulates all of it, when known before it runs (None for a spec
    whose plant or weights are drawn at its reset)."""
    if spec.randomize:
        return None
    scenario = spec.scenario_schedule()
    params = apply_imperfections(scenario.rig_params(spec.plant_params()), spec.imperfection_flags())
    job = [scenario, params, spec.control_period_s, spec.physics_step_s, scenario.duration_s]
    return reference_key(*job[:4]), job


def _shared_references(planned: Sequence[tuple[tuple, list] | None]) -> dict[tuple, list]:
    """The :func:`_reference` job of each key in ``planned``, as long as the longest run that needs it."""
    jobs: dict[tuple, list] = {}
    for plan in planned:
        if plan is not None:
            key, job = plan
            kept = jobs.setdefault(key, list(job))
            kept[-1] = max(kept[-1], job[-1])
    return jobs


def _timed_episode(spec: RunSpec, with_reference: bool) -> tuple[Trajectory, tuple, Trajectory | None, float]:
    """:func:`_episode` of ``spec`` in a pool's process, its reference if ``with_reference`` (a plant
    drawn at the reset, which no shared reference can be planned for), and its wall time."""
    start = time.perf_counter()
    trajectory, plant = _episode(spec)
    reference = simulate_reference(*plant, float(trajectory.time_s[-1])) if with_reference else None
    return trajectory, plant, reference, time.perf_counter() - start


def run_many(
    specs: Sequence[RunSpec],
    workers: int = 1,
    progress: Callable[[float], None] | None = None,
    keep_trajectories: bool = False,
) -> Iterator[list[tuple[int, RunResult]]]:
    """Run ``specs``, one batch per compiled model, and yield each batch's (index in ``specs``, result)
    as it ends. A spec or batch that raises gives failed results (``error``), never an exception;
    a process pool that breaks raises (:func:`~microg_env.workers.process_pool`: a RuntimeError
    saying what to do where its workers could not start).
    ``workers``: the batch's threads and the processes of the ideal references;
    ``progress(runs)``: finished fractions of runs; ``keep_trajectories``: keep each result's
    trajectory and reference (else only metrics, so memory holds one batch)."""
    for spec in specs:  # before anything runs
        validate.instance("run spec", spec, RunSpec)
    groups: dict[str, list[int]] = {}
    for i, spec in enumerate(specs):
        groups.setdefault(spec.batch_key, []).append(i)

    def failed(i: int, error: BaseException) -> list[tuple[int, RunResult]]:
        if progress is not None:
            progress(1)
        return [(i, RunResult(specs[i], None, error_text(error)))]

    with contextlib.ExitStack() as stack:
        pool = stack.enter_context(process_pool(workers)) if workers > 1 else None
        for every in groups.values():
            members = []
            for i in every:  # a spec whose controller cannot be made fails alone, before any stepping
                try:
                    _controller(specs[i])
                except Exception as error:
                    yield failed(i, error)
                    continue
                members.append(i)
            done: set[int] = set()
            start = time.perf_counter()
            try:
                for batch in _run_group([specs[i] for i in members], workers, progress, pool):
                    elapsed = (time.perf_counter() - start) / max(len(batch), 1)
                    start = time.perf_counter()
                    done.update(members[i] for i, _ in batch)
                    yield [(members[i], _finished(result, elapsed, keep_trajectories)) for i, result in batch]
            except BrokenProcessPool:  # the pool's fault, not the batch's: no later batch could run
                raise
            except Exception as error:  # recorded per run: one bad batch must not stop a campaign
                rest = [i for i in members if i not in done]
                if progress is not None:
                    progress(len(rest))
                yield [(i, RunResult(specs[i], None, error_text(error))) for i in rest]


def run_all(specs: Sequence[RunSpec], workers: int = 1, **kwargs) -> list[RunResult]:
    """Every result of :func:`run_many` (same arguments), in the order of ``specs``."""
    results: list = [None] * len(specs)
    for batch in run_many(specs, workers, **kwargs):
        for i, result in batch:
            results[i] = result
    return results


def _finished(result: RunResult, wall_s: float, keep: bool) -> RunResult:
    """``result`` with its wall time, and its trajectories only if ``keep``."""
    if keep:
        return replace(result, wall_s=wall_s)
    return replace(result, wall_s=wall_s, trajectory=None, reference=None)


def error_text(error: BaseException) -> str:
    """The error's one-line message and where it was raised."""
    frame = traceback.extract_tb(error.__traceback__)[-1] if error.__traceback__ else None
    where = f" ({frame.filename.rsplit('/', 1)[-1]}:{frame.lineno})" if frame else ""
    return f"{type(error).__name__}: {error}{where}"


def _controller(spec: RunSpec):
    if spec.controller == RETUNED_PID:
        raise ValueError(
            f"controller {RETUNED_PID!r} is tuned before it runs: "
            "run it with microg_env.experiments.tuning.run_with_retuning"
        )
    return make_controller(
        spec.controller, spec.control_period_s, spec.rig_params(), spec.gains, spec.sensor_set, spec.controller_digest
    )


def _reference(job: tuple) -> Trajectory:
    """The ideal-microgravity landing of one plant and schedule (a process pool's task)."""
    scenario, params, control_period_s, physics_step_s, duration_s = job
    return simulate_reference(scenario, params, control_period_s, physics_step_s, duration_s)


def _as_run_alone(scenario: Scenario, spec: RunSpec) -> Scenario:
    """A rig's schedule (its weights perhaps drawn) with the overrides of ``spec``'s own schedule
    only, as ``run(spec)`` records it (:meth:`RunSpec.rig_schedule` added the spec's)."""
    return replace(scenario, overrides=dict(spec.scenario_schedule().overrides))


def _run_group(group: Sequence[RunSpec], workers: int, progress, pool) -> Iterator[list[tuple[int, RunResult]]]:
    """One compiled model's specs in batches, each rig on its own schedule, with one ideal
    reference per plant and schedule (every controller on a seed meets the same plant), simulated
    as long as its longest run and cut for the others."""
    episodes = [
        EpisodeSpec(s.controller, s.rig_schedule(), s.seed, tuple(s.gains.items()), s.rig_params(), s.controller_digest)
        for s in group
    ]
    first = group[0]
    for batch in run_batches(episodes, first.batch_kwargs(), workers, progress):
        jobs: dict[tuple, list] = {}
        keys = []
        for _, trajectory, params, error in batch:
            if error is not None:  # no reference for a run its controller stopped
                keys.append(None)
                continue
            length = float(trajectory.time_s[-1])
            keys.append(reference_key(trajectory.scenario, params, first.control_period_s, first.physics_step_s))
            job = jobs.setdefault(
                keys[-1], [trajectory.scenario, params, first.control_period_s, first.physics_step_s, 0.0]
            )
            job[-1] = max(job[-1], length)
        computed = pool.map(_reference, jobs.values()) if pool is not None else map(_reference, jobs.values())
        references = dict(zip(jobs, computed, strict=True))
        out = []
        for (i, trajectory, _, error), key in zip(batch, keys, strict=True):
            if error is not None:  # its controller failed: only its runs fail
                out.append((i, RunResult(group[i], None, f"{error} at t = {trajectory.time_s[-1]:.3f} s")))
                continue
            # the schedule as the single environment records it: without the spec's overrides
            trajectory = replace(trajectory, scenario=_as_run_alone(trajectory.scenario, group[i]))
            reference = cut_reference(references[key], len(trajectory), trajectory.scenario)
            metrics = compute_metrics(trajectory, reference)
            out.append((i, RunResult(group[i], metrics, None, {}, math.nan, versions(), trajectory, reference)))
        yield out
