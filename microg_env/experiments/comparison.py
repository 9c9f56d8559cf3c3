"""Controllers compared on the same physics: every controller on the same scenarios and seeds.

Each case (controller, scenario, seed) is one run (:class:`~microg_env.rollout.spec.RunSpec`)
of ``MicroGravityLanding-v1`` with the speed action, every imperfection on and, with
``randomize``, the domain randomisation's plant (and with "full" or "wider" its drive) drawn from the seed,
so every controller meets the same plant, noise and drift. The scenarios are held out of training
(:func:`microg_env.scenarios.comparison_scenarios`); each runs its own block of seeds
(:func:`~microg_env.experiments.comparison_settings.scenario_seeds`, from :data:`TEST_SEED`, above
every training and validation seed), so each episode meets a plant of its own. The cases run through
:func:`microg_env.rollout.runner.run_many`: as rigs of ``mujoco.batch`` batches (``workers``
threads), each controller driving its rigs in one vectorised call, the ideal references in
``workers`` processes. Each case keeps its metrics and, for the first seed, x around the touchdown.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from microg_env import validate
from microg_env.analysis.metrics import COMPARED_WINDOW, RunMetrics, contacts
from microg_env.analysis.paired import Paired, paired
from microg_env.analysis.summary import Summary, finite_mean, summarise
from microg_env.controllers.registry import check_controller_name, controller_digest
from microg_env.experiments.comparison_settings import MAX_SEEDS, MAX_WORKERS, TEST_SEED, scenario_seeds
from microg_env.imperfections import Imperfections, apply_imperfections
from microg_env.interface import CONTROLLER_NAMES
from microg_env.params import CONTROL_PERIOD_S, PHYSICS_STEP_S, parameter_paths
from microg_env.rollout.runner import run_many
from microg_env.rollout.spec import RunSpec
from microg_env.scenarios import Scenario, comparison_scenarios
from microg_env.sim.model import DEFAULT_DRIVE_SCHEME
from microg_env.trajectory import Trajectory

#: The window of x kept for the figure, s before and after the first touchdown.
X_WINDOW_S = (-1.0, 3.0)
#: The floor bracket beside every comparison (#46): the ``oracle`` (told each episode's plant) on the
#: same episode with parts of the drive made ideal, so that each controller reads against what is
#: left once the drive's imperfections go, not against the oracle alone. They are reference points
#: of the oracle's structure, not bounds. ``floor-ideal-drive``: the drive a speed source that
#: follows its reference exactly (no speed loop, torque filter, torque limit, cogging or motor
#: friction); ``floor-no-cogging-friction``: the drive as assumed without its cogging and without
#: friction (the motor's, the screw's and the QZS guide's). The control delay, the sensors' noise
#: and the rest of the plant stay. Imperfections switched off, by floor.
FLOORS: dict[str, dict[str, bool]] = {
    "floor-ideal-drive": {"servo_lag": False},
    "floor-no-cogging-friction": {"cogging": False, "friction": False},
}
#: The controller each floor runs.
FLOOR_CONTROLLER = "oracle"


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
    "free_fall_excursion_m": Quantity("x in free fall", "µm", 1e6, lambda run: run.flexible_unit_excursion_free_fall_m),
    "collision_excursion_m": Quantity(
        "x at the collision", "µm", 1e6, lambda run: run.flexible_unit_excursion_collision_m
    ),
    "collision_instant_m": Quantity(  # the paper's "change at the instant of collision"
        "x change, 5 ms from touchdown", "µm", 1e6, lambda run: run.x_change_after_touchdown_m[COMPARED_WINDOW]
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


def _result(case: Case, metrics: RunMetrics, trajectory: Trajectory, keep_x: bool) -> CaseResult:
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
    seeds: dict[str, tuple[int, ...]]  # each scenario's own seeds (scenario_seeds)
    randomize: bool | str  # False, True (the plant), "full" (the plant and the drive) or "wider"
    control_period_s: float
    duration_s: float | None
    results: list[CaseResult] = field(default_factory=list)
    #: The controller the others are paired against (:meth:`paired`), or None.
    reference: str | None = None
    sensor_set: str = "extended"  # the rig's sensors (microg_env.interface.SENSOR_SETS)
    #: Names shown for controllers (``microg compare --label``): shown name -> the controller run.
    labels: dict[str, str] = field(default_factory=dict)
    #: The rig's parameters that differ from the paper's, by dotted path (``microg compare --rig``).
    overrides: dict[str, Any] = field(default_factory=dict)
    physics_step_s: float = PHYSICS_STEP_S
    #: The floors run beside the controllers (:data:`FLOORS`), each a row of its own.
    floors: tuple[str, ...] = ()

    @property
    def rows(self) -> tuple[str, ...]:
        """What the tables show, each paired with the reference: the controllers, then the floors."""
        return self.controllers + self.floors

    def relabelled(self, labels: Mapping[str, str]) -> Comparison:
        """This comparison with each controller run as one of ``labels``' values shown under its key
        (a policy folder's path becomes a short name in tables and figures)."""
        check_labels(labels, self.controllers)
        shown = {run: label for label, run in labels.items()}
        ran = {label: self.labels.get(run, run) for label, run in labels.items()}  # what ran, through earlier labels

        def name(controller: str) -> str:
            return shown.get(controller, controller)

        return replace(
            self,
            controllers=tuple(map(name, self.controllers)),
            results=[replace(r, case=replace(r.case, controller=name(r.case.controller))) for r in self.results],
            reference=None if self.reference is None else name(self.reference),
            labels={name: run for name, run in self.labels.items() if name not in shown} | ran,
        )

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

    @property
    def first_seed(self) -> int:
        """The first seed of the seed range: the k-th scenario of ``comparison_scenarios()`` runs
        its block from ``first_seed + k * MAX_SEEDS``."""
        name = next(iter(self.scenarios))
        return self.seeds[name][0] - (scenario_seeds(name, 0, 1)[0])

    @property
    def seeds_per_scenario(self) -> int:
        return len(next(iter(self.seeds.values())))

    def paired(
        self, controller: str, quantity: str, reference: str | None = None, scenario: str | None = None
    ) -> Paired:
        """``controller`` against ``reference`` (default :attr:`reference`) on the same scenarios and
        seeds, or on ``scenario``'s alone (:mod:`microg_env.analysis.paired`, resampling and testing
        by seed: a seed is one episode, on a plant of its own)."""
        reference = self.reference if reference is None else reference
        theirs = {(r.case.scenario, r.case.seed): r.values[quantity] for r in self.runs(reference, scenario)}
        ours = [r for r in self.runs(controller, scenario) if (r.case.scenario, r.case.seed) in theirs]
        return paired(
            [r.values[quantity] for r in ours],
            [theirs[(r.case.scenario, r.case.seed)] for r in ours],
            [r.case.seed for r in ours],
        )

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
            "seeds": {name: list(seeds) for name, seeds in self.seeds.items()},
            "randomize": self.randomize,
            "control_period_s": self.control_period_s,
            "physics_step_s": self.physics_step_s,
            "drive_scheme": DEFAULT_DRIVE_SCHEME,  # every run's: RunSpec keeps the environment's default
            "quantities": {
                name: {"label": q.label, "si_unit_times": q.scale, "unit": q.unit} for name, q in QUANTITIES.items()
            },
            "floors": {
                name: {"controller": FLOOR_CONTROLLER, "imperfections": dict(FLOORS[name])} for name in self.floors
            },
            "summary": {c: summaries(c, None) for c in self.rows},
            "per_scenario": {c: {s: summaries(c, s) for s in self.scenarios} for c in self.rows},
            "reference": self.reference,
            "sensor_set": self.sensor_set,
            "overrides": self.overrides,
            "labels": self.labels,
            "paired": {
                c: {name: self.paired(c, name).as_dict() for name in QUANTITIES}
                for c in self.rows
                if self.reference is not None and c != self.reference
            },
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


#: What a label may be: words of letters, digits, ``_ . + -``, single spaces between (a name that
#: reads in a Markdown table cell and a figure's legend).
LABEL_PATTERN = re.compile(r"[\w.+-]+( [\w.+-]+)*")


def check_labels(labels: Mapping[str, str], controllers: Sequence[str]) -> None:
    """Raise ValueError unless each label names one of ``controllers``, once, with a new short name:
    not another controller's, nor a controller's the registry knows (``oracle`` on ``adaptive``'s
    results would publish them as the oracle's)."""
    for label, run in labels.items():
        if label in FLOORS:
            raise ValueError(f"label {label}={run}: {label!r} names a floor row")
        if run not in controllers:
            raise ValueError(f"label {label}={run}: {run!r} is not one of the controllers {', '.join(controllers)}")
        if not LABEL_PATTERN.fullmatch(label):
            raise ValueError(f"label {label!r}={run}: a name is letters, digits, '_', '.', '+', '-' and single spaces")
        if label != run and (label in controllers or label in CONTROLLER_NAMES):
            raise ValueError(f"label {label}={run}: {label!r} names another controller")
    if len(set(labels.values())) < len(labels):
        raise ValueError(f"label: a controller is given two names ({', '.join(labels)})")


def _floor_overrides(overrides: Mapping[str, Any], off: Mapping[str, bool]) -> dict[str, Any]:
    """The rig ``overrides`` that a floor with the imperfections ``off`` runs: those it leaves as
    given (a cogging or friction value set by the rig is overwritten where the floor switches that
    imperfection off, and the run would refuse it as unused)."""
    params = RunSpec(overrides=overrides).rig_params()
    flags = replace(Imperfections(), **off)
    applied = parameter_paths(apply_imperfections(params, flags))
    given = parameter_paths(params)
    return {path: value for path, value in overrides.items() if applied[path] == given[path]}


def compare(
    controllers: Sequence[str],
    scenarios: Sequence[str] | None = None,
    seeds: int = 5,
    first_seed: int = TEST_SEED,
    randomize: bool | str = False,
    control_period_s: float = CONTROL_PERIOD_S,
    duration_s: float | None = None,
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
    reference: str | None = None,
    sensor_set: str = "extended",
    overrides: Mapping[str, Any] | None = None,
    physics_step_s: float = PHYSICS_STEP_S,
    floor: bool = True,
) -> Comparison:
    """Run every controller on every scenario and seed; ``progress(fraction)`` as episodes advance;
    ``reference``: one of ``controllers``, the others paired against it; ``sensor_set``: the rig's
    sensors ("paper": no pad force, no accelerometer); ``overrides``: the rig's parameters by dotted
    path (a rig file's), which every controller's model assumes too; ``physics_step_s``: the
    physics step (``benchmarks/convergence_comparison.py`` runs a comparison at two); ``floor``:
    the floor bracket (:data:`FLOORS`) on the same episodes."""
    known = comparison_scenarios()
    names = tuple(known) if scenarios is None else tuple(scenarios)
    for name in names:
        if name not in known:
            raise ValueError(f"scenario must be one of {', '.join(known)}, got {name!r}")
    for controller in controllers:
        if controller in FLOORS:
            raise ValueError(f"controller {controller!r} names a floor row; floor=True runs the floors")
        check_controller_name(controller, sensor_set)
    if not controllers or not names:
        raise ValueError("give at least one controller and one scenario")
    identities = [controller_digest(c) or c for c in controllers]  # a policy is its contents, however named
    for kind, given, same in (("controller", tuple(controllers), identities), ("scenario", names, names)):
        repeated = next((i for i in range(len(given)) if same[i] in same[:i]), None)
        if repeated is not None:  # its runs would count twice in every mean and test
            first = given[same.index(same[repeated])]
            also = "" if first == given[repeated] else f" (as {first!r} too)"
            raise ValueError(f"{kind} {given[repeated]!r} is given twice{also}")
    if reference is not None and reference not in controllers:
        raise ValueError(
            f"reference must be one of the compared controllers {', '.join(controllers)}, got {reference!r}"
        )
    validate.integer("seeds", seeds, 1, MAX_SEEDS)
    workers = validate.integer("workers", workers, 1, MAX_WORKERS)
    seed_lists = {name: scenario_seeds(name, first_seed, seeds) for name in names}
    floors = tuple(FLOORS) if floor else ()
    cases = [Case(c, s, seed) for s in names for seed in seed_lists[s] for c in (*controllers, *floors)]
    comparison = Comparison(
        tuple(controllers),
        {s: known[s] for s in names},
        seed_lists,
        randomize,
        control_period_s,
        duration_s,
        reference=reference,
        sensor_set=sensor_set,
        overrides=dict(RunSpec(overrides=overrides or {}).overrides),  # checked, a default's value dropped
        physics_step_s=physics_step_s,
        floors=floors,
    )
    # each row's rig: the comparison's, less what a floor's switched-off imperfections overwrite
    rigs = {name: _floor_overrides(comparison.overrides, FLOORS[name]) for name in floors}
    specs = []
    for case in cases:
        length = (
            known[case.scenario].duration_s if duration_s is None else min(known[case.scenario].duration_s, duration_s)
        )
        specs.append(
            RunSpec(
                case.scenario,
                FLOOR_CONTROLLER if case.controller in FLOORS else case.controller,
                case.seed,
                imperfections=FLOORS.get(case.controller, {}),
                randomize=randomize,
                control_period_us=control_period_s * 1e6,
                duration_s=length,
                sensor_set=sensor_set,
                overrides=rigs.get(case.controller, comparison.overrides),
                physics_step_us=physics_step_s * 1e6,
            )
        )
    results: list[CaseResult | None] = [None] * len(cases)
    for batch in run_many(specs, workers, progress, keep_trajectories=True):
        for i, result in batch:  # only the batch's trajectories are held, never every run's
            if not result.ok:
                raise ValueError(f"{cases[i].controller} on {cases[i].scenario}, seed {cases[i].seed}: {result.error}")
            first = cases[i].seed == seed_lists[cases[i].scenario][0]
            results[i] = _result(cases[i], result.metrics, result.trajectory, keep_x=first)
    comparison.results.extend(results)
    return comparison
