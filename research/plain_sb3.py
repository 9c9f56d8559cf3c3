"""Plain stable-baselines3 on a learning task: ``PPO("MlpPolicy", env)`` or ``SAC("MlpPolicy", env)``
with every default, on ``gym.make(ID)`` alone (one environment, no normalisation), as a new RL user
would run it (issue 45, item 3). Each seed is evaluated before training and after each budget in
``--steps``: the deterministic policy's mean return and mean x at the first collision (the episode's
largest x where it ends before one) on the task's own draws, seeds from 1000, its mean shortfall
and normalised score (microg_env/scores.py), and how many episodes end at a stroke's end.

Run: ``python research/plain_sb3.py [--env MicroGravityLanding-Command-v1] [--algo ppo] [--seeds 0,1,2]
[--steps 50000,100000] [--episodes 10] [--zero]``.
"""

from __future__ import annotations

import argparse
import math
import sys

import gymnasium as gym
import numpy as np

import microg_env  # noqa: F401  (registers the ids)
from microg_env.experiments.comparison_settings import TEST_SEED
from microg_env.scores import REFERENCES, normalized_score


def first_collision_x(x_m: np.ndarray, height_m: np.ndarray) -> float:
    """The largest |x| over the first contact (the foot at or below the pad, until it leaves it),
    or over the episode where it has none."""
    touching = np.flatnonzero(height_m <= 0.0)
    if not touching.size:
        return float(np.max(np.abs(x_m)))
    after = np.flatnonzero(height_m[touching[0] :] > 0.0)
    end = touching[0] + after[0] if after.size else x_m.size
    return float(np.max(np.abs(x_m[touching[0] : end])))


def evaluate(model, env_id: str, episodes: int) -> dict[str, float]:
    """The deterministic policy's mean return, shortfall and normalised score (microg_env.scores),
    mean x at the first collision and failures."""
    env = gym.make(env_id)
    returns, collisions, shortfalls, failures = [], [], [], 0
    for seed in range(TEST_SEED, TEST_SEED + episodes):
        observation, _ = env.reset(seed=seed)
        total, x, height, done = 0.0, [], [], False
        while not done:
            action, _ = model.predict(observation, deterministic=True)
            observation, reward, terminated, truncated, info = env.step(action)
            total += float(reward)
            x.append(info["x_m"])
            height.append(info["foot_height_m"])
            done = terminated or truncated
        failures += info["termination_reason"] is not None
        shortfalls.append(float(env.unwrapped.core.shortfall([0])[0]))
        returns.append(total)
        collisions.append(first_collision_x(np.array(x), np.array(height)))
    env.close()
    shortfall = float(np.mean(shortfalls))
    score = normalized_score(env_id, shortfall) if env_id in REFERENCES else math.nan
    return {
        "return": float(np.mean(returns)),
        "shortfall": shortfall,
        "score": score,
        "collision_um": float(np.mean(collisions)) * 1e6,
        "failures": failures,
    }


def _cells(row: dict[str, float]) -> str:
    """A row's return, shortfall, score, x at the collision and failures, as table cells."""
    cells = f"{row['return']:.1f} | {row['shortfall']:.2f} | {row['score']:.3g} | {row['collision_um']:.3g}"
    return f"{cells} | {row['failures']}"


class ZeroAction:
    """A model whose every action is 0."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.shape = shape

    def predict(self, observation, deterministic=True):
        return np.zeros(self.shape, dtype=np.float32), None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="MicroGravityLanding-Command-v1")
    parser.add_argument("--algo", choices=("ppo", "sac"), default="ppo")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--steps", default="50000,100000", help="budgets to evaluate at, increasing")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--zero", action="store_true", help="a first row: the zero action on the same episodes")
    args = parser.parse_args(argv)
    import torch
    from stable_baselines3 import PPO, SAC

    torch.set_num_threads(1)
    budgets = [int(s) for s in args.steps.split(",")]
    print(f"{args.algo} defaults on {args.env}; {args.episodes} episodes from seed {TEST_SEED}")
    print("| seed | steps | return | shortfall | normalised score | x at the collision [µm] | failures |")
    print("|---|---|---|---|---|---|---|")
    if args.zero:  # a residual's or a gain schedule's base; on the command task, the support held still
        row = evaluate(ZeroAction(gym.make(args.env).action_space.shape), args.env, args.episodes)
        print(f"| zero action | | {_cells(row)} |", flush=True)
    for seed in (int(s) for s in args.seeds.split(",")):
        model = (PPO if args.algo == "ppo" else SAC)("MlpPolicy", gym.make(args.env), seed=seed, verbose=0)
        done = 0
        for budget in (0, *budgets):
            if budget > done:
                model.learn(budget - done, reset_num_timesteps=False)
                done = budget
            row = evaluate(model, args.env, args.episodes)
            print(f"| {seed} | {budget} | {_cells(row)} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
