"""The strong classical baseline: the PID plus model-based feed-forward from the rig's nominal model.

It reads only the observation (the rig's sensors) and the rig's nominal parameters, never the
simulator's state. Two layers, both in the one speed command the drive accepts:

1. **The lander's motion, fed forward.** The lander's acceleration follows from the forces the
   sensors show, a = (F_pad - m g - k x) / (M + m) (Eq. 1 with the pad force measured, the test
   weights m known to the operator, the QZS's residual force -k x of Eq. 17, nominal M and k). Its
   velocity is that acceleration integrated and pulled towards the measured one (encoder speed
   plus ruler rate) with a gain ``velocity_observer_gain`` per control period; the command is that
   velocity one control period ahead (the command's delay) plus the PID on x. The integral no
   longer has to hold x = a/Ki to make the support accelerate, so the compensation error vanishes,
   and the pad force is followed as it rises at the collision.
2. **The drive's disturbances, cancelled.** The torque the support needs beyond the speed loop's
   own: the inertia J a, the balancer's stiffness and the screw's viscous loss, minus the motor's
   cogging torque A sin(72 theta) at the motor angle expected ``prediction_horizon_s`` ahead (the
   command's delay plus the torque filter), plus the motor's LuGre friction from a LuGre observer
   driven by the commanded speed. The drive takes only a speed reference, so the torque enters as a
   speed-reference offset dw chosen so that the drive's PI law adds it: kd dw + kp (accumulated
   reference offset) = torque.

Tuning (config/controllers.toml, ``[feedforward]``): the PID is the tuned ``pid`` (the
feed-forward leaves the feedback loop unchanged, so its margins hold); the prediction horizon and
the observer gain were chosen by the same cost as the PID's on conditions 1-3: a 2 ms horizon
(1 ms was 2.7 times worse, 3 ms 1.2 times), the observer gain made no measurable difference between
0.003 and 0.03 per period.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from microg_env.controllers.base import MAX_SPEED_M_S, Readings, VectorController
from microg_env.controllers.pid import PID, PIDGains, controller_config, load_gains
from microg_env.params import RigParams
from microg_env.sim.model import drive_inertia_kg_m2, flexible_unit, speed_loop_gains

#: Pad-force readings below this are taken as no contact (the sensor's noise is 0.1 N RMS), N.
CONTACT_THRESHOLD_N = 0.5


@dataclass(frozen=True)
class FeedforwardSettings:
    """The feed-forward's own settings (config/controllers.toml, ``[feedforward]``)."""

    velocity_observer_gain: float  # pull of the measured lander velocity per control period
    prediction_horizon_s: float  # how far ahead the drive's torque acts: delay + torque filter

    @classmethod
    def load(cls) -> FeedforwardSettings:
        entry = controller_config("feedforward")
        return cls(float(entry["velocity_observer_gain"]), float(entry["prediction_horizon_s"]))


class Feedforward(VectorController):
    """PID on x plus the nominal model's feed-forward; see the module docstring."""

    STATE: ClassVar[dict[str, float]] = {
        "_velocity": math.nan,  # the lander's, estimated (NaN: not yet)
        "_start": math.nan,  # the support's height at the start (the balancer's trim)
        "_reference_offset": 0.0,  # accumulated speed-reference offset x period, motor rad
        "_bristle": 0.0,  # the LuGre observer's state, motor rad
    }

    def __init__(
        self,
        control_period_s: float,
        params: RigParams | None = None,
        settings: FeedforwardSettings | None = None,
        gains: PIDGains | None = None,
    ) -> None:
        super().__init__()
        params = RigParams() if params is None else params
        self.settings = FeedforwardSettings.load() if settings is None else settings
        self.control_period_s = control_period_s
        self.pid = PID(load_gains("pid") if gains is None else gains, control_period_s)  # the feedback loop
        screw, servo = params.screw, params.servo
        unit = flexible_unit(params)
        self._mass = params.lander.mass_kg
        self._gravity = params.gravity_m_s2
        self._x_stiffness = unit.x_stiffness_n_per_m
        on_support = params.balancer.placement == "frame_support"
        self._support_stiffness = unit.balancer_stiffness_n_per_m if on_support else 0.0
        self._viscous = screw.viscous_n_s_per_m
        self._gear = screw.gear_rad_per_m
        self._kp, self._kd = speed_loop_gains(params)
        self._inertia = drive_inertia_kg_m2(params)
        self._servo = servo

    @property
    def setpoint_m(self) -> np.ndarray:
        return self.pid.setpoint_m

    def reset(self, ids: np.ndarray | None = None) -> None:
        super().reset(ids)
        self.pid.reset(ids)

    def grow(self, count: int) -> None:
        super().grow(count)
        self.pid.grow(count)

    def act(self, rows: np.ndarray, ids: np.ndarray | slice) -> np.ndarray:
        r = Readings.of(rows)
        period = self.control_period_s
        first = np.isnan(self._start[ids])
        if first.any():
            starting = self.rigs(ids)[first]
            self._start[starting] = r.support_position_m[first]
            self._velocity[starting] = (r.support_velocity_m_s + r.x_rate_m_s)[first]
        force = np.where(r.pad_force_n > CONTACT_THRESHOLD_N, r.pad_force_n, 0.0)
        accel = (force - r.placed_load_kg * self._gravity - self._x_stiffness * r.x_m) / (self._mass + r.placed_load_kg)
        velocity = self._velocity[ids] + accel * period
        velocity += self.settings.velocity_observer_gain * (r.support_velocity_m_s + r.x_rate_m_s - velocity)
        self._velocity[ids] = velocity
        speed = self.pid.command(r, ids, bias_m_s=velocity + accel * period)  # one period ahead
        torque = self._drive_torque(r, ids, speed, accel)
        reference_offset = self._reference_offset[ids]
        offset = (torque - self._kp * reference_offset) / (self._kd + self._kp * period)
        self._reference_offset[ids] = reference_offset + offset * period
        return (speed + offset / self._gear) / MAX_SPEED_M_S

    def _drive_torque(
        self, r: Readings, ids: np.ndarray | slice, speed_m_s: np.ndarray, accel_m_s2: np.ndarray
    ) -> np.ndarray:
        """Motor torque, N m, beyond the speed loop's own, that each rig's support will need."""
        servo, gear, period = self._servo, self._gear, self.control_period_s
        load = self._support_stiffness * (r.support_position_m - self._start[ids]) + self._viscous * speed_m_s
        torque = self._inertia * gear * accel_m_s2 + load / gear
        angle = gear * (r.support_position_m + r.support_velocity_m_s * self.settings.prediction_horizon_s)
        torque -= servo.cogging_torque_n_m * np.sin(servo.cogging_cycles_per_rev * angle)
        if servo.bristle_stiffness_n_m_per_rad > 0:  # LuGre friction of the commanded motion
            omega = gear * speed_m_s
            stribeck = servo.coulomb_torque_n_m + (servo.static_torque_n_m - servo.coulomb_torque_n_m) * np.exp(
                -((omega / servo.stribeck_speed_rad_s) ** 2)
            )
            rate = servo.bristle_stiffness_n_m_per_rad * np.abs(omega) / np.maximum(stribeck, 1e-12)
            decay = np.exp(-rate * period)
            moving = rate > 1e-12
            # exact over the period at constant speed
            step = np.where(moving, (1.0 - decay) / np.where(moving, rate, 1.0), period)
            previous = self._bristle[ids].copy()  # a view when ids is a slice
            bristle = decay * previous + step * omega
            self._bristle[ids] = bristle
            torque += servo.bristle_stiffness_n_m_per_rad * bristle + servo.bristle_damping_n_m_s_per_rad * (
                (bristle - previous) / period
            )
        return torque
