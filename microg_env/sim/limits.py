"""What the pad and the physics step can take: checks made before a run, never after it.

A pad whose contact (Eq. 7) lasts fewer than ``MIN_STEPS_PER_CONTACT`` physics steps would be
integrated so coarsely that the landing gains energy; a landing that would deform the pad by its
whole thickness bottoms out on the floor, where the linear law of Section 2 no longer holds. Both
are rejected with a one-line error that names the value and the bound.
"""

from __future__ import annotations

from microg_env.params import MIN_PAD_DAMPING_RATIO, MIN_STEPS_PER_CONTACT, PadParams
from microg_env.sim.contact import SpringDamperContact


def check_damping(mass_kg: float, stiffness_n_per_m: float, damping_n_s_per_m: float) -> SpringDamperContact:
    """The Section 2 contact, if its damping ratio is in [MIN_PAD_DAMPING_RATIO, 1)."""
    contact = SpringDamperContact(mass_kg, stiffness_n_per_m, damping_n_s_per_m)  # raises for xi >= 1
    if contact.xi < MIN_PAD_DAMPING_RATIO:
        raise ValueError(
            f"damping {damping_n_s_per_m!r} N s/m gives a damping ratio {contact.xi:.2g} for stiffness "
            f"{stiffness_n_per_m!r} N/m and mass {mass_kg:g} kg, below {MIN_PAD_DAMPING_RATIO:g}"
        )
    return contact


def check_pad(
    pad: PadParams, mass_kg: float, impact_speed_m_s: float, load_n: float, physics_step_s: float, context: str
) -> SpringDamperContact:
    """Raise ValueError if a lander of ``mass_kg`` landing at ``impact_speed_m_s`` under ``load_n``
    (the test weights' weight) needs a finer physics step, or would bottom the pad out."""
    contact = check_damping(mass_kg, pad.stiffness_n_per_m, pad.damping_n_s_per_m)
    finest = contact.contact_time_s / MIN_STEPS_PER_CONTACT
    if physics_step_s > finest:
        raise ValueError(
            f"pad stiffness {pad.stiffness_n_per_m:g} N/m ({context}) gives a {contact.contact_time_s * 1e3:.3g} ms "
            f"contact, fewer than {MIN_STEPS_PER_CONTACT} physics steps of {physics_step_s:g} s; "
            f"use physics_step_s <= {finest:.2g} s or a softer pad"
        )
    # The peak of the free collision plus the static sink under the weights bounds the deformation.
    depth = contact.max_deformation_m(impact_speed_m_s) + load_n / pad.stiffness_n_per_m
    if depth >= pad.thickness_m:
        raise ValueError(
            f"pad stiffness {pad.stiffness_n_per_m:g} N/m and damping {pad.damping_n_s_per_m:g} N s/m ({context}) "
            f"would deform the pad by {depth * 1e3:.1f} mm, beyond its {pad.thickness_m * 1e3:.0f} mm thickness"
        )
    return contact
