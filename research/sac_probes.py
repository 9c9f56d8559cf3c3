"""Probes of the gated SAC recipe: ``MicroGravityLanding-Residual-v5`` with the packaged sac.yml
trained with one change, and its validation cost (``microg train``'s: ``selection_cost`` on the
validation schedules, seeds from 500) on each rig every ``--eval-every`` steps, the base controller
alone first. The changes:

- ``--stack N``: memory. The last N decisions' observations stacked (stable-baselines3's
  ``VecFrameStack``, under ``VecNormalize``: SAC's replay buffer keeps VecNormalize's original
  observations, which must be the stacked ones). Deployed by a controller that keeps each rig's N
  observations.
- ``--privileged``: an asymmetric critic. The critics also see the episode's plant, drive and
  schedule (``recipe_probe.privileged_features``) and the true pad force, lander acceleration and
  x after each step (``info``); the actor's features extractor zeros them, so the deployed policy
  reads the observation alone.
- ``--peak-weight K``: the reward less K for each micrometre by which the first contact's running
  peak |x| grows (the contact as ``reward_by_phase.py`` reads it, at each step's last period), so
  an episode pays K per micrometre of that peak.
- ``--set KEY=VALUE``: environment keyword changes (``sensor_set=paper``: train on the paper's rig).

A probe, not a recipe: ``microg train`` does not take these options. docs/research-log.md ("The
gate's step") reports seed 6 of each.

Run: ``python research/sac_probes.py [--stack N | --privileged] [--peak-weight K] [--set KEY=VALUE]
--seed 6 [--timesteps 60000] [--eval-every 20000] [--episodes 40]``.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch
from finetune_probe import changes, costs
from recipe_probe import MaskedFlatten, ProbeObservation
from reward_by_phase import FirstContact
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecEnvWrapper, VecFrameStack, VecNormalize
from stable_baselines3.sac.policies import Actor, SACPolicy

from microg_env.controllers.policy import PolicyController
from microg_env.controllers.registry import deployed_controller, make_controller
from microg_env.interface import SENSOR_SETS
from microg_env.learning import hyperparams
from microg_env.learning.vec_env import BatchedVecEnv
from microg_env.params import CONTROL_PERIOD_S

ENV_ID = "MicroGravityLanding-Residual-v5"
#: What the privileged critic is told after each step, from ``info``, each divided by its scale.
LIVE = {"pad_force_n": 100.0, "lander_accel_m_s2": 0.1, "x_m": 1e-4}


class PeakReward(VecEnvWrapper):
    """The reward less ``weight`` per micrometre of growth of each rig's first-contact peak |x|
    (the contact as ``reward_by_phase.FirstContact`` reads it)."""

    def __init__(self, venv, weight: float) -> None:
        super().__init__(venv)
        self.weight = weight
        self.contact = FirstContact(venv.num_envs)
        self.peak_um = np.zeros(venv.num_envs)

    def reset(self):
        self.contact.reset(slice(None))
        self.peak_um[:] = 0.0
        return self.venv.reset()

    def step_wait(self):
        observations, rewards, dones, infos = self.venv.step_wait()
        reading = {key: np.array([info[key] for info in infos]) for key in ("foot_height_m", "pad_force_n", "x_m")}
        touching = self.contact.update(reading["foot_height_m"], reading["pad_force_n"])
        x_um = np.abs(reading["x_m"]) * 1e6
        growth = np.where(touching, np.maximum(0.0, x_um - self.peak_um), 0.0)
        self.peak_um = np.where(touching, np.maximum(self.peak_um, x_um), self.peak_um)
        self.contact.reset(dones)
        self.peak_um[dones] = 0.0
        return (
            observations,
            (np.asarray(rewards, dtype=np.float64) - self.weight * growth).astype(np.float32),
            dones,
            infos,
        )


class AsymmetricSACPolicy(SACPolicy):
    """SAC's MLP policy whose actor reads the first ``visible`` observation entries (the rest zeroed)
    and whose critics read all of them."""

    def __init__(self, *args, visible: int, **kwargs) -> None:
        self.visible = visible
        super().__init__(*args, **kwargs)

    def make_actor(self, features_extractor=None) -> Actor:
        masked = MaskedFlatten(self.observation_space, self.visible)
        return Actor(**self._update_features_extractor(self.actor_kwargs, masked)).to(self.device)

    def _get_constructor_parameters(self) -> dict:
        return super()._get_constructor_parameters() | {"visible": self.visible}


class ProbePolicy:
    """The trained model on a controller's observations: each acting rig's last ``stack`` shown
    observations (zeros before its first, as VecFrameStack at a reset), padded with zeros to the
    privileged size, normalised."""

    def __init__(self, model, normalized, stack: int, visible: int) -> None:
        self.model, self.normalized, self.stack, self.visible = model, normalized, stack, visible
        self.size = normalized.observation_space.shape[0] // stack
        self.history = np.zeros((0, stack, self.size), dtype=np.float32)  # per rig, grown as rigs appear
        self.acting = np.zeros(0, dtype=np.int64)  # the rigs of the next predict, set by the controller

    def _grow(self, count: int) -> None:
        if count > len(self.history):
            more = np.zeros((count - len(self.history), self.stack, self.size), dtype=np.float32)
            self.history = np.concatenate([self.history, more])

    def forget(self, rigs) -> None:
        self._grow(1 if isinstance(rigs, slice) else int(np.max(rigs, initial=-1)) + 1)
        self.history[rigs] = 0.0

    def predict(self, observations: np.ndarray, deterministic: bool = True):
        rigs = self.acting
        self._grow(int(np.max(rigs, initial=-1)) + 1)
        self.history[rigs, :-1] = self.history[rigs, 1:]
        self.history[rigs, -1] = 0.0
        self.history[rigs, -1, : self.visible] = observations
        stacked = self.history[rigs].reshape(rigs.size, -1)
        return self.model.predict(self.normalized.normalize_obs(stacked), deterministic=deterministic)


class ProbeController(PolicyController):
    """The deployed composition of :class:`ProbePolicy`: tells it which rigs act and forgets a rig's
    history at its reset."""

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        self.policy.acting = ids[self._periods[ids] % self.acting.decision_period == 0]  # count_periods' due rigs
        return super().act(rows, ids)

    def reset(self, ids: np.ndarray | None = None) -> None:
        super().reset(ids)
        self.policy.forget(slice(None) if ids is None else ids)


def build(env_kwargs: dict, stack: int, privileged: bool, peak_weight: float, seed: int):
    """The packaged recipe's SAC on ``env_kwargs`` with the probe's changes, untrained: the model,
    its VecNormalize and how many entries the observation has (the actor's)."""
    params = hyperparams.load("sac", ENV_ID)
    venv = BatchedVecEnv.make(params.n_envs, **env_kwargs)
    torch.set_num_threads(1)
    visible = venv.observation_space.shape[0]
    arguments = hyperparams.algo_arguments(params)
    policy = params.policy
    if peak_weight:
        venv = PeakReward(venv, peak_weight)
    if privileged:
        venv = ProbeObservation(venv, [], privileged=True, live=LIVE)
        policy = AsymmetricSACPolicy
        arguments["policy_kwargs"] = {**arguments.get("policy_kwargs", {}), "visible": visible}
    if stack > 1:
        venv = VecFrameStack(venv, stack)
    normalized = VecNormalize(venv, **params.normalize)
    return SAC(policy, normalized, seed=seed, device="cpu", verbose=0, **arguments), normalized, visible


def probe_controller(model, normalized, stack: int, visible: int, env_kwargs: dict) -> ProbeController:
    """The trained model deployed as :func:`deployed_controller` deploys a policy, with the probe's
    memory (as a :class:`ProbeController`, which only adds the two hooks)."""
    return deployed_controller(ProbePolicy(model, normalized, stack, visible), env_kwargs, ProbeController)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stack", type=int, default=1, help="decisions stacked (default 1: no memory)")
    parser.add_argument("--privileged", action="store_true", help="the critics see the plant and the true state")
    parser.add_argument("--peak-weight", type=float, default=0.0, help="reward less K per um of first-contact peak")
    parser.add_argument("--set", action="append", default=[], help="an env keyword change, KEY=VALUE; repeat")
    parser.add_argument("--seed", type=int, default=6)
    parser.add_argument("--timesteps", type=int, default=60000, help="training steps (default 60000)")
    parser.add_argument("--eval-every", type=int, default=20000, help="steps between validations (default 20000)")
    parser.add_argument("--episodes", type=int, default=40, help="validation episodes per rig (default 40)")
    args = parser.parse_args(argv)
    if not 1 <= args.stack <= 16:
        parser.error(f"--stack must be 1 to 16, got {args.stack}")
    if not args.peak_weight >= 0:  # NaN too
        parser.error(f"--peak-weight must be at least 0, got {args.peak_weight}")
    if args.timesteps < 1 or args.eval_every < 1:
        parser.error(f"--timesteps and --eval-every must be at least 1, got {args.timesteps}, {args.eval_every}")
    if args.privileged and args.stack != 1:
        parser.error("--privileged pads one observation with the critic's entries: --stack 1")
    if not 1 <= args.episodes <= 500:
        parser.error(f"--episodes must be 1 to 500, got {args.episodes}")
    try:
        env_kwargs = hyperparams.load("sac", ENV_ID).env_kwargs | changes(args.set)
        model, normalized, visible = build(env_kwargs, args.stack, args.privileged, args.peak_weight, args.seed)
    except (ValueError, TypeError) as error:
        parser.error(str(error))
    base = make_controller(env_kwargs["base_controller"], float(env_kwargs.get("control_period_s", CONTROL_PERIOD_S)))
    print(f"validation cost, {args.episodes} episodes per rig; {vars(args)}")
    print(f"| steps | wall [s] | {' | '.join(SENSOR_SETS)} |\n|---|---|{'---|' * len(SENSOR_SETS)}")
    print(f"| base alone | | {' | '.join(f'{c:.4f}' for c in costs(env_kwargs, base, args.episodes).values())} |")
    start = time.perf_counter()
    while model.num_timesteps < args.timesteps:
        model.learn(min(args.eval_every, args.timesteps - model.num_timesteps), reset_num_timesteps=False)
        row = costs(env_kwargs, probe_controller(model, normalized, args.stack, visible, env_kwargs), args.episodes)
        wall = time.perf_counter() - start
        print(f"| {model.num_timesteps} | {wall:.0f} | {' | '.join(f'{c:.4f}' for c in row.values())} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
