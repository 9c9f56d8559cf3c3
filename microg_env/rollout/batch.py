"""Many episodes at once: every (controller, scenario, seed) a rig of one ``mujoco.batch``.

:func:`run_batch` is the evaluation harness of :mod:`microg_env.rollout.episode` for many
episodes: the rigs are stepped together by :class:`~microg_env.envs.core.LandingCore`, each
controller drives its rigs in one vectorised call per control period, and each rig records the
same channels a single-environment episode records. Rig i seeded s runs exactly the episode
``run_episode`` runs on the single environment with seed s.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium.utils import seeding

from microg_env.analysis.metrics import RunMetrics, compute_metrics
from microg_env.analysis.summary import failure_rate
from microg_env.controllers.base import Controller, tell_plants
from microg_env.controllers.registry import make_controller
from microg_env.envs.core import TERMINATION_REASONS, LandingCore
from microg_env.params import RigParams
from microg_env.rollout.episode import PROGRESS_EVERY
from microg_env.scenarios import Scenario
from microg_env.sim.reference import simulate_reference
from microg_env.task import TaskSettings
from microg_env.trajectory import CHANNELS, Trajectory

#: Rigs stepped in one batch at most: the recorded channels take 14 x 8 bytes per rig and control
#: step (0.9 GB for 256 rigs of 30 s at 1 ms).
MAX_BATCH = 256


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode of a batch: who drives (a controller's name and the PID gains it replaces, as
    sorted (field, value) pairs; or a controller itself), which schedule (None: the settings', or
    one their ``scenario_sampler`` draws from the seed), from which seed, and the nominal rig a
    model-based controller named by ``controller`` is made for (None: the settings'; a controller
    given itself already has its own)."""

    controller: str | Controller
    scenario: Scenario | None
    seed: int
    gains: tuple[tuple[str, float], ...] = ()
    params: RigParams | None = None
    digest: str | None = None  # a policy's contents as its run was specified (RunSpec.controller_digest)


def run_batches(
    episodes: Sequence[EpisodeSpec],
    settings: Mapping[str, Any] | None = None,
    nthread: int = 0,
    progress: Callable[[float], None] | None = None,
) -> Iterator[list[tuple[int, Trajectory, RigParams, str | None]]]:
    """Run ``episodes`` on the rig of ``settings`` (``MicroGravityLandingEnv``'s keyword arguments:
    control period, physics step, imperfections, domain randomisation, params, and the schedule or
    sampler of the episodes that name none); with a domain randomisation each rig's plant is drawn
    from its seed. Yield each batch's runs as it ends: (index in ``episodes``, trajectory, the rig
    it ran on, error). A controller that raises or gives a non-finite action stops only its own
    rigs, there, with the error naming it (else None); the others run on. Every episode is a rig of
    one compiled model: their schedules may differ in their weights, start height, length and the
    parameters an episode sets (:data:`~microg_env.sim.model.EPISODE_PARAMETERS`), else the batch
    raises. At most :data:`MAX_BATCH` rigs are stepped at once, on ``nthread`` threads (0: one per
    usable core); ``progress(episodes)`` reports finished fractions of episodes."""
    settings = dict(settings or {})
    if len({episode.scenario is None for episode in episodes}) > 1:
        raise ValueError("episodes name a schedule each or none does (the settings' schedule or sampler), not some")
    chunks = -(-len(episodes) // MAX_BATCH)  # as few batches as fit, of equal size
    for bounds in np.array_split(np.arange(len(episodes)), max(chunks, 1)):
        if bounds.size:
            runs = _run_chunk([episodes[i] for i in bounds], settings, nthread, progress)
            yield [(int(i), *run) for i, run in zip(bounds, runs, strict=True)]


def run_batch(episodes: Sequence[EpisodeSpec], *args, **kwargs) -> list[tuple[Trajectory, RigParams, str | None]]:
    """Every run of :func:`run_batches` (same arguments), in the order of ``episodes``."""
    runs: list = [None] * len(episodes)
    for batch in run_batches(episodes, *args, **kwargs):
        for i, *run in batch:
            runs[i] = tuple(run)
    return runs


def evaluate_batch(
    settings: Mapping[str, Any], controller: Controller, seeds: Sequence[int], nthread: int = 0
) -> tuple[list[RunMetrics], float]:
    """:func:`microg_env.rollout.episode.evaluate` in one batch: the metrics of ``controller`` on
    each seed's episode of the environment of ``settings`` (its schedule, or one its
    ``scenario_sampler`` draws from the seed), and the failure rate (episodes ended at a limit).
    The rigs are the episodes the single environment runs one after another, bit for bit; a
    controller that raises or gives a non-finite action raises RuntimeError here, with its error
    (type and message) in the message."""
    task = TaskSettings(**settings)
    runs = []
    for trajectory, params, error in run_batch(
        [EpisodeSpec(controller, None, seed) for seed in seeds], settings, nthread
    ):
        if error is not None:
            raise RuntimeError(error)
        duration = float(trajectory.time_s[-1])
        reference = simulate_reference(
            trajectory.scenario, params, task.control_period_s, task.physics_step_s, duration
        )
        runs.append(compute_metrics(trajectory, reference))
    return runs, failure_rate(runs)


def _run_chunk(episodes, settings, nthread, progress) -> list[tuple[Trajectory, RigParams, str | None]]:
    n = len(episodes)
    scenarios = None if episodes[0].scenario is None else [e.scenario for e in episodes]
    core = LandingCore(n, TaskSettings(**settings), scenarios, batched=True, nthread=nthread)
    rngs = [seeding.np_random(e.seed)[0] for e in episodes]
    every = np.arange(n)
    core.reset(every, rngs)
    groups = []  # (name, controller, its rigs)
    for who in dict.fromkeys((e.controller, e.gains, e.params, e.digest) for e in episodes):
        rigs = np.array([i for i, e in enumerate(episodes) if (e.controller, e.gains, e.params, e.digest) == who])
        controller, gains, nominal, digest = who
        if isinstance(controller, str):
            nominal = core.base_params if nominal is None else nominal
            controller = make_controller(
                controller, core.settings.control_period_s, nominal, dict(gains), core.settings.sensor_set, digest
            )
        controller.reset(np.arange(rigs.size))
        plants = [core.episodes[i].params for i in rigs]
        tell_plants(controller, np.arange(rigs.size), plants, ideal_drive=core.rig.ideal_drive)
        groups.append((who[0] if isinstance(who[0], str) else type(who[0]).__name__, controller, rigs))
    channels = CHANNELS[:-1]  # every channel but the reward comes from info
    record = np.zeros((len(CHANNELS), n, int(core.max_steps.max()) + 1))
    info = core.info(every, np.zeros(n, dtype=np.int64))
    for c, name in enumerate(channels):
        record[c, :, 0] = info[name]
    reasons: list[str | None] = [None] * n
    errors: list[str | None] = [None] * n
    running = every
    is_running = np.ones(n, dtype=bool)
    actions = np.zeros(n)
    reported = 0.0
    while running.size:
        for name, controller, rigs in groups:
            active = is_running[rigs]
            if not active.any():
                continue
            live = rigs[active]
            try:
                actions[live] = controller(core.shown(live), ids=np.flatnonzero(active))[:, 0]  # as the env shows it
            except Exception as error:  # this controller's rigs stop here; the others run on
                _stop(live, f"controller {name!r} raised {type(error).__name__}: {error}", errors, is_running)
                continue
            bad = live[~np.isfinite(actions[live])]
            if bad.size:
                value = float(actions[bad[0]])
                _stop(bad, f"controller {name!r} gave a non-finite action ({value!r})", errors, is_running)
        running = running[is_running[running]]
        if not running.size:
            continue
        reward, codes, truncated, _ = core.step(running, np.clip(actions[running], -1.0, 1.0), rngs)
        info = core.info(running, codes)
        column = int(core.steps[running[0]])  # the rigs started together: one step count
        rows = slice(None) if running.size == n else running
        for c, name in enumerate(channels):
            record[c, rows, column] = info[name]
        record[-1, rows, column] = reward
        ended = (codes != 0) | truncated
        for i, code in zip(running[ended], codes[ended], strict=True):
            reasons[i] = TERMINATION_REASONS[code]
        is_running[running[ended]] = False
        running = running[~ended]
        if progress is not None and (not running.size or core.steps[running[0]] % PROGRESS_EVERY == 0):
            done = float(np.minimum(core.steps / core.max_steps, 1.0).sum())
            done = n if not running.size else done
            progress(done - reported)
            reported = done
    if progress is not None and reported < n:  # rigs a controller stopped count as done
        progress(n - reported)
    runs = []
    for i, episode in enumerate(core.episodes):
        length = int(core.steps[i]) + 1
        arrays = {name: record[c, i, :length].copy() for c, name in enumerate(CHANNELS)}
        arrays["stage"] = arrays["stage"].astype(int)
        trajectory = Trajectory(
            episode.scenario,
            episode.params.gravity_m_s2,
            episode.params.lander.mass_kg,
            termination_reason=reasons[i],
            **arrays,
        )
        runs.append((trajectory, episode.params, errors[i]))
    return runs


def _stop(rigs: np.ndarray, error: str, errors: list[str | None], is_running: np.ndarray) -> None:
    """End rigs ``rigs`` where they are, with ``error``."""
    for i in rigs:
        errors[i] = error
    is_running[rigs] = False
