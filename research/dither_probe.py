"""Where the compensation error goes: ``adaptive`` with a square wave fed through the learned
residual's own path, and the shipped SAC residual, on the held-out episodes of docs/research-log.md.

Each candidate is ``adaptive`` with a residual that alternates +-A (a share of the residual's
+-3 um) every decision (5 ms), through v4's twice high-passed setpoint, the square wave the SAC
policy comes close to; ``sac`` is a learned residual (``--policy``: the shipped
``residual-sac-adaptive`` by default, or a policy folder). Every candidate runs the
four held-out schedules on plants and drives drawn 1.5 times wider than training's, seeds from
1000, and is paired with ``adaptive`` alone (A = 0, the same episodes): ratio of means and the
share of seeds whose mean is lower. ``--off friction`` (or another imperfection) switches one off,
``--physics-step-us`` refines the step: the checks that the dither takes out the friction's bias
and not a numerical one. For ``sac`` it also prints how often the policy's action flips sign
between decisions before touchdown, and its mean component in phase with ``adaptive-dither``'s
square wave (one sign per 5 ms decision, + first; that square wave is 0.02 of the residual).

Run: ``python research/dither_probe.py [--amplitudes 0.02,0.05,0.1,0.3,sac] [--seeds 13]
[--sensors extended] [--off friction] [--physics-step-us 100] [--policy FOLDER]``.
"""

from __future__ import annotations

import argparse
import sys
from functools import partial
from multiprocessing import Pool

import gymnasium as gym
import numpy as np

from microg_env.analysis.metrics import contacts
from microg_env.controllers.registry import check_controller_name, deployed_controller, make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.experiments.comparison import QUANTITIES, TEST_SEED
from microg_env.imperfections import IMPERFECTION_NAMES
from microg_env.interface import OBSERVATION_INDEX
from microg_env.params import PHYSICS_STEP_S
from microg_env.rollout.episode import run_with_metrics
from microg_env.rollout.spec import RunSpec
from microg_env.scenarios import HELD_OUT

#: The learned residual's task, whose path the square wave takes.
TASK = gym.spec("MicroGravityLanding-Residual-v4").kwargs
#: The metrics printed.
SHOWN = ("compensation_error", "free_fall_excursion_m", "collision_excursion_m", "collision_instant_m")


class Recording:
    """A policy that keeps every action it gives (one rig)."""

    def __init__(self, policy) -> None:
        self.policy, self.actions = policy, []

    def predict(self, observation: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        action, state = self.policy.predict(observation, deterministic)
        self.actions.append(float(np.asarray(action).reshape(-1)[0]))
        return action, state


class SquareWave:
    """A policy whose action alternates +-``amplitude``, starting at +, one sign per decision."""

    def __init__(self, amplitude: float) -> None:
        self.amplitude = amplitude

    def predict(self, observation: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        previous = np.asarray(observation)[:, OBSERVATION_INDEX["previous_action"]]
        return np.where(previous > 0, -self.amplitude, self.amplitude).astype(np.float32)[:, None], None


def episode(
    case: tuple[str, str, int], sensors: str, off: tuple[str, ...], step_us: float, policy: str
) -> dict[str, float]:
    """The metrics of candidate ``case[0]`` on scenario ``case[1]``, seed ``case[2]``."""
    candidate, scenario, seed = case
    spec = RunSpec(
        scenario,
        "adaptive",
        seed,
        randomize="wider",
        sensor_set=sensors,
        physics_step_us=step_us,
        imperfections=dict.fromkeys(off, False),
    )
    env = MicroGravityLandingEnv(**spec.env_kwargs())
    if candidate == "sac":
        controller = make_controller(policy, env.settings.control_period_s)
        controller.policy = Recording(controller.policy)
    else:
        controller = deployed_controller(SquareWave(float(candidate)), TASK)
    try:
        trajectory, _, metrics = run_with_metrics(env, controller, seed)
    finally:
        env.close()
    values = {name: float(QUANTITIES[name].of(metrics)) for name in SHOWN}
    if candidate == "sac":  # the share of its decisions before touchdown that flip the action's sign
        found = contacts(trajectory)
        before = controller.policy.actions[: found[0].start // controller.acting.decision_period if found else None]
        values["flips"] = float(np.mean(np.diff(np.sign(before)) != 0))
        actions = np.array(controller.policy.actions)
        values["in_phase"] = float(np.mean(actions * np.where(np.arange(actions.size) % 2 == 0, 1.0, -1.0)))
    return values


def at_least_one(text: str) -> int:
    """A whole number >= 1 (argparse type)."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def amplitude_or_sac(text: str) -> str:
    """``sac``, or a share of the residual in (0, 1] (argparse type; 0 is the reference, always run)."""
    if text == "sac":
        return text
    try:
        share = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a number nor sac") from None
    if not 0.0 < share <= 1.0:
        raise argparse.ArgumentTypeError(f"{text!r}: a share of the residual must be in (0, 1]")
    return repr(share)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--amplitudes",
        type=lambda text: [amplitude_or_sac(part) for part in text.split(",")],
        default="0.02,0.05,0.1,0.3,sac",
        help="shares of the residual in (0, 1], or sac, comma-separated",
    )
    parser.add_argument("--seeds", type=at_least_one, default=13, help="seeds per schedule, from 1000")
    parser.add_argument("--sensors", choices=("extended", "paper"), default="extended")
    parser.add_argument("--off", default="", help="imperfections switched off, comma-separated")
    parser.add_argument("--physics-step-us", type=float, default=PHYSICS_STEP_S * 1e6)
    parser.add_argument("--workers", type=at_least_one, default=2)
    parser.add_argument("--policy", default="residual-sac-adaptive", help="the learned residual sac runs")
    args = parser.parse_args(argv)
    off = tuple(name for name in args.off.split(",") if name)
    for name in off:
        if name not in IMPERFECTION_NAMES:
            parser.error(f"--off: unknown imperfection {name!r}; known: {', '.join(IMPERFECTION_NAMES)}")
    candidates = ["0", *dict.fromkeys(args.amplitudes)]
    cases = [(c, s, seed) for c in candidates for s in HELD_OUT for seed in range(TEST_SEED, TEST_SEED + args.seeds)]
    try:
        check_controller_name(args.policy)
    except ValueError as error:
        parser.error(f"--policy: {error}")
    run = partial(episode, sensors=args.sensors, off=off, step_us=args.physics_step_us, policy=args.policy)
    with Pool(args.workers) as pool:
        values = dict(zip(cases, pool.map(run, cases, chunksize=4), strict=True))
    reference = {case[1:]: v for case, v in values.items() if case[0] == "0"}
    print("adaptive alone: " + ", ".join(f"{n} {np.mean([v[n] for v in reference.values()]):.4g}" for n in SHOWN))
    print("| candidate | " + " | ".join(SHOWN) + " |\n|---|" + "---|" * len(SHOWN))
    for candidate in candidates[1:]:
        cells = []
        for name in SHOWN:
            ours = {case[1:]: v[name] for case, v in values.items() if case[0] == candidate}
            ratio = np.mean(list(ours.values())) / np.mean([reference[k][name] for k in ours])
            seeds = range(TEST_SEED, TEST_SEED + args.seeds)
            lower = sum(np.mean([ours[s, seed] - reference[s, seed][name] for s in HELD_OUT]) < 0 for seed in seeds)
            cells.append(f"{ratio:.3f}× ({lower}/{args.seeds} seeds lower)")
        print(f"| {candidate} | " + " | ".join(cells) + " |")
    learned = [v for case, v in values.items() if case[0] == "sac"]
    if learned:
        flips, in_phase = [v["flips"] for v in learned], [v["in_phase"] for v in learned]
        print(
            f"sac flips its action's sign at {np.mean(flips):.0%} of its decisions before touchdown "
            f"({min(flips):.0%}-{max(flips):.0%} by episode); its component in phase with adaptive-dither's "
            f"square wave: {np.mean(in_phase):+.3f} of the residual ({min(in_phase):+.3f} to {max(in_phase):+.3f})"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
