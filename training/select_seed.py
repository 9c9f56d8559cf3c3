"""Choose which training seed to ship: each run's exported best policy (``RUN/policy``, chosen by the
run's own 5 validation episodes) on 40 validation episodes, seeds 500-539 of the validation
schedules (``scenarios.VALIDATION_SAMPLER``, 30-50 mm starts) with the run's plants and drives
drawn (its ``domain_randomization``), never a test seed. The rule is the lowest control cost
(``analysis.summary.control_cost``: mean |compensation error| [%] + worst x at the collision /
10 um), the cost the PID was tuned by; the base controller alone (a zero residual) is the line.

Run: ``python training/select_seed.py logs/sac/MicroGravityLanding-Residual-v4_1 ...``
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from microg_env.analysis.metrics import RunMetrics
from microg_env.analysis.summary import control_cost
from microg_env.controllers.registry import load_policy, policy_card
from microg_env.envs.settings import TaskSettings
from microg_env.learning.train import VALIDATION_SEED, validation_settings
from microg_env.rollout.batch import evaluate_batch

#: The validation episodes' seeds: training's own 5 validation seeds and 35 more.
SEEDS = tuple(range(VALIDATION_SEED, VALIDATION_SEED + 40))


def scores(runs: list[RunMetrics]) -> dict[str, float]:
    """The control cost and the figures it is made of, and the mean x in free fall (which it leaves out)."""
    errors = [abs(e) for run in runs for e in run.compensation_error_pct if np.isfinite(e)]
    return {
        "cost": control_cost(runs),
        "compensation_error_pct": float(np.mean(errors)),
        "worst_collision_um": max(run.flexible_unit_excursion_collision_m for run in runs) * 1e6,
        "free_fall_um": float(np.mean([run.flexible_unit_excursion_free_fall_m for run in runs])) * 1e6,
    }


def main(argv: list[str]) -> int:
    runs = list(dict.fromkeys(argv))
    if not runs:
        sys.exit("usage: python training/select_seed.py RUN_FOLDER [RUN_FOLDER ...]")
    try:
        cards = [policy_card(Path(run) / "policy") for run in runs]
    except ValueError as error:
        sys.exit(f"select_seed: {error}")
    task = cards[0]["env_kwargs"]
    if task.get("action_mode") != "residual":
        sys.exit(f"{runs[0]}: not a residual policy; the seed selection compares residuals on one base controller")
    for run, card in zip(runs, cards, strict=True):
        if json.dumps(card["env_kwargs"], sort_keys=True) != json.dumps(task, sort_keys=True):
            sys.exit(f"{run}: trained on another task than {runs[0]}; compare runs of one task")
    settings = validation_settings(task)
    period = TaskSettings(**settings).control_period_s
    rows = {f"zero residual ({task['base_controller']})": (task["base_controller"], "")}
    for run, card in zip(runs, cards, strict=True):
        rows[run] = (load_policy(Path(run) / "policy", period), card.get("seed", ""))
    print("| run | seed | cost | \\|compensation error\\| [%] | worst x, collision [um] | x in free fall [um] |")
    print("|---|---|---|---|---|---|")
    costs = {}
    for name, (controller, seed) in rows.items():
        runs_metrics, _ = evaluate_batch(settings, controller, SEEDS)
        row = scores(runs_metrics)
        costs[name] = row["cost"]
        print(
            f"| {name} | {seed} | {row['cost']:.4f} | {row['compensation_error_pct']:.4f} | "
            f"{row['worst_collision_um']:.3f} | {row['free_fall_um']:.3f} |",
            flush=True,
        )
    print(f"lowest control cost: {min(runs, key=costs.__getitem__)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
