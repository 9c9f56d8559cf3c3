"""What knowing each part of the plant is worth: the feed-forward told only some of the truth.

The feed-forward's model row (``PLANT_FIELDS``) is nominal; the ``oracle`` replaces all of it by the
episode's true plant. Here a feed-forward is told only some fields (the cogging; the cogging and the
motor's friction law; the cogging and the speed loop's gains; the lander's mass, the flexible unit's
stiffness and the friction levels), on plants and drives drawn by ``DomainRandomization.full()``,
and its mean x in free fall and at the collision is printed beside the feed-forward's and the
oracle's. The "what knowing the plant is worth" numbers of docs/research-log.md come from the default arguments.

Run: ``python research/partial_oracles.py [--condition 1] [--seeds 1000,1001,1002,1003,1004]``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from microg_env.analysis.summary import finite_mean
from microg_env.controllers.feedforward import PLANT_FIELDS, Feedforward, plant_model
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.imperfections import DomainRandomization
from microg_env.rollout.episode import run_with_metrics

COGGING = ("cogging", "cogging_phase")
TOLD = {
    "feedforward": (),
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
    "oracle": PLANT_FIELDS,
}


class PartialOracle(Feedforward):
    """The feed-forward told the true value of the plant fields ``told`` at every reset."""

    def __init__(self, control_period_s: float, told: tuple[str, ...]) -> None:
        super().__init__(control_period_s)
        self.columns = [PLANT_FIELDS.index(name) for name in told]

    def know_plants(self, ids: np.ndarray, plants: list, ideal_drive: bool = False) -> None:
        for i, params in zip(ids, plants, strict=True):
            self._plant[i, self.columns] = plant_model(params, ideal_drive)[self.columns]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--condition", type=int, default=1)
    parser.add_argument("--seeds", default="1000,1001,1002,1003,1004", help="test seeds, comma-separated")
    parser.add_argument("--duration", type=float, default=None, help="cap on each run's simulated time, s")
    args = parser.parse_args(argv)
    env = MicroGravityLandingEnv(condition=args.condition, domain_randomization=DomainRandomization.full())
    seeds = [int(text) for text in args.seeds.split(",")]
    for label, told in TOLD.items():
        runs = [
            run_with_metrics(env, PartialOracle(env.settings.control_period_s, told), s, args.duration)[2]
            for s in seeds
        ]
        free = finite_mean(run.flexible_unit_excursion_free_fall_m for run in runs) * 1e6
        collision = finite_mean(run.flexible_unit_excursion_collision_m for run in runs) * 1e6
        print(f"{label:34s} x in free fall {free:.3f} um, at the collision {collision:.3f} um")
    return 0


if __name__ == "__main__":
    sys.exit(main())
