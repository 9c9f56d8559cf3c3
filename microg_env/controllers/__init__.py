"""Controllers behind one interface (:class:`Controller`): the baselines and learned policies."""

from microg_env.controllers.base import Controller, SetpointController
from microg_env.controllers.feedforward import Feedforward
from microg_env.controllers.pid import PID, PIDGains, load_gains
from microg_env.controllers.policy import MLPPolicy, PolicyController
from microg_env.controllers.registry import load_policy, make_controller
from microg_env.interface import BASELINES, CONTROLLER_NAMES, Readings

__all__ = [
    "BASELINES",
    "CONTROLLER_NAMES",
    "PID",
    "Controller",
    "Feedforward",
    "MLPPolicy",
    "PIDGains",
    "PolicyController",
    "Readings",
    "SetpointController",
    "load_gains",
    "load_policy",
    "make_controller",
]
