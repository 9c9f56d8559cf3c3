"""What the midpoint drive costs: time per simulated second under each ``drive_scheme``.

The midpoint drive sets the drive's speed input before every physics step (docs/model.md,
"Drive scheme"): a single environment does it in its compiled loop, a vector environment steps its
``mujoco.batch`` one physics step a call. Both schemes run the same episodes (condition 2, every
imperfection on, 100 µs step), timed in alternation ``--repeats`` times; the table gives each
median and the median of the paired ratios midpoint / mujoco:

* ``single env, pid``: the PID's compiled loop;
* ``single env, feedforward``: the environment's steps;
* ``vector env N, pid``: N rigs stepped by one vectorised PID.

Usage: ``python benchmarks/bench_drive_scheme.py [--sizes 1 16 64] [--seconds 2] [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable

from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.envs.vector import MicroGravityLandingVectorEnv
from microg_env.rollout.episode import run_episode
from microg_env.sim.model import DRIVE_SCHEMES


def single(controller: str, scheme: str, seconds: float) -> Callable[[], None]:
    env = MicroGravityLandingEnv(condition=2, drive_scheme=scheme)
    policy = make_controller(controller, env.settings.control_period_s)
    return lambda: run_episode(env, policy, 0, duration_s=seconds)


def vector(size: int, scheme: str, seconds: float) -> Callable[[], None]:
    env = MicroGravityLandingVectorEnv(size, condition=2, drive_scheme=scheme)
    policy = make_controller("pid", env.core.settings.control_period_s)
    periods = round(seconds / env.core.settings.control_period_s)

    def run() -> None:
        observations, _ = env.reset(seed=0)
        for _ in range(periods):
            observations = env.step(policy(observations))[0]

    return run


def paired(make: Callable[[str], Callable[[], None]], repeats: int) -> tuple[float, float, float]:
    """Median seconds of each scheme's run, and the median ratio midpoint / mujoco, timed in turn."""
    runs = {scheme: make(scheme) for scheme in DRIVE_SCHEMES}
    for run in runs.values():
        run()  # compiled, warmed
    times: dict[str, list[float]] = {scheme: [] for scheme in DRIVE_SCHEMES}
    for _ in range(repeats):
        for scheme, run in runs.items():
            start = time.perf_counter()
            run()
            times[scheme].append(time.perf_counter() - start)
    ratio = statistics.median(m / n for m, n in zip(times["midpoint"], times["mujoco"], strict=True))
    return statistics.median(times["mujoco"]), statistics.median(times["midpoint"]), ratio


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 16, 64])
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated seconds a run")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    cases = {
        "single env, pid": lambda scheme: single("pid", scheme, args.seconds),
        "single env, feedforward": lambda scheme: single("feedforward", scheme, args.seconds),
    }
    for size in args.sizes:
        cases[f"vector env {size}, pid"] = lambda scheme, size=size: vector(size, scheme, args.seconds)
    print(f"| case | mujoco, s per simulated s | midpoint | midpoint / mujoco (median of {args.repeats} pairs) |")
    print("|---|---|---|---|")
    for name, make in cases.items():
        mujoco, midpoint, ratio = paired(make, args.repeats)
        print(f"| {name} | {mujoco / args.seconds:.3f} | {midpoint / args.seconds:.3f} | {ratio:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
