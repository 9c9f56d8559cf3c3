"""Throughput of the vector environment on mujoco.batch against raw Batch.step and the single env.

All in one run, on the same compiled model (condition 2, every imperfection on), medians of
``--repeats`` timings of ``--periods`` control periods (10 physics steps each):

* ``single env``: ``MicroGravityLandingEnv`` stepped by the PID, one rig (the N = 1 case of the core);
* ``vector env N``: ``MicroGravityLandingVectorEnv`` of N rigs stepped by one vectorised PID;
* ``raw Batch.step N``: the vector env's own ``mujoco.batch.Batch`` stepped ``nstep=10`` per period
  with no Python around it (the ceiling the vector env is measured against).

Throughput is simulation steps per second (rigs x physics steps / wall time).

Usage: ``python benchmarks/bench_batch.py [--sizes 1 16 64 256] [--periods 300] [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import sys

from timing import median_seconds

from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.envs.vector import MicroGravityLandingVectorEnv


def single_env_rate(periods: int, repeats: int) -> float:
    env = MicroGravityLandingEnv(condition=2)
    controller = make_controller("pid", env.control_period_s)
    observation, _ = env.reset(seed=0)

    def run() -> None:
        nonlocal observation
        for _ in range(periods):
            observation = env.step(controller(observation))[0]

    return periods * env.frame_skip / median_seconds(run, repeats)


def vector_rates(size: int, periods: int, repeats: int) -> tuple[float, float]:
    env = MicroGravityLandingVectorEnv(size, condition=2)
    controller = make_controller("pid", env.core.control_period_s)
    observations, _ = env.reset(seed=0)
    frame_skip = env.core.frame_skip

    def run() -> None:
        nonlocal observations
        for _ in range(periods):
            observations = env.step(controller(observations))[0]

    vector = size * periods * frame_skip / median_seconds(run, repeats)
    batch = env.core.physics.batch
    raw = (
        size
        * periods
        * frame_skip
        / median_seconds(lambda: [batch.step(nstep=frame_skip) for _ in range(periods)], repeats)
    )
    return vector, raw


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 16, 64, 256])
    parser.add_argument("--periods", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    single = single_env_rate(args.periods, args.repeats)
    print(f"single env (PID): {single:,.0f} simulation steps/s")
    print(
        f"{'N':>5}{'vector env [steps/s]':>23}{'raw Batch.step [steps/s]':>27}{'vector/raw':>12}{'vector/single':>15}"
    )
    for size in args.sizes:
        vector, raw = vector_rates(size, args.periods, args.repeats)
        print(f"{size:>5}{vector:>23,.0f}{raw:>27,.0f}{vector / raw:>12.2f}{vector / single:>15.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
