"""Choose which training seed to ship: each run's exported best policy (``RUN/policy``) on 200
validation episodes, seeds 500-699 of the validation schedules (``scenarios.VALIDATION_SAMPLER``,
30-50 mm starts) with the run's plants and drives drawn (its ``domain_randomization``), never a
test seed. The rule is the lowest selection cost (``analysis.summary.selection_cost``: mean
|compensation error| [%] + mean x at the collision / 10 um), the statistic the held-out comparison
reports; the base controller alone (a zero residual or gains action) is the line, or on a speed
task (no base) the paper's PID, and each run's mean x at the collision is also given as a ratio to
the line's on the same episodes. ``--sensor-set``
validates on another rig than the runs' own (``paper``: the paper's sensors).

Run: ``python training/select_seed.py [--episodes N] [--sensor-set paper]
logs/sac/MicroGravityLanding-Residual-v7_1 ...``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from microg_env.analysis.metrics import RunMetrics
from microg_env.analysis.summary import finite_mean, selection_cost
from microg_env.controllers.registry import load_policy, policy_card
from microg_env.experiments.comparison import TEST_SEED
from microg_env.interface import SENSOR_SETS
from microg_env.learning.train import VALIDATION_SEED, validation_runs, validation_settings
from microg_env.task import ActingSettings, TaskSettings

#: How many validation episodes, from VALIDATION_SEED, choose the seed unless told.
EPISODES = 200


def scores(runs: list[RunMetrics]) -> dict[str, float]:
    """The selection cost and the figures it is made of, the worst x at the collision and the mean
    x in free fall (which the cost leaves out)."""
    collision_um = [run.flexible_unit_excursion_collision_m * 1e6 for run in runs]
    return {
        "cost": selection_cost(runs),
        "compensation_error_pct": finite_mean(abs(e) for run in runs for e in run.compensation_error_pct),
        "collision_um": float(np.mean(collision_um)),
        "worst_collision_um": max(collision_um),
        "free_fall_um": float(np.mean([run.flexible_unit_excursion_free_fall_m for run in runs])) * 1e6,
    }


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="select_seed.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", metavar="RUN_FOLDER")
    parser.add_argument("--episodes", type=int, default=EPISODES, help=f"validation episodes (default {EPISODES})")
    parser.add_argument("--sensor-set", choices=SENSOR_SETS, help="the rig to validate on (default: the runs' own)")
    args = parser.parse_args(argv)
    if not 1 <= args.episodes <= TEST_SEED - VALIDATION_SEED:
        parser.error(f"--episodes must be 1 to {TEST_SEED - VALIDATION_SEED} (no test seed), got {args.episodes}")
    runs = list(dict.fromkeys(args.runs))
    try:
        cards = [policy_card(Path(run) / "policy") for run in runs]
    except ValueError as error:
        sys.exit(f"select_seed: {error}")
    task = cards[0]["env_kwargs"]
    for run, card in zip(runs, cards, strict=True):
        if json.dumps(card["env_kwargs"], sort_keys=True) != json.dumps(task, sort_keys=True):
            sys.exit(f"{run}: trained on another task than {runs[0]}; compare runs of one task")
    if args.sensor_set is not None:
        task = task | {"sensor_set": args.sensor_set}
    settings = validation_settings(task)
    period = TaskSettings(**settings).control_period_s
    seeds = range(VALIDATION_SEED, VALIDATION_SEED + args.episodes)
    mode = ActingSettings.of(task).action_mode
    if mode == "speed":  # no base: the paper's PID is the line
        zero, first = "pid", ("pid (the paper's)", "pid")
    else:
        zero = "zero action" if mode == "gains" else "zero residual"
        first = (f"{zero} ({task['base_controller']})", task["base_controller"])
    rows = {first[0]: (first[1], "")}  # first: the line
    for run, card in zip(runs, cards, strict=True):
        rows[run] = (load_policy(Path(run) / "policy", period), card.get("seed", ""))
    rig = task.get("sensor_set", "extended")
    print(f"{args.episodes} validation episodes, seeds {seeds[0]}-{seeds[-1]}, sensor set {rig}")
    print(
        f"| run | seed | cost | \\|compensation error\\| [%] | x, collision [um] | vs {zero} | "
        "worst x, collision [um] | x in free fall [um] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    costs, line = {}, None
    for name, (controller, seed) in rows.items():
        row = scores(validation_runs(task, controller, args.episodes)[0])
        costs[name] = row["cost"]
        if line is None:  # the line's, the first row
            line = row["collision_um"]
        print(
            f"| {name} | {seed} | {row['cost']:.4f} | {row['compensation_error_pct']:.4f} | "
            f"{row['collision_um']:.3f} | {row['collision_um'] / line:.3f}x | "
            f"{row['worst_collision_um']:.3f} | {row['free_fall_um']:.3f} |",
            flush=True,
        )
    print(f"lowest selection cost: {min(runs, key=costs.__getitem__)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
