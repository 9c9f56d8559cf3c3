"""The reproduction's findings: every number :mod:`microg_env.paper.report` states, computed from the
runs of :func:`microg_env.paper.reproduction.compute`, the paper's tables
(:mod:`microg_env.paper.tables`) and the rig's parameters. :func:`findings` is report.json; the
report is rendered from it alone."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import mujoco

from microg_env.analysis.metrics import COMPARED_WINDOW
from microg_env.controllers import load_gains
from microg_env.paper.reproduction import DRIFT_SEEDS, NUMBERS, PADS, PAPER_LIKE_GAINS, READINGS, Reproduction
from microg_env.paper.tables import (
    PUBLISHED,
    WORST_COLLISION_ERROR_PCT,
    WORST_DEFORMATION_ERROR_PCT,
    experiment_relative_error_pct,
)
from microg_env.params import RigParams
from microg_env.scenarios import CONDITIONS
from microg_env.sim.contact import SpringDamperContact
from microg_env.sim.model import flexible_unit
from microg_env.version import __version__


def residuals(rep: Reproduction, pad: str) -> tuple[list[float], list[float]]:
    """The full rig's peak deformation and collision acceleration with ``pad``, % of the experiment."""
    deformation, acceleration = [], []
    for number in NUMBERS:
        metrics, paper = rep.runs[pad, number].metrics, PUBLISHED[number]
        deformation.append(
            experiment_relative_error_pct(metrics.max_deformation_m * 1e3, paper.measured_max_deformation_mm)
        )
        acceleration.append(
            experiment_relative_error_pct(metrics.collision_accel_m_s2 * 1e3, paper.measured_collision_accel_mm_s2)
        )
    return deformation, acceleration


def paper_residuals() -> tuple[list[float], list[float]]:
    """The paper's own simulation against its experiment, % of the experiment."""
    deformation = [
        experiment_relative_error_pct(c.simulated_max_deformation_mm, c.measured_max_deformation_mm)
        for c in PUBLISHED.values()
    ]
    acceleration = [
        experiment_relative_error_pct(c.simulated_collision_accel_mm_s2, c.measured_collision_accel_mm_s2)
        for c in PUBLISHED.values()
    ]
    return deformation, acceleration


def findings(rep: Reproduction) -> dict[str, Any]:
    """Every number the report states, JSON-ready: report.json, from which the report is rendered."""
    deformation, acceleration = residuals(rep, "calibrated")
    paper_deformation, paper_acceleration = paper_residuals()
    ours = deformation + acceleration
    theirs = paper_deformation + paper_acceleration
    return {
        "microg_version": __version__,
        "mujoco_version": mujoco.__version__,
        "controller": rep.controller,
        "seed": rep.seed,
        "duration_s": rep.duration_s,
        "pads": {pad: {"stiffness_n_per_m": k, "damping_n_s_per_m": d} for pad, (k, d) in rep.pads.items()},
        "calibration": {
            **rep.calibration.as_dict(),
            "iterations": rep.calibration.iterations,
            "rms_residual_pct": rep.calibration.rms_residual_pct,
        },
        "simulation_fit": rep.simulation_fit.as_dict(),
        "metrics": {pad: {str(n): rep.runs[pad, n].metrics.as_dict() for n in NUMBERS} for pad in PADS},
        "rig_residuals_pct": {
            pad: dict(zip(("max_deformation", "collision_accel"), residuals(rep, pad), strict=True)) for pad in PADS
        },
        "paper_residuals_pct": {"max_deformation": paper_deformation, "collision_accel": paper_acceleration},
        "calibrated_better_than_paper": [abs(a) < abs(b) for a, b in zip(ours, theirs, strict=True)],
        "calibrated_within_paper_worst_errors": all(abs(v) <= WORST_DEFORMATION_ERROR_PCT for v in deformation)
        and all(abs(v) <= WORST_COLLISION_ERROR_PCT for v in acceleration),
        "paper_like_gains": list(PAPER_LIKE_GAINS),
        "eq17_compensation_error_pct": {
            f"{reading}/{label}": {str(n): rep.eq17[reading, label, n] for n in NUMBERS}
            for reading in READINGS
            for label in ("pid", "ki4000")
        },
        "drift_fifty_gram_stage_error_pct": {"seeds": list(DRIFT_SEEDS), **rep.drift},
        "balancer": balancer(rep),
        "closed_form": closed_form(rep),
        "differences": differences(rep),
    }


def _power_law_exponents() -> tuple[float, float, float]:
    """Exponents n of a contact F ~ d^n implied by the experiments' ratios between conditions 3 and 1.

    Undamped, F = k d^n gives d_max ~ V0^(2/(n+1)) and a_max ~ V0^(2n/(n+1)).
    """
    gravity = RigParams().gravity_m_s2
    mass = RigParams().lander.mass_kg
    speed_ratio = CONDITIONS[3].impact_speed_m_s(mass, gravity) / CONDITIONS[1].impact_speed_m_s(mass, gravity)
    deformation_ratio = PUBLISHED[3].measured_max_deformation_mm / PUBLISHED[1].measured_max_deformation_mm
    acceleration_ratio = PUBLISHED[3].measured_collision_accel_mm_s2 / PUBLISHED[1].measured_collision_accel_mm_s2
    p = math.log(deformation_ratio) / math.log(speed_ratio)  # = 2 / (n + 1)
    q = math.log(acceleration_ratio) / math.log(speed_ratio)  # = 2 n / (n + 1)
    return speed_ratio, 2.0 / p - 1.0, q / (2.0 - q)


def differences(rep: Reproduction) -> dict[str, Any]:
    """Every number the "Differences from the paper" section states, computed from the runs, the
    paper's tables and the rig's parameters (report.json's ``differences``)."""
    t1 = {n: rep.runs["paper", n].metrics for n in NUMBERS}
    errors = [e for n in NUMBERS for e in t1[n].compensation_error_pct]
    excursion = [t1[n].flexible_unit_excursion_collision_m * 1e6 for n in NUMBERS]
    deformation, acceleration = residuals(rep, "calibrated")
    sim_fit = rep.simulation_fit
    (k1, d1), (kc, dc) = rep.pads["paper"], rep.pads["calibrated"]
    speed_ratio, n_deformation, n_acceleration = _power_law_exponents()
    params = RigParams()
    unit = flexible_unit(params)
    omega0_squared = unit.x_stiffness_n_per_m / params.lander.mass_kg
    ki = load_gains(rep.controller).ki_per_s2
    reflected = (params.servo.rotor_inertia_kg_m2 + params.screw.screw_inertia_kg_m2) * params.screw.gear_rad_per_m**2
    stage1 = PUBLISHED[3].measured_descent_accel_mm_s2[0] / (t1[3].ideal_descent_accel_m_s2[0] * 1e3)
    landing1 = SpringDamperContact(params.lander.mass_kg + CONDITIONS[1].stages_kg[-1], k1, d1)
    paper_like = [rep.eq17["literal", "ki4000", n][0] for n in NUMBERS]
    return {
        "descent_error_pct": [min(errors), max(errors)],
        "integral_lag_error_pct": -100 * omega0_squared / (ki + omega0_squared),  # -(k/Ki)/(M + m + k/Ki)
        "ki_per_s2": ki,
        "omega0_squared_per_s2": omega0_squared,
        "paper_like_ki_per_s2": PAPER_LIKE_GAINS[1],
        "paper_like_descent_error_pct": [min(paper_like), max(paper_like)],
        "fifty_gram_error_pct": t1[3].compensation_error_pct[0],
        "fifty_gram_measured_mm_s2": PUBLISHED[3].measured_descent_accel_mm_s2[0],
        "fifty_gram_slow_pct": 100 * (1 - stage1),
        "fifty_gram_disturbance_n": (1 - stage1) * CONDITIONS[3].loads[0].mass_kg * params.gravity_m_s2,
        "collision_excursion_um": excursion,
        "integral_lag_at_collision_um": [t1[n].collision_accel_m_s2 / ki * 1e6 for n in NUMBERS],
        "speed_loop_gain_hz": params.servo.speed_loop_gain_hz,
        "moving_mass_kg": reflected + params.screw.support_mass_kg,
        "instant_change_um": [t1[n].x_change_after_touchdown_m[COMPARED_WINDOW] * 1e6 for n in NUMBERS],
        "force_error_n": max(excursion) * 1e-6 * abs(unit.x_stiffness_n_per_m),
        "deformation_fidelity_pct": max(
            abs(t1[n].max_deformation_m / t1[n].reference_max_deformation_m - 1) * 100 for n in NUMBERS
        ),
        "acceleration_fidelity_pct": max(
            abs(t1[n].collision_accel_m_s2 / t1[n].reference_collision_accel_m_s2 - 1) * 100 for n in NUMBERS
        ),
        "table1_pad": [k1, d1],
        "calibrated_pad": [kc, dc],
        "condition_1_impact_speed_mm_s": t1[1].impact_speed_m_s * 1e3,
        "condition_1_max_deformation_mm": t1[1].max_deformation_m * 1e3,
        "condition_1_collision_accel_mm_s2": t1[1].collision_accel_m_s2 * 1e3,
        "simulation_fit_pad": [sim_fit.stiffness_n_per_m, sim_fit.damping_n_s_per_m],
        "simulation_fit_residuals_pct": [*sim_fit.max_deformation_pct, *sim_fit.collision_accel_pct],
        "simulation_fit_stiffness_ratio": sim_fit.stiffness_n_per_m / k1,
        "calibrated_ratios": [kc / k1, dc / d1],
        "calibrated_worst_pct": [max(abs(v) for v in deformation), max(abs(v) for v in acceleration)],
        "impact_speed_ratio_3_to_1": speed_ratio,
        "measured_ratios_3_to_1": [
            PUBLISHED[3].measured_max_deformation_mm / PUBLISHED[1].measured_max_deformation_mm,
            PUBLISHED[3].measured_collision_accel_mm_s2 / PUBLISHED[1].measured_collision_accel_mm_s2,
        ],
        "power_law_exponents": [n_deformation, n_acceleration],
        "contact_shorter_than_half_period_pct": 100 * (1 - landing1.contact_time_s / landing1.half_period_s),
    }


def closed_form(rep: Reproduction) -> list[dict[str, Any]]:
    """Section 2's closed form beside the rig's first contact, per pad and condition: Eqs. (4), (7),
    (9), (10) and (12) for the rig's own impact speed and mass."""
    rows = []
    for pad in PADS:
        stiffness, damping = rep.pads[pad]
        for number in NUMBERS:
            metrics = rep.runs[pad, number].metrics
            mass = rep.runs[pad, number].trajectory.lander_mass_kg + CONDITIONS[number].stages_kg[-1]
            contact = SpringDamperContact(mass, stiffness, damping)
            speed = metrics.impact_speed_m_s
            rows.append(
                {
                    "pad": pad,
                    "condition": number,
                    "impact_speed_m_s": _json(speed),
                    "half_period_s": contact.half_period_s,
                    "contact_time_s": contact.contact_time_s,
                    "restitution_half_period": contact.restitution_half_period,
                    "restitution": contact.restitution,
                    "max_deformation_m": _json(contact.max_deformation_m(speed) if math.isfinite(speed) else math.nan),
                }
            )
    return rows


def balancer(rep: Reproduction) -> dict[str, Any]:
    """The screw's continuous torque in the rig as built, and with the balancer in parallel with the
    QZS, where the screw carries lander and support: (M + m_s) g / gear."""
    params = RigParams()
    parallel = replace(params, balancer=replace(params.balancer, placement="support_lander"))
    return {
        "servo_rms_torque_n_m": [rep.runs["paper", n].metrics.servo_rms_torque_n_m for n in NUMBERS],
        "rated_torque_n_m": params.servo.rated_torque_n_m,
        "parallel_static_torque_n_m": flexible_unit(parallel).screw_load_n / params.screw.gear_rad_per_m,
    }


def _json(value: float) -> float | None:
    """None for a number a run did not reach (NaN), as the metrics' records store it."""
    return value if math.isfinite(value) else None
