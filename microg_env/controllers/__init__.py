"""Controllers behind one interface (:class:`Controller`): the baselines and learned policies."""

from microg_env.controllers.base import Controller
from microg_env.controllers.pid import CONTROLLER_NAMES, PID, PIDGains, load_gains, make_controller
from microg_env.controllers.policy import PolicyController

__all__ = ["CONTROLLER_NAMES", "PID", "Controller", "PIDGains", "PolicyController", "load_gains", "make_controller"]
