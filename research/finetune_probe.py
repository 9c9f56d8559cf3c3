"""Fine-tuning a shipped SAC policy on changed draws: its model and observation statistics
(``model.zip``, ``vecnormalize.pkl``, kept in the source tree for this) trained on for
``--timesteps`` more steps on its task with env keyword changes (``--set sensor_set=mixed``: both
rigs), then the validation cost of ``microg train`` (``analysis.summary.selection_cost`` on the
validation schedules, seeds from 500) on each rig for the base controller alone, the shipped
policy and the fine-tuned one. The replay buffer starts empty (the shipped folder keeps none) and
the entropy coefficient where training left it. A probe, not a recipe: docs/research-log.md
("Training on both rigs") reports seeds 0 and 1 on ``residual-sac-gated`` (retired in 0.26.0:
microg-env 0.25.0 has it) with ``--set sensor_set=mixed`` and without (both undo the shipped
policy: without its replay buffer, fine-tuning is no test of the rig).

Run: ``python research/finetune_probe.py [--policy residual-sac-setpoint] [--set KEY=VALUE]
[--timesteps 20000] [--seed 0] [--episodes 40]``.
"""

from __future__ import annotations

import argparse
import sys

import torch
import yaml
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecNormalize

from microg_env.analysis.summary import selection_cost
from microg_env.controllers.registry import (
    deployed_controller,
    load_policy,
    make_controller,
    policy_card,
    shipped_policy_folder,
)
from microg_env.interface import SENSOR_SETS
from microg_env.learning.train import NormalizedPolicy, validation_runs
from microg_env.learning.vec_env import BatchedVecEnv


def changes(pairs: list[str]) -> dict:
    """``KEY=VALUE`` pairs as env keyword arguments, each value read as YAML (``0.5``, ``mixed``)."""
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ValueError(f"--set takes KEY=VALUE, got {pair!r}")
        out[key] = yaml.safe_load(value)
    return out


def costs(env_kwargs: dict, controller, episodes: int) -> dict[str, float]:
    """``controller``'s validation cost on each rig's sensors."""
    return {
        rig: selection_cost(validation_runs(env_kwargs | {"sensor_set": rig}, controller, episodes)[0])
        for rig in SENSOR_SETS
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="residual-sac-setpoint", help="a shipped SAC policy")
    parser.add_argument("--set", action="append", default=[], help="an env keyword change, KEY=VALUE; repeat")
    parser.add_argument("--timesteps", type=int, default=20000, help="steps of fine-tuning (default 20000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=40, help="validation episodes per rig (default 40)")
    args = parser.parse_args(argv)
    if args.timesteps < 1 or not 1 <= args.episodes <= 500:
        parser.error(f"--timesteps must be at least 1 and --episodes 1 to 500, got {args.timesteps}, {args.episodes}")
    try:
        folder = shipped_policy_folder(args.policy)
        card = policy_card(folder)
        if card.get("algo") != "sac":
            raise ValueError(f"policy {args.policy!r} was trained with {card.get('algo')!r}, not sac")
        for name in ("model.zip", "vecnormalize.pkl"):
            if not (folder / name).is_file():
                raise ValueError(f"policy {args.policy!r} has no {name} (the source tree keeps it, not the wheel)")
        env_kwargs = card["env_kwargs"] | changes(args.set)
        venv = BatchedVecEnv.make(1, **env_kwargs)
    except (ValueError, TypeError) as error:
        parser.error(str(error))
    torch.set_num_threads(1)
    normalized = VecNormalize.load(str(folder / "vecnormalize.pkl"), venv)
    model = SAC.load(folder / "model.zip", env=normalized, seed=args.seed, device="cpu")
    model.learn(args.timesteps, reset_num_timesteps=False)
    period = float(env_kwargs.get("control_period_s", 1e-3))
    rows = {
        f"{env_kwargs['base_controller']} alone": make_controller(env_kwargs["base_controller"], period),
        args.policy: load_policy(folder, period),
        f"fine-tuned {args.timesteps} steps, seed {args.seed}": deployed_controller(
            NormalizedPolicy(model, normalized), env_kwargs
        ),
    }
    print(f"validation cost, {args.episodes} episodes per rig; fine-tuned with {changes(args.set) or 'no change'}")
    print("| controller | " + " | ".join(SENSOR_SETS) + " |")
    print("|---" * (len(SENSOR_SETS) + 1) + "|")
    for name, controller in rows.items():
        row = costs(env_kwargs, controller, args.episodes)
        print(f"| {name} | " + " | ".join(f"{row[rig]:.4f}" for rig in SENSOR_SETS) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
