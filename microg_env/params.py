"""Rig parameters: the one source of truth, in SI units.

Every value cites the paper (Jia et al., Actuators 2024, 13(9), 361: a table, an equation or a
section) or is marked ``assumption`` with its reason. The MJCF template in ``mjcf/`` carries the
same geometry and masses (a test checks they agree); every force law is built from here by
:func:`microg_env.sim.model.build_rig`. Change a value with :func:`dataclasses.replace`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

#: Local gravity at Tianjin (39.1 deg N, near sea level) from the 1980 international gravity
#: formula. Assumption: the paper does not state g; its Table 2 implies 9.79-9.80 m/s^2.
GRAVITY_M_S2 = 9.8009

#: The rig's load capacity (Section 4.1: "the system can withstand a load of 620 kg").
LOAD_CAPACITY_KG = 620.0


def flat_punch_radius_m(stiffness_n_per_m: float, young_modulus_pa: float, poisson_ratio: float) -> float:
    """Radius of a rigid flat punch whose Boussinesq stiffness on an elastic half-space is K.

    K = 2 a E / (1 - nu^2) (the aluminium foot, 7.2 GPa, is rigid next to 33 kPa rubber), so
    a = K (1 - nu^2) / (2 E). With Table 1's K, E and nu this gives the foot radius used here.
    """
    return stiffness_n_per_m * (1.0 - poisson_ratio**2) / (2.0 * young_modulus_pa)


def _require_positive(obj: object, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"{type(obj).__name__}.{name} must be a positive finite number, got {value!r}")


def _require_non_negative(obj: object, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
            raise ValueError(f"{type(obj).__name__}.{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class PadParams:
    """The rubber landing pad (Section 2, Table 1) and how MuJoCo realises it."""

    stiffness_n_per_m: float = 4666.0  # Table 1, contact surface stiffness K
    damping_n_s_per_m: float = 200.0  # Table 1, damping factor D
    young_modulus_pa: float = 3.3e4  # Table 1, rubber Young's modulus
    poisson_ratio: float = 0.25  # Table 1, rubber Poisson's ratio
    half_width_m: float = 0.3  # assumption: 600 x 600 mm pad, wide enough for any foot
    thickness_m: float = 0.1  # assumption: 100 mm of rubber, above the largest deformation (~20 mm)
    #: MuJoCo constraint impedance d. Assumption: MuJoCo's minimum (mjMINIMP). The solver scales
    #: every other force acting during contact by (1 - d), so d = 1e-4 makes the static sink F/K
    #: and the impact response agree with the spring-damper to 1e-4 (see model.pad_contact_solref).
    impedance: float = 1.0e-4

    def __post_init__(self) -> None:
        _require_positive(
            self, "stiffness_n_per_m", "damping_n_s_per_m", "young_modulus_pa", "half_width_m", "thickness_m"
        )
        if not 0.0 <= self.poisson_ratio < 0.5:
            raise ValueError(f"PadParams.poisson_ratio must be in [0, 0.5), got {self.poisson_ratio!r}")
        if not 1.0e-4 <= self.impedance < 0.5:
            raise ValueError(f"PadParams.impedance must be in [1e-4, 0.5), got {self.impedance!r}")


@dataclass(frozen=True)
class LanderParams:
    """The lander (spacecraft) and its flat cylindrical foot."""

    mass_kg: float = 620.0  # Table 1, spacecraft mass
    #: Assumption: the flat-punch radius that Table 1's K, E and nu imply (66.3 mm, see
    #: flat_punch_radius_m). The paper gives no foot size; the contact law does not depend on it.
    foot_radius_m: float = round(flat_punch_radius_m(4666.0, 3.3e4, 0.25), 4)
    foot_height_m: float = 0.05  # assumption: a 50 mm thick foot plate

    def __post_init__(self) -> None:
        _require_positive(self, "mass_kg", "foot_radius_m", "foot_height_m")
        if self.mass_kg > LOAD_CAPACITY_KG:
            raise ValueError(
                f"LanderParams.mass_kg {self.mass_kg!r} kg exceeds the rig's {LOAD_CAPACITY_KG:g} kg load capacity"
            )


@dataclass(frozen=True)
class QZSParams:
    """Quasi-zero-stiffness mechanism between floating support and lander (Eq. 17)."""

    #: Eq. (17): G_r = 35.51 x + 0.4895, x in mm, G_r in N; the text calls 35.51 the stiffness in
    #: N/mm. Modelled as a restoring residual stiffness: the support force falls as x rises.
    stiffness_n_per_m: float = 35510.0
    force_offset_n: float = 0.4895  # Eq. (17), constant term of the force variation
    #: Assumption: share of the lander's weight the QZS carries at x = 0; the nitrogen balancer
    #: carries the rest. Only the sum is fixed (the rig is balanced before each test, Section 4.1);
    #: the split sets the balancer's force and so its gas-spring stiffness.
    weight_share: float = 0.2
    stroke_m: float = 0.05  # Section 4.1, guide stroke (+-25 mm about x = 0)
    #: Assumption: Coulomb friction of the QZS linear guide, in N. Preloaded recirculating-ball
    #: guides carrying almost no side load show 0.01-0.1 N per carriage; the paper attributes
    #: its 50 g stage error to disturbances of this size.
    guide_friction_n: float = 0.02
    #: Assumption: viscous loss of the QZS unit (guide seals, spring hysteresis), in N s/m;
    #: 50 N s/m damps the 1.2 Hz lander-on-QZS mode by 0.5 % of critical.
    guide_damping_n_s_per_m: float = 50.0

    def __post_init__(self) -> None:
        _require_positive(self, "stiffness_n_per_m", "stroke_m")
        _require_non_negative(self, "guide_friction_n", "guide_damping_n_s_per_m")
        if not math.isfinite(self.force_offset_n):
            raise ValueError(f"QZSParams.force_offset_n must be finite, got {self.force_offset_n!r}")
        if not 0.0 < self.weight_share <= 1.0:
            raise ValueError(f"QZSParams.weight_share must be in (0, 1], got {self.weight_share!r}")


@dataclass(frozen=True)
class BalancerParams:
    """Pascal nitrogen balancer in parallel with the QZS mechanism (Sections 3.1 and 4.1).

    It carries the weight the QZS does not. As a gas spring its stiffness is
    k = n F A / V (F its force, A its piston area, V its gas volume, n the polytropic index).
    """

    piston_area_m2: float = 8.0e-4  # assumption: 32 mm bore, i.e. ~6 MPa of nitrogen for ~4.9 kN
    gas_volume_m3: float = 0.01  # assumption: a 10 L accumulator ("small pressure change", 4.1)
    #: Assumption: adiabatic compression; a test lasts ~30 s, about the thermal time of a 10 L
    #: accumulator, so 1.4 is the stiffer (conservative) bound.
    polytropic_index: float = 1.4

    def __post_init__(self) -> None:
        _require_positive(self, "piston_area_m2", "gas_volume_m3", "polytropic_index")

    def stiffness_n_per_m(self, force_n: float) -> float:
        """Gas-spring stiffness k = n F A / V at balancing force F."""
        return self.polytropic_index * force_n * self.piston_area_m2 / self.gas_volume_m3


@dataclass(frozen=True)
class ScrewStageParams:
    """Stroke-amplification mechanism: belt, ball screw and floating support (Section 4.1)."""

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

    def __post_init__(self) -> None:
        _require_positive(
            self, "lead_m", "belt_ratio", "stroke_m", "max_speed_m_per_s", "support_mass_kg", "screw_inertia_kg_m2"
        )
        _require_non_negative(self, "travel_below_touchdown_m", "viscous_n_s_per_m")
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

    The drive runs a PI speed loop; with the position reference the integral of the speed
    reference, that is torque = Kv J (w_ref - w) + (Kv J / Ti) (theta_ref - theta), realised with
    MuJoCo's ``dcmotor`` on-board controller (kd = Kv J, kp = Kv J / Ti).
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
    #: Assumption: speed-loop gain Kv of a tuned Sigma-7 drive (factory default 40 Hz).
    speed_loop_gain_hz: float = 100.0
    speed_integral_time_s: float = 0.01  # assumption: Ti, ~ 4 / (2 pi Kv) rounded up
    #: Assumption: cogging torque of 0.5 % of rated, 72 cycles per revolution (slots x poles).
    cogging_torque_n_m: float = 0.24
    cogging_cycles_per_rev: int = 72
    #: Assumption: LuGre friction of screw bearings and nut at the motor: Coulomb and static
    #: torque, Stribeck speed, bristle stiffness (0.1 mrad pre-sliding) and damping.
    coulomb_torque_n_m: float = 0.6
    static_torque_n_m: float = 0.8
    stribeck_speed_rad_s: float = 0.5
    bristle_stiffness_n_m_per_rad: float = 6000.0
    bristle_damping_n_m_s_per_rad: float = 10.0

    def __post_init__(self) -> None:
        _require_positive(
            self,
            "rated_torque_n_m",
            "rated_speed_rpm",
            "rated_power_w",
            "rotor_inertia_kg_m2",
            "torque_constant_n_m_per_a",
            "resistance_ohm",
            "bus_voltage_v",
            "speed_loop_gain_hz",
            "speed_integral_time_s",
        )
        _require_non_negative(
            self,
            "cogging_torque_n_m",
            "coulomb_torque_n_m",
            "static_torque_n_m",
            "stribeck_speed_rad_s",
            "bristle_stiffness_n_m_per_rad",
            "bristle_damping_n_m_s_per_rad",
        )
        if not (isinstance(self.peak_torque_n_m, int | float) and self.peak_torque_n_m >= self.rated_torque_n_m):
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
    #: Assumption: 0.1 N RMS from the pad's force sensor (0.02 % of a 500 N range).
    force_noise_n: float = 0.1

    def __post_init__(self) -> None:
        _require_positive(self, "ruler_resolution_m", "encoder_counts_per_rev")
        _require_non_negative(self, "ruler_noise_m", "accelerometer_noise_density_m_s2_per_sqrt_hz", "force_noise_n")


@dataclass(frozen=True)
class BalancerDriftParams:
    """Slow drift of the nitrogen balancer's force with its gas temperature, dF/F = dT/T."""

    gas_temperature_k: float = 293.15  # assumption: a 20 C test hall
    #: Assumption: largest gas-temperature drift rate, K/s. A hall drifting 0.5 K/h reaches the gas
    #: through a steel accumulator with a thermal time of about an hour: ~1e-5 K/s. Each episode
    #: draws a rate uniformly in [-max, +max].
    max_temperature_rate_k_per_s: float = 1.0e-5

    def __post_init__(self) -> None:
        _require_positive(self, "gas_temperature_k")
        _require_non_negative(self, "max_temperature_rate_k_per_s")


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
    #: Assumption: 0.5 ms physics step; it divides the paper's 1000 and 500 us control periods and
    #: resolves the fastest dynamics (the 100 Hz speed loop) with Kv dt = 0.31.
    timestep_s: float = 5.0e-4

    def __post_init__(self) -> None:
        _require_positive(self, "gravity_m_s2", "timestep_s")
        parts = {"lander": LanderParams, "pad": PadParams, "qzs": QZSParams, "balancer": BalancerParams}
        parts |= {"screw": ScrewStageParams, "servo": ServoParams, "sensors": SensorParams}
        parts |= {"drift": BalancerDriftParams}
        for name, kind in parts.items():
            if not isinstance(getattr(self, name), kind):
                raise ValueError(
                    f"RigParams.{name} must be a {kind.__name__}, got {type(getattr(self, name)).__name__}"
                )
