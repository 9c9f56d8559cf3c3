"""PID tuning by simulation (docs/controllers.md; ``training/tune_pid.py`` runs the full tuner).

Candidates come from the x loop's closed form: with an ideal drive the loop of x is
(1 + Kd) s^2 + Kp s + (Ki + w0^2), w0^2 = k / M (Eq. 17's residual stiffness over the lander's
mass), so Kp = 2 zeta sqrt((1 + Kd)(Ki + w0^2)); for derivative on the measurement (``pid-dom``)
Kp and Ki are scaled by 1 + Kd. Each candidate runs on the tuning schedules, every imperfection on,
seed :data:`TUNING_SEED`, as rigs of one batch, and is scored by
:func:`~microg_env.analysis.summary.control_cost`; the best candidate that stays stable with every
gain doubled (gain margin >= 2) wins.

:func:`retune` does this on one spec's own rig and control period (a campaign's ``pid-retuned``),
with the smaller grid :data:`RETUNE_KI` x :data:`RETUNE_ZETA`; :func:`run_with_retuning` runs specs
that name ``pid-retuned`` as ``pid`` with the gains it chose, tuned once per rig before they run.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np

from microg_env import validate
from microg_env.analysis.summary import control_cost
from microg_env.controllers.pid import PIDGains, load_gains
from microg_env.rollout.runner import RunResult, error_text, run_all, run_many
from microg_env.rollout.spec import RETUNED_PID, RunSpec
from microg_env.sim.model import flexible_unit

#: The seed every candidate runs on (test and validation seeds start at 500).
TUNING_SEED = 0
#: Integral gains (s^-2) and damping ratios :func:`retune` tries on each rig and period.
RETUNE_KI = (2500.0, 5000.0, 10_000.0, 17_500.0, 30_000.0, 50_000.0)
RETUNE_ZETA = (0.5, 0.7, 1.0)


@dataclass(frozen=True)
class Candidate:
    """A candidate's gains and score: J, mean |compensation error| %, worst collision x um."""

    gains: PIDGains
    cost: float
    error_pct: float
    collision_um: float
    robust: bool  # stable with every gain doubled

    def gains_dict(self) -> dict[str, float]:
        return asdict(self.gains)


def candidate_gains(ki_per_s2: float, zeta: float, kd: float, dom: bool, omega0_squared: float) -> PIDGains:
    """The gains of one candidate (module docstring), rounded as the tuned ones are stored."""
    base = load_gains("pid-dom" if dom else "pid")
    if dom:  # -Kd dz_support/dt divides the loop's gains by 1 + Kd: scale them back up
        kp, ki = 2.0 * zeta * math.sqrt(ki_per_s2 + omega0_squared) * (1.0 + kd), ki_per_s2 * (1.0 + kd)
    else:
        kp, ki = 2.0 * zeta * math.sqrt((1.0 + kd) * (ki_per_s2 + omega0_squared)), ki_per_s2
    return replace(base, kp_per_s=round(kp, 1), ki_per_s2=float(round(ki)), kd=kd)


def omega0_squared(spec: RunSpec) -> float:
    """w0^2 = k / M of the spec's rig, s^-2 (negative for Eq. 17 read literally)."""
    params = spec.rig_params()
    return flexible_unit(params).x_stiffness_n_per_m / params.lander.mass_kg


def score(candidates: Sequence[PIDGains], schedules: Sequence[RunSpec], workers: int = 1) -> list[Candidate]:
    """Each candidate's cost over ``schedules`` (their gains and seed replaced) and whether it stays
    stable with every gain doubled: candidates and doubles run together, as batches of ``run_all``."""
    doubled = [replace(g, kp_per_s=2 * g.kp_per_s, ki_per_s2=2 * g.ki_per_s2, kd=2 * g.kd) for g in candidates]
    every = list(candidates) + doubled
    specs = [schedule.replace(seed=TUNING_SEED, gains=asdict(gains)) for gains in every for schedule in schedules]
    results = run_all(specs, workers)
    failed = [r.error for r in results if not r.ok]
    if failed:
        raise RuntimeError(f"a tuning run failed: {failed[0]}")
    n = len(schedules)
    metrics = [[r.metrics for r in results[k * n : (k + 1) * n]] for k in range(len(every))]
    out = []
    for k, gains in enumerate(candidates):
        runs = metrics[k]
        errors = [abs(e) for m in runs for e in m.compensation_error_pct if math.isfinite(e)]
        collision = max(m.flexible_unit_excursion_collision_m for m in runs) * 1e6
        robust = math.isfinite(control_cost(metrics[len(candidates) + k]))
        mean_error = float(np.mean(errors)) if errors else math.nan
        out.append(Candidate(gains, control_cost(runs), mean_error, collision, robust))
    return out


def best(scored: Sequence[Candidate]) -> Candidate:
    """The robust candidate of least cost; raises if no candidate of finite cost is robust."""
    ranked = sorted((c for c in scored if math.isfinite(c.cost) and c.robust), key=lambda c: c.cost)
    if not ranked:
        raise RuntimeError("no candidate both completes its runs and stays stable with its gains doubled")
    return ranked[0]


def retune(spec: RunSpec, workers: int = 1) -> Candidate:
    """The best robust ``pid`` on ``spec``'s own rig as its controller assumes it (no plant
    overrides), schedule and control period (nominal plant, seed :data:`TUNING_SEED`), from
    :data:`RETUNE_KI` x :data:`RETUNE_ZETA`."""
    schedule = spec.replace(controller="pid", gains={}, randomize=False, plant_overrides={})
    w0 = omega0_squared(schedule)
    candidates = [candidate_gains(ki, zeta, 0.0, False, w0) for ki in RETUNE_KI for zeta in RETUNE_ZETA]
    return best(score(candidates, [schedule], workers))


def run_with_retuning(
    specs: Sequence[RunSpec],
    workers: int = 1,
    progress: Callable[[float], None] | None = None,
    keep_trajectories: bool = False,
) -> Iterator[list[tuple[int, RunResult]]]:
    """:func:`~microg_env.rollout.runner.run_many` of ``specs`` (same arguments), each ``pid-retuned``
    spec first re-tuned on its rig and period (:func:`retune`, once per rig) and run as ``pid`` with
    those gains (its own ``gains`` replacing them field by field). Results carry the spec as given
    and the gains in ``tuned_gains``; a spec whose tuning fails fails alone."""
    for spec in specs:  # before anything is tuned
        validate.instance("run spec", spec, RunSpec)
    tuned: dict[str, dict[str, float] | BaseException] = {}
    runnable, gains, members = [], [], []
    for i, spec in enumerate(specs):
        if spec.controller != RETUNED_PID:
            runnable.append(spec)
            gains.append({})
            members.append(i)
            continue
        assumed = spec.replace(plant_overrides={}).plant_key  # what it is tuned on
        if assumed not in tuned:
            try:
                tuned[assumed] = retune(spec).gains_dict()
            except Exception as error:  # its runs fail; the others run on
                tuned[assumed] = error
        chosen = tuned[assumed]
        if isinstance(chosen, BaseException):
            if progress is not None:
                progress(1)
            yield [(i, RunResult(spec, None, error_text(chosen)))]
            continue
        merged = chosen | dict(spec.gains)
        runnable.append(spec.replace(controller="pid", gains=merged))
        gains.append(merged)
        members.append(i)
    for batch in run_many(runnable, workers, progress, keep_trajectories):
        yield [(members[k], replace(r, spec=specs[members[k]], tuned_gains=gains[k])) for k, r in batch]
