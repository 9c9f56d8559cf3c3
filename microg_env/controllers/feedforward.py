"""The strong classical baseline: the PID plus model-based feed-forward from the rig's nominal model.

It reads only the observation (the rig's sensors) and the rig's nominal parameters, never the
simulator's state. Two layers, both in the one speed command the drive accepts:

1. **The lander's motion, fed forward.** The lander's acceleration follows from the forces the
   sensors show, a = (F_pad - m g - k x) / (M + m) (Eq. 1 with the pad force measured, the test
   weights m known to the operator, the QZS's residual force -k x of Eq. 17, nominal M and k).
   With ``pad_model`` a rig without the pad force sensor (its reading exactly 0 N; a real one
   carries 0.1 N RMS of noise) takes F_pad from the pad's spring-damper, Eq. (1)'s K d + D d' at
   the foot's depth d below touchdown (the height the encoder and ruler give) and its rate, never
   pulling (the paper's sensors: Section 4.1's rig reads the encoder and the ruler only). Its
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
from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from microg_env import validate
from microg_env.compiled import jit
from microg_env.controllers.base import VectorController
from microg_env.controllers.pid import (
    LOOP_MAX_SPEED,
    PID,
    X_RATE,
    PIDGains,
    X,
    controller_config,
    load_gains,
    pid_command,
)
from microg_env.interface import MAX_SPEED_M_S, OBSERVATION_INDEX, SCALES
from microg_env.params import RigParams
from microg_env.sim.model import drive_inertia_kg_m2, flexible_unit, speed_loop_gains

#: Observation columns the feed-forward reads beyond the PID's.
SUPPORT_POSITION, SUPPORT_VELOCITY, PAD_FORCE, HEIGHT, PLACED_LOAD = (
    OBSERVATION_INDEX[name] for name in ("support_position", "support_velocity", "pad_force", "height", "placed_load")
)
#: Pad-force readings below this are taken as no contact (the sensor's noise is 0.1 N RMS), N.
CONTACT_THRESHOLD_N = 0.5


def tuned_settings(cls: type, name: str):
    """The settings record ``cls`` of controller ``name``, each field from config/controllers.toml."""
    entry = controller_config(name)
    return cls(*(float(entry[f.name]) for f in fields(cls)))


@dataclass(frozen=True)
class FeedforwardSettings:
    """The feed-forward's own settings (config/controllers.toml, ``[feedforward]``)."""

    velocity_observer_gain: float  # pull of the measured lander velocity per control period
    prediction_horizon_s: float  # how far ahead the drive's torque acts: delay + torque filter

    @classmethod
    def load(cls) -> FeedforwardSettings:
        return tuned_settings(cls, "feedforward")


#: What the feed-forward knows of a plant, in the order of a row of :func:`plant_model`.
PLANT_FIELDS = (
    "mass", "gravity", "x_stiffness", "support_stiffness", "viscous", "gear", "kp_speed", "kd_speed", "inertia",
    "cogging", "cogging_cycles", "cogging_phase", "bristle_stiffness", "bristle_damping", "coulomb", "static",
    "stribeck_speed", "pad_stiffness", "pad_damping",
)  # fmt: skip


GEAR = PLANT_FIELDS.index("gear")


#: The entries of a plant model that ask the drive for torque: an ideal drive (a speed source)
#: needs none, and its model holds them at 0 (:func:`plant_model`).
DRIVE_TORQUE_FIELDS = ("support_stiffness", "viscous", "inertia", "cogging", "bristle_stiffness")


def plant_model(params: RigParams, ideal_drive: bool = False) -> np.ndarray:
    """The feed-forward's model of the rig ``params`` (:data:`PLANT_FIELDS`, SI); with
    ``ideal_drive`` (a speed source) the :data:`DRIVE_TORQUE_FIELDS` are 0, so it asks for no torque."""
    screw, servo = params.screw, params.servo
    unit = flexible_unit(params)
    model = np.array(
        [
            params.lander.mass_kg, params.gravity_m_s2, unit.x_stiffness_n_per_m,
            unit.balancer_stiffness_n_per_m if params.balancer.placement == "frame_support" else 0.0,
            screw.viscous_n_s_per_m, screw.gear_rad_per_m, *speed_loop_gains(params), drive_inertia_kg_m2(params),
            servo.cogging_torque_n_m, float(servo.cogging_cycles_per_rev), servo.cogging_phase_rad,
            servo.bristle_stiffness_n_m_per_rad, servo.bristle_damping_n_m_s_per_rad, servo.coulomb_torque_n_m,
            servo.static_torque_n_m, servo.stribeck_speed_rad_s, params.pad.stiffness_n_per_m,
            params.pad.damping_n_s_per_m,
        ]
    )  # fmt: skip
    if ideal_drive:
        model[[PLANT_FIELDS.index(name) for name in DRIVE_TORQUE_FIELDS]] = 0.0
    return model


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
        pad_model: bool = False,
    ) -> None:
        self.pid = PID(load_gains("pid") if gains is None else gains, control_period_s)  # the feedback loop
        super().__init__(self.pid)
        self.settings = FeedforwardSettings.load() if settings is None else settings
        self.control_period_s = control_period_s
        #: The nominal plant, and each rig's plant model (a row of the nominal one).
        self.nominal = plant_model(RigParams() if params is None else params)
        self._plant = self.nominal[None].copy()
        #: The feed-forward's settings, in the order :func:`feedforward_actions` takes them.
        self.constants = (
            control_period_s, self.settings.velocity_observer_gain, self.settings.prediction_horizon_s, pad_model
        )  # fmt: skip

    def grow(self, count: int) -> None:
        if count > self.size:
            self._plant = np.vstack([self._plant, np.tile(self.nominal, (count - self.size, 1))])
        super().grow(count)

    @property
    def setpoint_m(self) -> np.ndarray:
        return self.pid.setpoint_m

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        actions = np.empty(ids.size, dtype=np.float32)
        feedforward_actions(
            rows, ids, SCALES, self._start, self._velocity, self._reference_offset, self._bristle, self._plant,
            *self.constants, actions, self.pid.loop(),
        )  # fmt: skip
        return actions


class Oracle(Feedforward):
    """The feed-forward given each episode's true plant (lander, pad, friction, drive), not the
    nominal one: not deployable (no operator knows the plant), a reference point for what knowing
    the plant is worth to this controller's structure, not a bound on any controller's. On a rig
    without the pad force sensor it takes the force from the true pad (``pad_model``). The
    harness tells it the plant at every reset (:meth:`know_plants`); it refuses to act on a rig
    whose plant it was not told."""

    def __init__(self, control_period_s: float, params: RigParams | None = None, gains: PIDGains | None = None) -> None:
        super().__init__(control_period_s, params, gains=gains, pad_model=True)

    def reset(self, ids: np.ndarray | None = None) -> None:
        super().reset(ids)
        self._plant[slice(None) if ids is None else np.asarray(ids, dtype=np.int64)] = math.nan

    def grow(self, count: int) -> None:
        start = self.size
        super().grow(count)
        self._plant[start:] = math.nan

    def know_plants(self, ids: np.ndarray, plants: list[RigParams], *, ideal_drive: bool) -> None:
        """Rigs ``ids`` run on ``plants`` this episode, with an ideal drive (a speed source) or not."""
        ids = np.asarray(ids, dtype=np.int64)
        self.grow(int(ids.max(initial=-1)) + 1)
        for i, params in zip(ids, plants, strict=True):
            self._plant[i] = plant_model(params, ideal_drive)

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        unknown = ids[np.isnan(self._plant[ids, 0])]
        if unknown.size:
            raise RuntimeError(
                f"oracle: rig {int(unknown[0])}'s plant was not given (know_plants after each reset); "
                "only microg's harnesses can run the oracle"
            )
        return super().act(rows, ids)


@jit
def feedforward_actions(
    rows, ids, scales, start, velocity, reference_offset, bristle, plant, period, observer_gain, horizon, pad_model,
    out, loop,
):  # fmt: skip
    """The feed-forward's actions (command / max_speed) for observations ``rows`` of rigs ``ids``,
    into ``out``; ``plant``: each rig's model (rows of :func:`plant_model`); ``pad_model``: the pad
    force from the pad's model where the rig reads none; ``loop``: its PID's (:meth:`PID.loop`)."""
    max_speed = loop[LOOP_MAX_SPEED]
    for j in range(ids.size):
        i = ids[j]
        model = plant[i]
        mass, gravity, x_stiffness, support_stiffness = model[0], model[1], model[2], model[3]
        viscous, gear, kp_speed, kd_speed, inertia = model[4], model[5], model[6], model[7], model[8]
        cogging, cogging_cycles, cogging_phase = model[9], model[10], model[11]
        bristle_stiffness, bristle_damping, coulomb, static, stribeck_speed = (
            model[12], model[13], model[14], model[15], model[16]
        )  # fmt: skip
        pad_stiffness, pad_damping = model[17], model[18]
        x = rows[j, X] * scales[X]
        x_rate = rows[j, X_RATE] * scales[X_RATE]
        position = rows[j, SUPPORT_POSITION] * scales[SUPPORT_POSITION]
        support_velocity = rows[j, SUPPORT_VELOCITY] * scales[SUPPORT_VELOCITY]
        pad_force = rows[j, PAD_FORCE] * scales[PAD_FORCE]
        placed = rows[j, PLACED_LOAD] * scales[PLACED_LOAD]
        if np.isnan(start[i]):  # the rig's first period: its trim and velocity as measured
            start[i] = position
            velocity[i] = support_velocity + x_rate
        # 1. The lander's motion (Eq. 1 with the pad force measured), fed forward one period ahead.
        if pad_model and pad_force == 0.0:  # no pad force sensor: Eq. (1)'s spring-damper at the measured foot
            depth = -rows[j, HEIGHT] * scales[HEIGHT]
            force = max(pad_stiffness * depth - pad_damping * (support_velocity + x_rate), 0.0) if depth > 0 else 0.0
        else:
            force = pad_force if pad_force > CONTACT_THRESHOLD_N else 0.0
        accel = (force - placed * gravity - x_stiffness * x) / (mass + placed)
        estimate = velocity[i] + accel * period
        estimate += observer_gain * (support_velocity + x_rate - estimate)
        velocity[i] = estimate
        speed = pid_command(i, x, x_rate, estimate + accel * period, loop)
        # 2. The motor torque beyond the speed loop's own that the support will need.
        load = support_stiffness * (position - start[i]) + viscous * speed
        torque = inertia * gear * accel + load / gear
        angle = gear * (position + support_velocity * horizon)
        torque -= cogging * np.sin(cogging_cycles * angle + cogging_phase)
        if bristle_stiffness > 0:  # LuGre friction of the commanded motion
            omega = gear * speed
            ratio = omega / stribeck_speed
            stribeck = coulomb + (static - coulomb) * np.exp(-(ratio * ratio))
            rate = bristle_stiffness * abs(omega) / max(stribeck, 1e-12)
            decay = np.exp(-rate * period)
            step = (1.0 - decay) / rate if rate > 1e-12 else period  # exact over the period at constant speed
            previous = bristle[i]
            bristle[i] = decay * previous + step * omega
            torque += bristle_stiffness * bristle[i] + bristle_damping * ((bristle[i] - previous) / period)
        # The torque as a speed-reference offset that the drive's PI law adds.
        accumulated = reference_offset[i]
        offset = (torque - kp_speed * accumulated) / (kd_speed + kp_speed * period)
        reference_offset[i] = accumulated + offset * period
        out[j] = (speed + offset / gear) / max_speed


@dataclass(frozen=True)
class AdaptiveSettings:
    """The adaptive feed-forward's own settings (config/controllers.toml, ``[adaptive]``)."""

    cogging_gain: float  # normalised LMS step of the cogging estimate, per control period
    min_cogging_hz: float  # the estimate learns only while the cogging passes faster than this
    high_pass_hz: float  # corner of the high-pass that takes the speed loop's slow lag out of eps

    @classmethod
    def load(cls) -> AdaptiveSettings:
        return tuned_settings(cls, "adaptive")


class AdaptiveFeedforward(Feedforward):
    """The feed-forward that learns the motor's cogging while it runs, from the encoder only: a
    deployable adaptive baseline (adaptive feed-forward cancellation, a filtered-x LMS).

    The cogging torque A sin(N theta + phase) = a sin(N theta) + b cos(N theta) that the
    feed-forward cancels has its coefficients (a, b) estimated per rig, starting from the nominal
    motor's. What the cancellation leaves moves the support off the drive's position reference
    (the integral of the commands sent, one period late): eps = theta_ref - theta responds to a
    residual torque r(theta) through the speed loop, eps = -H(j w) r at the cogging's frequency
    w = N dtheta/dt, with H = 1 / (-J w^2 + (kp + j w kd) / (1 + j w tau)) from the nominal drive
    (inertia J, PI gains, torque filter tau). Each period, while the cogging passes faster than
    ``min_cogging_hz``, (a, b) move against the gradient of eps^2: by -mu eps [sin, cos](N theta +
    arg H) / |H|. Everything else is the nominal feed-forward's.
    """

    STATE: ClassVar[dict[str, float]] = {
        **Feedforward.STATE,
        "_reference": math.nan,  # the drive's position reference as the commands sent imply, less
        # the offsets that ask it for the feed-forward's torque, m
        "_pending": 0.0,  # that part of the command sent last period, which the drive takes this period, m/s
        "_slow": 0.0,  # eps low-passed at high_pass_hz (eps minus it is the part the cogging moves), rad
    }

    def __init__(
        self,
        control_period_s: float,
        params: RigParams | None = None,
        gains: PIDGains | None = None,
        pad_model: bool = False,
    ) -> None:
        super().__init__(control_period_s, params, gains=gains, pad_model=pad_model)
        params = RigParams() if params is None else params
        self.adaptive = AdaptiveSettings.load()
        #: The adaptation's constants, in the order :func:`adapt_cogging` takes them.
        corner = 2 * math.pi * self.adaptive.high_pass_hz
        self.adaptive_constants = (
            self.adaptive.cogging_gain, 2 * math.pi * self.adaptive.min_cogging_hz, corner,
            1.0 - math.exp(-corner * control_period_s), params.servo.torque_filter_s,
        )  # fmt: skip

    def reset(self, ids: np.ndarray | None = None) -> None:
        super().reset(ids)
        self._plant[slice(None) if ids is None else np.asarray(ids, dtype=np.int64)] = (
            self.nominal
        )  # forget the estimate

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        adapt_cogging(
            rows, ids, SCALES, self._plant, self._reference, self._pending, self._slow, *self.adaptive_constants
        )  # fmt: skip
        before = self._reference_offset[ids]
        actions = super().act(rows, ids)
        offsets = (self._reference_offset[ids] - before) / self.nominal[GEAR]  # m
        advance_reference(ids, actions, offsets, MAX_SPEED_M_S, self.control_period_s, self._reference, self._pending)
        return actions


@dataclass(frozen=True)
class DitherSettings:
    """The dither's settings (config/controllers.toml, ``[adaptive-dither]``)."""

    amplitude_m: float  # half the square wave's peak-to-peak, added to the x setpoint
    period_s: float  # one full cycle

    def __post_init__(self) -> None:
        validate.non_negative("amplitude_m", self.amplitude_m, "m")
        validate.positive("period_s", self.period_s, "s")

    @classmethod
    def load(cls) -> DitherSettings:
        return tuned_settings(cls, "adaptive-dither")


class DitheredAdaptiveFeedforward(AdaptiveFeedforward):
    """The adaptive feed-forward with a square-wave dither on its x setpoint: +-``amplitude_m``,
    switching every half ``period_s`` rounded to whole control periods (so at a 2 ms control
    period a 10 ms dither runs at 12 ms), from + at each episode's start; a period shorter than
    two control periods is refused.

    Dither is the classical remedy for friction at low speed (Armstrong-Helouvry, Dupont and
    Canudas de Wit, Automatica 30(7), 1994, Section 5.3): the support descends at a few mm/s, where
    the LuGre friction of the screw and the QZS guide sticks and slips, and that leaves a bias in the
    force on the lander, the compensation error of Eq. (17)'s descent; a small fast oscillation
    keeps the contacts sliding, so the friction averages out. It reads what ``adaptive`` reads. A
    setpoint from a residual (:class:`~microg_env.controllers.policy.PolicyController`) is held as
    for ``adaptive``, the dither added to it; ``setpoint_m`` (and the environment's
    ``info["setpoint_m"]``) is that held setpoint, without the dither.
    """

    STATE: ClassVar[dict[str, float]] = {**AdaptiveFeedforward.STATE, "_dither_periods": 0.0}

    def __init__(
        self,
        control_period_s: float,
        params: RigParams | None = None,
        gains: PIDGains | None = None,
        dither: DitherSettings | None = None,
        pad_model: bool = False,
    ) -> None:
        super().__init__(control_period_s, params, gains=gains, pad_model=pad_model)
        self.dither = DitherSettings.load() if dither is None else dither
        if self.dither.period_s < 2 * control_period_s:
            raise ValueError(
                f"dither period_s {self.dither.period_s!r}: shorter than two control periods "
                f"({2 * control_period_s:g} s), a square wave cannot switch that fast"
            )
        #: Control periods between the square wave's switches.
        self.half_period = math.floor(self.dither.period_s / 2 / control_period_s + 0.5)

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        held = self.setpoint_m[ids]
        phase = (self._dither_periods[ids] // self.half_period) % 2
        self.setpoint_m[ids] = held + np.where(phase == 0, self.dither.amplitude_m, -self.dither.amplitude_m)
        try:
            actions = super().act(rows, ids)
        finally:
            self.setpoint_m[ids] = held
        self._dither_periods[ids] += 1
        return actions


@jit
def adapt_cogging(rows, ids, scales, plant, reference, pending, slow, gain, min_rate, corner, smoothing, torque_filter):
    """One step of the cogging estimate of rigs ``ids`` (rows 9 and 11 of ``plant``: amplitude and
    phase), from the encoder's position against the drive's reference; see :class:`AdaptiveFeedforward`."""
    for j in range(ids.size):
        i = ids[j]
        position = rows[j, SUPPORT_POSITION] * scales[SUPPORT_POSITION]
        if np.isnan(reference[i]):  # the first period: the drive's reference is where the support is
            reference[i] = position
            pending[i] = 0.0
            slow[i] = 0.0
            continue
        model = plant[i]
        gear, kp, kd, inertia, cycles = model[5], model[6], model[7], model[8], model[10]
        lag = gear * (reference[i] - position)  # motor rad
        slow[i] += smoothing * (lag - slow[i])
        error = lag - slow[i]
        rate = cycles * gear * rows[j, SUPPORT_VELOCITY] * scales[SUPPORT_VELOCITY]  # the cogging's, rad/s
        if abs(rate) < min_rate:
            continue
        w = abs(rate)
        response = 1.0 / (-inertia * w * w + (kp + 1j * w * kd) / (1.0 + 1j * w * torque_filter))
        response *= 1j * w / (1j * w + corner)  # the high-pass
        angle = cycles * gear * position + np.angle(response) * np.sign(rate)
        step = -gain * error / abs(response)
        a = model[9] * np.cos(model[11]) + step * np.sin(angle)
        b = model[9] * np.sin(model[11]) + step * np.cos(angle)
        model[9] = np.hypot(a, b)
        model[11] = np.arctan2(b, a)


@jit
def advance_reference(ids, actions, offsets, max_speed, period, reference, pending):
    """The drive's reference at the next period, less the feed-forward's torque offsets (``offsets``,
    m, this period's): this period it ramps at the command sent last period (the control delay);
    this period's command waits one period."""
    for j in range(ids.size):
        i = ids[j]
        command = min(max(float(actions[j]), -1.0), 1.0) * max_speed
        reference[i] += pending[i] * period
        pending[i] = command - offsets[j] / period


@dataclass(frozen=True)
class FrictionSettings:
    """The friction-level estimate's settings (config/controllers.toml, ``[adaptive-friction]``)."""

    friction_gain: float  # share of the torque error the level's factor takes up per control period
    min_friction_speed_rad_s: float  # the level is learned only while the motor turns faster than this

    def __post_init__(self) -> None:
        validate.non_negative("friction_gain", self.friction_gain)
        validate.non_negative("min_friction_speed_rad_s", self.min_friction_speed_rad_s, "rad/s")

    @classmethod
    def load(cls) -> FrictionSettings:
        return tuned_settings(cls, "adaptive-friction")


#: The factor on the nominal friction levels that :class:`FrictionAdaptiveFeedforward` may reach:
#: wider than any drawn plant's (``DomainRandomization.wider``: x0.25 to x1.75).
FRICTION_FACTOR_RANGE = (0.1, 3.0)


class FrictionAdaptiveFeedforward(DitheredAdaptiveFeedforward):
    """``adaptive-dither`` that also learns the level of the friction as it runs, from the encoder
    only (adaptive friction compensation; Canudas de Wit et al., IEEE TAC 40(3), 1995), and on a
    rig without the pad force sensor takes the pad force from the nominal pad (``pad_model``).

    The feed-forward asks the drive for the nominal LuGre friction torque; what the friction
    needs beyond that, the speed loop supplies by lagging its reference. At a steady speed the
    loop's integral holds that torque at kp times the slow lag (the lag the cogging estimate
    low-passes at ``high_pass_hz``). The friction's Coulomb and static levels are the nominal ones
    times one factor (the plants draw them so), and each period, while the motor turns faster than
    ``min_friction_speed_rad_s``, the factor moves by ``friction_gain`` times that torque over
    the nominal level at the measured speed, within :data:`FRICTION_FACTOR_RANGE`. It reads what
    ``adaptive`` reads; each episode starts from the nominal levels.
    """

    def __init__(self, control_period_s: float, params: RigParams | None = None, gains: PIDGains | None = None) -> None:
        super().__init__(control_period_s, params, gains=gains, pad_model=True)
        self.friction = FrictionSettings.load()
        #: The estimate's constants, in the order :func:`adapt_friction` takes them.
        self.friction_constants = (
            self.friction.friction_gain, self.friction.min_friction_speed_rad_s, *FRICTION_FACTOR_RANGE
        )  # fmt: skip

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        actions = super().act(rows, ids)
        adapt_friction(rows, ids, SCALES, self._plant, self.nominal, self._slow, *self.friction_constants)
        return actions


@jit
def adapt_friction(rows, ids, scales, plant, nominal, slow, gain, min_speed, lowest, highest):
    """One step of the friction levels' estimate of rigs ids (rows 14 and 15 of ``plant``: the
    Coulomb and static torques, one factor on ``nominal``'s), from the slow lag of the speed loop
    (``slow``, motor rad); see :class:`FrictionAdaptiveFeedforward`."""
    gear, kp = nominal[5], nominal[6]
    coulomb, static, stribeck_speed = nominal[14], nominal[15], nominal[16]
    if coulomb <= 0.0:  # no Coulomb level to scale
        return
    for j in range(ids.size):
        i = ids[j]
        speed = gear * rows[j, SUPPORT_VELOCITY] * scales[SUPPORT_VELOCITY]  # the motor's, rad/s
        ratio = speed / stribeck_speed
        level = coulomb + (static - coulomb) * np.exp(-(ratio * ratio))
        if abs(speed) < min_speed or level <= 0.0:
            continue
        factor = plant[i, 14] / coulomb + gain * kp * slow[i] / (np.sign(speed) * level)
        factor = min(max(factor, lowest), highest)
        plant[i, 14] = factor * coulomb
        plant[i, 15] = factor * static
