"""Rig parameters: the one source of truth for every physical value, in SI units.

Every value cites the paper (Jia et al., Actuators 2024, 13(9), 361: a table, an equation or a
section) or is marked ``assumption`` with its reason. The MJCF template in ``assets/`` carries the
same geometry and masses (a test checks they agree); every force law is built from here by
:func:`microg_env.sim.model.build_rig`. Change a value with :func:`dataclasses.replace` or, by
dotted path, with :func:`with_overrides` (``{"pad.stiffness_n_per_m": 8000.0}``).

The numerical settings of a simulation (physics step, control period) are not rig parameters;
their defaults and bounds are the module constants below.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass, field
from typing import Any

from microg_env import validate

#: Local gravity at Tianjin (39.1 deg N, near sea level) from the 1980 international gravity
#: formula. Assumption: the paper does not state g; its Table 2 implies 9.79-9.80 m/s^2.
GRAVITY_M_S2 = 9.8009

#: The rig's load capacity (Section 4.1: "the system can withstand a load of 620 kg").
LOAD_CAPACITY_KG = 620.0

#: Default physics step, s. The convergence study ``benchmarks/convergence.py`` (docs/model.md,
#: "Physics step" and "Drive scheme"): under the default midpoint drive the excursions of every
#: classical controller, every compensation error and the landing are within 1 % of a 4x finer step
#: (the adaptive ones' free fall 3 %), and the held-out means and ratios within 2 %
#: (``benchmarks/convergence_comparison.py``); the 5 ms dx keeps a first-order error of up to 4 %. It
#: divides all of the paper's control periods (1000, 500, 200 and 100 us), so they can be compared
#: on one step.
PHYSICS_STEP_S = 1.0e-4
#: Physics steps accepted, s: finer than 10 us buys nothing measurable, coarser than 1 ms does not
#: resolve the drive's 100 Hz speed loop.
PHYSICS_STEP_RANGE_S = (1.0e-5, 1.0e-3)
#: Default control period, s: the paper's 1 kHz loop (Section 4.1), at which the shipped policy was trained.
CONTROL_PERIOD_S = 1.0e-3
#: Control periods accepted, s: the RTX timer's fastest period (100 us, Section 4.1) to 10 ms.
CONTROL_PERIOD_RANGE_S = (1.0e-4, 1.0e-2)
#: Most control steps one run may take (a 30 s test at the fastest period is 300 000).
MAX_CONTROL_STEPS = 1_000_000
#: Least damping ratio of a pad (Eq. 2) accepted: 0.1 % of critical. Below it the damping is
#: immeasurable (a drop test could not fit D) and no rubber is that lossless.
MIN_PAD_DAMPING_RATIO = 1.0e-3
#: Fewest physics steps per pad contact time (Eq. 7): a drop test keeps its restitution within
#: 0.002 % of Eq. (9) at 100 (0.2 % at 10, where the contact starts to gain energy). A stiffer
#: pad is rejected with the physics step it would need.
MIN_STEPS_PER_CONTACT = 100


def flat_punch_radius_m(stiffness_n_per_m: float, young_modulus_pa: float, poisson_ratio: float) -> float:
    """Radius of a rigid flat punch whose Boussinesq stiffness on an elastic half-space is K.

    K = 2 a E / (1 - nu^2) (the aluminium foot, 7.2 GPa, is rigid next to 33 kPa rubber), so
    a = K (1 - nu^2) / (2 E). With Table 1's K, E and nu this gives the foot radius used here.
    """
    return stiffness_n_per_m * (1.0 - poisson_ratio**2) / (2.0 * young_modulus_pa)


#: Plausible range of every numeric parameter, (low, high, unit), inclusive: wide enough for any
#: rig of this kind, narrow enough that the model stays finite and integrable. A value outside is
#: rejected with its name.
RANGES: dict[str, tuple[float, float, str]] = {
    "PadParams.stiffness_n_per_m": (1.0, 1e9, "N/m"),
    "PadParams.damping_n_s_per_m": (1e-3, 1e7, "N s/m"),
    "PadParams.young_modulus_pa": (1e2, 1e12, "Pa"),
    "PadParams.half_width_m": (0.01, 10.0, "m"),
    "PadParams.thickness_m": (1e-3, 1.0, "m"),
    "LanderParams.mass_kg": (1.0, LOAD_CAPACITY_KG, "kg"),
    "LanderParams.foot_radius_m": (1e-3, 1.0, "m"),
    "LanderParams.foot_height_m": (1e-3, 1.0, "m"),
    "QZSParams.stroke_m": (1e-3, 1.0, "m"),
    "QZSParams.guide_friction_n": (0.0, 100.0, "N"),
    "QZSParams.guide_static_friction_n": (0.0, 100.0, "N"),
    "QZSParams.guide_stribeck_speed_m_s": (1e-6, 1.0, "m/s"),
    "QZSParams.guide_bristle_stiffness_n_per_m": (1.0, 1e9, "N/m"),
    "QZSParams.guide_bristle_damping_n_s_per_m": (0.0, 1e6, "N s/m"),
    "QZSParams.guide_damping_n_s_per_m": (0.0, 1e6, "N s/m"),
    "BalancerParams.piston_area_m2": (1e-6, 1.0, "m^2"),
    "BalancerParams.gas_volume_m3": (1e-5, 10.0, "m^3"),
    "BalancerParams.polytropic_index": (1.0, 1.67, ""),
    "ScrewStageParams.lead_m": (1e-3, 1.0, "m"),
    "ScrewStageParams.belt_ratio": (0.01, 100.0, ""),
    "ScrewStageParams.stroke_m": (0.01, 10.0, "m"),
    "ScrewStageParams.max_speed_m_per_s": (1e-3, 10.0, "m/s"),
    "ScrewStageParams.travel_below_touchdown_m": (0.0, 10.0, "m"),
    "ScrewStageParams.support_mass_kg": (0.1, 1e4, "kg"),
    "ScrewStageParams.screw_inertia_kg_m2": (1e-6, 10.0, "kg m^2"),
    "ScrewStageParams.viscous_n_s_per_m": (0.0, 1e6, "N s/m"),
    "ScrewStageParams.transmission_damping_ratio": (0.0, 1.0, ""),
    "ServoParams.rated_torque_n_m": (0.01, 1e4, "N m"),
    "ServoParams.rated_speed_rpm": (1.0, 1e5, "rpm"),
    "ServoParams.rated_power_w": (1.0, 1e7, "W"),
    "ServoParams.rotor_inertia_kg_m2": (1e-7, 10.0, "kg m^2"),
    "ServoParams.torque_constant_n_m_per_a": (1e-3, 100.0, "N m/A"),
    "ServoParams.resistance_ohm": (1e-4, 100.0, "ohm"),
    "ServoParams.bus_voltage_v": (1.0, 1e4, "V"),
    "ServoParams.speed_loop_gain_hz": (0.1, 1e4, "Hz"),
    "ServoParams.speed_integral_time_s": (1e-5, 10.0, "s"),
    "ServoParams.torque_filter_s": (0.0, 0.1, "s"),
    "ServoParams.cogging_torque_n_m": (0.0, 1e3, "N m"),
    "ServoParams.cogging_phase_rad": (-2 * math.pi, 2 * math.pi, "rad"),
    "ServoParams.coulomb_torque_n_m": (0.0, 1e3, "N m"),
    "ServoParams.static_torque_n_m": (0.0, 1e3, "N m"),
    "ServoParams.stribeck_speed_rad_s": (1e-6, 1e4, "rad/s"),
    "ServoParams.bristle_stiffness_n_m_per_rad": (0.0, 1e9, "N m/rad"),
    "ServoParams.bristle_damping_n_m_s_per_rad": (0.0, 1e6, "N m s/rad"),
    "SensorParams.ruler_resolution_m": (1e-12, 1e-3, "m"),
    "SensorParams.ruler_noise_m": (0.0, 1e-3, "m"),
    "SensorParams.accelerometer_noise_density_m_s2_per_sqrt_hz": (0.0, 1.0, "m/s^2/sqrt(Hz)"),
    "SensorParams.accelerometer_bias_m_s2": (-1.0, 1.0, "m/s^2"),
    "SensorParams.ruler_zero_offset_m": (-1e-3, 1e-3, "m"),
    "SensorParams.force_noise_n": (0.0, 1e3, "N"),
    "BalancerDriftParams.gas_temperature_k": (1.0, 1e3, "K"),
    "BalancerDriftParams.max_temperature_rate_k_per_s": (0.0, 0.1, "K/s"),
    "RigParams.gravity_m_s2": (0.1, 100.0, "m/s^2"),
}


def _check_ranges(obj: object) -> None:
    """Every field of ``obj`` with an entry in RANGES, within it."""
    kind = type(obj).__name__
    for f in dataclasses.fields(obj):
        key = f"{kind}.{f.name}"
        if key in RANGES:
            low, high, unit = RANGES[key]
            validate.between(key, getattr(obj, f.name), low, high, unit)


@dataclass(frozen=True)
class PadParams:
    """The rubber landing pad (Section 2, Table 1) and how MuJoCo realises it."""

    stiffness_n_per_m: float = 4666.0  # Table 1, contact surface stiffness K
    damping_n_s_per_m: float = 200.0  # Table 1, damping factor D
    young_modulus_pa: float = 3.3e4  # Table 1, rubber Young's modulus
    poisson_ratio: float = 0.25  # Table 1, rubber Poisson's ratio
    half_width_m: float = 0.3  # assumption: 600 x 600 mm pad, wide enough for any foot
    #: Assumption: 100 mm of rubber on a rigid floor. The foot bottoms out on the floor at this
    #: deformation; the environment ends the episode there and ``drop`` rejects impacts that would
    #: reach it (the largest deformation of the paper's tests is ~20 mm).
    thickness_m: float = 0.1
    #: MuJoCo constraint impedance d. Assumption: MuJoCo's minimum (mjMINIMP). The solver scales
    #: every other force acting during contact by (1 - d), so d = 1e-4 makes the static sink F/K
    #: and the impact response agree with the spring-damper to 1e-4 (see model.pad_contact_solref).
    impedance: float = 1.0e-4

    def __post_init__(self) -> None:
        _check_ranges(self)
        validate.between("PadParams.poisson_ratio", self.poisson_ratio, 0.0, 0.5, high_open=True)
        validate.between("PadParams.impedance", self.impedance, 1.0e-4, 0.5, high_open=True)


#: Pads selectable by name: Table 1's (PadParams' defaults), and the fits stored in config/pads.toml
#: with their provenance (:func:`microg_env.paper.calibration.pad_params`).
PAD_NAMES = ("paper", "calibrated", "paper-simulation")


@dataclass(frozen=True)
class LanderParams:
    """The lander (spacecraft) and its flat cylindrical foot."""

    mass_kg: float = 620.0  # Table 1, spacecraft mass
    #: Assumption: the flat-punch radius that Table 1's K, E and nu imply (66.3 mm, see
    #: flat_punch_radius_m). The paper gives no foot size; the contact law does not depend on it.
    foot_radius_m: float = round(flat_punch_radius_m(4666.0, 3.3e4, 0.25), 4)
    foot_height_m: float = 0.05  # assumption: a 50 mm thick foot plate

    def __post_init__(self) -> None:
        _check_ranges(self)  # the mass at most the rig's 620 kg capacity (Section 4.1)


@dataclass(frozen=True)
class QZSParams:
    """Quasi-zero-stiffness mechanism between floating support and lander (Eq. 17).

    Eq. (17) gives the variation of the mechanism's constant support force, G_r = 35.51 x + 0.4895
    (x in mm, G_r in N). Read literally, with x = z_lander - z_support, the force *grows* as the
    lander rises: a negative residual stiffness, a QZS mechanism tuned slightly past zero. The
    opposite reading is a restoring residual stiffness. ``residual_stiffness_n_per_m`` is k in
    F = F0 - k x: negative for the literal reading (the default), positive for a restoring one.
    The reproduction report shows both; the literal one reproduces the paper's simulated
    descents, which are 1.2-1.5 % faster than ideal (Table 3), a signature no restoring stiffness
    can give.

    The constant 0.4895 N is the weight of the 50 g test weight (0.05 kg x 9.79 m/s^2): the
    intercept of the force measured with that weight on the mechanism, not a force of the
    mechanism. Any constant force is trimmed out when the rig is balanced before a test (Section
    4.1), so it does not enter the model.
    """

    residual_stiffness_n_per_m: float = -35510.0  # Eq. (17), 35.51 N/mm, literal sign (see above)
    #: Assumption: share of the lander's weight the QZS carries at x = 0 when the balancer acts in
    #: parallel with it (``BalancerParams.placement = "support_lander"``); with the balancer between
    #: frame and support (the default) the QZS carries the whole lander.
    weight_share: float = 0.2
    stroke_m: float = 0.05  # Section 4.1, guide stroke (+-25 mm about x = 0)
    #: Assumption: Coulomb friction of the QZS linear guide, N. Two unsealed, lightly preloaded
    #: size-15 recirculating-ball carriages roll at ~0.1 N each (catalogue class; seals would add
    #: 1-2 N each). Of the order of the paper's unexplained 50 g stage error (52 % of 0.49 N), but
    #: chosen from the guide, not fitted to that number.
    guide_friction_n: float = 0.2
    #: Assumption: breakaway (static) friction of the guide, 1.25 x Coulomb (rolling guides show
    #: little stiction).
    guide_static_friction_n: float = 0.25
    #: Assumption: Stribeck speed of the guide, m/s (rolling contacts: ~1 mm/s).
    guide_stribeck_speed_m_s: float = 1.0e-3
    #: Assumption: pre-sliding (bristle) stiffness of the guide, N/m: a preloaded ball guide creeps
    #: ~2 um elastically before it slides (Coulomb / 2 um). The guide's friction is LuGre friction:
    #: a spring below that, Coulomb friction above, integrated exactly at any physics step.
    guide_bristle_stiffness_n_per_m: float = 1.0e5
    #: Assumption: bristle damping, N s/m: its force reaches the Coulomb level at the Stribeck
    #: speed (0.2 N at 1 mm/s). A larger one makes LuGre friction overshoot its breakaway level in
    #: every fast transient (at a touchdown, 8000 N s/m gave tens of newtons).
    guide_bristle_damping_n_s_per_m: float = 200.0
    #: Assumption: viscous loss of the QZS unit (guide seals, spring hysteresis), in N s/m;
    #: 50 N s/m damps the 1.2 Hz lander-on-QZS mode by 0.5 % of critical.
    guide_damping_n_s_per_m: float = 50.0

    def __post_init__(self) -> None:
        stiffness = validate.finite("QZSParams.residual_stiffness_n_per_m", self.residual_stiffness_n_per_m)
        if not 1.0 <= abs(stiffness) <= 1e8:
            raise ValueError(
                f"QZSParams.residual_stiffness_n_per_m must be, in magnitude, in [1, 1e8] N/m "
                f"(Eq. 17 gives 35.51 N/mm), got {self.residual_stiffness_n_per_m!r}"
            )
        _check_ranges(self)
        if self.guide_static_friction_n < self.guide_friction_n:
            raise ValueError(
                f"QZSParams.guide_static_friction_n {self.guide_static_friction_n!r} is below the Coulomb friction "
                f"{self.guide_friction_n!r}"
            )
        validate.between("QZSParams.weight_share", self.weight_share, 0.0, 1.0, high_open=True)
        if self.weight_share == 0.0:
            raise ValueError("QZSParams.weight_share must be in (0, 1), got 0.0")


#: Where the nitrogen balancer acts (``BalancerParams.placement``).
BALANCER_PLACEMENTS = ("frame_support", "support_lander")


@dataclass(frozen=True)
class BalancerParams:
    """Pascal nitrogen balancer (Sections 3.1 and 4.1), a gas spring of stiffness k = n F A / V.

    ``placement`` "frame_support" (the default, Section 4.1: it "can reduce the load of the screw
    to suppress the heat generation") puts it between frame and floating support, trimmed before
    each test to carry support and lander, so the screw holds almost nothing; "support_lander"
    puts it in parallel with the QZS, carrying the share of the lander's weight the QZS does not,
    and the screw then carries everything. F is its force, A its piston area, V its gas volume,
    n the polytropic index.
    """

    placement: str = "frame_support"
    piston_area_m2: float = 8.0e-4  # assumption: 32 mm bore, i.e. ~8 MPa of nitrogen for ~6.5 kN
    gas_volume_m3: float = 0.01  # assumption: a 10 L accumulator ("small pressure change", 4.1)
    #: Assumption: adiabatic compression; a test lasts ~30 s, about the thermal time of a 10 L
    #: accumulator, so 1.4 is the stiffer (conservative) bound.
    polytropic_index: float = 1.4

    def __post_init__(self) -> None:
        validate.choice("BalancerParams.placement", self.placement, BALANCER_PLACEMENTS)
        _check_ranges(self)

    def stiffness_n_per_m(self, force_n: float) -> float:
        """Gas-spring stiffness k = n F A / V at balancing force F."""
        return self.polytropic_index * force_n * self.piston_area_m2 / self.gas_volume_m3


@dataclass(frozen=True)
class ScrewStageParams:
    """Stroke-amplification mechanism: belt, ball screw and floating support (Section 4.1).

    The paper gives no stiffness for the belt or the screw. Assumption: they are rigid by default
    (the motor angle sets the support's position exactly through ``gear_rad_per_m``);
    ``transmission_stiffness_n_per_m`` makes them one spring between the motor side (rotor, screw
    and pulleys) and the support, so their effect can be measured (docs/model.md, "Transmission").
    """

    #: Derived: 1250 mm/s maximum vertical speed at the motor's 1500 rpm through a 1:1 belt.
    lead_m: float = 0.05
    belt_ratio: float = 1.0  # Section 4.1, synchronous belt 1:1
    stroke_m: float = 0.48  # Section 4.1, total screw stroke
    max_speed_m_per_s: float = 1.25  # Section 4.1, maximum vertical speed
    #: Assumption: the pad is installed so that the support can travel 80 mm below touchdown.
    travel_below_touchdown_m: float = 0.08
    #: Assumption: floating support (plate, nut, QZS housing, balancer body); the MJCF uses it too.
    support_mass_kg: float = 40.0
    #: Assumption: steel screw, 40 mm x 1 m (J = m r^2 / 2), plus both belt pulleys.
    screw_inertia_kg_m2: float = 0.0025
    #: Assumption: screw, nut and support-guide viscous loss, in N s/m at the support.
    viscous_n_s_per_m: float = 200.0
    #: The belt and the screw in series as one axial spring at the support, N/m; ``math.inf``
    #: (the default): rigid. Estimate: 1.0e8, from a 40 mm screw's shaft (E A / L with a 34 mm
    #: root over 1 m: 1.9e8), its preloaded nut (~1.5e9) and the 1:1 belt's two spans
    #: (~3e6 N/m each at a 50 mm pulley radius, through the gear: 2.4e8) in series.
    transmission_stiffness_n_per_m: float = math.inf
    #: Assumption: the transmission's damping ratio (steel screw and belt: 0.01-0.05).
    transmission_damping_ratio: float = 0.02

    def __post_init__(self) -> None:
        _check_ranges(self)
        if self.transmission_stiffness_n_per_m != math.inf:  # inf: rigid
            validate.between(
                "ScrewStageParams.transmission_stiffness_n_per_m", self.transmission_stiffness_n_per_m, 1e5, 1e12, "N/m"
            )
        if self.travel_below_touchdown_m >= self.stroke_m:
            raise ValueError(
                f"ScrewStageParams.travel_below_touchdown_m {self.travel_below_touchdown_m!r} "
                f"must be below the stroke {self.stroke_m!r}"
            )

    @property
    def gear_rad_per_m(self) -> float:
        """Motor angle per metre of support travel: 2 pi belt_ratio / lead."""
        return 2.0 * math.pi * self.belt_ratio / self.lead_m

    @property
    def range_m(self) -> tuple[float, float]:
        """Support travel about touchdown (support coordinate 0 = foot on the unloaded pad)."""
        return (-self.travel_below_touchdown_m, self.stroke_m - self.travel_below_touchdown_m)


@dataclass(frozen=True)
class ServoParams:
    """Yaskawa servo drive and motor (Section 4.1) with its own speed loop.

    Source of the rated numbers: Section 4.1 names "the servo motor SGD7S-550A" with 7.5 kW, 48 N m
    and 1500 rpm. SGD7S is Yaskawa's Sigma-7 SERVOPACK (the drive), not a motor, and its 550A code
    is, in Yaskawa's naming, a 5.5 kW model; the stated 7.5 kW / 48 N m / 1500 rpm are those of a
    7.5 kW, 1500 rpm Sigma-7 motor. The model takes the motor numbers the paper states; what the
    drive would add (its own current limit) is not modelled beyond ``peak_torque_n_m``.

    The drive runs a PI speed loop on its speed reference; with the position reference the
    integral of the speed reference, torque = Kv J (w_ref - w) + (Kv J / Ti) (theta_ref - theta),
    realised with MuJoCo's ``dcmotor`` on-board controller (kd = Kv J, kp = Kv J / Ti). The drive
    interpolates the position reference between control periods (a ramp at the commanded speed),
    and filters its torque reference (first order, ``torque_filter_s``) before the current loop.
    """

    rated_torque_n_m: float = 48.0  # Section 4.1
    rated_speed_rpm: float = 1500.0  # Section 4.1
    rated_power_w: float = 7500.0  # Section 4.1
    #: Assumption: 2.5 x rated, the instantaneous maximum of Yaskawa's 7.5 kW Sigma-7 motors.
    #: ``math.inf`` removes the limit.
    peak_torque_n_m: float = 119.0
    #: Assumption: rotor inertia of a 7.5 kW, 1500 rpm medium-inertia motor (catalogue class).
    rotor_inertia_kg_m2: float = 0.0101
    torque_constant_n_m_per_a: float = 0.88  # assumption: 48 N m at ~55 A rated current
    resistance_ohm: float = 0.08  # assumption: winding resistance of a 200 V, 7.5 kW motor
    bus_voltage_v: float = 283.0  # derived: 200 V AC class drive, sqrt(2) x 200 V DC bus
    #: Assumption: speed-loop gain Kv of a tuned Sigma-7 drive; the factory default is 40 Hz, and the
    #: paper gives none. It matters: the PID's x at the collision is 22.6 um at 50 Hz against 9.9 at
    #: 100 Hz (docs/studies/period-bandwidth).
    speed_loop_gain_hz: float = 100.0
    speed_integral_time_s: float = 0.01  # assumption: Ti, ~ 4 / (2 pi Kv) rounded up
    #: Assumption: the Sigma-7's first-stage torque reference filter at its factory default
    #: (Pn401 = 1.00 ms), a first-order lag of the torque command; realised as the time constant
    #: of the dcmotor's current (the drive's current loop follows the filtered reference).
    torque_filter_s: float = 1.0e-3
    #: Assumption: cogging torque of 0.5 % of rated, 72 cycles per revolution (slots x poles).
    cogging_torque_n_m: float = 0.24
    cogging_cycles_per_rev: int = 72
    #: Assumption: the cogging's phase at the motor angle 0 (the support at its coordinate 0), rad;
    #: the torque is A sin(72 theta + phase). Unknown to an operator (nothing on the rig measures it).
    cogging_phase_rad: float = 0.0
    #: Assumption: LuGre friction of screw bearings and nut at the motor: Coulomb and static
    #: torque, Stribeck speed, bristle stiffness (0.1 mrad pre-sliding) and damping.
    coulomb_torque_n_m: float = 0.6
    static_torque_n_m: float = 0.8
    stribeck_speed_rad_s: float = 0.5
    bristle_stiffness_n_m_per_rad: float = 6000.0
    bristle_damping_n_m_s_per_rad: float = 10.0

    def __post_init__(self) -> None:
        _check_ranges(self)
        validate.integer("ServoParams.cogging_cycles_per_rev", self.cogging_cycles_per_rev, 1, 1000)
        if self.peak_torque_n_m != math.inf:  # inf: no limit
            validate.positive("ServoParams.peak_torque_n_m", self.peak_torque_n_m, "N m", 1e5)
        if self.peak_torque_n_m < self.rated_torque_n_m:
            raise ValueError(
                f"ServoParams.peak_torque_n_m {self.peak_torque_n_m!r} is below the rated torque "
                f"{self.rated_torque_n_m!r}"
            )
        if self.static_torque_n_m < self.coulomb_torque_n_m:
            raise ValueError(
                f"ServoParams.static_torque_n_m {self.static_torque_n_m!r} is below the Coulomb torque "
                f"{self.coulomb_torque_n_m!r}"
            )


@dataclass(frozen=True)
class SensorParams:
    """The rig's sensors as the controller sees them (Section 4.1 names them; values assumed)."""

    #: Assumption: an exposed grating ruler with interpolating read head (5 nm measuring step,
    #: 5 nm RMS noise), fine enough to resolve the 0.15-0.3 um changes the paper reports.
    ruler_resolution_m: float = 5.0e-9
    ruler_noise_m: float = 5.0e-9
    #: Assumption: the Sigma-7 motor's 24-bit absolute encoder (3 nm of support travel per count).
    encoder_counts_per_rev: int = 2**24
    #: Assumption: a quartz-flex servo accelerometer, 5 ug/sqrt(Hz) (1.1 mm/s^2 RMS per 1 kHz sample).
    accelerometer_noise_density_m_s2_per_sqrt_hz: float = 5.0e-6 * GRAVITY_M_S2
    #: Assumption: the accelerometer's bias after calibration, m/s^2 (up positive). 0 here; a
    #: quartz-flex unit keeps tens of ug after a field calibration (4e-4 m/s^2 is 41 ug), which
    #: reads straight into a descent measured by the accelerometer (docs/studies/fifty-gram-floor).
    accelerometer_bias_m_s2: float = 0.0
    #: Assumption: 0.1 N RMS from the pad's force sensor (0.02 % of a 500 N range).
    force_noise_n: float = 0.1
    #: Assumption: the grating ruler reads 0 at the QZS's balance point, m (the paper balances the
    #: rig before each test). An offset makes the controller hold x at -offset, where the QZS's
    #: residual stiffness (Eq. 17) pushes the lander with k_r x: 7 um is 0.25 N, the force that
    #: would slow the 50 g stage to the paper's -0.38 mm/s^2 (docs/studies/fifty-gram-floor).
    ruler_zero_offset_m: float = 0.0

    def __post_init__(self) -> None:
        _check_ranges(self)
        validate.integer("SensorParams.encoder_counts_per_rev", self.encoder_counts_per_rev, 1, 2**40)


@dataclass(frozen=True)
class BalancerDriftParams:
    """Slow drift of the nitrogen balancer's force with its gas temperature, dF/F = dT/T."""

    gas_temperature_k: float = 293.15  # assumption: a 20 C test hall
    #: Assumption: largest gas-temperature drift rate, K/s: a hall drifting 0.5 K/h. The steel
    #: accumulator's thermal lag (about an hour) delays such a ramp but does not slow it, so the
    #: gas follows at the hall's rate, 0.5/3600 = 1.4e-4 K/s. Each episode draws a rate uniformly
    #: in [-max, +max].
    max_temperature_rate_k_per_s: float = 0.5 / 3600.0

    def __post_init__(self) -> None:
        _check_ranges(self)


@dataclass(frozen=True)
class RigParams:
    """The whole rig. ``RigParams()`` is the paper's rig with this project's stated assumptions."""

    lander: LanderParams = field(default_factory=LanderParams)
    pad: PadParams = field(default_factory=PadParams)
    qzs: QZSParams = field(default_factory=QZSParams)
    balancer: BalancerParams = field(default_factory=BalancerParams)
    screw: ScrewStageParams = field(default_factory=ScrewStageParams)
    servo: ServoParams = field(default_factory=ServoParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    drift: BalancerDriftParams = field(default_factory=BalancerDriftParams)
    gravity_m_s2: float = GRAVITY_M_S2

    def __post_init__(self) -> None:
        _check_ranges(self)
        for f in dataclasses.fields(self):
            if f.name != "gravity_m_s2":  # each part's default factory is its class
                validate.instance(f"RigParams.{f.name}", getattr(self, f.name), f.default_factory)


@functools.cache
def paper_rig() -> RigParams:
    """``RigParams()``, built and validated once (it is immutable): what a spec's rig starts from,
    thousands of times in a campaign's expansion."""
    return RigParams()


#: The rigs :func:`parameter_paths` and :func:`with_overrides` keep, each at most: a campaign's
#: expansion asks for the same few rigs thousands of times. An entry holds its rig, so the rig's
#: id is not reused while the entry stands; a rig equal to another is still a rig of its own.
_MAX_KEPT = 1024
#: id of a rig -> (the rig, its paths).
_PATHS: dict[int, tuple[RigParams, dict[str, object]]] = {}


def parameter_paths(params: RigParams | None = None) -> dict[str, object]:
    """Every leaf parameter by dotted path (``"pad.stiffness_n_per_m"``) with its value (the
    caller's own copy)."""
    params = paper_rig() if params is None else params
    return dict(_kept(_PATHS, id(params), params, lambda: _paths(params)))


def _kept(store: dict, key: Hashable, rig: RigParams, make: Callable[[], Any]) -> Any:
    """What ``store`` holds at ``key`` if it was made from ``rig`` itself, else ``make()``, kept
    there (the store emptied first once it holds :data:`_MAX_KEPT`)."""
    base, made = store.get(key, (None, None))
    if base is not rig:
        if len(store) >= _MAX_KEPT:
            store.clear()
        made = make()
        store[key] = (rig, made)
    return made


def _paths(params: RigParams) -> dict[str, object]:
    paths: dict[str, object] = {}
    for f in dataclasses.fields(params):
        value = getattr(params, f.name)
        if dataclasses.is_dataclass(value):
            for g in dataclasses.fields(value):
                paths[f"{f.name}.{g.name}"] = getattr(value, g.name)
        else:
            paths[f.name] = value
    return paths


def typed_overrides(name: str, values: Mapping[str, object]) -> dict[str, object]:
    """``values`` by dotted path, each checked against the paper's rig: a known path, a value of its
    default's type (an integer for a float is taken as that float), finite unless its default is
    not; a ValueError naming ``name`` and the path otherwise. The values' own ranges and how they
    combine are :func:`with_overrides`' to check."""
    validate.instance(name, values, Mapping)
    defaults = parameter_paths()
    out: dict[str, object] = {}
    for path, value in sorted(values.items()):
        if path not in defaults:
            raise ValueError(f"{name}: unknown parameter {validate.shown(path)}; known: {', '.join(sorted(defaults))}")
        kind = type(defaults[path])
        if kind is float and isinstance(value, int | float) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise ValueError(f"{name}: {path} must be a {kind.__name__}, got {validate.shown(value)}")
        if kind is float and not math.isfinite(value) and value != defaults[path]:  # an infinite default: itself
            raise ValueError(f"{name}: {path} must be finite, got {validate.shown(value)}")
        out[path] = value
    return out


#: (a base rig's id, each override's path, type and repr) -> (the base, the rig made from it): the
#: key tells 1 from 1.0 and True, and -0.0 from 0.0.
_OVERRIDDEN: dict[tuple, tuple[RigParams, RigParams]] = {}


def with_overrides(params: RigParams, overrides: Mapping[str, object]) -> RigParams:
    """``params`` with the values at the given dotted paths replaced (validated as usual; the
    values of one part are replaced together, so related limits may move together)."""
    validate.instance("overrides", overrides, Mapping)
    if not overrides:
        return params
    key = (id(params), tuple((path, type(value), repr(value)) for path, value in overrides.items()))
    return _kept(_OVERRIDDEN, key, params, lambda: _overridden(params, overrides))


def _overridden(params: RigParams, overrides: Mapping[str, object]) -> RigParams:
    known = parameter_paths(params)
    parts: dict[str, dict[str, object]] = {}
    top: dict[str, object] = {}
    for path, value in overrides.items():
        if path not in known:
            raise ValueError(f"unknown parameter {path!r}; known: {', '.join(sorted(known))}")
        part, _, name = path.partition(".")
        if name:
            parts.setdefault(part, {})[name] = value
        else:
            top[part] = value
    changes = {part: dataclasses.replace(getattr(params, part), **values) for part, values in parts.items()}
    return dataclasses.replace(params, **changes, **top)
