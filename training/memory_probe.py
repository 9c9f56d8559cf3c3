"""Does memory help the learned residual? The v3 recipe trained with its normalised observations
stacked over the last ``--stack`` decisions (stable-baselines3's ``VecFrameStack`` after
``VecNormalize``, as rl-baselines3-zoo's ``frame_stack``; 1: no memory, the shipped recipe), and its
returns paired with the zero residual's (``adaptive`` alone) on the same seeds: the training draws
and the held-out schedules (``scenarios.HELD_OUT``), as in the returns table (training/returns_table.py).

A probe, not a recipe: ``microg train`` and ``PolicyController`` do not stack observations, so a
stacked policy cannot be shipped or compared by ``microg compare`` yet; this measures whether it
would be worth it (docs/controllers.md, "Memory").

Run: ``python training/memory_probe.py --stack 4 --seed 0 [--timesteps 1000000] [--seeds 100]
[--held-out-seeds 13] [--scenarios training,heavy-second,...]``.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch
from returns_table import ENV_IDS, episode_return, make_env

from microg_env.experiments.comparison import TEST_SEED
from microg_env.learning import hyperparams
from microg_env.learning.vec_env import BatchedVecEnv
from microg_env.scenarios import HELD_OUT

ENV_ID = ENV_IDS[0]


def train(stack: int, seed: int, timesteps: int):
    """The v3 recipe for ``timesteps`` steps with ``stack`` decisions stacked: the model and its
    VecNormalize (frozen)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    params = hyperparams.load("ppo", ENV_ID)
    normalized = VecNormalize(BatchedVecEnv.make(params.n_envs, **params.env_kwargs), **params.normalize)
    env = VecFrameStack(normalized, stack) if stack > 1 else normalized
    model = PPO(params.policy, env, seed=seed, device="cpu", verbose=0, **hyperparams.algo_arguments(params))
    env.seed(seed)
    model.learn(timesteps)
    normalized.training = False
    return model, normalized


def actor(model, normalized, stack: int):
    """A fresh episode's deterministic actions: each observation normalised, stacked after the
    last ``stack - 1`` (zeros before the first, as VecFrameStack at a reset)."""
    size = normalized.observation_space.shape[0]
    history = np.zeros(size * stack, dtype=np.float32)

    def act(observation: np.ndarray) -> np.ndarray:
        history[:-size] = history[size:].copy()
        history[-size:] = normalized.normalize_obs(observation)
        return model.predict(history[None], deterministic=True)[0].reshape(-1)

    return act


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stack", type=int, default=4, help="decisions stacked (1: no memory; default 4)")
    parser.add_argument("--seed", type=int, default=0, help="training seed")
    parser.add_argument("--timesteps", type=int, default=1_000_000, help="training steps (default the recipe's)")
    parser.add_argument("--seeds", type=int, default=100, help="training draws, seeds from 1000 (default 100)")
    parser.add_argument("--held-out-seeds", type=int, default=13, help="seeds per held-out schedule (default 13)")
    parser.add_argument(
        "--scenarios",
        default=",".join(("training", *HELD_OUT)),
        help="comma-separated: training and comparison scenarios (default: training and the held-out ones)",
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    start = time.perf_counter()
    model, normalized = train(args.stack, args.seed, args.timesteps)
    print(f"stack {args.stack}, seed {args.seed}: {args.timesteps} steps in {time.perf_counter() - start:.0f} s")
    print("| schedule | policy | zero residual | paired difference (± standard error) | policy higher |")
    print("|---|---|---|---|---|")
    for scenario in args.scenarios.split(","):
        count = args.seeds if scenario == "training" else args.held_out_seeds
        env = make_env(ENV_ID, scenario)
        seeds = range(TEST_SEED, TEST_SEED + count)
        policy = np.array([episode_return(env, actor(model, normalized, args.stack), s) for s in seeds])
        zero = np.array([episode_return(env, lambda obs: np.zeros(1, dtype=np.float32), s) for s in seeds])
        difference = policy - zero
        error = difference.std(ddof=1) / np.sqrt(count) if count > 1 else float("nan")
        print(
            f"| {scenario} | {policy.mean():.1f} | {zero.mean():.1f} | {difference.mean():+.1f} ± {error:.1f} "
            f"| {(difference > 0).sum()}/{count} |",
            flush=True,
        )
        env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
