"""Controllers by name: the ones the CLI, the comparison and the evaluation harness select.

A name is a classical baseline, a policy shipped with the package (``microg_env/policies/``), or
the path of an exported policy folder (a run's ``policy/``, written by ``microg train``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

from microg_env import validate
from microg_env.controllers.base import Controller
from microg_env.controllers.feedforward import AdaptiveFeedforward, Feedforward, Oracle
from microg_env.controllers.pid import PID, load_gains
from microg_env.controllers.policy import (
    CARD_FILE,
    check_policy_folder,
    load_policy,
    shipped_policies,
    shipped_policy_folder,
)
from microg_env.params import CONTROL_PERIOD_RANGE_S, RigParams

#: The classical baselines: the paper's PID, its derivative-on-measurement variant, the PID with
#: the nominal model's feed-forward, that feed-forward learning the motor's cogging as it runs
#: (``adaptive``), and the bound: the feed-forward told the episode's true plant (``oracle``, not
#: deployable).
BASELINES = ("pid", "pid-dom", "feedforward", "adaptive", "oracle")
#: The baselines built on the feed-forward (their feedback loop is ``pid``'s).
FEEDFORWARDS = {"feedforward": Feedforward, "adaptive": AdaptiveFeedforward, "oracle": Oracle}
#: Every controller selectable by name: the baselines and the shipped policies.
CONTROLLER_NAMES = BASELINES + shipped_policies()


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
