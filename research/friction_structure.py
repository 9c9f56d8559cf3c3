"""Where `adaptive-friction`'s gain comes from: the friction's static level, which it guesses by
scaling it with the Coulomb level it learns (0.27.0).

Runs `adaptive-dither`, `adaptive-friction` (one factor on both levels) and a variant that scales
the Coulomb level alone (the static level kept nominal) on (a) held-out schedules with plants and
drives drawn 1.5 times wider than training's, where both levels are drawn with one factor, and (b)
the nominal plant with the motor's Coulomb level alone moved (the drive study's design), and
prints each one's mean x at the collision and its mean ratio to the dither's.

Run: ``python research/friction_structure.py [--scenarios heavy-second,fast-impact,light-long,three-stage]
[--seeds 4000,4001] [--coulomb 0.2,0.8] [--duration S]``. docs/research-log.md ("0.27.0") quotes
the default arguments.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from microg_env.controllers.feedforward import PLANT_FIELDS, DitheredAdaptiveFeedforward, FrictionAdaptiveFeedforward
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.imperfections import DomainRandomization
from microg_env.rollout.episode import run_with_metrics
from microg_env.scenarios import comparison_scenarios

STATIC = PLANT_FIELDS.index("static")


class CoulombOnly(FrictionAdaptiveFeedforward):
    """`adaptive-friction` whose learned factor scales the Coulomb level alone."""

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        actions = super().act(rows, ids)
        self._plant[ids, STATIC] = self.nominal[STATIC]
        return actions


CONTROLLERS = {
    "adaptive-dither": DitheredAdaptiveFeedforward,
    "adaptive-friction (both levels)": FrictionAdaptiveFeedforward,
    "the Coulomb level alone": CoulombOnly,
}


def table(label: str, envs: list[MicroGravityLandingEnv], seeds: list[int], duration: float | None) -> None:
    """Each controller's mean x at the collision over ``envs`` x ``seeds`` and its mean ratio to the dither's."""
    runs = {
        name: np.array(
            [
                run_with_metrics(env, make(env.settings.control_period_s), seed, duration)[
                    2
                ].flexible_unit_excursion_collision_m
                for env in envs
                for seed in seeds
            ]
        )
        for name, make in CONTROLLERS.items()
    }
    print(label)
    dither = runs["adaptive-dither"]
    for name, values in runs.items():
        print(f"  {name:32s} {np.nanmean(values) * 1e6:.3f} um, {np.nanmean(values / dither):.3f} x the dither's")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", default="heavy-second,fast-impact,light-long,three-stage")
    parser.add_argument("--seeds", default="4000,4001", help="seeds of the drawn plants, comma-separated")
    parser.add_argument("--coulomb", default="0.2,0.8", help="the motor's Coulomb levels moved alone, N m")
    parser.add_argument("--duration", type=float, default=None, help="cap on each run's simulated time, s")
    args = parser.parse_args(argv)
    known = comparison_scenarios()
    scenarios = [known[name] for name in args.scenarios.split(",")]
    seeds = [int(text) for text in args.seeds.split(",")]
    drawn = [MicroGravityLandingEnv(scenario=s, domain_randomization=DomainRandomization.wider()) for s in scenarios]
    table(f"plants drawn 1.5 times wider, seeds {args.seeds}", drawn, seeds, args.duration)
    for coulomb in (float(text) for text in args.coulomb.split(",")):
        plants = [MicroGravityLandingEnv(scenario=s, params={"servo.coulomb_torque_n_m": coulomb}) for s in scenarios]
        table(
            f"the nominal plant with the Coulomb level {coulomb:g} N m alone, seed 1000", plants, [1000], args.duration
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
