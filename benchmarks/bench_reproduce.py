"""Wall time of ``microg reproduce``, beside one 30 s episode measured in the same process.

Times the whole command in this process (six 30 s runs with their references and metrics, the
Eq. 17 and balancer-drift runs, the report and its five figures), reporting the median of several
repeats, beside one 30 s ``run_episode`` of condition 1 as the baseline.

Usage: ``python benchmarks/bench_reproduce.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from timing import median_seconds

from microg_env.cli import main as microg
from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.rollout.episode import run_episode


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--duration", type=float, default=30.0, help="simulated time per run (default 30 s)")
    args = parser.parse_args(argv)
    env = MicroGravityLandingEnv(condition=1)
    controller = make_controller("pid", env.settings.control_period_s)
    baseline = median_seconds(lambda: run_episode(env, controller, seed=0, duration_s=args.duration), args.repeats)
    with tempfile.TemporaryDirectory() as folder:
        out = str(Path(folder) / "reproduction")

        def reproduce() -> None:
            assert microg(["reproduce", "--out", out, "--quiet", "--duration", str(args.duration)]) == 0

        total = median_seconds(reproduce, args.repeats)
    print(
        f"microg reproduce: {total:.2f} s (median of {args.repeats}); "
        f"one {args.duration:g} s episode: {baseline:.3f} s; "
        f"ratio {total / baseline:.1f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
