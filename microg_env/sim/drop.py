"""Pad drop test: the lander lands on the pad in MuJoCo, measured against Section 2's closed form.

The lander (rig removed, no field: the free collision of Eq. 1) reaches the pad at speed V0. From
the simulated trace we measure contact time, restitution and peak deformation, and fit K and D by
least squares to the force-deformation trace (F = K d + D d'), and compare each with
:class:`~microg_env.sim.contact.SpringDamperContact`. :func:`static_sink` checks the other half of the
contact law: the settled deformation under a constant load F must be F/K.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import mujoco
import numpy as np

from microg_env import validate
from microg_env.params import MIN_STEPS_PER_CONTACT, PHYSICS_STEP_RANGE_S, PHYSICS_STEP_S, RANGES, RigParams
from microg_env.sim.contact import SpringDamperContact
from microg_env.sim.limits import check_damping
from microg_env.sim.model import PadTest, build_pad_test
from microg_env.validate import FieldError

#: Physics steps the drop starts above the pad (reached at constant speed in zero field).
_APPROACH_STEPS = 5
#: Physics steps per contact time the drop aims for; the step is never finer than the finest
#: physics step accepted, and the pad is rejected below MIN_STEPS_PER_CONTACT.
_STEPS_PER_CONTACT = 2000
#: Smallest peak deformation the drop test resolves, m.
_MIN_DEFORMATION_M = 1.0e-6
#: Longest contact (and static settling) a drop test simulates, s.
_MAX_SIMULATED_S = 120.0


@dataclass(frozen=True)
class DropTrace:
    """Sampled drop: every array is at the same instants (the state before each physics step)."""

    time_s: np.ndarray
    height_m: np.ndarray  # sole height above the undeformed pad (negative: deforming it)
    velocity_m_s: np.ndarray  # lander velocity, up positive
    force_n: np.ndarray  # pad contact force (the pad_force touch sensor)


@dataclass(frozen=True)
class Compared:
    """A simulated value beside its closed-form value."""

    sim: float
    analytic: float

    @property
    def rel_error(self) -> float:
        return (self.sim - self.analytic) / self.analytic

    def as_dict(self) -> dict[str, float]:
        return {"sim": self.sim, "analytic": self.analytic, "rel_error": self.rel_error}


@dataclass(frozen=True)
class DropReport:
    """Drop test result: each quantity simulated and in closed form."""

    mass_kg: float
    stiffness_n_per_m: float
    damping_n_s_per_m: float
    impact_speed_m_s: float
    contact: SpringDamperContact
    contact_time_s: Compared
    restitution: Compared
    max_deformation_m: Compared
    fitted_stiffness_n_per_m: Compared
    fitted_damping_n_s_per_m: Compared
    trace: DropTrace

    def as_dict(self) -> dict[str, dict[str, float]]:
        """The five compared quantities, as ``microg drop --json`` prints them."""
        names = (
            "contact_time_s",
            "restitution",
            "max_deformation_m",
            "fitted_stiffness_n_per_m",
            "fitted_damping_n_s_per_m",
        )
        return {name: getattr(self, name).as_dict() for name in names}


def drop_physics_step(contact: SpringDamperContact) -> float:
    """The physics step of a drop test: 1/2000 of the contact time, within the accepted range."""
    low, high = PHYSICS_STEP_RANGE_S
    return min(max(contact.contact_time_s / _STEPS_PER_CONTACT, low), PHYSICS_STEP_S, high)


def validate_drop(
    mass_kg: float, stiffness: float, damping: float, impact_speed: float, params: RigParams
) -> SpringDamperContact:
    """Reject inputs the Section 2 model, the rig or the physics step cannot take, naming the bad value."""
    for name, value, key in (
        ("mass", mass_kg, "LanderParams.mass_kg"),
        ("stiffness", stiffness, "PadParams.stiffness_n_per_m"),
        ("damping", damping, "PadParams.damping_n_s_per_m"),
    ):
        low, high, unit = RANGES[key]  # the same bounds as the rig's parameters
        validate.between(name, value, low, high, unit)
    validate.positive("velocity", impact_speed, "m/s")
    contact = check_damping(mass_kg, stiffness, damping)
    if contact.contact_time_s > _MAX_SIMULATED_S:
        raise FieldError(
            f"stiffness {stiffness!r} N/m with mass {mass_kg!r} kg gives a {contact.contact_time_s:.3g} s contact, "
            f"longer than the {_MAX_SIMULATED_S:g} s a drop test simulates",
            "stiffness",
            "mass",
        )
    if contact.contact_time_s / drop_physics_step(contact) < MIN_STEPS_PER_CONTACT:
        raise FieldError(
            f"stiffness {stiffness!r} N/m with mass {mass_kg!r} kg gives a {contact.contact_time_s:.3g} s contact, "
            f"fewer than {MIN_STEPS_PER_CONTACT} of the finest physics step ({PHYSICS_STEP_RANGE_S[0]:g} s)",
            "stiffness",
            "mass",
        )
    depth = contact.max_deformation_m(impact_speed)
    if depth >= params.pad.thickness_m:
        raise FieldError(
            f"velocity {impact_speed!r} m/s gives a {depth * 1e3:.1f} mm deformation, beyond the pad's "
            f"{params.pad.thickness_m * 1e3:.0f} mm thickness",
            "velocity",
        )
    if depth < _MIN_DEFORMATION_M:
        raise FieldError(
            f"velocity {impact_speed!r} m/s gives a {depth * 1e6:.3g} um deformation, below the "
            f"{_MIN_DEFORMATION_M * 1e6:g} um the drop test resolves",
            "velocity",
        )
    return contact


def simulate_drop(pad_test: PadTest, impact_speed_m_s: float, duration_s: float) -> DropTrace:
    """Start the sole a few steps above the pad at ``impact_speed_m_s`` downward; record ``duration_s``."""
    model = pad_test.model
    data = mujoco.MjData(model)
    data.qpos[0] = _APPROACH_STEPS * model.opt.timestep * impact_speed_m_s
    data.qvel[0] = -impact_speed_m_s
    n_steps = math.ceil(duration_s / model.opt.timestep)
    time, height, velocity, force = (np.empty(n_steps) for _ in range(4))
    pad_force = data.sensor("pad_force").data
    for k in range(n_steps):
        time[k], height[k], velocity[k] = data.time, data.qpos[0], data.qvel[0]
        mujoco.mj_step(model, data)
        force[k] = pad_force[0]  # sensors of a step are computed at its starting state
    return DropTrace(time, height, velocity, force)


def fit_spring_damper(deformation_m: np.ndarray, rate_m_s: np.ndarray, force_n: np.ndarray) -> tuple[float, float]:
    """Least-squares K and D of F = K d + D d' over the given samples."""
    design = np.column_stack([deformation_m, rate_m_s])
    (stiffness, damping), *_ = np.linalg.lstsq(design, force_n, rcond=None)
    return float(stiffness), float(damping)


def _contact_window(trace: DropTrace) -> tuple[float, float, np.ndarray]:
    """Touchdown and lift-off times (interpolated within a step) and the in-contact samples."""
    in_contact = trace.force_n > 0.0
    if not in_contact.any():
        raise RuntimeError("the foot never touched the pad")
    first, last = np.flatnonzero(in_contact)[[0, -1]]
    if last + 1 >= trace.time_s.size:
        raise RuntimeError("the trace ends before the foot leaves the pad")
    # Touchdown: the sole height crosses zero between samples first-1 and first.
    h0, h1 = trace.height_m[first - 1], trace.height_m[first]
    t_touch = trace.time_s[first - 1] + h0 / (h0 - h1) * (trace.time_s[first] - trace.time_s[first - 1])
    # Lift-off: the force falls to zero; extend its last slope by the remaining force.
    f_prev, f_last = trace.force_n[last - 1], trace.force_n[last]
    dt = trace.time_s[last] - trace.time_s[last - 1]
    t_lift = trace.time_s[last] + f_last / (f_prev - f_last) * dt
    return t_touch, t_lift, in_contact


def drop_test(
    mass_kg: float,
    stiffness_n_per_m: float,
    damping_n_s_per_m: float,
    impact_speed_m_s: float,
    params: RigParams | None = None,
) -> DropReport:
    """Drop a lander of ``mass_kg`` on a pad (K, D) at ``impact_speed_m_s`` and compare with Section 2."""
    params = RigParams() if params is None else params
    contact = validate_drop(mass_kg, stiffness_n_per_m, damping_n_s_per_m, impact_speed_m_s, params)
    params = replace(
        params,
        lander=replace(params.lander, mass_kg=mass_kg),
        pad=replace(params.pad, stiffness_n_per_m=stiffness_n_per_m, damping_n_s_per_m=damping_n_s_per_m),
    )
    step = drop_physics_step(contact)
    pad_test = build_pad_test(params, physics_step_s=step)
    trace = simulate_drop(pad_test, impact_speed_m_s, _APPROACH_STEPS * step + 1.2 * contact.contact_time_s)
    t_touch, t_lift, in_contact = _contact_window(trace)
    deformation, rate = -trace.height_m, -trace.velocity_m_s
    fitted_k, fitted_d = fit_spring_damper(deformation[in_contact], rate[in_contact], trace.force_n[in_contact])
    return DropReport(
        mass_kg=mass_kg,
        stiffness_n_per_m=stiffness_n_per_m,
        damping_n_s_per_m=damping_n_s_per_m,
        impact_speed_m_s=impact_speed_m_s,
        contact=contact,
        contact_time_s=Compared(t_lift - t_touch, contact.contact_time_s),
        # In zero field the lander leaves at the speed it has when the force vanishes.
        restitution=Compared(trace.velocity_m_s[-1] / impact_speed_m_s, contact.restitution),
        max_deformation_m=Compared(float(deformation.max()), contact.max_deformation_m(impact_speed_m_s)),
        fitted_stiffness_n_per_m=Compared(fitted_k, stiffness_n_per_m),
        fitted_damping_n_s_per_m=Compared(fitted_d, damping_n_s_per_m),
        trace=trace,
    )


def static_sink(params: RigParams, load_n: float, settle_decays: float = 12.0) -> float:
    """Settled deformation of the pad under the lander pressed down by a constant ``load_n``, m.

    The lander starts at rest on the undeformed pad in zero field; the load is applied as a
    constant force and the pad rings down for ``settle_decays`` decay times 2M/D.
    """
    validate.positive("load", load_n, "N")
    duration = settle_decays * 2.0 * params.lander.mass_kg / params.pad.damping_n_s_per_m
    validate.positive("settling time", duration, "s", _MAX_SIMULATED_S, "settle_decays decay times 2 M / D")
    pad_test = build_pad_test(params)
    model = pad_test.model
    data = mujoco.MjData(model)
    data.qfrc_applied[0] = -load_n
    for _ in range(math.ceil(duration / model.opt.timestep)):
        mujoco.mj_step(model, data)
    return -float(data.qpos[0])
