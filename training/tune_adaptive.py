"""Choose the adaptive feed-forward's LMS step; the result goes into microg_env/config/controllers.toml.

Each candidate step drives conditions 1-3 on validation seeds 500-502 (never a test seed) with plants
and drives drawn (``DomainRandomization.full()``), and is scored by the PID tuner's cost J = mean
|compensation error| [%] + collision excursion [um] / 10 (training/tune_pid.py). Prints J of each.

Run: ``python training/tune_adaptive.py [--steps 0.001,0.003,0.01,0.03] [--seeds 3]``.
"""

from __future__ import annotations

import argparse
import sys

from microg_env.analysis.summary import finite_mean
from microg_env.controllers.registry import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.imperfections import DomainRandomization
from microg_env.learning.train import VALIDATION_SEED
from microg_env.rollout.episode import run_with_metrics


def cost(step: float, seeds: int, duration_s: float | None) -> float:
    """J of the adaptive feed-forward with LMS step ``step``."""
    values = []
    for number in (1, 2, 3):
        env = MicroGravityLandingEnv(condition=number, domain_randomization=DomainRandomization.full())
        for seed in range(VALIDATION_SEED, VALIDATION_SEED + seeds):
            controller = make_controller("adaptive", env.control_period_s)
            controller.adaptive_constants = (step, *controller.adaptive_constants[1:])
            metrics = run_with_metrics(env, controller, seed, duration_s)[2]
            error = finite_mean(map(abs, metrics.compensation_error_pct))
            values.append(error + metrics.flexible_unit_excursion_collision_m * 1e6 / 10)
    return finite_mean(values)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", default="0.001,0.003,0.01,0.03", help="candidate LMS steps, comma-separated")
    parser.add_argument("--seeds", type=int, default=3, help="validation seeds per condition (from 500)")
    parser.add_argument("--duration", type=float, default=None, help="cap on each run's simulated time, s")
    args = parser.parse_args(argv)
    for step in (float(text) for text in args.steps.split(",")):
        print(f"step {step:g}: J = {cost(step, args.seeds, args.duration):.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
