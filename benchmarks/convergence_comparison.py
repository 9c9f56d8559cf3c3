"""Convergence of a comparison's numbers with the physics step: the README's or the nominal plant's.

``benchmarks/convergence.py`` checks every metric of single episodes on the nominal plant. This runs
a comparison (``microg compare``, the same seeds for every controller, every sensor) at the default
physics step and at a step four times finer: by default the one the README quotes (held-out
schedules, plants and drives drawn 1.5 times wider than training's); with ``--randomize none
--scenarios condition-1,condition-2,condition-3,heavy-second,light-long --seeds 5`` the nominal
plant's (docs/controllers.md's "nominal plant" comparison). It prints for each controller and
headline quantity the mean at both steps, the change of the mean, the largest change of one
episode, and the paired ratio to the reference (mean over mean, as the comparison reports it) at
both steps (docs/model.md, "Drive scheme").

Usage: ``python benchmarks/convergence_comparison.py [--controllers pid,adaptive-dither,...]
[--reference adaptive-dither] [--scenarios heavy-second,...] [--seeds 2] [--randomize wider|none]
[--steps-us 100 25] [--workers 2]``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from microg_env.analysis.summary import finite_mean
from microg_env.experiments.comparison import QUANTITIES, compare
from microg_env.scenarios import HELD_OUT

#: The controllers the README's table names, and the quantities it reports.
CONTROLLERS = "pid,feedforward,adaptive,adaptive-dither,oracle,residual-sac-setpoint"
HEADLINE = ("collision_excursion_m", "free_fall_excursion_m", "compensation_error")
#: ``--randomize``: the comparison's plants.
RANDOMIZE = {"wider": "wider", "none": False}


def values(comparison, controller: str, quantity: str) -> np.ndarray:
    """The quantity of every episode of ``controller``, in the comparison's case order."""
    return np.array([run.values[quantity] for run in comparison.runs(controller)])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", default=CONTROLLERS)
    parser.add_argument("--reference", default="adaptive-dither")
    parser.add_argument("--scenarios", default=",".join(HELD_OUT))
    parser.add_argument("--seeds", type=int, default=2, help="seeds per schedule (default 2)")
    parser.add_argument("--randomize", choices=RANDOMIZE, default="wider", help="the plants (default: wider)")
    parser.add_argument("--steps-us", type=float, nargs=2, default=[100.0, 25.0])
    parser.add_argument("--duration", type=float, default=None, help="cap on each episode (default: its own)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    controllers = args.controllers.split(",")
    if args.reference not in controllers:
        parser.error(f"--reference must be one of --controllers, got {args.reference!r}")
    runs = [
        compare(
            controllers,
            args.scenarios.split(","),
            seeds=args.seeds,
            randomize=RANDOMIZE[args.randomize],
            duration_s=args.duration,
            workers=args.workers,
            reference=args.reference,
            physics_step_s=step_us / 1e6,
            floor=False,
        )
        for step_us in args.steps_us
    ]
    coarse, fine = args.steps_us
    episodes = len(runs[0].runs(args.reference))
    plants = "nominal plant" if args.randomize == "none" else "plants and drives drawn 1.5 times wider"
    print(f"{episodes} episodes ({plants}), physics step {coarse:g} and {fine:g} us")
    print(
        f"| controller | quantity | mean at {coarse:g} us | at {fine:g} us | change of the mean | largest change,"
        f" one episode | / {args.reference} at {coarse:g} us | at {fine:g} us |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for controller in controllers:
        for quantity in HEADLINE:
            q = QUANTITIES[quantity]
            a, b = (values(run, controller, quantity) for run in runs)
            ok = np.isfinite(a) & np.isfinite(b) & (b != 0)
            worst = np.abs(a[ok] / b[ok] - 1.0).max() if ok.any() else np.nan
            coarse_mean, fine_mean = finite_mean(a), finite_mean(b)
            change = coarse_mean / fine_mean - 1.0
            ratios = ["—", "—"]
            if controller != args.reference:
                ratios = [f"{run.paired(controller, quantity).ratio:.3f}" for run in runs]
            print(
                f"| `{controller}` | {q.label} [{q.unit}] | {coarse_mean * q.scale:.4g} | {fine_mean * q.scale:.4g}"
                f" | {100 * change:+.1f} % | {100 * worst:.1f} % | {ratios[0]} | {ratios[1]} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
