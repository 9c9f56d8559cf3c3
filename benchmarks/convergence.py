"""Convergence of every reported metric with the physics step (the study behind PHYSICS_STEP_S).

Runs the paper's three conditions with each controller (the tuned PID, the feed-forward and the
shipped residual policy), every imperfection on, seed 0, at a range of physics steps, and compares
each metric with its value at a step four times finer than the candidate. A step converges when
every metric is within 1 % of that finer value and every compensation error within 0.02
percentage points (the criterion of the fidelity review).

Usage: ``python benchmarks/convergence.py [--steps-us 200 100 50 25] [--duration S]
[--controllers pid,feedforward,residual-ppo]``. Prints one table per controller and condition and,
last, the steps that converge on all three conditions, per controller.
"""

from __future__ import annotations

import argparse
import math
import sys

from microg_env.analysis.metrics import MEASURED_METRICS, RunMetrics
from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.rollout.episode import run_with_metrics

RELATIVE_TOLERANCE = 0.01
COMPENSATION_TOLERANCE_PP = 0.02


def run(controller: str, condition: int, physics_step_s: float, duration_s: float | None) -> RunMetrics:
    env = MicroGravityLandingEnv(condition=condition, physics_step_s=physics_step_s)
    return run_with_metrics(env, make_controller(controller, env.control_period_s), seed=0, duration_s=duration_s)[2]


def deviations(coarse: RunMetrics, fine: RunMetrics) -> dict[str, float]:
    """Per metric: the coarse value's deviation from the fine one (pp for compensation, else relative)."""
    out = {}
    for name in MEASURED_METRICS:
        a, b = getattr(coarse, name), getattr(fine, name)
        pairs = zip(a, b, strict=True) if isinstance(a, list) else [(a, b)]
        worst = 0.0
        for x, y in pairs:
            if not (math.isfinite(x) and math.isfinite(y)):
                continue
            worst = max(worst, abs(x - y) if name == "compensation_error_pct" else abs(x / y - 1.0))
        out[name] = worst
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps-us", type=float, nargs="+", default=[200.0, 100.0, 50.0, 25.0])
    parser.add_argument("--duration", type=float, default=None, help="simulated time per run (default: 30 s)")
    parser.add_argument("--controllers", default="pid,feedforward,residual-ppo")
    args = parser.parse_args(argv)
    steps = sorted(s * 1e-6 for s in args.steps_us)
    verdicts = []
    for controller in args.controllers.split(","):
        converged = {step: True for step in steps}
        for condition in (1, 2, 3):
            results = {step: run(controller, condition, step, args.duration) for step in steps}
            print(f"{controller}, condition {condition}: deviation from the run at a 4x finer step", end=" ")
            print("(compensation error in pp)")
            print(f"  {'metric':<40}" + "".join(f"{step * 1e6:>10.1f}us" for step in steps))
            table = {step: deviations(results[step], results[step / 4]) for step in steps if step / 4 in results}
            for name in MEASURED_METRICS:
                cells = "".join(f"{table[s][name]:>12.4g}" if s in table else f"{'-':>12}" for s in steps)
                print(f"  {name:<40}{cells}")
            for step, deviation in table.items():
                ok = all(
                    value <= (COMPENSATION_TOLERANCE_PP if name == "compensation_error_pct" else RELATIVE_TOLERANCE)
                    for name, value in deviation.items()
                )
                converged[step] = converged[step] and ok
            for step in steps:
                if step not in table:
                    converged[step] = False
        good = [step for step, ok in converged.items() if ok]
        verdicts.append(f"{controller}: " + (", ".join(f"{s * 1e6:g} us" for s in good) or "none"))
    print("converged on all three conditions:", "; ".join(verdicts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
