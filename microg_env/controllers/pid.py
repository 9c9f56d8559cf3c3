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

The loop holds x at ``setpoint_m`` (0: the rig's purpose); the environment's residual mode moves it.
Its gains are each rig's ``kp_scale``, ``ki_scale`` and ``kd_scale`` times the tuned ones (1: as
tuned); the environment's gains mode (the paper's Conclusions: learning that "automatically
adjusts the control parameters during the collision") sets them. A scaled Ki scales the integral's
increments, not the integral held: a change of Ki does not step the command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from importlib import resources
from typing import Any, ClassVar

import numpy as np

from microg_env.compiled import jit
from microg_env.controllers.base import VectorController
from microg_env.files import parse_toml
from microg_env.interface import MAX_SPEED_M_S, OBSERVATION_INDEX, SCALES

#: Observation columns the feedback loops read.
X, X_RATE, SUPPORT_VELOCITY = (OBSERVATION_INDEX[name] for name in ("x", "x_rate", "support_velocity"))


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


def controller_config(name: str) -> dict[str, Any]:
    """The tuned settings of controller ``name`` from config/controllers.toml."""
    text = resources.files("microg_env").joinpath("config", "controllers.toml").read_text(encoding="utf-8")
    table = parse_toml(text)
    if name not in table:
        raise ValueError(f"no settings for controller {name!r}; known: {', '.join(sorted(table))}")
    return table[name]


def load_gains(name: str) -> PIDGains:
    """The tuned PID gains of controller ``name`` ("pid" or "pid-dom")."""
    entry = controller_config(name)
    return PIDGains(**{f.name: float(entry[f.name]) for f in fields(PIDGains)})


class PID(VectorController):
    """PID on x commanding the support speed; see the module docstring for the two D terms."""

    STATE: ClassVar[dict[str, float]] = {
        "_integral": 0.0,
        "_derivative": 0.0,
        "setpoint_m": 0.0,
        "kp_scale": 1.0,
        "ki_scale": 1.0,
        "kd_scale": 1.0,
    }

    def __init__(self, gains: PIDGains, control_period_s: float, derivative_on_measurement: bool = False) -> None:
        super().__init__()
        self.gains = gains
        self.control_period_s = control_period_s
        self.derivative_on_measurement = derivative_on_measurement
        alpha = control_period_s / (gains.derivative_filter_s + control_period_s)  # the derivative's filter
        #: The loop's constants, in the order :meth:`loop` gives them after its state.
        self.constants = tuple(
            float(value)  # floats, whatever numbers the gains were given as: one compiled signature
            for value in (
                gains.kp_per_s, gains.ki_per_s2, gains.kd, alpha, gains.integral_limit_m_s, control_period_s,
                MAX_SPEED_M_S,
            )
        )  # fmt: skip

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        actions = np.empty(ids.size, dtype=np.float32)
        pid_actions(rows, ids, *self.kernel_args(), actions)
        return actions

    def kernel_args(self) -> tuple:
        """:func:`pid_actions`'s arguments after the observations and rigs, but its output."""
        return (SCALES, self.derivative_on_measurement, self.loop())

    def schedule(self, ids: np.ndarray, scales: np.ndarray) -> None:
        """Multiply rigs ``ids``' tuned Kp, Ki and Kd by ``scales`` (n, 3) from their next command on
        (an episode starts at 1, as tuned)."""
        self.kp_scale[ids], self.ki_scale[ids], self.kd_scale[ids] = scales.T

    def loop(self) -> tuple:
        """:func:`pid_command`'s ``loop``: this loop's state (setpoint, integral, filtered
        derivative and the gains' multipliers, one entry per rig) and its constants
        (:attr:`constants`)."""
        return (
            self.setpoint_m, self._integral, self._derivative, self.kp_scale, self.ki_scale, self.kd_scale,
            *self.constants,
        )  # fmt: skip


#: Where :meth:`PID.loop`'s tuple holds the drive's maximum speed, m/s (the action's unit).
LOOP_MAX_SPEED = 12


@jit
def pid_command(i, x, rate, bias, loop):
    """Rig ``i``'s speed command, m/s, for its ruler reading ``x`` and derivative input ``rate``;
    ``bias`` (a feed-forward, m/s) is added inside the saturation, so the anti-windup sees the whole
    command. ``loop`` is :meth:`PID.loop`'s tuple; the rig's integral and filtered derivative are
    updated in it."""
    (
        setpoint,
        integral,
        derivative,
        kp_scale,
        ki_scale,
        kd_scale,
        kp,
        ki,
        kd,
        alpha,
        integral_limit,
        period,
        max_speed,
    ) = loop
    error = x - setpoint[i]
    filtered = derivative[i] + alpha * (rate - derivative[i])
    derivative[i] = filtered
    previous = integral[i]
    integrated = min(max(previous + ki * ki_scale[i] * error * period, -integral_limit), integral_limit)
    command = bias + kp * kp_scale[i] * error + integrated + kd * kd_scale[i] * filtered
    # Conditional integration: do not wind the integral further into a saturated command.
    if abs(command) <= max_speed or (command > 0) != (error > 0):
        integral[i] = integrated
    return min(max(command, -max_speed), max_speed)


@jit
def pid_actions(rows, ids, scales, on_measurement, loop, out):
    """The PID's actions (command / max_speed) for observations ``rows`` of rigs ``ids``, into
    ``out``; ``loop`` is :meth:`PID.loop`'s tuple."""
    max_speed = loop[LOOP_MAX_SPEED]
    for j in range(ids.size):
        x = rows[j, X] * scales[X]
        if on_measurement:
            rate = -(rows[j, SUPPORT_VELOCITY] * scales[SUPPORT_VELOCITY])
        else:
            rate = rows[j, X_RATE] * scales[X_RATE]
        out[j] = pid_command(ids[j], x, rate, 0.0, loop) / max_speed
