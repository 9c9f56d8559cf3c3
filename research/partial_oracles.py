"""What knowing each part of the plant is worth: a feed-forward told only some of the truth.

The feed-forward's model row (``PLANT_FIELDS``) is nominal; the ``oracle`` replaces all of it by the
episode's true plant. Here a feed-forward (``--base feedforward``, or ``adaptive-dither``) is told
only some fields (the cogging; the cogging and the motor's friction law; the cogging and the speed
loop's gains; the lander's mass, the flexible unit's stiffness and the friction levels; the
friction's levels alone; its shape alone), on plants and drives drawn by
``DomainRandomization.full()`` (or ``--randomize wider``), and its mean x in free fall and at the
collision is printed beside the base's and the oracle's. The "what knowing the plant is worth"
numbers of docs/research-log.md come from the default arguments; 0.27.0's (what
``adaptive-dither`` gains from the friction's levels) from ``--base adaptive-dither --randomize
wider --scenarios heavy-second,fast-impact,light-long,three-stage --seeds 4000,4001``.

Run: ``python research/partial_oracles.py [--condition 1 | --scenarios A,B] [--seeds 1000,1001,1002,1003,1004]
[--base adaptive-dither] [--randomize wider]``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from microg_env.analysis.summary import finite_mean
from microg_env.controllers.feedforward import PLANT_FIELDS, DitheredAdaptiveFeedforward, Feedforward, plant_model
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.imperfections import DomainRandomization
from microg_env.rollout.episode import run_with_metrics
from microg_env.scenarios import comparison_scenarios

COGGING = ("cogging", "cogging_phase")
TOLD = {
    "nothing told": (),
    "cogging": COGGING,
    "cogging and friction law": (
        *COGGING,
        "bristle_stiffness",
        "bristle_damping",
        "stribeck_speed",
        "coulomb",
        "static",
    ),
    "cogging and speed loop": (*COGGING, "kp_speed", "kd_speed"),
    "mass, stiffness, friction levels": ("mass", "x_stiffness", "coulomb", "static"),
    "friction levels": ("coulomb", "static"),
    "friction shape": ("bristle_stiffness", "bristle_damping", "stribeck_speed"),
    "oracle": PLANT_FIELDS,
}


#: The controllers a partial oracle may be built on.
BASES = {"feedforward": Feedforward, "adaptive-dither": DitheredAdaptiveFeedforward}


def partial_oracle(base: type[Feedforward], control_period_s: float, told: tuple[str, ...]) -> Feedforward:
    """``base`` told the true value of the plant fields ``told`` at every reset."""
    columns = [PLANT_FIELDS.index(name) for name in told]

    class PartialOracle(base):
        def know_plants(self, ids: np.ndarray, plants: list, *, ideal_drive: bool) -> None:
            for i, params in zip(ids, plants, strict=True):
                self._plant[i, columns] = plant_model(params, ideal_drive)[columns]

    return PartialOracle(control_period_s)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--condition", type=int, default=1)
    parser.add_argument("--scenarios", default=None, help="comparison scenarios instead, comma-separated")
    parser.add_argument("--seeds", default="1000,1001,1002,1003,1004", help="test seeds, comma-separated")
    parser.add_argument("--base", choices=tuple(BASES), default="feedforward", help="the controller told the plant")
    parser.add_argument("--randomize", choices=("full", "wider"), default="full", help="the plants' ranges")
    parser.add_argument("--duration", type=float, default=None, help="cap on each run's simulated time, s")
    args = parser.parse_args(argv)
    draws = getattr(DomainRandomization, args.randomize)()
    if args.scenarios is None:
        envs = [MicroGravityLandingEnv(condition=args.condition, domain_randomization=draws)]
    else:
        known = comparison_scenarios()
        envs = [
            MicroGravityLandingEnv(scenario=known[name], domain_randomization=draws)
            for name in args.scenarios.split(",")
        ]
    seeds = [int(text) for text in args.seeds.split(",")]
    for label, told in TOLD.items():
        runs = [
            run_with_metrics(
                env, partial_oracle(BASES[args.base], env.settings.control_period_s, told), s, args.duration
            )[2]
            for env in envs
            for s in seeds
        ]
        free = finite_mean(run.flexible_unit_excursion_free_fall_m for run in runs) * 1e6
        collision = finite_mean(run.flexible_unit_excursion_collision_m for run in runs) * 1e6
        print(f"{label:34s} x in free fall {free:.3f} um, at the collision {collision:.3f} um")
    return 0


if __name__ == "__main__":
    sys.exit(main())
