"""Controllers by name: the ones the CLI, the comparison and the evaluation harness select.

A name is a classical baseline, a policy shipped with the package (``microg_env/policies/``), or
the path of an exported policy folder (a run's ``policy/``, written by ``microg train``). A folder
is checked before it runs (its card's settings, the base controller a classical one, the network's
sizes) and deployed as it was trained (:func:`deployed_controller`).
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Mapping
from dataclasses import replace
from importlib import resources
from pathlib import Path
from typing import Any

from microg_env import validate
from microg_env.controllers.base import Controller
from microg_env.controllers.feedforward import AdaptiveFeedforward, DitheredAdaptiveFeedforward, Feedforward, Oracle
from microg_env.controllers.pid import PID, load_gains
from microg_env.controllers.policy import CARD_FILE, NETWORK_FILE, MLPPolicy, PolicyController
from microg_env.interface import (
    ACTION_MODES,
    RESIDUAL_HIGHPASS_RANGE_HZ,
    RESIDUAL_LIMIT_M,
    hidden_entries,
    highpass_order,
    residual_gate,
    residual_gate_point,
)
from microg_env.params import CONTROL_PERIOD_RANGE_S, CONTROL_PERIOD_S, RigParams
from microg_env.validate import FieldError

#: The classical baselines: the paper's PID, its derivative-on-measurement variant, the PID with
#: the nominal model's feed-forward, that feed-forward learning the motor's cogging as it runs
#: (``adaptive``), that with a dither on its setpoint against the friction (``adaptive-dither``),
#: and the bound: the feed-forward told the episode's true plant (``oracle``, not deployable).
BASELINES = ("pid", "pid-dom", "feedforward", "adaptive", "adaptive-dither", "oracle")
#: The baselines built on the feed-forward (their feedback loop is ``pid``'s).
FEEDFORWARDS = {
    "feedforward": Feedforward,
    "adaptive": AdaptiveFeedforward,
    "adaptive-dither": DitheredAdaptiveFeedforward,
    "oracle": Oracle,
}
#: Most bytes a policy card may hold.
MAX_CARD_BYTES = 2**20


def is_policy_folder(name: str) -> bool:
    """Whether ``name`` is the path of an exported policy folder (rather than a controller's name)."""
    return name not in CONTROLLER_NAMES and (Path(name) / CARD_FILE).is_file()


def check_controller_name(name: str) -> str:
    """``name`` if it selects a controller, else a ValueError listing what does."""
    if name in CONTROLLER_NAMES:
        return name
    if is_policy_folder(name):
        check_policy_folder(name)  # a broken folder is named now, not after the work has started
        return name
    raise ValueError(
        f"controller must be one of {', '.join(CONTROLLER_NAMES)} or a policy folder (holding {CARD_FILE}), "
        f"got {name!r}"
    )


def make_controller(
    name: str, control_period_s: float, params: RigParams | None = None, gains: Mapping[str, float] | None = None
) -> Controller:
    """The named controller with its tuned settings; ``params`` is the nominal rig a model-based
    controller assumes (default: the paper's rig, whatever the plant it drives); ``gains`` replace
    fields of a baseline's tuned PID gains (``{"ki_per_s2": 5000.0}``; the feed-forward's feedback loop
    is ``pid``'s)."""
    check_controller_name(name)
    validate.between("control_period_s", control_period_s, *CONTROL_PERIOD_RANGE_S, "s")
    if gains and name not in BASELINES:
        raise ValueError(f"gains {dict(gains)!r}: controller {name!r} has no PID gains to replace")
    if name in BASELINES:
        tuned = replace(load_gains("pid" if name in FEEDFORWARDS else name), **(gains or {}))
        if name in FEEDFORWARDS:
            return FEEDFORWARDS[name](control_period_s, params, gains=tuned)
        return PID(tuned, control_period_s, derivative_on_measurement=name == "pid-dom")
    folder = Path(name) if is_policy_folder(name) else shipped_policy_folder(name)
    return load_policy(folder, control_period_s)


def shipped_policies() -> tuple[str, ...]:
    """Names of the policies shipped in the package (``microg_env/policies/<name>/``)."""
    root = resources.files("microg_env").joinpath("policies")
    if not root.is_dir():
        return ()
    return tuple(sorted(p.name for p in root.iterdir() if p.is_dir() and p.joinpath(CARD_FILE).is_file()))


#: Every controller selectable by name: the baselines and the shipped policies.
CONTROLLER_NAMES = BASELINES + shipped_policies()


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


#: The env_kwargs of a policy card that say how the deployed policy acts (:func:`_check_deployment`
#: reads each, and the control period), so a policy is run only on the task it was trained on.
ACTING_KEYS = (
    "action_mode",
    "base_controller",
    "decision_period",
    "residual_limit_m",
    "residual_highpass_hz",
    "residual_highpass_order",
    "residual_gate_m",
    "residual_gate_on",
    "hidden_observations",
)


def _check_deployment(env: dict[str, Any]) -> None:
    """The env_kwargs a deployed policy reads: of the right kinds and ranges, the base controller a
    classical one (a policy on a policy, or on itself, is refused)."""
    validate.choice("action_mode", env.get("action_mode", "speed"), ACTION_MODES)
    validate.choice("base_controller", env.get("base_controller", "pid"), BASELINES)
    if type(env.get("decision_period", 1)) is not int:
        raise ValueError(f"decision_period must be an integer, got {env['decision_period']!r}")
    validate.integer("decision_period", env.get("decision_period", 1), 1, 1000)
    validate.between("control_period_s", env.get("control_period_s", CONTROL_PERIOD_S), *CONTROL_PERIOD_RANGE_S, "s")
    validate.positive("residual_limit_m", env.get("residual_limit_m", RESIDUAL_LIMIT_M), "m", 1e-3)
    validate.between("residual_highpass_hz", env.get("residual_highpass_hz", 0.0), *RESIDUAL_HIGHPASS_RANGE_HZ, "Hz")
    highpass_order(env.get("residual_highpass_order", 1))
    residual_gate(env.get("residual_gate_m"))
    residual_gate_point(env.get("residual_gate_on", "action"))
    hidden_entries(env.get("hidden_observations", ()))


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
        raise FieldError(
            f"control_period_s {control_period_s!r}: policy {Path(folder).name!r} was trained at "
            f"{trained_period * 1e6:g} us and runs only at that period",
            "control_period_s",
        )
    return deployed_controller(policy, env)


def deployed_controller(
    policy: Any, env_kwargs: dict[str, Any], controller: type[PolicyController] = PolicyController
) -> PolicyController:
    """``policy``, trained in ``MicroGravityLanding-v1`` with ``env_kwargs``, as the controller it
    is deployed as: a residual on its base controller, acting every decision period (a
    ``controller``, :class:`PolicyController` or a subclass of it)."""
    residual = env_kwargs.get("action_mode", "speed") == "residual"
    period = float(env_kwargs.get("control_period_s", CONTROL_PERIOD_S))
    return controller(
        policy,
        decision_period=int(env_kwargs.get("decision_period", 1)),
        base=make_controller(env_kwargs.get("base_controller", "pid"), period) if residual else None,
        residual_limit_m=float(env_kwargs.get("residual_limit_m", RESIDUAL_LIMIT_M)),
        residual_highpass_hz=float(env_kwargs.get("residual_highpass_hz", 0.0)),
        control_period_s=period,
        residual_highpass_order=env_kwargs.get("residual_highpass_order", 1),
        hidden_observations=env_kwargs.get("hidden_observations", ()),
        residual_gate_m=env_kwargs.get("residual_gate_m"),
        residual_gate_on=env_kwargs.get("residual_gate_on", "action"),
    )
