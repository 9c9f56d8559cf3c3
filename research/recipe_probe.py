"""Probes of the learned residual's recipe: the v3 recipe (``MicroGravityLanding-Residual-v3`` with
the packaged hyperparameters of ``--algo``: ppo.yml, the default, or sac.yml) trained with one
change, and its returns paired with the zero residual's (``adaptive`` alone) on the same seeds:
the training draws and the held-out schedules (``scenarios.HELD_OUT``), as in the returns table
(training/returns_table.py). The changes:

- ``--stack N``: memory. The normalised observations of the last N decisions stacked
  (stable-baselines3's ``VecFrameStack`` after ``VecNormalize``, as rl-baselines3-zoo's ``frame_stack``).
- ``--privileged``: an asymmetric critic (PPO, unstacked only). The value function also sees the
  episode's true plant and drive (:func:`privileged_features`); the actor sees the observation only
  (its features extractor zeros the rest), so the deployed policy reads the sensors alone.
- ``--blind NAMES``: observation entries neither the actor nor the critic reads (zeroed), e.g. the
  absolute positions ``support_position,height`` that place a held-out schedule outside the
  trained range.

A probe, not a recipe: ``microg train`` does not take these options. With ``--stack 1`` the policy
is deployable as it is, and ``--out FOLDER`` exports it (the actor's weights on the observation,
a zero weight on a blind entry) as a policy folder that ``microg compare --controllers FOLDER``
runs; a stacked policy needs a history ``PolicyController`` does not keep. ``--seeds 0
--held-out-seeds 0`` skips the returns (docs/research-log.md, "Probes of the recipe").

Run: ``python research/recipe_probe.py [--algo ppo|sac] [--stack 1] [--privileged] [--blind NAMES] --seed 0
[--timesteps N] [--seeds 100] [--held-out-seeds 13] [--scenarios training,heavy-second,...]
[--out FOLDER]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Mapping
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.vec_env import VecEnvWrapper

from microg_env.controllers.feedforward import PLANT_FIELDS, plant_model
from microg_env.controllers.policy import MLPPolicy
from microg_env.envs.core import Episode
from microg_env.experiments.comparison import TEST_SEED
from microg_env.interface import CARD_FILE, NETWORK_FILE, OBSERVATION_INDEX
from microg_env.learning import hyperparams
from microg_env.learning.export import actor_layers
from microg_env.learning.vec_env import BatchedVecEnv
from microg_env.scenarios import HELD_OUT

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "training"))  # a user tool the probes share
from returns_table import episode_return, make_env

ENV_ID = "MicroGravityLanding-Residual-v3"
#: Where plant_model holds the cogging's phase (the critic gets its cosine and sine).
COGGING_PHASE = PLANT_FIELDS.index("cogging_phase")


def privileged_features(episode: Episode) -> np.ndarray:
    """What the critic is told of an episode: the feed-forward's model of its plant and drive
    (:func:`~microg_env.controllers.feedforward.plant_model`), the pad's K and D, the QZS guide's
    friction, the torque filter; its schedule (two weights, the second's switch height, the start
    height) and the balancer's drift rate."""
    params, scenario = episode.params, episode.scenario
    model = plant_model(params)
    loads = [*scenario.loads, *scenario.loads[:1]][:2]  # a one-weight schedule repeats its weight
    return np.array(
        [
            *np.delete(model, COGGING_PHASE), np.cos(model[COGGING_PHASE]), np.sin(model[COGGING_PHASE]),
            params.pad.stiffness_n_per_m, params.pad.damping_n_s_per_m,
            params.qzs.guide_friction_n, params.qzs.guide_static_friction_n, params.servo.torque_filter_s,
            *(load.mass_kg for load in loads), loads[1].height_m or 0.0,
            episode.height_m, episode.drift_rate_k_per_s,
        ]
    )  # fmt: skip


class ProbeObservation(VecEnvWrapper):
    """The batched env's observations with the ``blind`` entries zeroed and, if ``privileged``, each
    rig's :func:`privileged_features` appended (an ended episode's terminal observation with its
    own), then the ``live`` info entries after each step, each divided by its scale (zeros after a
    reset)."""

    def __init__(
        self, venv: BatchedVecEnv, blind: list[int], privileged: bool, live: Mapping[str, float] | None = None
    ) -> None:
        self.blind, self.privileged, self.live = blind, privileged, dict(live or {})
        drawn = venv.env.core.draw_episode(0, np.random.default_rng(0))  # any episode: the features' size
        size = venv.observation_space.shape[0] + (privileged_features(drawn).size if privileged else 0)
        space = gym.spaces.Box(-np.inf, np.inf, (size + len(self.live),), np.float32)
        super().__init__(venv, observation_space=space)
        self._features: np.ndarray | None = None  # each rig's current episode's, once drawn
        self._readings = np.zeros((venv.num_envs, len(self.live)))  # each rig's last step's live entries

    def _features_of(self, rigs: np.ndarray) -> np.ndarray:
        return np.array([privileged_features(self.venv.env.core.episodes[i]) for i in rigs])

    def _augment(self, observations: np.ndarray, features: np.ndarray | None, readings: np.ndarray) -> np.ndarray:
        observations = np.array(observations, dtype=np.float32)
        observations[..., self.blind] = 0.0
        if self.privileged:
            observations = np.concatenate([observations, features.astype(np.float32)], axis=-1)
        return np.concatenate([observations, readings.astype(np.float32)], axis=-1)

    def reset(self) -> np.ndarray:
        observations = self.venv.reset()
        if self.privileged:
            self._features = self._features_of(np.arange(self.num_envs))
        self._readings[:] = 0.0
        return self._augment(observations, self._features, self._readings)

    def step_wait(self):
        observations, rewards, dones, infos = self.venv.step_wait()
        if self.live:
            self._readings = np.array([[info[key] / scale for key, scale in self.live.items()] for info in infos])
        ended = np.flatnonzero(dones)
        for i in ended:
            ending = self._features[i] if self.privileged else None
            infos[i]["terminal_observation"] = self._augment(
                infos[i]["terminal_observation"], ending, self._readings[i]
            )
        if self.privileged and ended.size:  # the ended rigs' next episodes
            self._features[ended] = self._features_of(ended)
        self._readings[ended] = 0.0
        return self._augment(observations, self._features, self._readings), rewards, dones, infos


class MaskedFlatten(FlattenExtractor):
    """The observation with every entry from ``visible`` on zeroed: the actor's view."""

    def __init__(self, observation_space: gym.spaces.Box, visible: int) -> None:
        super().__init__(observation_space)
        mask = torch.zeros(observation_space.shape[0])
        mask[:visible] = 1.0
        self.register_buffer("mask", mask)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return super().forward(observations) * self.mask


class AsymmetricPolicy(ActorCriticPolicy):
    """stable-baselines3's MLP actor-critic with its own features extractor each: the critic's sees
    the whole (privileged) observation, the actor's its first ``visible`` entries."""

    def __init__(self, *args, visible: int, **kwargs) -> None:
        super().__init__(*args, **kwargs | {"share_features_extractor": False})
        self.visible = visible
        self.pi_features_extractor = MaskedFlatten(self.observation_space, visible)
        self.features_extractor = self.pi_features_extractor

    def _get_constructor_parameters(self) -> dict:
        return super()._get_constructor_parameters() | {"visible": self.visible}  # PPO.load rebuilds it


def train(algo: str, stack: int, privileged: bool, blind: list[int], seed: int, timesteps: int):
    """The v3 recipe of ``algo`` (its packaged hyperparameters) for ``timesteps`` steps with the
    probe's change: the model and its VecNormalize (frozen)."""
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    params = hyperparams.load(algo, ENV_ID)
    batched = BatchedVecEnv.make(params.n_envs, **params.env_kwargs)
    probed = ProbeObservation(batched, blind, privileged) if privileged or blind else batched
    normalized = VecNormalize(probed, **params.normalize)
    env = VecFrameStack(normalized, stack) if stack > 1 else normalized
    arguments = hyperparams.algo_arguments(params)
    policy = params.policy
    if privileged:
        policy = AsymmetricPolicy
        visible = batched.observation_space.shape[0]
        arguments["policy_kwargs"] = {**arguments.get("policy_kwargs", {}), "visible": visible}
    model = {"ppo": PPO, "sac": SAC}[algo](policy, env, seed=seed, device="cpu", verbose=0, **arguments)
    env.seed(seed)
    model.learn(timesteps)
    normalized.training = False
    return model, normalized


def actor(model, normalized, stack: int, blind: list[int]):
    """A fresh episode's deterministic actions: each observation (blind entries zeroed, privileged
    ones zero: the actor's extractor zeros them anyway) normalised, stacked after the last
    ``stack - 1`` (zeros before the first, as VecFrameStack at a reset)."""
    size = normalized.observation_space.shape[0]
    history = np.zeros(size * stack, dtype=np.float32)
    full = np.zeros(size, dtype=np.float32)

    def act(observation: np.ndarray) -> np.ndarray:
        full[: observation.size] = observation
        full[blind] = 0.0
        history[:-size] = history[size:].copy()
        history[-size:] = normalized.normalize_obs(full)
        return model.predict(history[None], deterministic=True)[0].reshape(-1)

    return act


def export(model, normalized, blind: list[int], folder: Path, card: dict) -> None:
    """The unstacked actor as a policy folder on the observation alone: the first layer's columns
    of privileged entries dropped, of blind ones zeroed (their statistics the identity)."""
    weights, biases, activation, squash, mean_clip = actor_layers(model)
    size = len(OBSERVATION_INDEX)
    first = weights[0][:, :size].copy()
    first[:, blind] = 0.0
    mean, var = normalized.obs_rms.mean[:size].copy(), normalized.obs_rms.var[:size].copy()
    mean[blind], var[blind] = 0.0, 1.0
    clip, epsilon = float(normalized.clip_obs), float(normalized.epsilon)
    network = MLPPolicy((first, *weights[1:]), biases, activation, squash, mean, var, clip, epsilon, mean_clip)
    folder.mkdir(parents=True, exist_ok=True)
    network.save(folder / NETWORK_FILE)
    (folder / CARD_FILE).write_text(json.dumps(card, indent=2) + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=("ppo", "sac"), default="ppo", help="the learner (default ppo)")
    parser.add_argument("--stack", type=int, default=1, help="decisions stacked (1: no memory, the default)")
    parser.add_argument("--privileged", action="store_true", help="the critic sees the plant and schedule")
    parser.add_argument("--blind", default="", help="comma-separated observation entries nobody reads")
    parser.add_argument("--seed", type=int, default=0, help="training seed")
    parser.add_argument("--timesteps", type=int, help="training steps (default the recipe's: 10^6 PPO, 3 x 10^5 SAC)")
    parser.add_argument("--seeds", type=int, default=100, help="training draws, seeds from 1000 (default 100)")
    parser.add_argument("--held-out-seeds", type=int, default=13, help="seeds per held-out schedule (default 13)")
    parser.add_argument(
        "--scenarios",
        default=",".join(("training", *HELD_OUT)),
        help="comma-separated: training and comparison scenarios (default: training and the held-out ones)",
    )
    parser.add_argument("--out", type=Path, help="export the (unstacked) policy to this folder")
    args = parser.parse_args(argv)
    names = [name for name in args.blind.split(",") if name]
    unknown = [name for name in names if name not in OBSERVATION_INDEX]
    if unknown:
        parser.error(f"--blind: no observation entry {unknown[0]!r}; entries: {', '.join(OBSERVATION_INDEX)}")
    if args.stack < 1:
        parser.error(f"--stack must be at least 1, got {args.stack}")
    if args.privileged and args.algo != "ppo":
        parser.error("--privileged is PPO's asymmetric actor-critic: --algo ppo")
    if args.algo == "sac" and args.stack != 1:
        parser.error(
            "--stack with --algo sac: SAC's replay buffer keeps VecNormalize's unstacked observations here; "
            "research/sac_probes.py --stack stacks under VecNormalize"
        )
    if args.privileged and args.stack != 1:
        parser.error("--privileged masks one observation's privileged entries: --stack 1")
    if args.out is not None and args.stack != 1:
        parser.error("--out exports an unstacked policy: --stack 1")
    blind = [OBSERVATION_INDEX[name] for name in names]
    timesteps = hyperparams.load(args.algo, ENV_ID).n_timesteps if args.timesteps is None else args.timesteps
    torch.set_num_threads(1)
    start = time.perf_counter()
    model, normalized = train(args.algo, args.stack, args.privileged, blind, args.seed, timesteps)
    wall = time.perf_counter() - start
    change = f"{args.algo}, stack {args.stack}, privileged {args.privileged}, blind {names or 'none'}"
    print(f"{change}, seed {args.seed}: {timesteps} steps in {wall:.0f} s", flush=True)
    if args.out is not None:
        command = "python research/recipe_probe.py " + " ".join(argv if argv is not None else sys.argv[1:])
        card = {
            "env_id": ENV_ID,
            "env_kwargs": gym.spec(ENV_ID).kwargs,
            "command": command,
            "seed": args.seed,
            "algo": args.algo,
            "timesteps": timesteps,
            "wall_s": round(wall, 1),
            "probe": {"algo": args.algo, "stack": args.stack, "privileged": args.privileged, "blind": names},
        }
        export(model, normalized, blind, args.out, card)
        print(f"exported to {args.out}")
    scenarios = [s for s in args.scenarios.split(",") if (args.seeds if s == "training" else args.held_out_seeds)]
    if scenarios:
        print("| schedule | policy | zero residual | paired difference (± standard error) | policy higher |")
        print("|---|---|---|---|---|")
    for scenario in scenarios:
        count = args.seeds if scenario == "training" else args.held_out_seeds
        env = make_env(ENV_ID, scenario)
        seeds = range(TEST_SEED, TEST_SEED + count)
        policy = np.array([episode_return(env, actor(model, normalized, args.stack, blind), s) for s in seeds])
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
