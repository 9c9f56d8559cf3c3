"""What the pad, the test weights and the physics step can take: checks made before a run, never after it.

A pad whose contact (Eq. 7) lasts fewer than ``MIN_STEPS_PER_CONTACT`` physics steps would be
integrated so coarsely that the landing gains energy; a landing that would deform the pad by its
whole thickness bottoms out on the floor, where the linear law of Section 2 no longer holds. The
rig's other explicitly integrated modes (the drive's speed loop, the friction bristles, the QZS
spring) must be resolved by the physics step too. Each is rejected with a one-line error that
names the value and the bound.
"""

from __future__ import annotations

import math

from microg_env import validate
from microg_env.params import MIN_PAD_DAMPING_RATIO, MIN_STEPS_PER_CONTACT, PadParams, RigParams
from microg_env.sim.contact import SpringDamperContact
from microg_env.validate import FieldError


def validate_loads(loads_kg: tuple[float, ...], lander_mass_kg: float) -> None:
    """Test weights are small excitations of the balanced lander.

    The rig simulates 1e-2 to 1e-4 g (Conclusions); a total m above M/99 would make the simulated
    field m g / (M + m) exceed 1e-2 g.
    """
    for i, mass in enumerate(loads_kg):
        validate.positive(f"load {i} mass", mass, "kg")
    limit = lander_mass_kg / 99.0
    if sum(loads_kg) > limit:
        raise FieldError(
            f"loads totalling {sum(loads_kg):g} kg on a {lander_mass_kg:g} kg lander exceed {limit:.2f} kg, "
            f"the most that keeps the simulated field within the rig's 1e-2 g range",
            "loads_kg",
        )


def check_damping(mass_kg: float, stiffness_n_per_m: float, damping_n_s_per_m: float) -> SpringDamperContact:
    """The Section 2 contact, if its damping ratio is in [MIN_PAD_DAMPING_RATIO, 1)."""
    contact = SpringDamperContact(mass_kg, stiffness_n_per_m, damping_n_s_per_m)  # raises for xi >= 1
    if contact.xi < MIN_PAD_DAMPING_RATIO:
        raise FieldError(
            f"damping {damping_n_s_per_m!r} N s/m gives a damping ratio {contact.xi:.2g} for stiffness "
            f"{stiffness_n_per_m!r} N/m and mass {mass_kg:g} kg, below {MIN_PAD_DAMPING_RATIO:g}",
            "stiffness_n_per_m",  # the pad's K and D set the ratio; the stiffness named first
            "damping_n_s_per_m",
            "mass_kg",
        )
    return contact


def check_pad_model(pad: PadParams, mass_kg: float, physics_step_s: float, context: str) -> SpringDamperContact:
    """Raise ValueError if the pad, carrying ``mass_kg``, is over- or under-damped or too stiff for
    the physics step (its contact would last fewer than MIN_STEPS_PER_CONTACT steps)."""
    contact = check_damping(mass_kg, pad.stiffness_n_per_m, pad.damping_n_s_per_m)
    finest = contact.contact_time_s / MIN_STEPS_PER_CONTACT
    if physics_step_s > finest:
        raise FieldError(
            f"pad stiffness {pad.stiffness_n_per_m:g} N/m ({context}) gives a {contact.contact_time_s * 1e3:.3g} ms "
            f"contact, fewer than {MIN_STEPS_PER_CONTACT} physics steps of {physics_step_s:g} s; "
            f"use physics_step_s <= {finest:.2g} s or a softer pad",
            "stiffness_n_per_m",
            "physics_step_s",
        )
    return contact


def usable_depth_m(params: RigParams) -> tuple[float, str]:
    """How deep the foot may sink into the pad, m, and what limits it: the pad's thickness (the
    foot bottoms out) or the screw's travel below touchdown (the support must follow the foot)."""
    pad, travel = params.pad.thickness_m, params.screw.travel_below_touchdown_m
    if travel < pad:
        return travel, f"the screw's {travel * 1e3:.0f} mm of travel below touchdown"
    return pad, f"the pad's {pad * 1e3:.0f} mm thickness"


def check_pad(
    params: RigParams, mass_kg: float, impact_speed_m_s: float, load_n: float, physics_step_s: float, context: str
) -> SpringDamperContact:
    """Raise ValueError if a lander of ``mass_kg`` landing at ``impact_speed_m_s`` under ``load_n``
    (the test weights' weight) needs a finer physics step, or would sink deeper than the rig allows."""
    pad = params.pad
    contact = check_pad_model(pad, mass_kg, physics_step_s, context)
    # The peak of the free collision plus the static sink under the weights bounds the deformation.
    depth = contact.max_deformation_m(impact_speed_m_s) + load_n / pad.stiffness_n_per_m
    limit, what = usable_depth_m(params)
    if depth >= limit:
        raise FieldError(
            f"pad stiffness {pad.stiffness_n_per_m:g} N/m and damping {pad.damping_n_s_per_m:g} N s/m ({context}) "
            f"would deform the pad by {depth * 1e3:.1f} mm, beyond {what}",
            "stiffness_n_per_m",
            "damping_n_s_per_m",
        )
    return contact


#: Largest product of an explicitly integrated mode's frequency and the physics step.
MAX_OMEGA_DT = 1.0


def transmission_omega(params: RigParams) -> float:
    """The compliant transmission's mode, rad/s: the motor side (rotor, screw and pulleys, reflected
    to the support: J gear^2) against the support on the transmission's spring."""
    screw, servo = params.screw, params.servo
    motor_side_kg = (servo.rotor_inertia_kg_m2 + screw.screw_inertia_kg_m2) * screw.gear_rad_per_m**2
    return math.sqrt(screw.transmission_stiffness_n_per_m * (1.0 / motor_side_kg + 1.0 / screw.support_mass_kg))


def check_integrable(
    params: RigParams, physics_step_s: float, ideal_drive: bool, explicit_damping: bool = False
) -> None:
    """Raise ValueError if a mode the integrator treats explicitly is too fast for the physics step.

    ``explicit_damping``: MuJoCo's ``euler`` integrator (the midpoint drive), which is implicit in
    the joints' damping only, so the LuGre laws' bristle damping and the transmission's damping
    are explicit too: their rates (damping over inertia) count as modes."""
    screw, servo, qzs = params.screw, params.servo, params.qzs
    mass = params.lander.mass_kg
    modes = [("QZSParams.residual_stiffness_n_per_m", math.sqrt(abs(qzs.residual_stiffness_n_per_m) / mass))]
    if qzs.guide_friction_n > 0:
        modes.append(
            ("QZSParams.guide_bristle_stiffness_n_per_m", math.sqrt(qzs.guide_bristle_stiffness_n_per_m / mass))
        )
    if not ideal_drive:
        inertia = (
            servo.rotor_inertia_kg_m2 + screw.screw_inertia_kg_m2 + screw.support_mass_kg / screw.gear_rad_per_m**2
        )
        modes.append(("ServoParams.speed_loop_gain_hz", 2.0 * math.pi * servo.speed_loop_gain_hz))
        if servo.bristle_stiffness_n_m_per_rad > 0:
            modes.append(
                ("ServoParams.bristle_stiffness_n_m_per_rad", math.sqrt(servo.bristle_stiffness_n_m_per_rad / inertia))
            )
        if math.isfinite(screw.transmission_stiffness_n_per_m):
            modes.append(("ScrewStageParams.transmission_stiffness_n_per_m", transmission_omega(params)))
        if explicit_damping and servo.bristle_stiffness_n_m_per_rad > 0:
            motor = servo.rotor_inertia_kg_m2 + screw.screw_inertia_kg_m2  # the motor side alone
            modes.append(("ServoParams.bristle_damping_n_m_s_per_rad", servo.bristle_damping_n_m_s_per_rad / motor))
        if explicit_damping and math.isfinite(screw.transmission_stiffness_n_per_m):
            rate = 2.0 * screw.transmission_damping_ratio * transmission_omega(params)
            modes.append(("ScrewStageParams.transmission_damping_ratio", rate))
    if explicit_damping and qzs.guide_friction_n > 0:
        modes.append(("QZSParams.guide_bristle_damping_n_s_per_m", qzs.guide_bristle_damping_n_s_per_m / mass))
    for name, omega in modes:
        if omega * physics_step_s > MAX_OMEGA_DT:
            raise FieldError(
                f"{name} makes a {omega:.3g} rad/s mode, too fast for physics_step_s {physics_step_s:g} s "
                f"(omega dt {omega * physics_step_s:.2g} > {MAX_OMEGA_DT:g}); use physics_step_s <= "
                f"{MAX_OMEGA_DT / omega:.2g} s",
                name,
                "physics_step_s",
            )
