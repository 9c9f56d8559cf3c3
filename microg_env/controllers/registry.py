"""Controllers by name: the ones the CLI, the comparison and the evaluation harness select.

A name is a classical baseline, a policy shipped with the package (``microg_env/policies/``), or
the path of an exported policy folder (a run's ``policy/``, written by ``microg train``). A folder
is checked before it runs (its card's settings, the base controller a classical one, the network's
sizes) and deployed as it was trained (:func:`deployed_controller`).
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
import zipfile
from collections.abc import Mapping
from dataclasses import fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

import gymnasium as gym

from microg_env import validate
from microg_env.controllers.base import Controller
from microg_env.controllers.feedforward import (
    AdaptiveFeedforward,
    DitheredAdaptiveFeedforward,
    Feedforward,
    FrictionAdaptiveFeedforward,
    Oracle,
)
from microg_env.controllers.pid import PID, load_gains
from microg_env.controllers.policy import MAX_NETWORK_BYTES, MLPPolicy, PolicyController
from microg_env.interface import (
    BASELINES,
    CARD_FILE,
    MIXED_SENSORS,
    NETWORK_FILE,
    SENSOR_SETS,
    action_size,
    hidden_entries,
    is_policy_folder,
    selects_policy,
    shipped_policies,
)
from microg_env.params import CONTROL_PERIOD_RANGE_S, RigParams
from microg_env.retired import RETIRED, retirement
from microg_env.task import ACTING_KEYS, ActingSettings, TaskSettings
from microg_env.validate import FieldError, fault

#: The baselines built on the feed-forward (their feedback loop is ``pid``'s).
FEEDFORWARDS = {
    "feedforward": Feedforward,
    "adaptive": AdaptiveFeedforward,
    "adaptive-dither": DitheredAdaptiveFeedforward,
    "adaptive-friction": FrictionAdaptiveFeedforward,
    "oracle": Oracle,
}
#: Most bytes a policy card may hold.
MAX_CARD_BYTES = 2**20
#: The keys of a policy card: those ``microg train`` writes (:mod:`microg_env.learning.train`, its
#: run's ``card``); env_kwargs, the task, is the one a card must hold (a probe's card holds it alone).
CARD_KEYS = (
    "env_id",
    "env_kwargs",
    "algo",
    "command",
    "resume_commands",
    "seed",
    "timesteps",
    "target_timesteps",
    "wall_s",
    "machine",
    "hyperparams",
    "validation",
    "versions",
)
#: The entry point of the environment ids this package registers (``MicroGravityLanding-*``).
ENTRY_POINT = "microg_env.envs.landing:MicroGravityLandingEnv"


def check_controller_name(name: str, sensor_set: str = "extended") -> str:
    """``name`` if it selects a controller that runs on a rig of ``sensor_set`` (a policy: one
    trained on what that rig reads, :func:`check_sensor_set`), else a ValueError listing what does
    (:func:`~microg_env.interface.selects_policy`)."""
    if selects_policy(name):
        card = _checked_card(policy_folder(name))  # a broken folder named now, not once the work started
        check_sensor_set(name, card["env_kwargs"], sensor_set)
    return name


def _checked_card(folder: Path) -> dict[str, Any]:
    """The card :func:`check_policy_folder` reads (a copy), read and checked once per contents of
    the folder (:func:`folder_digest`, which a spec computes anyway): a campaign names one policy
    in thousands of specs. :func:`load_policy` checks afresh."""
    files = [folder / name for name in BEHAVIOUR_FILES]
    try:  # only regular files of a policy's size are read whole: not a pipe, a device, a huge file
        readable = all(f.is_file() and f.stat().st_size <= MAX_NETWORK_BYTES for f in files)
        digest = folder_digest(folder) if readable else None
    except OSError:
        digest = None
    if digest is None:  # check_policy_folder names what is wrong, or passes what is right
        return check_policy_folder(folder)[0]
    return copy.deepcopy(_checked_contents(str(folder), digest))


@functools.lru_cache(maxsize=256)
def _checked_contents(folder: str, digest: str) -> dict[str, Any]:
    """The card of ``folder`` whose files hash to ``digest``, checked (the key: ``digest``)."""
    return check_policy_folder(folder)[0]


def policy_folder(name: str) -> Path:
    """The folder of policy ``name``: a shipped policy's, or the folder ``name`` is the path of."""
    return Path(name) if is_policy_folder(name) else shipped_policy_folder(name)


def make_controller(
    name: str,
    control_period_s: float,
    params: RigParams | None = None,
    gains: Mapping[str, float] | None = None,
    sensor_set: str = "extended",
    digest: str | None = None,
) -> Controller:
    """The named controller with its tuned settings; ``params`` is the nominal rig a model-based
    controller assumes (default: the paper's rig, whatever the plant it drives); ``gains`` replace
    fields of a baseline's tuned PID gains (``{"ki_per_s2": 5000.0}``; the feed-forward's feedback loop
    is ``pid``'s); ``sensor_set``: the rig's (a policy is refused on one that lacks what it read in
    training); ``digest``: a policy's contents as a run was specified (:func:`load_policy`)."""
    check_controller_name(name, sensor_set)
    validate.between("control_period_s", control_period_s, *CONTROL_PERIOD_RANGE_S, "s")
    if gains and name not in BASELINES:
        raise ValueError(f"gains {dict(gains)!r}: controller {name!r} has no PID gains to replace")
    if name in BASELINES:
        tuned = replace(load_gains("pid" if name in FEEDFORWARDS else name), **(gains or {}))
        if name in FEEDFORWARDS:
            return FEEDFORWARDS[name](control_period_s, params, gains=tuned)
        return PID(tuned, control_period_s, derivative_on_measurement=name == "pid-dom")
    return load_policy(policy_folder(name), control_period_s, sensor_set, digest, params)


def policy_card(folder: str | Path) -> dict[str, Any]:
    """The ``policy.json`` of an exported policy folder: how it acts, how it was trained; a
    ValueError naming the file if it is not a card :data:`CARD_KEYS` (each once) whose env_kwargs
    are settings of the task that a policy may be deployed with and whose env_id they agree with."""
    path = Path(folder) / CARD_FILE
    if not path.exists():
        raise ValueError(f"policy folder {str(folder)!r} has no {CARD_FILE}")
    if not path.is_file() or path.stat().st_size > MAX_CARD_BYTES:
        raise ValueError(f"{str(path)!r} is not a policy card (a regular file of at most {MAX_CARD_BYTES} bytes)")
    try:
        card = json.loads(path.read_text(encoding="utf-8"), object_pairs_hook=_once_each)
    except (OSError, UnicodeDecodeError, ValueError) as error:  # ValueError: JSONDecodeError, a repeated key
        raise ValueError(f"cannot read {str(path)!r}: {error}") from None
    if not (isinstance(card, dict) and isinstance(card.get("env_kwargs"), dict)):
        raise ValueError(f"{str(path)!r} is not a policy card (a JSON object with an env_kwargs object)")
    unknown = sorted(set(card) - set(CARD_KEYS))
    if unknown:
        raise ValueError(f"{str(path)!r}: unknown key {unknown[0]!r}; a policy card holds {', '.join(CARD_KEYS)}")
    try:
        _check_deployment(card["env_kwargs"])
    except ValueError as error:
        raise ValueError(f"{str(path)!r}: env_kwargs.{error}") from None
    try:
        _check_env_id(card)
    except ValueError as error:
        raise ValueError(f"{str(path)!r}: {error}") from None
    return card


def _once_each(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object's pairs as a dict, or a ValueError naming a key given twice (the last would win)."""
    seen = set()
    for key, _ in pairs:
        if key in seen:
            raise ValueError(f"key {key!r} is given twice")
        seen.add(key)
    return dict(pairs)


def _check_deployment(env: dict[str, Any]) -> None:
    """The env_kwargs of a card are the task's settings, read through the task's own check
    (:class:`~microg_env.task.TaskSettings`: each of its kind and range, and the combinations the
    environment refuses refused here too), so a policy is deployed only with settings it could have
    been trained with; the base controller a classical one (a policy on a policy is refused)."""
    unknown = sorted(set(env) - set(TASK_DEFAULTS))
    if unknown:
        raise ValueError(f"{unknown[0]} is not a setting of the task (a keyword argument of MicroGravityLanding-v1)")
    try:
        TaskSettings(**env)
    except FieldError as error:
        raise ValueError(str(error)) from None
    except (TypeError, ValueError) as error:  # a value of the wrong kind for a record the task builds
        raise ValueError(f"{fault(error)} (not a setting the task takes)") from None


#: The task's settings (the environment's keyword arguments) with their defaults.
TASK_DEFAULTS = {option.name: option.default for option in fields(TaskSettings)}


def _check_env_id(card: dict[str, Any]) -> None:
    """A card's env_id, if it has one: an id this package registers whose acting settings
    (:data:`ACTING_KEYS`) the card's env_kwargs do not contradict. A run's env_kwargs are its id's
    registered ones updated by its hyperparameter entry's (:mod:`microg_env.learning.hyperparams`),
    so an entry may change one (give v7 another base controller, say),
    but one left out is deployed at its default: where the id registers another value, the policy
    was trained with that one."""
    if "env_id" not in card:
        return
    env_id, env = card["env_id"], card["env_kwargs"]
    if isinstance(env_id, str) and env_id in RETIRED:
        raise ValueError(f"env_id {retirement(env_id)}")
    ours = sorted(name for name, spec in gym.registry.items() if spec.entry_point == ENTRY_POINT)
    if not isinstance(env_id, str) or env_id not in ours:
        raise ValueError(f"env_id must be one of {', '.join(ours)}, got {validate.shown(env_id)}")
    defaults, registered = TASK_DEFAULTS, gym.registry[env_id].kwargs
    for key in ACTING_KEYS:
        if key in registered and key not in env and registered[key] != defaults[key]:
            raise ValueError(
                f"env_kwargs leaves out {key}: deployed at its default {defaults[key]!r}, while env_id {env_id!r} "
                f"trained at its registered {registered[key]!r}"
            )


def deployed_hidden(env_kwargs: Mapping[str, Any]) -> tuple[str, ...]:
    """The observation entries a policy trained with ``env_kwargs`` reads as 0 when deployed: its
    ``hidden_observations`` and the sensors its training rig lacked (:data:`SENSOR_SETS`; none when
    trained on both, ``sensor_set="mixed"``), so that on any rig it sees what training showed it."""
    trained = env_kwargs.get("sensor_set", TASK_DEFAULTS["sensor_set"])
    lacked = () if trained == MIXED_SENSORS else SENSOR_SETS[trained]
    return tuple(dict.fromkeys((*hidden_entries(env_kwargs.get("hidden_observations", ())), *lacked)))


def check_sensor_set(name: str, env_kwargs: Mapping[str, Any], sensor_set: str) -> None:
    """A ValueError naming policy ``name``, the sensor set it was trained on and ``sensor_set`` (a
    rig's; "mixed": either) if that rig lacks a sensor the policy read in training: it would read 0
    there, as it never did. (A policy trained on both rigs met both; one that hides an entry reads
    0 there on every rig, :func:`deployed_hidden`.)"""
    validate.choice("sensor_set", sensor_set, (*SENSOR_SETS, MIXED_SENSORS))
    trained = env_kwargs.get("sensor_set", TASK_DEFAULTS["sensor_set"])
    if trained == MIXED_SENSORS:
        return
    shown_zero = set(deployed_hidden(env_kwargs))
    runs_on = [rig for rig, lacks in SENSOR_SETS.items() if set(lacks) <= shown_zero]
    for rig in tuple(SENSOR_SETS) if sensor_set == MIXED_SENSORS else (sensor_set,):
        unread = [entry for entry in SENSOR_SETS[rig] if entry not in shown_zero]
        if unread:
            drawn = f" (drawn by {sensor_set!r})" if rig != sensor_set else ""
            raise ValueError(
                f"policy {name!r} was trained on the {trained!r} sensor set and reads {', '.join(unread)}, which "
                f"the {rig!r} sensor set{drawn} lacks; it runs on sensor set {' or '.join(map(repr, runs_on))} only"
            )


def shipped_policy_folder(name: str) -> Path:
    if name not in shipped_policies():
        raise ValueError(f"no shipped policy {name!r}; shipped: {', '.join(shipped_policies()) or 'none'}")
    return Path(str(resources.files("microg_env").joinpath("policies", name)))


def check_policy_folder(folder: str | Path) -> tuple[dict[str, Any], MLPPolicy]:
    """The card and network of an exported policy folder, or a ValueError naming what is wrong."""
    card = policy_card(folder)
    try:
        policy = MLPPolicy.load(Path(folder) / NETWORK_FILE)
    except (OSError, KeyError, ValueError, TypeError, zipfile.BadZipFile) as error:
        raise ValueError(f"policy folder {str(folder)!r}: cannot read {NETWORK_FILE} ({error})") from None
    mode = ActingSettings.of(card["env_kwargs"]).action_mode
    if policy.action_size != action_size(mode):
        raise ValueError(
            f"policy folder {str(folder)!r}: its network gives {policy.action_size} numbers an action, and "
            f"action_mode {mode!r} takes {action_size(mode)}"
        )
    return card, policy


def load_policy(
    folder: str | Path,
    control_period_s: float,
    sensor_set: str = "extended",
    digest: str | None = None,
    params: RigParams | None = None,
) -> PolicyController:
    """The exported policy in ``folder`` as a controller; it must run at the control period it
    was trained at (its decision period and base controller's tuning are tied to it), on a rig of
    a ``sensor_set`` that reads what it read in training (:func:`check_sensor_set`). With ``digest``
    (the contents a run was specified with, :func:`controller_digest`) its files must still read so
    once loaded: a run is never of a policy other than the one its identity names. ``params``: the
    nominal rig its base controller assumes, as :func:`make_controller`'s."""
    card, policy = check_policy_folder(folder)
    if digest is not None and folder_digest(folder) != digest:
        raise ValueError(
            f"policy folder {str(folder)!r} changed since the run was specified (its files no longer read "
            f"{digest}): run it again"
        )
    env = card["env_kwargs"]
    check_sensor_set(Path(folder).name, env, sensor_set)
    trained_period = float(env.get("control_period_s", TASK_DEFAULTS["control_period_s"]))
    if abs(control_period_s - trained_period) > 1e-9:
        raise FieldError(
            f"control_period_s {control_period_s!r}: policy {Path(folder).name!r} was trained at "
            f"{trained_period * 1e6:g} us and runs only at that period",
            "control_period_s",
        )
    return deployed_controller(policy, env, params=params)


def deployed_controller(
    policy: Any,
    env_kwargs: Mapping[str, Any],
    controller: type[PolicyController] = PolicyController,
    params: RigParams | None = None,
) -> PolicyController:
    """``policy``, trained in ``MicroGravityLanding-v1`` with ``env_kwargs``, as the controller it
    is deployed as (a ``controller``, :class:`PolicyController` or a subclass of it): acting as its
    :class:`~microg_env.task.ActingSettings` say, on its base controller in residual and gains mode (assuming
    the nominal rig ``params``, default the paper's), shown what it was shown in training
    (:func:`deployed_hidden`)."""
    acting = ActingSettings.of(env_kwargs)
    period = float(env_kwargs.get("control_period_s", TASK_DEFAULTS["control_period_s"]))
    base = make_controller(acting.base_controller, period, params) if acting.action_mode != "speed" else None
    return controller(policy, replace(acting, hidden_observations=deployed_hidden(env_kwargs)), base, period)


#: The files of a policy folder that define how it acts: what :func:`controller_digest` reads.
BEHAVIOUR_FILES = (CARD_FILE, NETWORK_FILE)


def controller_digest(name: str) -> str | None:
    """What a policy is, for a run's identity: the SHA-256 of its folder's :data:`BEHAVIOUR_FILES`
    (a shipped policy by name, or a folder by any spelling of its path: the same contents, the same
    digest; new contents in the same folder, a new one). None for a classical baseline."""
    return None if name in BASELINES else folder_digest(policy_folder(name))


def folder_digest(folder: str | Path) -> str:
    """The SHA-256 of a policy folder's :data:`BEHAVIOUR_FILES`, as :func:`controller_digest` gives it."""
    digest = hashlib.sha256()
    for file in BEHAVIOUR_FILES:
        data = (Path(folder) / file).read_bytes()
        digest.update(f"{file}:{len(data)}:".encode())
        digest.update(data)
    return f"sha256:{digest.hexdigest()}"
