"""Throughput of the single environment on a 30 s test condition, against bare mj_step replaying its inputs.

For each controller it times, interleaved over ``--repeats`` rounds and reporting medians:

* ``episode``: ``run_episode`` - the environment stepped at 1 kHz by the controller for the
  condition's 30 s, every imperfection on, the trajectory recorded (what ``microg run`` simulates);
* ``bare``: the same model and ``MjData`` stepped for the same physics steps with nothing but the
  episode's recorded drive inputs (``ctrl``, the slew rate, the balancer's drift force) written
  before each control period's ``mj_step`` - the floor any controller loop in Python can reach.

The ratio bare/episode is the environment's throughput as a share of that floor (1: no overhead).
Both run MuJoCo's own drive stepping (``drive_scheme="mujoco"``): the bare loop can replay its
inputs once a period, which the midpoint drive's per-step speed input cannot be
(``benchmarks/bench_drive_scheme.py`` times the midpoint drive against it).
The residual policy is ``residual-sac-setpoint`` (acting every 5 periods on ``adaptive-dither``, gated to the contact).

Usage: ``python benchmarks/bench_run.py [--repeats N] [--condition N] [--controllers pid,feedforward] [--duration S]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import mujoco

from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.rollout.episode import run_episode
from microg_env.sim.model import SLEW_PARAMETER


def replay_inputs(env: MicroGravityLandingEnv, controller, seed: int, duration_s: float | None) -> tuple[list, int]:
    """The drive inputs written before each control period of one episode, and the steps per period."""
    inputs = []
    core = env.core

    def record(env, info) -> None:
        inputs.append(
            (
                env.unwrapped.data.ctrl.copy(),
                float(core.physics.model.actuator_dynprm[core.rig.servo, SLEW_PARAMETER]),
                env.unwrapped.data.qfrc_applied.copy(),
            )
        )

    run_episode(env, controller, seed=seed, duration_s=duration_s, on_step=record)
    return inputs[1:], env.settings.frame_skip  # the first is the reset's


def bare(env: MicroGravityLandingEnv, inputs: list, frame_skip: int) -> None:
    """``mj_step`` over the episode's periods with its recorded inputs and no other Python."""
    model, data, servo = env.model, mujoco.MjData(env.model), env.core.rig.servo
    env.rig.reset(data, env.active_scenario.descent_height_m)
    dynprm, ctrl, qfrc = model.actuator_dynprm, data.ctrl, data.qfrc_applied
    for control, slew, force in inputs:
        ctrl[:] = control
        dynprm[servo, SLEW_PARAMETER] = slew
        qfrc[:] = force
        mujoco.mj_step(model, data, nstep=frame_skip)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--condition", type=int, default=1)
    parser.add_argument("--controllers", default="pid,feedforward,residual-sac-setpoint")
    parser.add_argument("--duration", type=float, default=None, help="cap on the episode, s (default: the condition's)")
    args = parser.parse_args(argv)
    print(f"condition {args.condition}, medians of {args.repeats} interleaved rounds")
    print(f"{'controller':<14}{'episode [s]':>13}{'bare [s]':>10}{'bare/episode':>14}{'steps/s':>10}")
    for name in args.controllers.split(","):
        env = MicroGravityLandingEnv(condition=args.condition, drive_scheme="mujoco")
        controller = make_controller(name, env.settings.control_period_s)
        inputs, frame_skip = replay_inputs(env, controller, seed=0, duration_s=args.duration)
        episodes, floors = [], []
        for _ in range(args.repeats):
            start = time.perf_counter()
            run_episode(env, controller, seed=0, duration_s=args.duration)
            episodes.append(time.perf_counter() - start)
            start = time.perf_counter()
            bare(env, inputs, frame_skip)
            floors.append(time.perf_counter() - start)
        episode, floor = statistics.median(episodes), statistics.median(floors)
        ratios = statistics.median(f / e for f, e in zip(floors, episodes, strict=True))
        print(f"{name:<14}{episode:>13.3f}{floor:>10.3f}{ratios:>14.2f}{len(inputs) / episode:>10.0f}")
        env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
