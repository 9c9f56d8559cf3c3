"""What the reward pays a learned residual for, phase by phase: its return minus the zero
residual's on the same seeds, before the first contact, during it and after it, beside what it
does to the first contact's peak x, and the action it holds when the gate opens (what enters the
high-pass as a step with ``residual_gate_on="action"``): means over the seeds ± their standard error.

The reward scores x in decades every control period (docs/environment.md, "Rewards"), so a
residual that lowers the collision's peak but raises x where x is small can earn nothing for it.
docs/research-log.md's "Training on both rigs" ran it with ``--seeds 100`` on v5 and
``residual-sac-gated`` (both retired in 0.26.0: microg-env 0.25.0 has them); the defaults run the
shipped ``residual-sac-setpoint`` on v6's own draws (seeds from 1000), on each sensor set.
``--reward-scale-m`` scores x from another x0 than the id's (10 nm). Phases and the peak are
read at each step's last control period (every ``decision_period``-th): the first contact from the
first step with the foot below the pad's surface to the first step after it with no pad force
(the boundaries of ``analysis.metrics.contacts``, at the step's resolution), so the peak is a lower
bound of the comparison's "x at the collision", and a step that crosses a boundary counts whole
to the later phase.

Run: ``python research/reward_by_phase.py [--env MicroGravityLanding-Residual-v6]
[--policy residual-sac-setpoint] [--seeds 40] [--reward-scale-m 1e-8]``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

from microg_env.experiments.comparison import TEST_SEED
from microg_env.interface import SENSOR_SETS, gated_actions

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "training"))  # a user tool the probes share
from returns_table import ENV_IDS, policy_actor

#: The phases of an episode, in order.
PHASES = ("before the contact", "first contact", "after it")


def zero_residual(observation: np.ndarray) -> np.ndarray:
    """The line to beat: the base controller alone."""
    return np.zeros(1, dtype=np.float32)


class FirstContact:
    """Each of ``num_rigs`` rigs' phase (an index into :data:`PHASES`), from the readings at each
    step's last control period: the contact from the foot's first reading below the pad's surface to
    the first reading after it with no pad force."""

    def __init__(self, num_rigs: int) -> None:
        self.phase = np.zeros(num_rigs, dtype=np.int64)
        self.pushed = np.zeros(num_rigs, dtype=bool)

    def update(self, foot_height_m: np.ndarray, pad_force_n: np.ndarray) -> np.ndarray:
        """Each rig's phase after a step's readings; returns whether each is in the first contact."""
        self.phase[(self.phase == 0) & (foot_height_m < 0.0)] = 1
        touching = self.phase == 1
        self.pushed |= touching & (pad_force_n > 0.0)
        self.phase[touching & self.pushed & (pad_force_n <= 0.0)] = 2
        return self.phase == 1

    def reset(self, rigs) -> None:
        self.phase[rigs], self.pushed[rigs] = 0, False


def phase_returns(env: gym.Env, act, seed: int | None) -> tuple[np.ndarray, float, float]:
    """The return of each phase (:data:`PHASES`) of one episode (reset with ``seed``; None: the
    env's next), its first contact's peak |x|, m, and the action at the first decision the
    environment's gate passes (NaN without a gate, or if it never opens)."""
    obs, _ = env.reset(seed=seed)
    returns, contact, peak, done = np.zeros(len(PHASES)), FirstContact(1), 0.0, False
    opening, gate_m = math.nan, env.unwrapped.settings.residual_gate_m
    while not done:
        action = act(obs)
        gate_open = gate_m is not None and gated_actions(np.ones(1), env.unwrapped.core.observation[:1], gate_m)[0]
        if gate_open and math.isnan(opening):  # the gate's own reading and comparison
            opening = float(np.ravel(action)[0])
        obs, reward, terminated, truncated, info = env.step(action)
        done = terminated or truncated
        if contact.update(np.array([info["foot_height_m"]]), np.array([info["pad_force_n"]]))[0]:
            peak = max(peak, abs(float(info["x_m"])))
        returns[contact.phase[0]] += float(reward)
    return returns, peak, opening


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", choices=ENV_IDS, default="MicroGravityLanding-Residual-v6")
    parser.add_argument("--policy", default="residual-sac-setpoint", help="a shipped policy or a policy folder")
    parser.add_argument("--seeds", type=int, default=40, help="episodes per sensor set, seeds from 1000 (default 40)")
    parser.add_argument("--reward-scale-m", type=float, help="x0 of the reward, m (default the id's)")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error(f"--seeds must be at least 1, got {args.seeds}")
    scale = {} if args.reward_scale_m is None else {"reward_scale_m": args.reward_scale_m}
    try:
        act = policy_actor(args.env, args.policy)
    except ValueError as error:
        parser.error(f"--policy: {error}")
    print(f"{args.policy} minus the zero residual on {args.env}'s draws, {args.seeds} seeds from {TEST_SEED}")
    header = [f"return, {phase}" for phase in PHASES] + ["peak x, first contact [um]"]
    header.append("the policy's action at the gate's opening (itself, not a difference)")
    print("| sensors | " + " | ".join(header) + " |")
    print("|---" * (len(header) + 1) + "|")
    for sensors in SENSOR_SETS:
        try:
            env = gym.make(args.env, sensor_set=sensors, **scale)
        except ValueError as error:
            parser.error(str(error))
        differences, peaks, openings = [], [], []
        for seed in range(TEST_SEED, TEST_SEED + args.seeds):
            (mine, peak, opening), (base, base_peak, _) = (phase_returns(env, a, seed) for a in (act, zero_residual))
            differences.append(mine - base)
            peaks.append((peak - base_peak) * 1e6)
            openings.append(opening)
        env.close()
        columns = np.column_stack([np.array(differences), peaks, openings])
        error = columns.std(axis=0, ddof=1) / np.sqrt(len(columns)) if len(columns) > 1 else np.zeros(len(columns.T))
        cells = [f"{mean:+.3f} ± {se:.3f}" for mean, se in zip(columns.mean(axis=0), error, strict=True)]
        print(f"| {sensors} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
