"""Hyperparameter files in rl-baselines3-zoo's format: ``<algo>.yml``, one entry per env id.

An entry holds the algorithm's keyword arguments plus the zoo's own keys: ``n_envs``,
``n_timesteps``, ``policy``, ``normalize`` (``true``, or VecNormalize's keyword arguments as a
mapping or its string), ``env_kwargs``, schedules written ``lin_<initial value>``, and
``policy_kwargs`` as a mapping or the zoo's ``"dict(...)"`` string. A run's ``env_kwargs`` are the
registered id's defaults updated by the entry's, so a run folder says the whole task. Strings are parsed, never
evaluated: ``dict(...)`` with literal values and ``nn.<Activation>`` are all they may hold. The
packaged files are ``microg_env/hyperparams/``, the same files ``python -m rl_zoo3.train -conf``
reads.
"""

from __future__ import annotations

import ast
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gymnasium.envs.registration import registry

from microg_env import validate
from microg_env.controllers.policy import MIN_CLIP_OBS
from microg_env.files import read_yaml
from microg_env.learning.settings import ALGORITHMS, MAX_ENVS
from microg_env.validate import shown

#: Algorithm arguments microg train sets itself (from its options), refused in a file.
SET_BY_TRAIN = ("device", "seed", "verbose", "tensorboard_log", "env", "policy")
#: Algorithm arguments that count something, each a positive integer (target_update_interval 0
#: divided by zero at the first update; stats_window_size 0 averaged no episodes).
COUNT_KEYS = (
    "n_steps",
    "batch_size",
    "n_epochs",
    "buffer_size",
    "policy_delay",
    "target_update_interval",
    "stats_window_size",
)
#: Algorithm arguments that are integers, by their least value: COUNT_KEYS from 1, learning_starts
#: from 0, gradient_steps and sde_sample_freq from -1 (one update per step collected; a sample only
#: at a rollout's start). gradient_steps 0 is refused too: a run that never updates its policy.
INTEGER_KEYS = dict.fromkeys(COUNT_KEYS, 1) | {"learning_starts": 0, "gradient_steps": -1, "sde_sample_freq": -1}
#: TQC's quantiles per critic network unless policy_kwargs give n_quantiles, and those of each it
#: drops unless top_quantiles_to_drop_per_net says (sb3-contrib's defaults).
TQC_QUANTILES, TQC_DROPPED = 25, 2
#: The zoo's keys that are not the algorithm's keyword arguments.
ZOO_KEYS = ("n_envs", "n_timesteps", "policy", "normalize", "env_kwargs")
#: Keys rl-baselines3-zoo reads that ``microg train`` does not (use ``python -m rl_zoo3.train``).
UNSUPPORTED_KEYS = (
    "env_wrapper",
    "vec_env_wrapper",
    "callback",
    "frame_stack",
    "monitor_kwargs",
    "replay_buffer_class",
)
#: Schedules the zoo writes as ``lin_<value>``.
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")
#: Algorithm arguments that are numbers, checked before a run starts (the algorithms check few of
#: them, some only when training reaches them): in [0, 1], positive, at least 0; OFF_KEYS may be
#: null (off), SCHEDULE_KEYS a schedule, an off-policy ent_coef ``auto`` or ``auto_<initial value>``.
UNIT_KEYS = ("gamma", "gae_lambda", "tau")
POSITIVE_KEYS = ("learning_rate", "clip_range", "clip_range_vf", "target_kl", "max_grad_norm")
NON_NEGATIVE_KEYS = ("vf_coef", "ent_coef")
OFF_KEYS = ("clip_range_vf", "target_kl")
#: The same for the numbers of policy_kwargs (TQC and CrossQ check none of them: 0 quantiles
#: trained a critic of nothing, a negative momentum made the actor's output NaN) and of normalize
#: (VecNormalize's: a clip_obs of 0 makes every observation 0).
POLICY_COUNT_KEYS = ("n_critics", "n_quantiles")
POLICY_UNIT_KEYS = ("batch_norm_momentum",)
POLICY_POSITIVE_KEYS = ("batch_norm_eps",)
NORMALIZE_POSITIVE_KEYS = ("clip_obs", "clip_reward", "epsilon")
#: The policies an entry may name (the observation is a vector).
POLICIES = ("MlpPolicy",)
#: ``nn.<name>`` in a policy_kwargs string.
ACTIVATION_NAMES = ("Tanh", "ReLU", "ELU", "LeakyReLU", "GELU", "SiLU")


@dataclass(frozen=True)
class Hyperparams:
    """One resolved entry: what the run needs beyond the algorithm's keyword arguments."""

    algo: str
    env_id: str
    n_envs: int
    n_timesteps: int
    policy: str
    normalize: dict[str, Any] | None  # VecNormalize's keyword arguments, or None for no normalisation
    env_kwargs: dict[str, Any]
    algo_kwargs: dict[str, Any] = field(default_factory=dict)  # as written (schedules still strings)
    source: str = ""

    def as_config(self) -> dict[str, Any]:
        """The resolved entry as written to the run's ``config.yml`` (the zoo's keys and the algorithm's)."""
        config = {"n_envs": self.n_envs, "n_timesteps": self.n_timesteps, "policy": self.policy}
        config["normalize"] = self.normalize if self.normalize is not None else False
        config["env_kwargs"] = self.env_kwargs
        return config | self.algo_kwargs


def packaged_file(algo: str) -> Path:
    """The hyperparameter file shipped for ``algo``."""
    if algo not in ALGORITHMS:
        raise ValueError(f"--algo must be one of {', '.join(ALGORITHMS)}, got {shown(algo)}")
    return Path(__file__).resolve().parents[1] / "hyperparams" / f"{algo}.yml"


def load(algo: str, env_id: str, path: str | Path | None = None) -> Hyperparams:
    """The entry for ``env_id`` in ``path`` (default: the packaged ``<algo>.yml``)."""
    path = packaged_file(algo) if path is None else Path(path)
    table = read_yaml(path, "hyperparameter file")
    if not isinstance(table, dict) or env_id not in table:
        known = ", ".join(map(str, table)) if isinstance(table, dict) else "none"
        raise ValueError(f"hyperparameter file {shown(str(path))} has no entry {shown(env_id)} (entries: {known})")
    if not isinstance(table[env_id], dict):
        raise ValueError(
            f"hyperparameter file {shown(str(path))}: entry {shown(env_id)} must be a mapping, "
            f"got {shown(table[env_id])}"
        )
    entry = dict(table[env_id])
    where = f"{path.name}[{env_id}]"
    for key in UNSUPPORTED_KEYS:
        if key in entry:
            raise ValueError(f"{where}: {shown(key)} is not supported by microg train (run python -m rl_zoo3.train)")
    algo_kwargs = {k: v for k, v in entry.items() if k not in ZOO_KEYS}
    for key in SET_BY_TRAIN:
        if key in algo_kwargs:
            raise ValueError(f"{where}: {shown(key)} is set by microg train (use its options), not the file")
    texts = SCHEDULE_KEYS if algo == "ppo" else (*SCHEDULE_KEYS, "ent_coef")  # each checked below
    _check_numbers(algo_kwargs, where, INTEGER_KEYS, UNIT_KEYS, POSITIVE_KEYS, NON_NEGATIVE_KEYS, texts)
    if algo_kwargs.get("gradient_steps") == 0:
        raise ValueError(f"{where}.gradient_steps must be -1 (one per step collected) or a positive integer, got 0")
    if isinstance(algo_kwargs.get("ent_coef"), str):
        _learned_coefficient(algo_kwargs["ent_coef"], f"{where}.ent_coef")
    if algo_kwargs.get("target_entropy", "auto") != "auto":
        validate.finite(f"{where}.target_entropy", algo_kwargs["target_entropy"])
    policy = entry.get("policy", POLICIES[0])
    if policy not in POLICIES:
        raise ValueError(f"{where}.policy must be one of {', '.join(POLICIES)}, got {shown(policy)}")
    env_kwargs = {} if entry.get("env_kwargs") is None else entry["env_kwargs"]
    if not isinstance(env_kwargs, dict):
        raise ValueError(f"{where}.env_kwargs must be a mapping, got {shown(env_kwargs)}")
    for key in ("max_episode_steps", "render_mode"):
        if key in env_kwargs:
            raise ValueError(
                f"{where}.env_kwargs: {key} is not a setting of the task (its episodes end with the schedule)"
            )
    if "policy_kwargs" in algo_kwargs:
        policy_kwargs = algo_kwargs["policy_kwargs"] = _policy_kwargs(algo_kwargs["policy_kwargs"], where)
        counts = dict.fromkeys(POLICY_COUNT_KEYS, 1)
        _check_numbers(policy_kwargs, f"{where}.policy_kwargs", counts, POLICY_UNIT_KEYS, POLICY_POSITIVE_KEYS)
    quantiles = (algo_kwargs.get("policy_kwargs") or {}).get("n_quantiles", TQC_QUANTILES)
    if "top_quantiles_to_drop_per_net" in algo_kwargs:  # TQC's: the critic must keep a quantile
        name = f"{where}.top_quantiles_to_drop_per_net"
        dropped = algo_kwargs["top_quantiles_to_drop_per_net"]
        algo_kwargs["top_quantiles_to_drop_per_net"] = validate.integer(name, dropped, 0, int(quantiles) - 1)
    elif algo == "tqc" and quantiles <= TQC_DROPPED:
        raise ValueError(
            f"{where}.policy_kwargs.n_quantiles must be more than the {TQC_DROPPED} TQC drops "
            f"(top_quantiles_to_drop_per_net's default), got {quantiles}"
        )
    if "train_freq" in algo_kwargs:
        algo_kwargs["train_freq"] = _train_freq(algo_kwargs["train_freq"], f"{where}.train_freq")
    for key in SCHEDULE_KEYS:
        if isinstance(algo_kwargs.get(key), str):
            schedule(algo_kwargs[key], f"{where}.{key}")  # check it now
    normalize = _normalize(entry.get("normalize", False), algo_kwargs.get("gamma"), where)
    seen: set[int] = set()
    for name, value in (("env_kwargs", env_kwargs), ("normalize", normalize), *algo_kwargs.items()):
        _check_finite(value, f"{where}.{name}", seen)
    return Hyperparams(
        algo=algo,
        env_id=env_id,
        n_envs=_bounded_int(entry.get("n_envs", 1), f"{where}.n_envs", MAX_ENVS),
        n_timesteps=_integer(entry.get("n_timesteps", 0), f"{where}.n_timesteps"),
        policy=policy,
        normalize=normalize,
        env_kwargs=dict(registry[env_id].kwargs) | env_kwargs if env_id in registry else dict(env_kwargs),
        algo_kwargs=algo_kwargs,
        source=str(path),
    )


def schedule(text: str, where: str):
    """``lin_<value>``: the zoo's linear schedule from ``value`` at the start to 0 at the end."""
    kind, _, value = text.partition("_")
    try:
        initial = float(value)
    except ValueError:
        initial = None
    if kind != "lin" or initial is None or not 0.0 < initial < math.inf:
        raise ValueError(f"{where}: schedule must be written lin_<value> with a positive value, got {shown(text)}")
    return lambda progress_remaining: progress_remaining * initial


def _learned_coefficient(text: str, where: str) -> None:
    """An off-policy ``ent_coef`` learned from 1 (``auto``) or from a positive value (``auto_<value>``)."""
    kind, _, value = text.partition("_")
    try:
        initial = 1.0 if text == "auto" else float(value)
    except ValueError:
        initial = math.nan
    if kind != "auto" or not 0.0 < initial < math.inf:
        raise ValueError(f"{where} must be a number, auto or auto_<positive value>, got {shown(text)}")


def _train_freq(value: Any, where: str) -> int | tuple[int, str]:
    """An off-policy rollout: n steps, or [n, step] or [n, episode]."""
    if not isinstance(value, list | tuple):
        return _integer(value, where)
    if len(value) != 2 or value[1] not in ("step", "episode"):
        raise ValueError(f"{where} must be n, [n, step] or [n, episode], got {shown(value)}")
    return _integer(value[0], f"{where}[0]"), value[1]


def _check_numbers(
    values: dict[str, Any],
    where: str,
    integers: dict[str, int],
    units: tuple[str, ...],
    positives: tuple[str, ...],
    non_negatives: tuple[str, ...] = (),
    texts: tuple[str, ...] = (),
) -> None:
    """The numbers of ``values`` in their ranges by key: integers (made ints) from their least value,
    in [0, 1], positive, at least 0. Null where OFF_KEYS are off, and text where ``texts`` may be
    written as text, are left to their own checks."""
    for key, value in values.items():
        name = f"{where}.{key}"
        if (value is None and key in OFF_KEYS) or (isinstance(value, str) and key in texts):
            continue
        if key in integers:
            values[key] = _integer(value, name, integers[key])
        elif key in units:
            validate.between(name, value, 0.0, 1.0)
        elif key in positives:
            validate.positive(name, value)
        elif key in non_negatives:
            validate.at_least(name, value, 0.0)


def _check_finite(value: Any, where: str, seen: set[int]) -> None:
    """Every number in ``value``, through its mappings and lists, finite; else a ValueError naming
    its key. A shared part (a YAML alias) is walked once."""
    if isinstance(value, float):
        validate.finite(where, value)
    elif isinstance(value, dict | list | tuple) and id(value) not in seen:
        seen.add(id(value))
        items = value.items() if isinstance(value, dict) else enumerate(value)
        for key, item in items:
            _check_finite(item, f"{where}.{key}" if isinstance(value, dict) else f"{where}[{key}]", seen)


def algo_arguments(params: Hyperparams) -> dict[str, Any]:
    """The algorithm's keyword arguments, schedules and activations made objects."""
    import torch.nn as nn

    kwargs = dict(params.algo_kwargs)
    for key in SCHEDULE_KEYS:
        if isinstance(kwargs.get(key), str):
            kwargs[key] = schedule(kwargs[key], key)
    policy_kwargs = dict(kwargs.get("policy_kwargs") or {})
    if isinstance(policy_kwargs.get("activation_fn"), str):
        policy_kwargs["activation_fn"] = getattr(nn, policy_kwargs["activation_fn"].removeprefix("nn."))
    if policy_kwargs:
        kwargs["policy_kwargs"] = policy_kwargs
    return kwargs


def _bounded_int(value: Any, where: str, high: int) -> int:
    value = _integer(value, where)
    if value > high:
        raise ValueError(f"{where} must be at most {high}, got {value}")
    return value


def _integer(value: Any, where: str, low: int = 1) -> int:
    """An integer (also written 1e4) of at least ``low``."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        kind = "a positive integer" if low == 1 else f"an integer of at least {low}"
        raise ValueError(f"{where} must be {kind}, got {shown(value)}")
    return value


def _normalize(value: Any, gamma: Any, where: str) -> dict[str, Any] | None:
    """VecNormalize's keyword arguments (the zoo passes the algorithm's gamma on), or None."""
    if value is False or value is None:
        return None
    if value is True:
        kwargs: dict[str, Any] = {}
    elif isinstance(value, str):
        kwargs = _literal_call(value, f"{where}.normalize")
    elif isinstance(value, dict):
        kwargs = dict(value)
    else:
        raise ValueError(f"{where}.normalize must be true, false or VecNormalize's arguments, got {shown(value)}")
    if gamma is not None:
        kwargs["gamma"] = gamma
    _check_numbers(kwargs, f"{where}.normalize", {}, ("gamma",), NORMALIZE_POSITIVE_KEYS)
    if "clip_obs" in kwargs:  # as the exported policy must have it
        why = "a clip inside one standard deviation blinds the policy"
        validate.at_least(f"{where}.normalize.clip_obs", kwargs["clip_obs"], MIN_CLIP_OBS, why=why)
    return kwargs


def _policy_kwargs(value: Any, where: str) -> dict[str, Any]:
    if isinstance(value, dict):
        return dict(value)
    if isinstance(value, str):
        return _literal_call(value, f"{where}.policy_kwargs")
    raise ValueError(f"{where}.policy_kwargs must be a mapping or a dict(...) string, got {shown(value)}")


def _literal_call(text: str, where: str) -> dict[str, Any]:
    """``dict(a=1, ...)`` or ``{'a': 1, ...}`` with literal values and ``nn.<Activation>`` names,
    parsed without evaluating anything; activations come back as the string ``nn.<name>``."""
    try:
        tree = ast.parse(text.strip(), mode="eval").body
    except SyntaxError:
        raise ValueError(f"{where}: cannot parse {shown(text)}") from None

    def value(node: ast.AST) -> Any:
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "nn":
            if node.attr not in ACTIVATION_NAMES:
                raise ValueError(f"{where}: unknown activation nn.{node.attr} (known: {', '.join(ACTIVATION_NAMES)})")
            return f"nn.{node.attr}"
        if isinstance(node, ast.Call):
            return call(node)
        if isinstance(node, ast.List):
            return [value(item) for item in node.elts]
        if isinstance(node, ast.Dict):
            if None in node.keys:  # a ``**mapping``
                raise ValueError(f"{where}: only literal values may appear in {shown(text)}")
            keys = [ast.literal_eval(k) for k in node.keys]
            repeated = next((key for i, key in enumerate(keys) if key in keys[:i]), None)
            if repeated is not None:  # the last would win, silently
                raise ValueError(f"{where}: key {shown(repeated)} is given twice in {shown(text)}")
            return {key: value(v) for key, v in zip(keys, node.values, strict=True)}
        try:
            return ast.literal_eval(node)
        except ValueError:
            raise ValueError(f"{where}: only literal values may appear in {shown(text)}") from None

    def call(node: ast.Call) -> dict[str, Any]:
        if not (isinstance(node.func, ast.Name) and node.func.id == "dict") or node.args:
            raise ValueError(f"{where}: only dict(key=value, ...) may appear in {shown(text)}")
        return {keyword.arg: value(keyword.value) for keyword in node.keywords}

    result = value(tree)
    if not isinstance(result, dict):
        raise ValueError(f"{where}: expected a dict, got {shown(text)}")
    return result
