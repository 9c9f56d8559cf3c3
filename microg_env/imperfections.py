"""The real rig's imperfections, each switchable, and domain randomisation for training.

:class:`Imperfections` says which non-ideal effects are on (all by default). Those that live in the
MuJoCo model (friction, cogging, the torque limit) are removed from the parameters by
:func:`apply_imperfections`; the drive's lag is removed by building the ideal drive (a speed
source, :func:`microg_env.sim.model.build_rig`); the environment applies the others (sensor noise
and quantisation, one control period of command delay, balancer drift) while it steps.
:func:`check_parameters_used` refuses a rig parameter set to a value that an imperfection switched
off (or the sensor set) would leave without effect.
:class:`DomainRandomization` draws a perturbed lander, pad, friction and set of test weights for
each episode, and with :meth:`DomainRandomization.full` the drive (cogging, motor friction law,
speed loop, torque filter); every draw is a model field value, so a reset never recompiles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from microg_env import validate
from microg_env.params import LOAD_CAPACITY_KG, RigParams, parameter_paths
from microg_env.scenarios import Scenario
from microg_env.sim.limits import check_pad, validate_loads
from microg_env.validate import FieldError


@dataclass(frozen=True)
class Imperfections:
    """Which non-ideal effects are simulated; values and reasons are in params.py."""

    #: The drive's PI speed loop (100 Hz), its torque filter and its torque limit. Off: an ideal
    #: drive, a speed source that follows the reference exactly, with no lag and no chatter.
    servo_lag: bool = True
    #: The drive's peak torque (119 N m). Off: unlimited torque.
    torque_limit: bool = True
    #: LuGre friction of screw and nut and of the QZS guide, the screw's and the guide's viscous loss.
    friction: bool = True
    #: Motor cogging torque (0.5 % of rated, 72 cycles per revolution).
    cogging: bool = True
    #: Noise and quantisation of grating ruler, encoder, accelerometer and pad force sensor, and the
    #: accelerometer's bias (SensorParams). Off: every sensor reads the truth.
    sensor_noise: bool = True
    #: The speed command reaches the drive one control period late (sampling plus fieldbus).
    control_delay: bool = True
    #: The balancer's force drifts with its gas temperature (BalancerDriftParams).
    balancer_drift: bool = True

    def __post_init__(self) -> None:
        for f in fields(self):
            if not isinstance(getattr(self, f.name), bool):
                raise ValueError(f"Imperfections.{f.name} must be True or False, got {getattr(self, f.name)!r}")

    @classmethod
    def none(cls) -> Imperfections:
        """An ideal rig: every imperfection off."""
        return cls(**dict.fromkeys(IMPERFECTION_NAMES, False))


#: The imperfections by name (the fields of :class:`Imperfections`).
IMPERFECTION_NAMES = tuple(f.name for f in fields(Imperfections))


def apply_imperfections(params: RigParams, imperfections: Imperfections) -> RigParams:
    """``params`` with the model-level imperfections that are off removed."""
    servo, screw, qzs = params.servo, params.screw, params.qzs
    if not imperfections.torque_limit:
        servo = replace(servo, peak_torque_n_m=math.inf)
    if not imperfections.friction:
        servo = replace(servo, bristle_stiffness_n_m_per_rad=0.0)
        screw = replace(screw, viscous_n_s_per_m=0.0)
        qzs = replace(qzs, guide_friction_n=0.0, guide_static_friction_n=0.0, guide_damping_n_s_per_m=0.0)
    if not imperfections.cogging:
        servo = replace(servo, cogging_torque_n_m=0.0)
    return replace(params, servo=servo, screw=screw, qzs=qzs)


#: The parts of :class:`RigParams` that the environment reads only while an imperfection is on, by
#: its name: every sensor's noise, bias and resolution (off: exact readings) and the balancer's drift
#: (off: no drift rate, so nothing divides by the gas's temperature).
READ_ONLY_WHEN_ON = {"sensor_noise": "sensors", "balancer_drift": "drift"}
#: The sensor parameters that only one observation entry reads, by that entry: a sensor set that
#: lacks it (:data:`~microg_env.interface.SENSOR_SETS`) leaves them unread. The accelerometer's noise
#: and bias are read on every set: its reading is the trajectory's ``accelerometer_m_s2`` and the
#: ``accelerometer_descent_accel_m_s2`` metric.
READ_ONLY_BY_ENTRY = {"pad_force": ("sensors.force_noise_n",)}


def check_parameters_used(
    params: RigParams, imperfections: Imperfections, sensor_set: str, missing: tuple[str, ...], source: str
) -> None:
    """Raise a FieldError naming the first parameter set in ``params`` (a value other than the
    paper's rig's, ``RigParams()``) that the run would not use: one that an imperfection that is off
    overwrites (:func:`apply_imperfections`) or does not read (:data:`READ_ONLY_WHEN_ON`), or one
    only a reading in ``missing``, the observation entries ``sensor_set`` lacks, reads
    (:data:`READ_ONLY_BY_ENTRY`). ``source`` names what set it (``RunSpec.overrides``, ``params``).
    A parameter left at its default is never refused."""
    given, defaults = parameter_paths(params), parameter_paths()
    chosen = [path for path, value in given.items() if value != defaults[path]]
    if not chosen:
        return
    for name in IMPERFECTION_NAMES:
        if getattr(imperfections, name):
            continue
        applied = parameter_paths(apply_imperfections(params, replace(Imperfections(), **{name: False})))
        unread = READ_ONLY_WHEN_ON.get(name)
        for path in chosen:
            if applied[path] != given[path]:
                effect = f"which sets it to {applied[path]!r}"
            elif path.partition(".")[0] == unread:
                effect = "which leaves it unread"
            else:
                continue
            raise FieldError(
                f"{source} {path} = {given[path]!r}: imperfection {name!r} is off, {effect}; "
                "switch it on or leave the parameter out",
                path,
                "imperfections",
            )
    for entry in missing:
        for path in READ_ONLY_BY_ENTRY.get(entry, ()):
            if path in chosen:
                raise FieldError(
                    f"{source} {path} = {given[path]!r}: sensor_set {sensor_set!r} has no {entry} reading, which "
                    "leaves it unread; choose another sensor set or leave the parameter out",
                    path,
                    "sensor_set",
                )


#: How much wider than :meth:`DomainRandomization.full` held-out test plants are drawn.
WIDER = 1.5
#: The randomisations known by name (:meth:`DomainRandomization.preset`): the plant (the
#: defaults), the plant and the drive, both from wider ranges.
PRESETS = ("plant", "full", "wider")


@dataclass(frozen=True)
class DomainRandomization:
    """Half-widths of uniform relative perturbations drawn at every reset (0 turns one off).

    The lander's mass is drawn in [M (1 - w), min(M (1 + w), 620 kg)]: never above the rig's
    capacity. Friction scales the QZS guide's Coulomb friction and the motor's LuGre torques by
    one factor. :meth:`check` rejects, before any episode, ranges that could draw an impossible rig.
    """

    lander_mass: float = 0.02
    load_mass: float = 0.05
    pad_stiffness: float = 0.3
    pad_damping: float = 0.3
    friction: float = 0.5
    #: The drive model (off by default, so that a randomisation written before these existed draws
    #: the same plants; :meth:`full` turns them on). ``cogging``: the cogging torque's amplitude;
    #: ``cogging_phase``: its phase, drawn in +-``cogging_phase`` x pi rad (1: anywhere); ``lugre``:
    #: the motor-side LuGre bristle stiffness and damping and the Stribeck speed, each on its own;
    #: ``speed_loop``: the speed loop's gain Kv (its bandwidth); ``torque_filter``: the drive's
    #: torque-filter time constant.
    cogging: float = 0.0
    cogging_phase: float = 0.0
    lugre: float = 0.0
    speed_loop: float = 0.0
    torque_filter: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            whole = f.name == "cogging_phase"  # a phase anywhere in the cycle is a full width of 1
            validate.between(f"DomainRandomization.{f.name}", getattr(self, f.name), 0.0, 1.0, high_open=not whole)

    @classmethod
    def full(cls) -> DomainRandomization:
        """The plant and the drive as uncertain as an operator's knowledge of them (engineering
        assumptions, none measured on the paper's rig): the defaults, and the cogging's amplitude
        +-50 % (catalogue values are typical, not guaranteed) at an unknown phase (nothing on the rig
        measures the magnets' angle against the screw's zero), the motor's pre-sliding friction law
        +-50 % (LuGre parameters identified on one rig scatter by that much), the speed loop's gain
        +-20 % (it is set against an estimated inertia) and the torque filter +-30 %."""
        return cls(cogging=0.5, cogging_phase=1.0, lugre=0.5, speed_loop=0.2, torque_filter=0.3)

    @classmethod
    def wider(cls) -> DomainRandomization:
        """Test plants from a wider range than training draws: every half-width of :meth:`full`
        times :data:`WIDER` (the cogging's phase is drawn anywhere already)."""
        full = cls.full()
        return cls(**{f.name: getattr(full, f.name) * WIDER for f in fields(cls)} | {"cogging_phase": 1.0})

    @property
    def draws_drive(self) -> bool:
        """Whether any of the drive's parameters is drawn."""
        return any((self.cogging, self.cogging_phase, self.lugre, self.speed_loop, self.torque_filter))

    @classmethod
    def preset(cls, name: str) -> DomainRandomization:
        """The randomisation named ``name``, one of :data:`PRESETS`."""
        validate.choice("domain_randomization", name, PRESETS)
        return cls() if name == "plant" else getattr(cls, name)()

    def _lander_range(self, params: RigParams) -> tuple[float, float]:
        mass = params.lander.mass_kg
        return mass * (1.0 - self.lander_mass), min(mass * (1.0 + self.lander_mass), LOAD_CAPACITY_KG)

    def check(self, params: RigParams, scenario: Scenario, physics_step_s: float) -> None:
        """Raise ValueError if some draw for ``scenario`` on ``params`` would be an impossible rig."""
        lightest, heaviest = self._lander_range(params)
        most_load = sum(scenario.loads_kg) * (1.0 + self.load_mass)
        limit = lightest / 99.0
        if most_load > limit:
            raise FieldError(
                f"domain_randomization: DomainRandomization.lander_mass {self.lander_mass!r} with load_mass "
                f"{self.load_mass!r} can draw "
                f"{most_load:.3g} kg of test weights on a {lightest:.3g} kg lander, above the {limit:.3g} kg "
                f"that keeps the field within the rig's 1e-2 g range",
                "domain_randomization",
                "loads_kg",
            )
        pad, g = params.pad, params.gravity_m_s2
        for k_scale in (1.0 - self.pad_stiffness, 1.0 + self.pad_stiffness):
            for d_scale in (1.0 - self.pad_damping, 1.0 + self.pad_damping):
                for mass in (lightest, heaviest):
                    drawn = replace(
                        pad,
                        stiffness_n_per_m=pad.stiffness_n_per_m * k_scale,
                        damping_n_s_per_m=pad.damping_n_s_per_m * d_scale,
                    )
                    total = mass + most_load
                    speed = scenario.impact_speed_m_s(mass, g) * math.sqrt(1.0 + self.load_mass)
                    try:
                        check_pad(
                            replace(params, pad=drawn), total, speed, most_load * g, physics_step_s, "extreme draw"
                        )
                    except ValueError as error:  # the pad's fields, then the randomisation's
                        fields = (*getattr(error, "fields", ()), "domain_randomization")
                        raise FieldError(f"domain_randomization: {error}", *fields) from None

    def sample(
        self, params: RigParams, loads_kg: tuple[float, ...], rng: np.random.Generator
    ) -> tuple[RigParams, tuple[float, ...]]:
        """A perturbed copy of ``params`` and of the test weights ``loads_kg``.

        The plant comes from a child of ``rng`` (``rng.spawn``), the weights from ``rng`` itself: a
        seed draws one plant whatever its schedule (its number of weights, or what a sampler drew
        before), so schedules run from different seeds meet different plants."""
        plant = rng.spawn(1)[0]

        def scale(width: float, source: np.random.Generator = plant) -> float:
            return float(source.uniform(1.0 - width, 1.0 + width))

        loads = tuple(mass * scale(self.load_mass, rng) for mass in loads_kg)
        lander = replace(params.lander, mass_kg=float(plant.uniform(*self._lander_range(params))))
        pad = replace(
            params.pad,
            stiffness_n_per_m=params.pad.stiffness_n_per_m * scale(self.pad_stiffness),
            damping_n_s_per_m=params.pad.damping_n_s_per_m * scale(self.pad_damping),
        )
        f = scale(self.friction)
        servo = replace(
            params.servo,
            coulomb_torque_n_m=params.servo.coulomb_torque_n_m * f,
            static_torque_n_m=params.servo.static_torque_n_m * f,
        )
        qzs = replace(
            params.qzs,
            guide_friction_n=params.qzs.guide_friction_n * f,
            guide_static_friction_n=params.qzs.guide_static_friction_n * f,
        )
        drive: dict[str, float] = {}  # drawn only where on, after the plant: the defaults' plant stays the same
        if self.cogging:
            drive["cogging_torque_n_m"] = servo.cogging_torque_n_m * scale(self.cogging)
        if self.cogging_phase:
            width = self.cogging_phase * math.pi
            drive["cogging_phase_rad"] = servo.cogging_phase_rad + float(plant.uniform(-width, width))
        if self.lugre:
            drive["bristle_stiffness_n_m_per_rad"] = servo.bristle_stiffness_n_m_per_rad * scale(self.lugre)
            drive["bristle_damping_n_m_s_per_rad"] = servo.bristle_damping_n_m_s_per_rad * scale(self.lugre)
            drive["stribeck_speed_rad_s"] = servo.stribeck_speed_rad_s * scale(self.lugre)
        if self.speed_loop:
            drive["speed_loop_gain_hz"] = servo.speed_loop_gain_hz * scale(self.speed_loop)
        if self.torque_filter:
            drive["torque_filter_s"] = servo.torque_filter_s * scale(self.torque_filter)
        validate_loads(loads, lander.mass_kg)
        return replace(params, lander=lander, pad=pad, servo=replace(servo, **drive), qzs=qzs), loads
