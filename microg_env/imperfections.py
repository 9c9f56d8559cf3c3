"""The real rig's imperfections, each switchable, and domain randomisation for training.

:class:`Imperfections` says which non-ideal effects are on (all by default). Those that live in the
MuJoCo model (servo lag, torque limit, friction, cogging) are applied to the parameters by
:func:`apply_imperfections`; the environment applies the others (sensor noise and quantisation,
one control period of command delay, balancer drift) while it steps. :class:`DomainRandomization`
draws a perturbed rig and load for each episode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from microg_env.params import LOAD_CAPACITY_KG, RigParams
from microg_env.scenarios import LoadStep, Scenario


@dataclass(frozen=True)
class Imperfections:
    """Which non-ideal effects are simulated; values and reasons are in params.py."""

    #: The drive's PI speed loop (100 Hz, ServoParams). Off: the loop runs at the fastest gain the
    #: physics step resolves, Kv = 1/(4 dt) Hz (500 Hz at 0.5 ms), a near-ideal speed source.
    servo_lag: bool = True
    #: The drive's peak torque (119 N m). Off: unlimited torque.
    torque_limit: bool = True
    #: LuGre friction of screw and nut, the screw's viscous loss, the QZS guide's friction and damping.
    friction: bool = True
    #: Motor cogging torque (0.5 % of rated, 72 cycles per revolution).
    cogging: bool = True
    #: Noise and quantisation of grating ruler, encoder, accelerometer and pad force sensor.
    sensor_noise: bool = True
    #: The speed command reaches the drive one control period late (sampling plus fieldbus).
    control_delay: bool = True
    #: The balancer's force drifts with its gas temperature (BalancerDriftParams).
    balancer_drift: bool = True

    @classmethod
    def none(cls) -> Imperfections:
        """An ideal rig: every imperfection off."""
        return cls(**{f.name: False for f in fields(cls)})


def apply_imperfections(params: RigParams, imperfections: Imperfections) -> RigParams:
    """``params`` with the model-level imperfections that are off removed."""
    servo, screw, qzs = params.servo, params.screw, params.qzs
    if not imperfections.servo_lag:
        gain_hz = 0.25 / params.timestep_s
        servo = replace(servo, speed_loop_gain_hz=gain_hz, speed_integral_time_s=4.0 / (2.0 * math.pi * gain_hz))
    if not imperfections.torque_limit:
        servo = replace(servo, peak_torque_n_m=math.inf)
    if not imperfections.friction:
        servo = replace(servo, bristle_stiffness_n_m_per_rad=0.0)
        screw = replace(screw, viscous_n_s_per_m=0.0)
        qzs = replace(qzs, guide_friction_n=0.0, guide_damping_n_s_per_m=0.0)
    if not imperfections.cogging:
        servo = replace(servo, cogging_torque_n_m=0.0)
    return replace(params, servo=servo, screw=screw, qzs=qzs)


@dataclass(frozen=True)
class DomainRandomization:
    """Half-widths of uniform relative perturbations drawn at every reset (0 turns one off)."""

    lander_mass: float = 0.02  # the lander is never heavier than the 620 kg capacity
    load_mass: float = 0.05
    pad_stiffness: float = 0.3
    pad_damping: float = 0.3
    friction: float = 0.5

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (isinstance(value, int | float) and 0.0 <= value < 1.0):
                raise ValueError(f"DomainRandomization.{f.name} must be in [0, 1), got {value!r}")

    def sample(self, params: RigParams, scenario: Scenario, rng: np.random.Generator) -> tuple[RigParams, Scenario]:
        """A perturbed copy of ``params`` and ``scenario``."""

        def scale(width: float) -> float:
            return float(rng.uniform(1.0 - width, 1.0 + width))

        loads = tuple(LoadStep(load.mass_kg * scale(self.load_mass), load.height_m) for load in scenario.loads)
        scenario = replace(
            scenario,
            loads=loads,
            lander_mass_kg=min(scenario.lander_mass_kg * scale(self.lander_mass), LOAD_CAPACITY_KG),
            pad_stiffness_n_per_m=scenario.pad_stiffness_n_per_m * scale(self.pad_stiffness),
            pad_damping_n_s_per_m=scenario.pad_damping_n_s_per_m * scale(self.pad_damping),
        )
        f = scale(self.friction)
        servo = replace(
            params.servo,
            coulomb_torque_n_m=params.servo.coulomb_torque_n_m * f,
            static_torque_n_m=params.servo.static_torque_n_m * f,
        )
        qzs = replace(params.qzs, guide_friction_n=params.qzs.guide_friction_n * scale(self.friction))
        return replace(params, servo=servo, qzs=qzs), scenario
