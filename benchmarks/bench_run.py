"""Wall time of a 30 s test condition under the PID baseline, beside bare mj_step on the same model.

For each condition it times, several times over and reporting medians:

* ``episode``: ``run_episode`` - the environment stepped at 1 kHz by the PID for 30 s of simulated
  time, every imperfection on, the trajectory recorded (what ``microg run`` simulates);
* ``run``: ``run_with_metrics`` - the episode plus the ideal-microgravity reference and the metrics
  (all of ``microg run`` but printing);
* ``bare mj_step``: the same model stepped for the same number of physics steps with no Python
  around it, measured in the same process as the baseline the ratios refer to.

Usage: ``python benchmarks/bench_run.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import sys

import mujoco
from timing import median_seconds

from microg_env.analysis.evaluate import run_episode, run_with_metrics
from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    print(f"{'condition':<10}{'episode [s]':>13}{'run [s]':>10}{'bare mj_step [s]':>18}{'episode/bare':>14}")
    for number in (1, 2, 3):
        env = MicroGravityLandingEnv(condition=number)
        controller = make_controller("pid", env.control_period_s)
        episode = median_seconds(lambda env=env, c=controller: run_episode(env, c, seed=0), args.repeats)
        full = median_seconds(lambda env=env, c=controller: run_with_metrics(env, c, seed=0), args.repeats)
        steps = round(env.active_scenario.duration_s / env.control_period_s) * env.frame_skip
        data = mujoco.MjData(env.model)
        env.rig.reset(data, env.active_scenario.descent_height_m)
        bare = median_seconds(lambda m=env.model, d=data, n=steps: mujoco.mj_step(m, d, nstep=n), args.repeats)
        print(f"{number:<10}{episode:>13.3f}{full:>10.3f}{bare:>18.3f}{episode / bare:>14.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
