"""Learned policies behind the controller interface, and the policies shipped with the package.

A policy trained in ``MicroGravityLanding-v1`` acts every ``decision_period`` control periods and,
in the residual action mode, moves the setpoint of a base controller that commands the drive every
period. :class:`PolicyController` does the same outside the training environment, so a learned
controller runs in the speed-action environment of every other controller, on the same physics:
it rebuilds the observation the policy was trained on (its own previous action and the base
controller's last command in entries 8 and 9) and composes the policy with its base.

:class:`MLPPolicy` is a trained stable-baselines3 actor (PPO or SAC) exported to NumPy with its
observation normalisation (``VecNormalize``), so a shipped policy runs without torch; the shipped
policies live in ``microg_env/policies/<name>/`` with the exported network (``policy.npz``), the
stable-baselines3 model and normalisation for fine-tuning (``model.zip``, ``vecnormalize.pkl``)
and the command, seed, budget and results of their training (``policy.json``).
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from microg_env.compiled import jit
from microg_env.controllers.base import MAX_SPEED_M_S, SetpointController, VectorController, tell_plants
from microg_env.envs.observation import OBSERVATION_INDEX, OBSERVATION_SCALES
from microg_env.params import CONTROL_PERIOD_S

RESIDUAL_LIMIT_M = 1e-6
"""The x setpoint a residual action of +-1 stands for, m: a few times the feedforward baseline's
collision excursion (about 1 um), so the whole action range is useful near touchdown."""

#: Activations of the exported networks (stable-baselines3's defaults: PPO tanh, SAC ReLU).
ACTIVATIONS = {"tanh": np.tanh, "relu": lambda z: np.maximum(z, 0.0)}
#: Files of an exported policy folder.
NETWORK_FILE, CARD_FILE = "policy.npz", "policy.json"
#: Most bytes an exported network may hold once unpacked (the shipped one: 23 kB); checked from the
#: archive's headers before anything is read, so a small archive cannot unpack to gigabytes.
MAX_NETWORK_BYTES = 64 * 2**20
#: Most bytes a policy card may hold.
MAX_CARD_BYTES = 2**20


@dataclass(frozen=True)
class MLPPolicy:
    """A deterministic actor: normalise the observation, run the layers, squash or clip to [-1, 1].

    ``predict`` matches stable-baselines3's ``model.predict(obs_normalised, deterministic=True)``.
    """

    weights: tuple[np.ndarray, ...]  # (out, in) per layer, as torch stores them
    biases: tuple[np.ndarray, ...]
    activation: str  # between hidden layers
    squash: bool  # tanh on the output (SAC) rather than a clip (PPO)
    obs_mean: np.ndarray
    obs_var: np.ndarray
    clip_obs: float
    epsilon: float = 1e-8

    def __post_init__(self) -> None:
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {', '.join(ACTIVATIONS)}, got {self.activation!r}")
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
        if self.weights[-1].ndim != 2 or self.weights[-1].shape[0] != 1:
            raise ValueError(f"the last layer must give the one action, got weight {self.weights[-1].shape}")
        size = self.obs_mean.shape[0]
        for weight, bias in zip(self.weights, self.biases, strict=True):
            if weight.ndim != 2 or weight.shape[1] != size or bias.shape != (weight.shape[0],):
                raise ValueError(f"layer shapes do not chain: weight {weight.shape}, bias {bias.shape}, input {size}")
            size = weight.shape[0]
        object.__setattr__(self, "_obs_std", np.sqrt(self.obs_var + self.epsilon))  # once, not every call

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
        action = np.tanh(z) if self.squash else np.minimum(np.maximum(z, -1.0), 1.0)
        return action.astype(np.float32), None

    def save(self, path: str | Path) -> None:
        from microg_env.files import atomic_path

        arrays = {f"weight_{i}": w for i, w in enumerate(self.weights)}
        arrays |= {f"bias_{i}": b for i, b in enumerate(self.biases)}
        arrays |= {"obs_mean": self.obs_mean, "obs_var": self.obs_var}
        meta = {
            "activation": self.activation,
            "squash": self.squash,
            "clip_obs": self.clip_obs,
            "epsilon": self.epsilon,
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
            layers = sum(1 for key in data.files if key.startswith("weight_"))
            return cls(
                tuple(data[f"weight_{i}"] for i in range(layers)),
                tuple(data[f"bias_{i}"] for i in range(layers)),
                meta["activation"],
                bool(meta["squash"]),
                data["obs_mean"],
                data["obs_var"],
                float(meta["clip_obs"]),
                float(meta["epsilon"]),
            )


class PolicyController(VectorController):
    """A learned policy (anything with ``predict(obs, deterministic=True)``: a stable-baselines3
    model, an :class:`MLPPolicy`) as a controller of the speed-action environment.

    The policy acts every ``decision_period`` control periods. With a ``base`` controller its
    action is a setpoint for x, ``action * residual_limit_m``, that the base holds while commanding
    the drive every period (the residual mode of ``MicroGravityLanding-v1``); without one the action
    is the speed command, held. An all-zero residual is exactly the base controller. Many rigs'
    observations go through the policy in one batch.
    """

    STATE: ClassVar[dict[str, float]] = {"_periods": 0.0, "_action": 0.0, "_base_command_m_s": 0.0}

    def __init__(
        self,
        policy: Any,
        deterministic: bool = True,
        decision_period: int = 1,
        base: SetpointController | None = None,
        residual_limit_m: float = RESIDUAL_LIMIT_M,
    ) -> None:
        from microg_env import validate

        super().__init__(*(() if base is None else (base,)))
        self.policy = policy
        self.deterministic = deterministic
        self.decision_period = validate.integer("decision_period", decision_period, 1, 1000)
        self.base = base
        self.residual_limit_m = validate.positive("residual_limit_m", residual_limit_m, "m", 1e-3)

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        due = np.empty(ids.size, dtype=np.bool_)
        if count_periods(ids, self._periods, self.decision_period, due):
            acting = ids[due]
            seen = np.array(rows[due], dtype=np.float32)  # what the training environment showed
            seen[:, OBSERVATION_INDEX["previous_action"]] = self._action[acting]
            seen[:, OBSERVATION_INDEX["base_command"]] = (
                self._base_command_m_s[acting] / OBSERVATION_SCALES["base_command"]
            )
            action, _ = self.policy.predict(seen, deterministic=self.deterministic)
            self._action[acting] = np.clip(np.asarray(action, dtype=np.float32).reshape(-1), -1.0, 1.0)
            if self.base is not None:
                self.base.setpoint_m[acting] = self._action[acting] * self.residual_limit_m
        if self.base is None:
            return self._action[ids]
        command = self.base.act(rows, ids)  # grown with this controller (a part of it)
        self._base_command_m_s[ids] = command.astype(np.float64) * MAX_SPEED_M_S
        return command

    def know_plants(self, ids: np.ndarray, plants: list) -> None:
        """Pass the plants on to a base that takes them (an oracle base)."""
        if self.base is not None:
            tell_plants(self.base, ids, plants)


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


# -- shipped policies ---------------------------------------------------------------------------


def shipped_policies() -> tuple[str, ...]:
    """Names of the policies shipped in the package (``microg_env/policies/<name>/``)."""
    root = resources.files("microg_env").joinpath("policies")
    if not root.is_dir():
        return ()
    return tuple(sorted(p.name for p in root.iterdir() if p.is_dir() and p.joinpath(CARD_FILE).is_file()))


def policy_card(folder: str | Path) -> dict[str, Any]:
    """The ``policy.json`` of an exported policy folder: how it acts, how it was trained."""
    path = Path(folder) / CARD_FILE
    if not path.exists():
        raise ValueError(f"policy folder {str(folder)!r} has no {CARD_FILE}")
    if not path.is_file() or path.stat().st_size > MAX_CARD_BYTES:
        raise ValueError(f"{str(path)!r} is not a policy card (a regular file of at most {MAX_CARD_BYTES} bytes)")
    try:
        card = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"cannot read {str(path)!r}: {error}") from None
    if not (isinstance(card, dict) and isinstance(card.get("env_kwargs"), dict)):
        raise ValueError(f"{str(path)!r} is not a policy card (a JSON object with an env_kwargs object)")
    try:
        _check_deployment(card["env_kwargs"])
    except ValueError as error:
        raise ValueError(f"{str(path)!r}: env_kwargs.{error}") from None
    return card


def _check_deployment(env: dict[str, Any]) -> None:
    """The env_kwargs a deployed policy reads: of the right kinds and ranges, the base controller a
    classical one (a policy on a policy, or on itself, is refused)."""
    from microg_env import validate
    from microg_env.controllers.registry import BASELINES
    from microg_env.params import CONTROL_PERIOD_RANGE_S

    validate.choice("action_mode", env.get("action_mode", "speed"), ("speed", "residual"))
    validate.choice("base_controller", env.get("base_controller", "pid"), BASELINES)
    if type(env.get("decision_period", 1)) is not int:
        raise ValueError(f"decision_period must be an integer, got {env['decision_period']!r}")
    validate.integer("decision_period", env.get("decision_period", 1), 1, 1000)
    validate.between("control_period_s", env.get("control_period_s", CONTROL_PERIOD_S), *CONTROL_PERIOD_RANGE_S, "s")
    validate.positive("residual_limit_m", env.get("residual_limit_m", RESIDUAL_LIMIT_M), "m", 1e-3)


def shipped_policy_folder(name: str) -> Path:
    if name not in shipped_policies():
        raise ValueError(f"no shipped policy {name!r}; shipped: {', '.join(shipped_policies()) or 'none'}")
    return Path(str(resources.files("microg_env").joinpath("policies", name)))


def check_policy_folder(folder: str | Path) -> tuple[dict[str, Any], MLPPolicy]:
    """The card and network of an exported policy folder, or a ValueError naming what is wrong."""
    card = policy_card(folder)
    try:
        return card, MLPPolicy.load(Path(folder) / NETWORK_FILE)
    except (OSError, KeyError, ValueError, TypeError, zipfile.BadZipFile) as error:
        raise ValueError(f"policy folder {str(folder)!r}: cannot read {NETWORK_FILE} ({error})") from None


def load_policy(folder: str | Path, control_period_s: float) -> PolicyController:
    """The exported policy in ``folder`` as a controller; it must run at the control period it
    was trained at (its decision period and base controller's tuning are tied to it)."""
    card, policy = check_policy_folder(folder)
    env = card["env_kwargs"]
    trained_period = float(env.get("control_period_s", CONTROL_PERIOD_S))
    if abs(control_period_s - trained_period) > 1e-9:
        raise ValueError(
            f"control_period_s {control_period_s!r}: policy {Path(folder).name!r} was trained at "
            f"{trained_period * 1e6:g} us and runs only at that period"
        )
    return deployed_controller(policy, env)


def deployed_controller(policy: Any, env_kwargs: dict[str, Any]) -> PolicyController:
    """``policy``, trained in ``MicroGravityLanding-v1`` with ``env_kwargs``, as the controller it
    is deployed as: a residual on its base controller, acting every decision period."""
    from microg_env.controllers.registry import make_controller

    residual = env_kwargs.get("action_mode", "speed") == "residual"
    period = float(env_kwargs.get("control_period_s", CONTROL_PERIOD_S))
    return PolicyController(
        policy,
        decision_period=int(env_kwargs.get("decision_period", 1)),
        base=make_controller(env_kwargs.get("base_controller", "pid"), period) if residual else None,
        residual_limit_m=float(env_kwargs.get("residual_limit_m", RESIDUAL_LIMIT_M)),
    )
