"""Export a trained stable-baselines3 actor with its observation normalisation to NumPy
(:class:`microg_env.controllers.policy.MLPPolicy`), and write a policy folder."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from microg_env.controllers.policy import MLPPolicy
from microg_env.files import replace_folder
from microg_env.interface import CARD_FILE, NETWORK_FILE
from microg_env.learning.settings import CONTRIB_ALGORITHMS

#: stable-baselines3's files in a policy folder, for fine-tuning and the zoo's ``enjoy``.
MODEL_FILE, NORMALIZATION_FILE = "model.zip", "vecnormalize.pkl"


#: torch's activations an exported network may hold, by their names in
#: :data:`~microg_env.controllers.policy.ACTIVATIONS`.
TORCH_ACTIVATIONS = {
    "Tanh": "tanh",
    "ReLU": "relu",
    "ELU": "elu",
    "LeakyReLU": "leaky_relu",
    "GELU": "gelu",
    "SiLU": "silu",
}


def actor_layers(model: Any) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...], str, bool, float]:
    """The deterministic actor of a PPO, SAC, TQC or CrossQ ``model``: its layers' weights and
    biases (float64, the first on the whole observation the model was trained on), the activation
    between them, whether its output is squashed by a tanh (SAC; TQC's and CrossQ's actors are built
    as SAC's; PPO's with ``squash_output``) rather than clipped (PPO), and the clip of the output before
    the tanh (``clip_mean`` with gSDE; 0: none). CrossQ's batch renormalisation layers are folded into
    the layers they feed (:func:`fold_batch_renorm`). What the export cannot compute as the model does
    is refused, named."""
    import torch.nn as nn
    from gymnasium import spaces
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.torch_layers import FlattenExtractor

    contrib = sys.modules.get("sb3_contrib")  # imported wherever a TQC or CrossQ model is
    squashed = (SAC, *(getattr(contrib, name) for name in CONTRIB_ALGORITHMS.values() if hasattr(contrib, name)))

    if isinstance(model, PPO):
        policy = model.policy
        extractor, hidden, head = policy.pi_features_extractor, policy.mlp_extractor.policy_net, policy.action_net
    elif isinstance(model, squashed):
        policy = model.actor
        extractor, hidden, head = policy.features_extractor, policy.latent_pi, policy.mu
    else:
        raise ValueError(f"can export PPO, SAC, TQC and CrossQ policies, got {type(model).__name__}")
    if not isinstance(extractor, FlattenExtractor):
        raise ValueError(f"can export MLP policies only, got a {type(extractor).__name__}")
    space = model.action_space
    if not (
        isinstance(space, spaces.Box)
        and len(space.shape) == 1
        and (space.low == -1.0).all()
        and (space.high == 1.0).all()
    ):
        raise ValueError(f"can export policies of actions in [-1, 1], got the action space {space}")
    modules = [*hidden, *(head if isinstance(head, nn.Sequential) else [head])]
    mean_clip = 0.0
    if type(modules[-1]) is nn.Hardtanh:  # clip_mean's (gSDE), before the tanh
        clip = modules.pop()
        if clip.min_val != -clip.max_val:
            raise ValueError(f"can export a symmetric clip of the output, got {clip}")
        mean_clip = float(clip.max_val)
    for module in modules:  # torch's default parameters, as the NumPy activations compute them
        if type(module).__name__ in TORCH_ACTIVATIONS and repr(module) != repr(type(module)()):
            raise ValueError(f"can export activations with torch's default parameters, got {module}")
    layers, others = fold_batch_renorm(modules)
    activations = {TORCH_ACTIVATIONS.get(name, name) for name in others}
    if not activations <= set(TORCH_ACTIVATIONS.values()) or len(activations) > 1:
        raise ValueError(
            f"can export networks of one activation of {', '.join(TORCH_ACTIVATIONS)} between linear layers, "
            f"got {', '.join(sorted(others))}"
        )
    activation = activations.pop() if activations else "tanh"  # no hidden layer: none is applied
    weights, biases = zip(*layers, strict=True)
    return weights, biases, activation, bool(policy.squash_output), mean_clip


def fold_batch_renorm(modules: list[Any]) -> tuple[list[tuple[np.ndarray, np.ndarray]], set[str]]:
    """The linear layers of ``modules`` (weight, bias in float64) and the names of the other
    modules' types, with each batch renormalisation layer (sb3-contrib's ``BatchRenorm1d``, CrossQ's)
    folded into the linear layer it feeds. A deployed CrossQ actor runs in evaluation mode, where
    such a layer is the affine map y = s (x - m) / sqrt(v + eps) + b by its running mean m and
    variance v: y = a x + c, and W y + d = (W diag(a)) x + (W c + d)."""
    import torch.nn as nn

    layers, others = [], set()
    scale = shift = None  # the affine map waiting for the next linear layer
    for module in modules:
        if isinstance(module, nn.Linear):
            weight = _array(module.weight)
            bias = _array(module.bias)
            if scale is not None:
                weight, bias = weight * scale[None, :], weight @ shift + bias
                scale = shift = None
            layers.append((weight, bias))
        elif hasattr(module, "ra_mean") and hasattr(module, "ra_var"):  # BatchRenorm
            std = np.sqrt(_array(module.ra_var) + module.eps)
            a, c = 1.0 / std, -_array(module.ra_mean) / std
            if module.affine:
                gain = _array(module.scale)
                a, c = gain * a, gain * c + _array(module.bias)
            scale, shift = (a, c) if scale is None else (a * scale, a * shift + c)
        elif scale is not None:
            raise ValueError(f"a batch renormalisation feeds a {type(module).__name__}, not a linear layer")
        else:
            others.add(type(module).__name__)
    if scale is not None:
        raise ValueError("the network ends with a batch renormalisation, which has no linear layer to fold into")
    return layers, others


def _array(tensor: Any) -> np.ndarray:
    return tensor.detach().cpu().numpy().astype(np.float64)


def export_policy(model: Any, vecnormalize: Any | None) -> MLPPolicy:
    """The deterministic actor of a PPO, SAC, TQC or CrossQ ``model`` (:func:`actor_layers`) and the observation
    statistics of ``vecnormalize`` (None: no normalisation) as an :class:`MLPPolicy`."""
    weights, biases, activation, squash, mean_clip = actor_layers(model)
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
        mean_clip,
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
