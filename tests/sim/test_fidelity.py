"""The fidelity review's findings, each measured on the full rig (conditions of Table 2, the PID).

Each test fails on the model before the review: the drive's dithered reference, the chattering
ideal drive, results that moved with the physics step, frictionless-looking guide friction, a
restoring reading of Eq. (17) that cannot give the paper's fast descents, and a balancer drift
ten times too slow.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from microg_env import Imperfections
from microg_env.analysis.metrics import MEASURED_METRICS, RunMetrics
from microg_env.controllers import PID, load_gains, make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.params import PHYSICS_STEP_S, BalancerParams, QZSParams, RigParams
from microg_env.rollout.episode import run_with_metrics
from microg_env.scenarios import CONDITIONS
from microg_env.sim.model import flexible_unit

#: Condition 3 up to the end of its 50 g stage (the foot reaches 25 mm after ~8.7 s).
STAGE_1_S = 8.5


def _run(condition: int = 3, duration_s: float | None = None, seed: int = 0, **kwargs) -> RunMetrics:
    env = MicroGravityLandingEnv(condition=condition, **kwargs)
    return run_with_metrics(
        env, make_controller("pid", env.settings.control_period_s), seed=seed, duration_s=duration_s
    )[2]


@pytest.mark.slow
def test_ideal_rig_lands_as_the_ideal_microgravity_reference():
    """Every imperfection off: an ideal drive (no lag, no chatter). The landing matches the
    reference to 0.1 %; the descent differs from it only by the PID's own integral lag x = a/Ki,
    (k/Ki) / (M + m + k/Ki) in closed form, which no drive can remove. The old near-ideal drive
    chattered and landed 0.24 % off."""
    metrics = _run(1, 12.0, imperfections=Imperfections.none())
    assert metrics.max_deformation_m == pytest.approx(metrics.reference_max_deformation_m, rel=1e-3)
    # The collision: its peak per unit of impact speed (the linear pad's constant) differs only by
    # the QZS force k x the PID lets through while x lags (~0.6 N of a 58 N peak).
    reference_speed = CONDITIONS[1].impact_speed_m_s(620.0, RigParams().gravity_m_s2)
    assert metrics.collision_accel_m_s2 / metrics.impact_speed_m_s == pytest.approx(
        metrics.reference_collision_accel_m_s2 / reference_speed, rel=5e-3
    )
    k = flexible_unit(RigParams()).x_stiffness_n_per_m
    lag = k / load_gains("pid").ki_per_s2
    expected = -100.0 * lag / (620.0 + 0.49 + lag)
    assert metrics.compensation_error_pct[0] == pytest.approx(expected, abs=0.05)


def test_ideal_rig_with_the_feedforward_matches_the_reference_within_0_05_percent():
    """What the PID's integral lag keeps from the ideal rig, the nominal model's feed-forward
    removes: every imperfection off, |compensation error| <= 0.05 % and the peak deformation within
    0.1 % of the ideal-microgravity reference."""
    env = MicroGravityLandingEnv(condition=1, imperfections=Imperfections.none())
    metrics = run_with_metrics(
        env, make_controller("feedforward", env.settings.control_period_s), seed=0, duration_s=12.0
    )[2]
    assert abs(metrics.compensation_error_pct[0]) <= 0.05
    assert metrics.max_deformation_m == pytest.approx(metrics.reference_max_deformation_m, rel=1e-3)


@pytest.mark.parametrize("condition", [1, 3])
@pytest.mark.slow
def test_metrics_at_the_default_physics_step_are_converged(condition):
    """Within 1 % (compensation errors within 0.02 percentage points) of a step four times finer.

    The RMS height error to the reference's rebound apex integrates the descent error over the
    fall, t^2 / 2 x a x (error): in condition 3 the QZS guide's friction holds the 50 g stage's
    error near zero, and the 0.005 pp by which it moves (well within 0.02 pp) moves a ~20 um RMS by
    more than 1 %. There the RMS must move by no more than that descent difference explains.
    """
    duration = {1: 12.0, 3: 20.0}[condition]  # through the apex of the first rebound
    env = MicroGravityLandingEnv(condition=condition)
    trajectory, _, coarse = run_with_metrics(env, make_controller("pid", 1e-3), seed=0, duration_s=duration)
    fine = _run(condition, duration, physics_step_s=PHYSICS_STEP_S / 4)
    for name in MEASURED_METRICS:
        a, b = getattr(coarse, name), getattr(fine, name)
        pairs = zip(a, b, strict=True) if isinstance(a, list) else [(a, b)]
        for x, y in pairs:
            if name == "compensation_error_pct":
                assert x == pytest.approx(y, abs=0.02), name
            elif name == "x_change_after_touchdown_m":
                # The first milliseconds of contact resolve the touchdown's place in the step: 1.5 % (5 ms)
                # and 0.4 % (10 ms) for condition 1, 4.4 % and 2.0 % for condition 3 (issue #20, item 1).
                assert x == pytest.approx(y, rel=0.05), name
            elif name != "reference_rms_height_error_m":
                assert x == pytest.approx(y, rel=0.01), name
    explained = 0.0  # height difference the descent differences make by the end of each stage, m
    for stage, (a, b, ideal) in enumerate(
        zip(coarse.compensation_error_pct, fine.compensation_error_pct, coarse.ideal_descent_accel_m_s2, strict=True)
    ):
        seconds = np.ptp(trajectory.time_s[trajectory.stage == stage])
        explained += 0.5 * abs(ideal) * abs(a - b) / 100 * seconds**2
    rms_change = abs(coarse.reference_rms_height_error_m - fine.reference_rms_height_error_m)
    assert rms_change <= 0.01 * fine.reference_rms_height_error_m + explained


@pytest.mark.slow
def test_guide_friction_measurably_changes_the_50_g_stage():
    """The drive's old dither averaged the guide's friction away; now it acts."""
    with_friction = _run(3, STAGE_1_S)
    no_guide_friction = replace(
        RigParams(), qzs=replace(QZSParams(), guide_friction_n=0.0, guide_static_friction_n=0.0)
    )
    without = _run(3, STAGE_1_S, params=no_guide_friction)
    assert abs(with_friction.compensation_error_pct[0] - without.compensation_error_pct[0]) > 0.05


def test_eq17_read_literally_gives_the_papers_fast_descent():
    """Table 3's simulated descents are 1.22-1.45 % faster than ideal. Eq. (17) read literally (a
    negative residual stiffness) with an integral gain of 4000 s^-2 falls that fast; the restoring
    reading can only fall slow."""
    gains = replace(load_gains("pid"), kp_per_s=88.0, ki_per_s2=4000.0)  # zeta 0.7 at Ki = 4000
    errors = {}
    for sign in (-1.0, 1.0):
        params = replace(RigParams(), qzs=replace(QZSParams(), residual_stiffness_n_per_m=sign * 35510.0))
        env = MicroGravityLandingEnv(condition=1, params=params)
        errors[sign] = run_with_metrics(env, PID(gains, 1e-3), seed=0, duration_s=4.5)[2].compensation_error_pct[0]
    assert 1.2 <= errors[-1.0] <= 1.6
    assert errors[1.0] < 0.0


@pytest.mark.slow
def test_balancer_drift_reaches_the_lander_only_when_the_balancer_carries_it():
    """A 0.5 K/h hall drifts the gas at 1.4e-4 K/s (the old premise, 1e-5, ignored that a lag
    delays a ramp without slowing it). Between frame and support the drive absorbs the drift; in
    parallel with the QZS it shifts the 50 g stage by percent from seed to seed."""
    spreads = {}
    for placement in ("frame_support", "support_lander"):
        params = replace(RigParams(), balancer=BalancerParams(placement=placement))
        errors = [_run(3, STAGE_1_S, seed=seed, params=params).compensation_error_pct[0] for seed in range(3)]
        spreads[placement] = max(errors) - min(errors)
    assert RigParams().drift.max_temperature_rate_k_per_s == pytest.approx(0.5 / 3600)
    assert spreads["support_lander"] > 1.0
    assert spreads["frame_support"] < 0.3


@pytest.mark.slow
def test_pid_is_robust_with_every_gain_doubled():
    """The tuning's gain margin: with the torque filter the old gains (Kp 198, Ki 20000) were not."""
    for name in ("pid", "pid-dom"):
        gains = load_gains(name)
        doubled = replace(gains, kp_per_s=2 * gains.kp_per_s, ki_per_s2=2 * gains.ki_per_s2, kd=2 * gains.kd)
        env = MicroGravityLandingEnv(condition=2)
        controller = PID(doubled, 1e-3, derivative_on_measurement=name == "pid-dom")
        metrics = run_with_metrics(env, controller, seed=0, duration_s=12.0)[2]
        assert metrics.termination_reason is None
        assert math.isfinite(metrics.flexible_unit_excursion_collision_m)
        assert metrics.flexible_unit_excursion_collision_m < 100e-6


@pytest.mark.slow
def test_stiff_pads_are_rejected_before_they_can_create_energy():
    stiff = CONDITIONS[1]
    params = replace(RigParams(), pad=replace(RigParams().pad, stiffness_n_per_m=1e9, damping_n_s_per_m=1e5))
    with pytest.raises(ValueError, match="physics_step_s <="):
        MicroGravityLandingEnv(scenario=stiff, params=params)
    # The stiffest pad the default step accepts lands without gaining energy.
    accepted = replace(RigParams(), pad=replace(RigParams().pad, stiffness_n_per_m=1.4e7, damping_n_s_per_m=600.0))
    metrics = _run(1, 12.0, params=accepted)  # through the rebound's apex
    assert metrics.rebound_height_m < CONDITIONS[1].descent_height_m
    assert 0.0 < metrics.restitution < 1.0
    assert np.isfinite(metrics.max_deformation_m)
