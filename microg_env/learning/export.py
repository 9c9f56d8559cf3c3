"""Export a trained stable-baselines3 actor with its observation normalisation to NumPy
(:class:`microg_env.controllers.policy.MLPPolicy`), and write a policy folder."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from microg_env.controllers.policy import CARD_FILE, NETWORK_FILE, MLPPolicy
from microg_env.files import replace_folder

#: stable-baselines3's files in a policy folder, for fine-tuning and the zoo's ``enjoy``.
MODEL_FILE, NORMALIZATION_FILE = "model.zip", "vecnormalize.pkl"


def actor_layers(model: Any) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...], str, bool]:
    """The deterministic actor of a PPO, SAC or TQC ``model``: its layers' weights and biases
    (float64, the first on the whole observation the model was trained on), the activation between
    them and whether its output is squashed (SAC; TQC's actor is built as SAC's) rather than
    clipped (PPO)."""
    import torch.nn as nn
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.torch_layers import FlattenExtractor

    tqc = getattr(sys.modules.get("sb3_contrib"), "TQC", None)  # imported wherever a TQC model is

    if isinstance(model, PPO):
        policy = model.policy
        extractor, hidden = policy.pi_features_extractor, policy.mlp_extractor.policy_net
        head, squash = policy.action_net, False
    elif isinstance(model, SAC) or (tqc is not None and isinstance(model, tqc)):
        actor = model.actor
        extractor, hidden, head, squash = actor.features_extractor, actor.latent_pi, actor.mu, True
    else:
        raise ValueError(f"can export PPO, SAC and TQC policies, got {type(model).__name__}")
    if not isinstance(extractor, FlattenExtractor):
        raise ValueError(f"can export MLP policies only, got a {type(extractor).__name__}")
    linear = [m for m in hidden if isinstance(m, nn.Linear)] + [head]
    kinds = {type(m).__name__ for m in hidden if not isinstance(m, nn.Linear)}
    activation = {frozenset({"Tanh"}): "tanh", frozenset({"ReLU"}): "relu"}.get(frozenset(kinds))
    if activation is None:
        raise ValueError(f"can export tanh or ReLU networks, got {sorted(kinds)}")
    weights = tuple(m.weight.detach().cpu().numpy().astype(np.float64) for m in linear)
    biases = tuple(m.bias.detach().cpu().numpy().astype(np.float64) for m in linear)
    return weights, biases, activation, squash


def export_policy(model: Any, vecnormalize: Any | None) -> MLPPolicy:
    """The deterministic actor of a PPO, SAC or TQC ``model`` (:func:`actor_layers`) and the observation
    statistics of ``vecnormalize`` (None: no normalisation) as an :class:`MLPPolicy`."""
    weights, biases, activation, squash = actor_layers(model)
    size = model.observation_space.shape[0]
    if vecnormalize is not None and vecnormalize.norm_obs:
        mean, var = vecnormalize.obs_rms.mean, vecnormalize.obs_rms.var
        clip_obs, epsilon = float(vecnormalize.clip_obs), float(vecnormalize.epsilon)
    else:  # the identity: zero mean, unit variance (epsilon 0), no clip in practice
        mean, var, clip_obs, epsilon = np.zeros(size), np.ones(size), float(np.finfo(np.float32).max), 0.0
    return MLPPolicy(
        weights,
        biases,
        activation,
        squash,
        np.asarray(mean, dtype=np.float64),
        np.asarray(var, dtype=np.float64),
        clip_obs,
        epsilon,
    )


def write_policy_folder(folder: Path, model: Any, vecnormalize: Any | None, card: dict[str, Any]) -> None:
    """Write ``folder``: the exported network, its card, and stable-baselines3's model and
    normalisation statistics, swapped in whole once complete (an interrupted write leaves the
    previous folder as it was)."""

    def fill(staging: Path) -> None:
        export_policy(model, vecnormalize).save(staging / NETWORK_FILE)
        model.save(staging / MODEL_FILE)  # SB3 keeps a path with a suffix as it is
        if vecnormalize is not None:
            vecnormalize.save(str(staging / NORMALIZATION_FILE))
        (staging / CARD_FILE).write_text(json.dumps(card, indent=2) + "\n", encoding="utf-8")

    replace_folder(folder, fill)
