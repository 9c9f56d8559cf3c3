"""The PID baseline of Section 3.1.

It closes a position loop on the grating ruler's x and commands the
stroke amplifier's speed: v = Kp x + Ki integral(x) + D, clipped to the drive's +-1250 mm/s with
conditional-integration anti-windup. Two derivative terms are offered:

* ``pid``: derivative of the error, D = Kd dx/dt. With x = z_lander - z_support this feeds the
  lander's velocity change forward to the support, including its jump at impact.
* ``pid-dom``: the paper's suggested improvement (Conclusions), derivative on the measurement.
  The setpoint of the support position is the lander's position (the "given value") and the
  controlled variable is the support's own position, so D = -Kd dz_support/dt (servo encoder):
  the jump of the lander's velocity at impact no longer kicks the command.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, fields
from importlib import resources
from typing import Any

import numpy as np

from microg_env.envs.landing import OBSERVATION_INDEX, OBSERVATION_SCALES

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

#: Drive speed that the action +-1 stands for, m/s (Section 4.1).
MAX_SPEED_M_S = 1.25


@dataclass(frozen=True)
class PIDGains:
    """Gains of the velocity-command PID on x (units make v in m/s from x in m)."""

    kp_per_s: float
    ki_per_s2: float
    kd: float
    derivative_filter_s: float
    integral_limit_m_s: float

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"PIDGains.{f.name} must be a finite number >= 0, got {value!r}")


def load_gains(name: str) -> PIDGains:
    """The tuned gains of controller ``name`` ("pid" or "pid-dom") from config/controllers.toml."""
    text = resources.files("microg_env").joinpath("config", "controllers.toml").read_text(encoding="utf-8")
    table = tomllib.loads(text)
    if name not in table:
        raise ValueError(f"no gains for controller {name!r}; known: {', '.join(sorted(table))}")
    entry = table[name]
    return PIDGains(**{f.name: float(entry[f.name]) for f in fields(PIDGains)})


class PID:
    """PID on x commanding the support speed; see the module docstring for the two D terms."""

    def __init__(self, gains: PIDGains, control_period_s: float, derivative_on_measurement: bool = False) -> None:
        self.gains = gains
        self.control_period_s = control_period_s
        self.derivative_on_measurement = derivative_on_measurement
        self._alpha = control_period_s / (gains.derivative_filter_s + control_period_s)
        self.reset()

    def reset(self) -> None:
        self._integral = 0.0
        self._derivative = 0.0

    def __call__(self, observation: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        g = self.gains
        x = float(observation[_X]) * _X_SCALE
        if self.derivative_on_measurement:
            rate = -float(observation[_SUPPORT_VELOCITY]) * _SUPPORT_VELOCITY_SCALE
        else:
            rate = float(observation[_X_RATE]) * _X_RATE_SCALE
        self._derivative += self._alpha * (rate - self._derivative)
        integral = self._integral + g.ki_per_s2 * x * self.control_period_s
        integral = min(max(integral, -g.integral_limit_m_s), g.integral_limit_m_s)
        command = g.kp_per_s * x + integral + g.kd * self._derivative
        # Conditional integration: do not wind the integral further into a saturated command.
        if abs(command) <= MAX_SPEED_M_S or (command > 0) != (x > 0):
            self._integral = integral
        command = min(max(command, -MAX_SPEED_M_S), MAX_SPEED_M_S)
        return np.array([command / MAX_SPEED_M_S], dtype=np.float32)


#: Controllers selectable by name in the CLI and the evaluation harness.
CONTROLLER_NAMES = ("pid", "pid-dom")


def make_controller(name: str, control_period_s: float) -> PID:
    """The named baseline with its tuned gains."""
    if name not in CONTROLLER_NAMES:
        raise ValueError(f"controller must be one of {', '.join(CONTROLLER_NAMES)}, got {name!r}")
    return PID(load_gains(name), control_period_s, derivative_on_measurement=name == "pid-dom")


_X, _X_RATE = OBSERVATION_INDEX["x"], OBSERVATION_INDEX["x_rate"]
_SUPPORT_VELOCITY = OBSERVATION_INDEX["support_velocity"]
_X_SCALE, _X_RATE_SCALE = OBSERVATION_SCALES["x"], OBSERVATION_SCALES["x_rate"]
_SUPPORT_VELOCITY_SCALE = OBSERVATION_SCALES["support_velocity"]
