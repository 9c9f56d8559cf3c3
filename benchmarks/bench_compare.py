"""Wall time of ``microg compare`` and ``microg train``, beside the physics they cannot avoid.

* ``compare``: the command as a user runs it (``--controllers``, ``--scenarios``, ``--seeds``), and
  its physics floor measured in the same run: raw ``Batch.step`` of each scenario's batch
  (controllers x seeds rigs, every core) in one call over its first 0.3 s (free fall: no contact,
  the cheapest physics), scaled to the scenario's duration - a floor no implementation can beat
  (under the default midpoint drive the raw call skips its per-step speed input, so it is lower still).
* ``train``: ``microg train --algo ppo`` with the packaged recipe for ``--timesteps`` steps (its
  evaluations included), as environment steps per second of wall time.

Usage: ``python benchmarks/bench_compare.py [--seeds 16] [--timesteps 102400] [--duration S]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time

from microg_env.cli import main as microg
from microg_env.envs.vector import MicroGravityLandingVectorEnv
from microg_env.scenarios import condition


def seconds(argv: list[str]) -> float:
    """Wall time of one ``microg`` command (it must succeed)."""
    start = time.perf_counter()
    assert microg(argv) == 0, argv
    return time.perf_counter() - start


def physics_floor(controllers: int, seeds: int, scenarios: list[str], duration_s: float | None) -> float:
    """Raw ``Batch.step`` time of the comparison's physics: one batch of controllers x seeds rigs
    per scenario, its first 0.3 s in one call, scaled to the scenario's duration."""
    total, window_s = 0.0, 0.3
    for name in scenarios:
        number = int(name.rsplit("-", 1)[1])
        env = MicroGravityLandingVectorEnv(controllers * seeds, condition=number)
        env.reset(seed=0)
        duration = condition(number).duration_s if duration_s is None else duration_s
        start = time.perf_counter()
        env.core.physics.batch.step(nstep=round(window_s / env.core.settings.physics_step_s))
        total += (time.perf_counter() - start) * duration / window_s
        env.close()
    return total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", default="pid,feedforward,residual-sac-setpoint")
    parser.add_argument("--scenarios", default="condition-1,condition-2,condition-3")
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--duration", type=float, default=None, help="cap on each episode (default: the scenario's)")
    parser.add_argument("--timesteps", type=int, default=102400, help="training steps (0: no training)")
    args = parser.parse_args(argv)
    scenarios = args.scenarios.split(",")
    command = ["compare", "--controllers", args.controllers, "--scenarios", args.scenarios]
    command += ["--seeds", str(args.seeds), "--json"]
    if args.duration is not None:
        command += ["--duration", str(args.duration)]
    wall = seconds(command)
    floor = physics_floor(len(args.controllers.split(",")), args.seeds, scenarios, args.duration)
    print(f"microg compare ({args.seeds} seeds): {wall:.1f} s; its physics on raw Batch.step: {floor:.1f} s")
    if args.timesteps:
        with tempfile.TemporaryDirectory() as folder:
            train = ["train", "--algo", "ppo", "--timesteps", str(args.timesteps), "--log-folder", folder]
            wall = seconds([*train, "--quiet"])
        print(f"microg train --algo ppo: {args.timesteps} steps in {wall:.1f} s ({args.timesteps / wall:,.0f} steps/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
