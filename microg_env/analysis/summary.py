"""Summaries of runs' metrics: over seeds (mean, spread, worst case) and the costs controllers are
tuned and learned policies selected by."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from microg_env.analysis.metrics import RunMetrics


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


def finite_mean(values: Iterable[float]) -> float:
    """The mean of the finite values (a stage or window a run did not reach is NaN); NaN if none."""
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def failure_rate(runs: Sequence[RunMetrics]) -> float:
    """The share of ``runs`` that ended at a limit (0 for none)."""
    return sum(run.termination_reason is not None for run in runs) / max(len(runs), 1)


def control_cost(runs: Iterable[RunMetrics]) -> float:
    """The cost controllers are tuned by: J = mean |compensation error| [%] over the load stages of
    ``runs`` long enough to measure (a second of free fall) + the worst flexible-unit excursion at
    the collision [um] / 10 (the two headline figures of Section 3.2, weighted so 0.1 % counts as
    1 um). Infinite if a run ended at a limit or missed its collision, or no stage could be measured."""
    return _cost(runs, max)


def selection_cost(runs: Iterable[RunMetrics]) -> float:
    """The cost learned policies are selected by (training's best model, the shipped seed):
    :func:`control_cost` with the mean excursion at the collision in place of the worst, the
    statistic ``microg compare`` reports (the worst of a few dozen episodes is one draw's extreme;
    docs/research-log.md shows it choosing seeds out of their held-out order)."""
    return _cost(runs, np.mean)


def _cost(runs: Iterable[RunMetrics], excursion: Callable[[list[float]], float]) -> float:
    """Mean |compensation error| [%] + ``excursion`` of the runs' excursions at the collision [um] / 10."""
    errors, excursions = [], []
    for run in runs:
        if run.termination_reason is not None:
            return math.inf
        errors += [abs(e) for e in run.compensation_error_pct if math.isfinite(e)]
        excursions.append(run.flexible_unit_excursion_collision_m * 1e6)
    if not errors or not all(map(math.isfinite, excursions)):
        return math.inf
    return float(np.mean(errors) + excursion(excursions) / 10.0)
