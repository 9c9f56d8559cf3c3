"""Choose the adaptive feed-forward's LMS step, its dither, or the friction level's gain; the result
goes into microg_env/config/controllers.toml.

Each candidate drives conditions 1-3 on validation seeds 500-502 (never a test seed) with plants
and drives drawn (``DomainRandomization.full()``), and is scored by the PID tuner's cost J = mean
|compensation error| [%] + collision excursion [um] / 10 (training/tune_pid.py). Prints J of each,
and beside it what J does not weigh: x in free fall and x's change over the first 5 ms of contact.

Run: ``python training/tune_adaptive.py [--steps 0.001,0.003,0.01,0.03] [--seeds 3]`` (the LMS
step of ``adaptive``), or ``python training/tune_adaptive.py --dither 0,30,60,150,300 --periods
4,10,20`` (amplitudes in nm and periods in ms of ``adaptive-dither``'s square wave, every pair), or
``python training/tune_adaptive.py --friction 0,0.003,0.01,0.03 --min-speeds 0.5,1`` (the gain and
the lowest motor speed, rad/s, of ``adaptive-friction``'s level estimate, every pair; gain 0 is
``adaptive-dither`` with the pad model). ``--friction`` scores each candidate as the learned
controllers are selected: ``selection_cost`` on the 40 validation episodes (seeds 500-539, the
validation schedules, plants and drives drawn) that ``residual-sac-setpoint`` was chosen on.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from microg_env.analysis.metrics import COMPARED_WINDOW
from microg_env.analysis.summary import finite_mean, selection_cost
from microg_env.controllers.base import Controller
from microg_env.controllers.feedforward import DitheredAdaptiveFeedforward, DitherSettings, FrictionAdaptiveFeedforward
from microg_env.controllers.registry import make_controller, policy_card, shipped_policy_folder
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.imperfections import DomainRandomization
from microg_env.learning.train import VALIDATION_SEED, validation_runs
from microg_env.rollout.episode import run_with_metrics
from microg_env.task import TaskSettings


def scores(make: Callable[[float], Controller], seeds: int, duration_s: float | None) -> tuple[float, float, float]:
    """J of the controllers ``make(control_period_s)`` builds, and their mean x in free fall and
    change of x over the first 5 ms of contact (um)."""
    costs, free_fall, first_5_ms = [], [], []
    for number in (1, 2, 3):
        env = MicroGravityLandingEnv(condition=number, domain_randomization=DomainRandomization.full())
        for seed in range(VALIDATION_SEED, VALIDATION_SEED + seeds):
            metrics = run_with_metrics(env, make(env.settings.control_period_s), seed, duration_s)[2]
            error = finite_mean(map(abs, metrics.compensation_error_pct))
            costs.append(error + metrics.flexible_unit_excursion_collision_m * 1e6 / 10)
            free_fall.append(metrics.flexible_unit_excursion_free_fall_m * 1e6)
            first_5_ms.append(metrics.x_change_after_touchdown_m[COMPARED_WINDOW] * 1e6)
        env.close()
    return finite_mean(costs), finite_mean(free_fall), finite_mean(first_5_ms)


def with_step(step: float) -> Callable[[float], Controller]:
    """``adaptive`` with LMS step ``step``."""

    def make(control_period_s: float) -> Controller:
        controller = make_controller("adaptive", control_period_s)
        controller.adaptive_constants = (step, *controller.adaptive_constants[1:])
        return controller

    return make


def with_dither(amplitude_m: float, period_s: float) -> Callable[[float], Controller]:
    """``adaptive-dither`` with this square wave."""

    def make(control_period_s: float) -> Controller:
        return DitheredAdaptiveFeedforward(control_period_s, dither=DitherSettings(amplitude_m, period_s))

    return make


#: The validation episodes ``--friction`` scores on: those the shipped residual was selected on.
FRICTION_EPISODES = 40


def validation_scores(make: Callable[[float], Controller]) -> tuple[float, float, float, float]:
    """The selection cost of the controller ``make(control_period_s)`` builds on the validation
    episodes of ``residual-sac-setpoint``'s task, and its mean x at the collision and in free fall
    (um) and |compensation error| (%) there."""
    card = policy_card(shipped_policy_folder("residual-sac-setpoint"))
    period = TaskSettings(**card["env_kwargs"]).control_period_s
    runs, _ = validation_runs(card["env_kwargs"], make(period), FRICTION_EPISODES)
    return (
        selection_cost(runs),
        finite_mean(run.flexible_unit_excursion_collision_m for run in runs) * 1e6,
        finite_mean(run.flexible_unit_excursion_free_fall_m for run in runs) * 1e6,
        finite_mean(finite_mean(map(abs, run.compensation_error_pct)) for run in runs),
    )


def with_friction(gain: float, min_speed_rad_s: float) -> Callable[[float], Controller]:
    """``adaptive-friction`` with this gain and lowest speed."""

    def make(control_period_s: float) -> Controller:
        controller = FrictionAdaptiveFeedforward(control_period_s)
        controller.friction_constants = (gain, min_speed_rad_s, *controller.friction_constants[2:])
        return controller

    return make


def floats(text: str) -> list[float]:
    return [float(value) for value in text.split(",")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", default="0.001,0.003,0.01,0.03", help="candidate LMS steps, comma-separated")
    parser.add_argument("--dither", default=None, help="tune the dither instead: amplitudes, nm, comma-separated")
    parser.add_argument("--periods", default="10", help="with --dither: the square wave's periods, ms, comma-separated")
    parser.add_argument("--friction", default=None, help="tune the friction level's gain instead, comma-separated")
    parser.add_argument("--min-speeds", default="0.5", help="with --friction: lowest motor speeds, rad/s")
    parser.add_argument("--seeds", type=int, default=3, help="validation seeds per condition (from 500)")
    parser.add_argument("--duration", type=float, default=None, help="cap on each run's simulated time, s")
    args = parser.parse_args(argv)
    if args.friction is not None:
        candidates = {
            f"friction gain {gain:g}, from {speed:g} rad/s": with_friction(gain, speed)
            for speed in floats(args.min_speeds)
            for gain in floats(args.friction)
        }
    elif args.dither is None:
        candidates = {f"step {step:g}": with_step(step) for step in floats(args.steps)}
    else:
        candidates = {
            f"dither {amplitude:g} nm, {period:g} ms": with_dither(amplitude * 1e-9, period * 1e-3)
            for period in floats(args.periods)
            for amplitude in floats(args.dither)
        }
    for name, make in candidates.items():
        if args.friction is not None:
            cost, collision, free_fall, error = validation_scores(make)
            print(
                f"{name}: cost {cost:.4f}  (x at the collision {collision:.3f} um, in free fall {free_fall:.3f} um, "
                f"|compensation error| {error:.5f} %)"
            )
            continue
        cost, free_fall, first_5_ms = scores(make, args.seeds, args.duration)
        print(f"{name}: J = {cost:.4f}  (x in free fall {free_fall:.3f} um, 5 ms from touchdown {first_5_ms:.3f} um)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
