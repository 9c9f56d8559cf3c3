"""Controllers compared on the same physics: every controller on the same scenarios and seeds.

Each case (controller, scenario, seed) is one episode of ``MicroGravityLanding-v1`` with the
speed action, every imperfection on and, with ``randomize``, the domain randomisation's plant
drawn from the seed, so every controller meets the same plant, noise and drift. The scenarios are
held out of training (:func:`microg_env.scenarios.comparison_scenarios`) and the seeds start at
:data:`TEST_SEED`, above every training and validation seed. The cases run as rigs of
``mujoco.batch`` batches (:func:`microg_env.analysis.batch.run_batches`, ``workers`` threads), each
controller driving its rigs in one vectorised call; the ideal references run in ``workers``
processes. Each case keeps its metrics and, for the first seed, x around the touchdown.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from microg_env import validate
from microg_env.analysis.batch import EpisodeSpec, run_batches
from microg_env.analysis.evaluate import Summary, finite_mean, summarise
from microg_env.analysis.metrics import RunMetrics, compute_metrics, contacts
from microg_env.analysis.trajectory import Trajectory
from microg_env.params import CONTROL_PERIOD_S, PHYSICS_STEP_S, RigParams
from microg_env.scenarios import Scenario, comparison_scenarios
from microg_env.sim.reference import simulate_reference

#: First test seed: training seeds its environments from 0 (``n_envs`` of them), validation from 500.
TEST_SEED = 1000
#: Most seeds per scenario and worker processes a comparison takes.
MAX_SEEDS, MAX_WORKERS = 1000, 256
#: The window of x kept for the figure, s before and after the first touchdown.
X_WINDOW_S = (-1.0, 3.0)


@dataclass(frozen=True)
class Quantity:
    """A compared metric: how to read it from a run, and how to show it."""

    label: str
    unit: str
    scale: float  # SI value * scale = shown value
    of: Callable[[RunMetrics], float]


def _deformation_error(run: RunMetrics) -> float:
    return abs(run.max_deformation_m / run.reference_max_deformation_m - 1.0)


#: What the comparison reports, all magnitudes (larger is worse), SI in the JSON.
QUANTITIES: dict[str, Quantity] = {
    "compensation_error": Quantity(
        "compensation error (abs.)", "%", 1.0, lambda run: finite_mean(map(abs, run.compensation_error_pct))
    ),
    "residual_gravity_g": Quantity(
        "residual gravity error", "g", 1.0, lambda run: finite_mean(map(abs, run.residual_gravity_g))
    ),
    "free_fall_excursion_m": Quantity("x in free fall", "um", 1e6, lambda run: run.flexible_unit_excursion_free_fall_m),
    "collision_excursion_m": Quantity(
        "x at the collision", "um", 1e6, lambda run: run.flexible_unit_excursion_collision_m
    ),
    "deformation_error": Quantity("peak deformation vs ideal", "%", 100.0, _deformation_error),
}


@dataclass(frozen=True)
class Case:
    """One episode of the comparison."""

    controller: str
    scenario: str
    seed: int


@dataclass(frozen=True)
class CaseResult:
    case: Case
    metrics: RunMetrics
    values: dict[str, float]  # QUANTITIES, SI (NaN where the run did not reach it)
    x_window: tuple[np.ndarray, np.ndarray] | None = None  # (time from touchdown s, x m), first seed only

    @property
    def failed(self) -> bool:
        return self.metrics.termination_reason is not None


def _reference(job: tuple[Scenario, RigParams, float, float, float]) -> Trajectory:
    """The ideal-microgravity landing of one plant and schedule (a process pool's task)."""
    scenario, params, control_period_s, physics_step_s, duration_s = job
    return simulate_reference(scenario, params, control_period_s, physics_step_s, duration_s)


def _result(case: Case, trajectory: Trajectory, reference: Trajectory, keep_x: bool) -> CaseResult:
    metrics = compute_metrics(trajectory, reference)
    window = None
    found = contacts(trajectory)
    if keep_x and found:
        t = trajectory.time_s - trajectory.time_s[found[0].start]
        keep = (t >= X_WINDOW_S[0]) & (t <= X_WINDOW_S[1])
        window = (t[keep], trajectory.x_m[keep])
    values = {name: float(quantity.of(metrics)) for name, quantity in QUANTITIES.items()}
    return CaseResult(case, metrics, values, window)


@dataclass(frozen=True)
class Comparison:
    """Every case's result, and summaries over seeds and scenarios."""

    controllers: tuple[str, ...]
    scenarios: dict[str, Scenario]
    seeds: tuple[int, ...]
    randomize: bool
    control_period_s: float
    duration_s: float | None
    results: list[CaseResult] = field(default_factory=list)

    def runs(self, controller: str, scenario: str | None = None) -> list[CaseResult]:
        return [
            r
            for r in self.results
            if r.case.controller == controller and (scenario is None or r.case.scenario == scenario)
        ]

    def summary(self, controller: str, quantity: str, scenario: str | None = None) -> Summary:
        """Mean, std and worst (largest) of ``quantity`` over the controller's runs (those that reached it)."""
        runs = self.runs(controller, scenario)
        return summarise([r.values for r in runs], lambda values: values[quantity])

    def failure_rate(self, controller: str, scenario: str | None = None) -> float:
        runs = self.runs(controller, scenario)
        return sum(r.failed for r in runs) / max(len(runs), 1)

    def as_dict(self) -> dict:
        """JSON-ready: settings, summaries per controller (and per scenario), and every case."""

        def clean(value: float) -> float | None:
            return value if math.isfinite(value) else None

        def summaries(controller: str, scenario: str | None) -> dict:
            out = {}
            for name in QUANTITIES:
                s = self.summary(controller, name, scenario)
                out[name] = {"mean": clean(s.mean), "std": clean(s.std), "worst": clean(s.worst)}
            return out | {"failure_rate": self.failure_rate(controller, scenario)}

        return {
            "controllers": list(self.controllers),
            "scenarios": {
                name: {
                    "loads": [[load.mass_kg, load.height_m] for load in s.loads],
                    "descent_height_m": s.descent_height_m,
                    "duration_s": s.duration_s if self.duration_s is None else min(s.duration_s, self.duration_s),
                }
                for name, s in self.scenarios.items()
            },
            "seeds": list(self.seeds),
            "randomize": self.randomize,
            "control_period_s": self.control_period_s,
            "quantities": {
                name: {"label": q.label, "si_unit_times": q.scale, "unit": q.unit} for name, q in QUANTITIES.items()
            },
            "summary": {c: summaries(c, None) for c in self.controllers},
            "per_scenario": {c: {s: summaries(c, s) for s in self.scenarios} for c in self.controllers},
            "cases": [
                {
                    "controller": r.case.controller,
                    "scenario": r.case.scenario,
                    "seed": r.case.seed,
                    "termination_reason": r.metrics.termination_reason,
                    "values": {k: clean(v) for k, v in r.values.items()},
                }
                for r in self.results
            ],
        }


def compare(
    controllers: Sequence[str],
    scenarios: Sequence[str] | None = None,
    seeds: int = 5,
    first_seed: int = TEST_SEED,
    randomize: bool = False,
    control_period_s: float = CONTROL_PERIOD_S,
    duration_s: float | None = None,
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
) -> Comparison:
    """Run every controller on every scenario and seed; ``progress(fraction)`` as episodes advance."""
    from microg_env.controllers.registry import check_controller_name

    known = comparison_scenarios()
    names = tuple(known) if scenarios is None else tuple(scenarios)
    for name in names:
        if name not in known:
            raise ValueError(f"scenario must be one of {', '.join(known)}, got {name!r}")
    for controller in controllers:
        check_controller_name(controller)
    if not controllers or not names:
        raise ValueError("give at least one controller and one scenario")
    validate.integer("seeds", seeds, 1, MAX_SEEDS)
    workers = validate.integer("workers", workers, 1, MAX_WORKERS)
    seed_list = tuple(range(first_seed, first_seed + seeds))
    cases = [Case(c, s, seed) for s in names for seed in seed_list for c in dict.fromkeys(controllers)]
    comparison = Comparison(
        tuple(dict.fromkeys(controllers)),
        {s: known[s] for s in names},
        seed_list,
        randomize,
        control_period_s,
        duration_s,
    )
    episodes = [EpisodeSpec(case.controller, known[case.scenario], case.seed) for case in cases]
    results: list[CaseResult | None] = [None] * len(cases)
    with contextlib.ExitStack() as stack:
        pool = stack.enter_context(ProcessPoolExecutor(max_workers=workers)) if workers > 1 else None
        for batch in run_batches(episodes, control_period_s, randomize, duration_s, workers, progress):
            # One reference per plant, schedule and length: every controller meets the same plant on a
            # seed. Only the batch's trajectories and references are held, never every run's.
            jobs, keys = {}, []
            for _, trajectory, params in batch:
                length = float(trajectory.time_s[-1])
                keys.append((repr(trajectory.scenario), repr(params), length))
                jobs.setdefault(keys[-1], (trajectory.scenario, params, control_period_s, PHYSICS_STEP_S, length))
            computed = pool.map(_reference, jobs.values()) if pool is not None else map(_reference, jobs.values())
            references = dict(zip(jobs, computed, strict=True))
            for (i, trajectory, _), key in zip(batch, keys, strict=True):
                results[i] = _result(cases[i], trajectory, references[key], keep_x=cases[i].seed == seed_list[0])
    comparison.results.extend(results)
    return comparison
