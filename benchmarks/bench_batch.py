"""Throughput of the vector environment on mujoco.batch against raw Batch.step and the single env.

All in one run, on the same compiled model (condition 2, every imperfection on), medians of
``--repeats`` timings of ``--periods`` control periods (10 physics steps each):

* ``single env``: ``MicroGravityLandingEnv`` stepped by the PID, one rig (the N = 1 case of the core);
* ``vector env N``: ``MicroGravityLandingVectorEnv`` of N rigs stepped by one vectorised PID;
* ``raw Batch.step N``: the vector env's own ``mujoco.batch.Batch`` on the same threads, from the
  same state as the vector env's timed periods (``Batch.state`` saved and restored), stepped through
  all of them in one call (``nstep = 10 x periods``), the fastest the API allows: the ceiling the
  vector env is measured against, with no Python between periods at all.

Throughput is simulation steps per second (rigs x physics steps / wall time). Every case runs
MuJoCo's own drive stepping (``drive_scheme="mujoco"``), which raw ``Batch.step`` can step through;
``benchmarks/bench_drive_scheme.py`` times the midpoint drive against it.

Usage: ``python benchmarks/bench_batch.py [--sizes 1 16 64 256] [--periods 300] [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

from timing import median_seconds

from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.envs.vector import MicroGravityLandingVectorEnv


def single_env_rate(periods: int, repeats: int) -> float:
    env = MicroGravityLandingEnv(condition=2, drive_scheme="mujoco")
    controller = make_controller("pid", env.settings.control_period_s)
    observation, _ = env.reset(seed=0)

    def run() -> None:
        nonlocal observation
        for _ in range(periods):
            observation = env.step(controller(observation))[0]

    return periods * env.settings.frame_skip / median_seconds(run, repeats)


def vector_rates(size: int, periods: int, repeats: int) -> tuple[float, float, float]:
    """Median vector env and raw Batch.step rates and the median of their ratios, timed in turn."""
    env = MicroGravityLandingVectorEnv(size, condition=2, drive_scheme="mujoco")
    controller = make_controller("pid", env.core.settings.control_period_s)
    observations, _ = env.reset(seed=0)
    frame_skip, batch = env.core.settings.frame_skip, env.core.physics.batch
    steps = size * periods * frame_skip
    vector, raw = [], []
    for _ in range(repeats):
        before = batch.state.copy()
        start = time.perf_counter()
        for _ in range(periods):
            observations = env.step(controller(observations))[0]
        vector.append(steps / (time.perf_counter() - start))
        after = batch.state.copy()
        batch.state[:] = before
        start = time.perf_counter()
        batch.step(nstep=frame_skip * periods)
        raw.append(steps / (time.perf_counter() - start))
        batch.state[:] = after  # the vector env goes on from where it was
    ratio = statistics.median(v / r for v, r in zip(vector, raw, strict=True))
    return statistics.median(vector), statistics.median(raw), ratio


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
        vector, raw, ratio = vector_rates(size, args.periods, args.repeats)
        print(f"{size:>5}{vector:>23,.0f}{raw:>27,.0f}{ratio:>12.2f}{vector / single:>15.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
