"""The reward ladder: does a learning task's return rank controllers as its headline metric does?

Each rung drives the id's own draws (its training schedules, plants and drives, seeds from
``--first-seed``). On a residual id: the paper's PID and the other classical controllers as the base
with a zero residual (the zero residual on the id's base is the base itself), the shipped policy as
trained and with its action scaled by 0.5, 1.5 and -1, and uniform random actions. On the
gain-scheduling id: its base PID as tuned (the zero action), the other classical controllers,
constant gain schedules (:data:`SCHEDULES`), uniform random actions and, with ``--policy``, a policy
trained on it, scaled as above. On the command id (a speed action, no base): the paper's PID (the
reference), the other classical controllers, the PID under the constant gain schedules, the zero
action (the support held still), uniform random actions and a policy, scaled as above. Every rung
runs in the speed-action environment through
:class:`~microg_env.controllers.policy.PolicyController`, which acts as the training environment
does, so one rollout gives both the headline metric (x at the first collision, as ``microg
compare`` reports it) and every control period's true x, from which the return is scored for each
reward scale x0 (``--scales``) offline: the id's reward with that x0, summed over the episode and
divided by the decision period (a step's reward is the mean over its periods). The report gives
each rung's mean return and metric, Spearman's rank correlation of the rungs' mean returns with
their negated mean metrics per x0, and the policy's return minus its base's, paired by seed (mean,
its standard error and the sign test's p).

Run: ``python training/reward_ladder.py [--env MicroGravityLanding-Residual-v6] [--policy NAME]
[--seeds 40] [--scales 1e-8,1e-7,1e-6] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from returns_table import ENV_IDS as LEARNING_IDS
from returns_table import action_mode

import microg_env  # noqa: F401  (registers the ids)
from microg_env.analysis.metrics import contacts
from microg_env.analysis.paired import sign_test_p
from microg_env.controllers.registry import ACTING_KEYS, deployed_controller, make_controller
from microg_env.envs.landing import MicroGravityLandingEnv, x_reward
from microg_env.experiments.comparison_settings import TEST_SEED
from microg_env.interface import action_size
from microg_env.rollout.batch import EpisodeSpec, run_batch
from microg_env.trajectory import Trajectory

#: Classical rungs: each the id's base swapped for it, with a zero residual (on a gains id: run as itself).
CLASSICAL = ("pid", "feedforward", "adaptive", "adaptive-dither")
#: A gains id's constant schedules: rung name -> the action held throughout (the log2 of Kp's, Ki's and
#: Kd's multipliers at the default gain limit of 2).
SCHEDULES = {
    "Kp x2": (1.0, 0.0, 0.0),
    "Ki x2": (0.0, 1.0, 0.0),
    "Kp x1/2": (-1.0, 0.0, 0.0),
    "Ki x1/2": (0.0, -1.0, 0.0),
    "all x1/2": (-1.0, -1.0, -1.0),
}
#: The name of the rung that is an id's base controller alone (on a command id: the paper's PID), by action mode.
ZERO = {"residual": "zero residual", "gains": "zero action", "speed": "reference"}
#: A command id's classical rungs, each commanding the drive itself.
COMMAND_CLASSICAL = ("pid", "pid-dom", *CLASSICAL[1:])
#: How a command id's rungs run the PID under a constant gain schedule.
SCHEDULED_PID = {"action_mode": "gains", "base_controller": "pid"}
#: The shipped policy's action scaled: rungs named "policy x<scale>".
SCALES = (0.5, 1.0, 1.5, -1.0)
#: Rank agreement the ladder must reach (Spearman's rho of mean return against negated mean metric).
MIN_SPEARMAN = 0.9


class ScaledPolicy:
    """A policy's deterministic action times ``scale`` (clipped to the action's range by the controller)."""

    def __init__(self, policy, scale: float) -> None:
        self.policy, self.scale = policy, scale

    def predict(self, observation, deterministic: bool = True):
        action, state = self.policy.predict(observation, deterministic=True)
        return np.asarray(action) * self.scale, state


class RandomPolicy:
    """Uniform random actions in [-1, 1], ``size`` numbers each, from its own generator."""

    def __init__(self, seed: int, size: int = 1) -> None:
        self.rng, self.size = np.random.default_rng(seed), size

    def predict(self, observation, deterministic: bool = True):
        shape = (np.atleast_2d(observation).shape[0], self.size)
        return self.rng.uniform(-1.0, 1.0, size=shape).astype(np.float32), None


class ConstantPolicy:
    """The same ``action`` at every decision."""

    def __init__(self, action: Sequence[float]) -> None:
        self.action = np.asarray(action, dtype=np.float32)

    def predict(self, observation, deterministic: bool = True):
        return np.tile(self.action, (np.atleast_2d(observation).shape[0], 1)), None


@dataclass(frozen=True)
class Rung:
    """One controller's episodes: x at the first collision (the episode's largest x where it ended
    before one), each
    episode's true x at every control period, and the periods of its first contact."""

    name: str
    collision_m: np.ndarray
    x_m: list[np.ndarray]
    contact: list[slice]

    def returns(self, scale_m: float, limit_m: float, decision_period: int, contact_only: bool) -> np.ndarray:
        """Each episode's return under the reward with x0 = ``scale_m``, as the environment pays it
        (each step the mean over the periods it ran, the last one perhaps short), over every period
        or only the first contact's."""
        out = []
        for x, window in zip(self.x_m, self.contact, strict=True):
            paid = x_reward(x, scale_m, limit_m)
            if contact_only:  # the periods outside the first contact pay nothing
                outside = np.ones(x.size, dtype=bool)
                outside[window] = False
                paid[outside] = 0.0
            steps = range(0, x.size, decision_period)
            out.append(sum(paid[i : i + decision_period].mean() for i in steps))
        return np.array(out)


def first_contact(trajectory: Trajectory) -> slice:
    """The rows of the first contact, touchdown to lift-off (``microg compare``'s), or an empty slice."""
    found = contacts(trajectory)
    if not found or found[0].end is None:
        return slice(0, 0)
    return slice(found[0].start, found[0].end)


def speed_settings(env_id: str) -> dict:
    """The id's draws in the speed-action environment: its keywords but the acting settings."""
    return {k: v for k, v in gym.spec(env_id).kwargs.items() if k not in ACTING_KEYS}


def speed_env(env_id: str) -> MicroGravityLandingEnv:
    """The id's draws in the speed-action environment (:func:`speed_settings`)."""
    return MicroGravityLandingEnv(**speed_settings(env_id))


def controllers(env_id: str, policy: str | None, seed: int) -> dict[str, object]:
    """The ladder's rungs for ``env_id`` (a residual, gains or command id; ``policy`` one trained on
    it, or None): name -> a fresh controller."""
    kwargs = gym.spec(env_id).kwargs
    mode = action_mode(env_id)
    period = MicroGravityLandingEnv().settings.control_period_s
    rungs: dict[str, object] = {}
    if mode == "speed":
        for name in COMMAND_CLASSICAL:
            rungs[f"{name} ({ZERO[mode]})" if name == "pid" else name] = make_controller(name, period)
        for name, action in SCHEDULES.items():
            rungs[f"pid {name}"] = deployed_controller(ConstantPolicy(action), SCHEDULED_PID)
        rungs["zero action"] = deployed_controller(ConstantPolicy((0.0,)), kwargs)
    else:
        base = kwargs["base_controller"]
        for name in (*CLASSICAL, base) if base not in CLASSICAL else CLASSICAL:
            rungs[f"{name} ({ZERO[mode]})" if name == base else name] = make_controller(name, period)
    if mode == "gains":
        for name, action in SCHEDULES.items():
            rungs[name] = deployed_controller(ConstantPolicy(action), kwargs)
    if policy is not None:
        network = make_controller(policy, period).policy
        for scale in SCALES:
            rungs[f"{policy} x{scale:g}"] = deployed_controller(ScaledPolicy(network, scale), kwargs)
    rungs["random"] = deployed_controller(RandomPolicy(seed, action_size(mode)), kwargs)
    return rungs


def run_ladder(env_id: str, policy: str | None, seeds: Sequence[int]) -> list[Rung]:
    """Every rung on every seed, as rigs of batches (:func:`~microg_env.rollout.batch.run_batch`:
    each the single environment's episode, bit for bit; the random rung's one generator is drawn
    from across its rigs, so its draws depend on how the rigs are batched)."""
    rungs = controllers(env_id, policy, seeds[0])
    episodes = [EpisodeSpec(controller, None, seed) for controller in rungs.values() for seed in seeds]
    runs = iter(run_batch(episodes, speed_settings(env_id)))
    out = []
    for name in rungs:
        collision, xs, windows = [], [], []
        for _ in seeds:
            trajectory, _, error = next(runs)
            if error is not None:
                raise RuntimeError(f"{name}: {error}")
            window = first_contact(trajectory)
            x = np.asarray(trajectory.x_m)
            # an episode without a whole first contact (ended at a stroke's end by an unstable schedule before
            # touchdown, or still on the pad at its end) counts the largest x it reached: a failure ranks last
            collision.append(float(np.max(np.abs(x[window] if window.stop else x))))
            xs.append(x[1:])  # the periods run (the first row is the reset)
            windows.append(slice(max(window.start - 1, 0), max(window.stop - 1, 0)))
        out.append(Rung(name, np.array(collision), xs, windows))
    return out


def spearman(a: Sequence[float], b: Sequence[float]) -> float:
    """Spearman's rank correlation (average ranks for ties)."""
    from scipy.stats import spearmanr

    return float(spearmanr(a, b).statistic)


def report(env_id: str, policy: str | None, rungs: list[Rung], scales: Sequence[float]) -> dict:
    env = speed_env(env_id)
    kwargs = gym.spec(env_id).kwargs
    limit, period = env.core.x_limit_m, int(kwargs.get("decision_period", 1))
    base = next(r for r in rungs if r.name.endswith(f"({ZERO[action_mode(env_id)]})"))
    shipped = None if policy is None else next(r for r in rungs if r.name == f"{policy} x1")
    metric = {r.name: float(np.mean(r.collision_m)) for r in rungs}
    out: dict = {"env": env_id, "policy": policy, "episodes": len(base.x_m), "metric_m": metric, "by_scale": {}}
    for scale, contact_only in [(s, c) for c in (False, True) for s in scales]:
        returns = {r.name: r.returns(scale, limit, period, contact_only) for r in rungs}
        means = {name: float(values.mean()) for name, values in returns.items()}
        entry = {
            "mean_return": means,
            "spearman": spearman([means[r.name] for r in rungs], [-metric[r.name] for r in rungs]),
        }
        if shipped is not None:
            gain = returns[shipped.name] - returns[base.name]
            entry |= {
                "policy_minus_base": float(gain.mean()),
                "policy_minus_base_se": float(gain.std(ddof=1) / math.sqrt(gain.size)) if gain.size > 1 else math.nan,
                "policy_minus_base_sign_p": sign_test_p(gain),
            }
        out["by_scale"][f"{scale:g}{', first contact' if contact_only else ''}"] = entry
    return out


def render(result: dict) -> str:
    scales = list(result["by_scale"])
    lines = [
        f"{result['env']}, {result['episodes']} episodes of its own draws per rung; x0 in m",
        "",
        "| rung | x at the collision [µm] | " + " | ".join(f"return, x0 = {s}" for s in scales) + " |",
        "|---|---|" + "---|" * len(scales),
    ]
    for name, x in sorted(result["metric_m"].items(), key=lambda item: item[1]):
        cells = [f"{result['by_scale'][s]['mean_return'][name]:.2f}" for s in scales]
        lines.append(f"| {name} | {x * 1e6:.3g} | " + " | ".join(cells) + " |")
    lines.append(
        "| Spearman (return, -x) | | " + " | ".join(f"{result['by_scale'][s]['spearman']:.3f}" for s in scales) + " |"
    )
    if result["policy"] is None:
        return "\n".join(lines)
    lines.append(
        f"| {result['policy']} − base, paired | | "
        + " | ".join(
            f"{v['policy_minus_base']:+.2f} ± {v['policy_minus_base_se']:.2f} (p = {v['policy_minus_base_sign_p']:.2g})"
            for v in result["by_scale"].values()
        )
        + " |"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="MicroGravityLanding-Residual-v6", help="a residual, gains or command id")
    parser.add_argument(
        "--policy", help="a policy trained on it (shipped or a folder; default residual-sac-setpoint on a residual id)"
    )
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--first-seed", type=int, default=TEST_SEED)
    parser.add_argument("--scales", default="1e-8,1e-7,1e-6", help="reward scales x0 to score, m")
    parser.add_argument("--json", help="also write the result here")
    args = parser.parse_args(argv)
    if args.env not in LEARNING_IDS:
        parser.error(f"--env must be one of {', '.join(LEARNING_IDS)}, got {args.env!r}")
    mode = action_mode(args.env)
    if args.policy is None and mode == "residual":
        args.policy = "residual-sac-setpoint"
    scales = [float(s) for s in args.scales.split(",")]
    rungs = run_ladder(args.env, args.policy, range(args.first_seed, args.first_seed + args.seeds))
    result = report(args.env, args.policy, rungs, scales)
    print(render(result))
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(result, handle, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
