"""Learned policies behind the controller interface.

A policy trained in ``MicroGravityLanding-v1`` acts every ``decision_period`` control periods and,
in the residual action mode, moves the setpoint of a base controller that commands the drive every
period. :class:`PolicyController` does the same outside the training environment, so a learned
controller runs in the speed-action environment of every other controller, on the same physics:
it rebuilds the observation the policy was trained on (its own previous action and the base
controller's last command in entries 8 and 9) and composes the policy with its base.

:class:`MLPPolicy` is a trained stable-baselines3 or sb3-contrib actor (PPO, SAC, TQC, CrossQ) exported to
NumPy with its observation normalisation (``VecNormalize``), so a shipped policy runs without torch. A policy folder
holds the exported network (``policy.npz``) and the command, seed, budget and results of its
training (``policy.json``); a training run's folder also the stable-baselines3 model and
normalisation to fine-tune from (``model.zip``, ``vecnormalize.pkl``, kept for the shipped policies
in the source tree, not in the wheel). Finding a policy by name or folder, and checking a folder
before it runs, is :mod:`microg_env.controllers.registry`'s.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from microg_env import validate
from microg_env.compiled import jit
from microg_env.controllers.base import SetpointController, VectorController, tell_plants
from microg_env.controllers.pid import PID
from microg_env.files import atomic_path
from microg_env.interface import (
    MAX_SPEED_M_S,
    OBSERVATION_INDEX,
    OBSERVATION_SCALES,
    action_size,
    gain_scales,
    gated_actions,
    gated_setpoint,
    highpass_gain,
    speed_actions,
)
from microg_env.params import CONTROL_PERIOD_S
from microg_env.task import ActingSettings

_erf = np.frompyfunc(math.erf, 1, 1)  # NumPy has no erf
#: Activations of the exported networks, torch's with their default parameters: those a policy_kwargs may name
#: (``microg_env.learning.hyperparams.ACTIVATION_NAMES``; stable-baselines3's defaults: PPO tanh, SAC, TQC and
#: CrossQ ReLU).
ACTIVATIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "tanh": np.tanh,
    "relu": lambda z: np.maximum(z, 0.0),
    "elu": lambda z: np.where(z > 0.0, z, np.expm1(np.minimum(z, 0.0))),
    "leaky_relu": lambda z: np.where(z >= 0.0, z, 0.01 * z),
    "gelu": lambda z: 0.5 * z * (1.0 + _erf(z / math.sqrt(2.0)).astype(np.float64)),  # torch's exact GELU
    "silu": lambda z: z * 0.5 * (1.0 + np.tanh(0.5 * z)),  # z sigmoid(z), without exp's overflow
}
#: The smallest observation clip a policy may have, in standard deviations (VecNormalize's default
#: is 10): a clip inside one makes most observations one constant, a policy blind to them.
MIN_CLIP_OBS = 1.0
#: Most bytes an exported network may hold once unpacked (the shipped one: 23 kB); checked from the
#: archive's headers before anything is read, so a small archive cannot unpack to gigabytes.
MAX_NETWORK_BYTES = 64 * 2**20


@dataclass(frozen=True)
class MLPPolicy:
    """A deterministic actor: normalise the observation, run the layers, squash or clip to [-1, 1].

    ``predict`` matches stable-baselines3's ``model.predict(obs_normalised, deterministic=True)``.
    ``clip_obs`` is VecNormalize's (the exporter writes float32's largest for no normalisation);
    ``mean_clip``, the clip of the output to +-mean_clip before its tanh (SAC's, TQC's and CrossQ's
    ``clip_mean`` with gSDE; 0: none).
    """

    weights: tuple[np.ndarray, ...]  # (out, in) per layer, as torch stores them
    biases: tuple[np.ndarray, ...]
    activation: str  # between hidden layers
    squash: bool  # tanh on the output (SAC, TQC, CrossQ, PPO's squash_output) rather than a clip (PPO)
    obs_mean: np.ndarray
    obs_var: np.ndarray
    clip_obs: float
    epsilon: float = 1e-8
    mean_clip: float = 0.0

    def __post_init__(self) -> None:
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {', '.join(ACTIVATIONS)}, got {self.activation!r}")
        if not isinstance(self.squash, bool):
            raise ValueError(f"squash must be true or false, got {validate.shown(self.squash)}")
        object.__setattr__(
            self,
            "clip_obs",
            validate.at_least(
                "clip_obs", self.clip_obs, MIN_CLIP_OBS, why="a clip inside one standard deviation blinds the policy"
            ),
        )
        object.__setattr__(self, "epsilon", validate.non_negative("epsilon", self.epsilon))
        object.__setattr__(self, "mean_clip", validate.non_negative("mean_clip", self.mean_clip))
        if len(self.weights) != len(self.biases) or not self.weights:
            raise ValueError("a policy needs as many bias vectors as weight matrices, and at least one layer")
        arrays = (*self.weights, *self.biases, self.obs_mean, self.obs_var)
        if any(a.dtype.kind != "f" for a in arrays) or not all(np.isfinite(a).all() for a in arrays):
            raise ValueError("every weight, bias and normalisation statistic must be a finite float array")
        if self.obs_mean.shape != (len(OBSERVATION_SCALES),) or self.obs_var.shape != self.obs_mean.shape:
            raise ValueError(
                f"obs_mean and obs_var must have the observation's shape ({len(OBSERVATION_SCALES)},), "
                f"got {self.obs_mean.shape} and {self.obs_var.shape}"
            )
        if (self.obs_var < 0).any():
            raise ValueError("obs_var must not be negative")
        if (self.obs_var + self.epsilon <= 0).any():
            raise ValueError("obs_var + epsilon must be positive, the deviation every observation is divided by")
        if self.weights[-1].ndim != 2 or self.weights[-1].shape[0] < 1:
            raise ValueError(f"the last layer must give the action's numbers, got weight {self.weights[-1].shape}")
        size = self.obs_mean.shape[0]
        for weight, bias in zip(self.weights, self.biases, strict=True):
            if weight.ndim != 2 or weight.shape[1] != size or bias.shape != (weight.shape[0],):
                raise ValueError(f"layer shapes do not chain: weight {weight.shape}, bias {bias.shape}, input {size}")
            size = weight.shape[0]
        object.__setattr__(self, "_obs_std", np.sqrt(self.obs_var + self.epsilon))  # once, not every call

    @property
    def action_size(self) -> int:
        """How many numbers the policy's action holds (its last layer's outputs)."""
        return int(self.weights[-1].shape[0])

    def normalize(self, observation: np.ndarray) -> np.ndarray:
        """VecNormalize's observation normalisation with the training statistics."""
        scaled = (observation - self.obs_mean) / self._obs_std
        return np.minimum(np.maximum(scaled, -self.clip_obs), self.clip_obs)

    def predict(self, observation: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        z = self.normalize(np.asarray(observation, dtype=np.float64))
        act = ACTIVATIONS[self.activation]
        for i, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            z = z @ weight.T + bias
            if i < len(self.weights) - 1:
                z = act(z)
        if self.mean_clip > 0.0:
            z = np.minimum(np.maximum(z, -self.mean_clip), self.mean_clip)
        action = np.tanh(z) if self.squash else np.minimum(np.maximum(z, -1.0), 1.0)
        return action.astype(np.float32), None

    def save(self, path: str | Path) -> None:
        arrays = {f"weight_{i}": w for i, w in enumerate(self.weights)}
        arrays |= {f"bias_{i}": b for i, b in enumerate(self.biases)}
        arrays |= {"obs_mean": self.obs_mean, "obs_var": self.obs_var}
        meta = {
            "activation": self.activation,
            "squash": self.squash,
            "clip_obs": self.clip_obs,
            "epsilon": self.epsilon,
            "mean_clip": self.mean_clip,
        }
        with atomic_path(path) as temporary, open(temporary, "wb") as stream:
            np.savez(stream, **arrays, meta=np.array(json.dumps(meta)))

    @classmethod
    def load(cls, path: str | Path) -> MLPPolicy:
        path = Path(path)
        if not path.is_file():  # not a FIFO or a device that would block or never end
            raise ValueError("not a regular file")
        with zipfile.ZipFile(path) as archive:
            unpacked = sum(member.file_size for member in archive.infolist())
        if unpacked > MAX_NETWORK_BYTES:
            raise ValueError(f"it unpacks to {unpacked} bytes, more than the {MAX_NETWORK_BYTES} a policy may hold")
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            if not isinstance(meta, dict):
                raise ValueError(f"its meta must be a JSON object, got {validate.shown(meta)}")
            layers = sum(1 for key in data.files if key.startswith("weight_"))
            return cls(
                tuple(data[f"weight_{i}"] for i in range(layers)),
                tuple(data[f"bias_{i}"] for i in range(layers)),
                meta["activation"],
                meta["squash"],
                data["obs_mean"],
                data["obs_var"],
                meta["clip_obs"],
                meta["epsilon"],
                meta.get("mean_clip", 0.0),  # absent from files written before it
            )


class PolicyController(VectorController):
    """A learned policy (anything with ``predict(obs, deterministic=True)``: a stable-baselines3
    model, an :class:`MLPPolicy`) as a controller, acting as its :class:`~microg_env.task.ActingSettings`
    say, as the environment does.

    The policy acts every ``decision_period`` control periods. In ``action_mode="residual"`` its
    action is a setpoint for x, ``action * residual_limit_m``, that the ``base`` controller holds
    while commanding the drive every period; in ``action_mode="gains"`` it multiplies the ``base``
    PID's gains (:func:`~microg_env.interface.gain_scales`; the mean of its numbers is the
    observation's previous action, as in the environment); in speed mode the action is the speed
    command up to ``speed_limit_m_s``, held.
    The setpoint is the action high-passed (:func:`~microg_env.interface.residual_setpoint`) and
    gated (:func:`~microg_env.interface.gated_setpoint`) as the settings say, and the
    ``hidden_observations`` read 0 to the policy. An all-zero residual is exactly the base
    controller. Many rigs' observations go through the policy in one batch.
    """

    STATE: ClassVar[dict[str, float]] = {
        "_periods": 0.0,
        "_action": 0.0,
        "_base_command_m_s": 0.0,
        "_filtered_action": 0.0,
        "_setpoint_m": 0.0,
        "_stage_m": 0.0,
    }

    def __init__(
        self,
        policy: Any,
        acting: ActingSettings | None = None,
        base: SetpointController | None = None,
        control_period_s: float = CONTROL_PERIOD_S,
        deterministic: bool = True,
    ) -> None:
        acting = validate.instance("acting", ActingSettings() if acting is None else acting, ActingSettings)
        if (base is not None) != (acting.action_mode != "speed"):
            raise ValueError(
                f"a policy of action_mode {acting.action_mode!r} acts {'on' if base is None else 'without'} a base "
                f"controller, got base {type(base).__name__}"
            )
        if acting.action_mode == "gains" and not isinstance(base, PID):
            raise ValueError(f"a gains policy schedules a PID's gains, got base {type(base).__name__}")
        width = getattr(policy, "action_size", action_size(acting.action_mode))
        if width != action_size(acting.action_mode):
            raise ValueError(
                f"the policy gives {width} numbers an action, and action_mode {acting.action_mode!r} takes "
                f"{action_size(acting.action_mode)}"
            )
        super().__init__(*(() if base is None else (base,)))
        self.policy = policy
        self.acting = acting
        self.deterministic = deterministic
        self.base = base
        self._residual_gain = highpass_gain(acting.residual_highpass_hz, acting.decision_period * control_period_s)
        self._second_stage = acting.residual_highpass_order == 2
        self._hidden = [OBSERVATION_INDEX[name] for name in acting.hidden_observations]
        self._size = action_size(acting.action_mode)

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        due = np.empty(ids.size, dtype=np.bool_)
        if count_periods(ids, self._periods, self.acting.decision_period, due):
            acting = ids[due]
            seen = np.array(rows[due], dtype=np.float32)  # what the training environment showed
            seen[:, OBSERVATION_INDEX["previous_action"]] = self._action[acting]
            seen[:, OBSERVATION_INDEX["base_command"]] = (
                self._base_command_m_s[acting] / OBSERVATION_SCALES["base_command"]
            )
            seen[:, self._hidden] = 0.0
            action, _ = self.policy.predict(seen, deterministic=self.deterministic)
            action = np.clip(np.asarray(action, dtype=np.float32).reshape(acting.size, self._size), -1.0, 1.0)
            if self.acting.action_mode == "gains":
                gated = gated_actions(action, rows[due], self.acting.residual_gate_m)
                self.base.schedule(acting, gain_scales(gated, self.acting.gain_limit))
            self._action[acting] = action.mean(axis=1, dtype=np.float64)  # the environment's; one number: itself
            if self.acting.action_mode == "residual":
                self.base.setpoint_m[acting] = gated_setpoint(
                    self._action[acting],
                    rows[due],
                    acting,
                    self.acting.residual_gate_m,
                    self.acting.residual_gate_on,
                    self.acting.residual_limit_m,
                    self._residual_gain,
                    (self._filtered_action, self._setpoint_m, self._stage_m if self._second_stage else None),
                )
        if self.base is None:
            return speed_actions(self._action[ids], self.acting.speed_limit_m_s)
        command = self.base.act(rows, ids)  # grown with this controller (a part of it)
        self._base_command_m_s[ids] = command.astype(np.float64) * MAX_SPEED_M_S
        return command

    def know_plants(self, ids: np.ndarray, plants: list, *, ideal_drive: bool) -> None:
        """Pass the plants on to a base that takes them (an oracle base)."""
        if self.base is not None:
            tell_plants(self.base, ids, plants, ideal_drive=ideal_drive)


@jit
def count_periods(ids, periods, decision_period, due):
    """Count a control period of rigs ``ids``; ``due[j]``: rig j's policy acts in it (its first
    period, then every ``decision_period``). Returns how many are due."""
    count = 0
    for j in range(ids.size):
        i = ids[j]
        due[j] = periods[i] % decision_period == 0
        periods[i] += 1
        count += due[j]
    return count
