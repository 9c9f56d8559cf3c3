"""The physics step on held-out randomised plants under each ``drive_scheme`` (issue 47).

Runs ``adaptive-dither`` and the shipped ``residual-sac-setpoint`` on held-out schedules with plants
and drives drawn 1.5 times wider than training's (``domain_randomization="wider"``), at 100 and
25 µs, under each scheme, and prints the change of the mean x at the collision, the per-episode
changes, and the learned / dither ratio (geometric mean over the episodes) at each step.

Run: ``python research/drive_scheme_held_out.py [--scenarios heavy-second,fast-impact,three-stage,high-start]
[--seeds 1000,1001,1002,1003] [--duration S]``. docs/model.md ("Drive scheme") quotes its defaults.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.rollout.episode import run_with_metrics
from microg_env.scenarios import HELD_OUT
from microg_env.sim.model import DRIVE_SCHEMES

CONTROLLERS = ("adaptive-dither", "residual-sac-setpoint")
STEPS_S = (1e-4, 2.5e-5)


def collision_x(scheme: str, controller: str, step_s: float, args: argparse.Namespace) -> np.ndarray:
    """x at the collision, m, of every episode (schedule x seed)."""
    out = []
    for name in args.scenarios.split(","):
        for seed in map(int, args.seeds.split(",")):
            env = MicroGravityLandingEnv(
                scenario=HELD_OUT[name], domain_randomization="wider", physics_step_s=step_s, drive_scheme=scheme
            )
            policy = make_controller(controller, env.settings.control_period_s)
            out.append(run_with_metrics(env, policy, seed=seed, duration_s=args.duration)[2])
    return np.array([run.flexible_unit_excursion_collision_m for run in out])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", default="heavy-second,fast-impact,three-stage,high-start")
    parser.add_argument("--seeds", default="1000,1001,1002,1003")
    parser.add_argument("--duration", type=float, default=None, help="simulated s per episode (default: its own)")
    args = parser.parse_args(argv)
    for scheme in DRIVE_SCHEMES:
        x = {(c, s): collision_x(scheme, c, s, args) for c in CONTROLLERS for s in STEPS_S}
        for controller in CONTROLLERS:
            coarse, fine = x[(controller, STEPS_S[0])], x[(controller, STEPS_S[1])]
            change = np.abs(coarse / fine - 1.0)
            print(f"{scheme:<9} {controller:<22} mean x {coarse.mean() * 1e6:.4f} / {fine.mean() * 1e6:.4f} um,"
                  f" change of the mean {100 * (coarse.mean() / fine.mean() - 1):+.1f} %, per episode median"
                  f" {100 * np.median(change):.1f} % max {100 * change.max():.1f} %", flush=True)  # fmt: skip
        ratios = [np.exp(np.log(x[(CONTROLLERS[1], s)] / x[(CONTROLLERS[0], s)]).mean()) for s in STEPS_S]
        print(f"{scheme:<9} learned / dither {ratios[0]:.3f} at 100 us, {ratios[1]:.3f} at 25 us", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
