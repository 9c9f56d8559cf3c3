"""Metrics against closed forms, on synthetic trajectories and on the ideal reference."""

import math
import tempfile
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from microg_env.analysis.metrics import compute_metrics, contacts, descent_acceleration, landing, stage_windows
from microg_env.params import RigParams
from microg_env.scenarios import CONDITIONS, LoadStep, Scenario
from microg_env.sim import reference as reference_module
from microg_env.sim.contact import SpringDamperContact
from microg_env.sim.model import build_pad_test
from microg_env.sim.reference import simulate_reference
from microg_env.trajectory import CHANNELS, Trajectory

DT = 1e-3
SCENARIO = Scenario("synthetic", (LoadStep(0.49),), descent_height_m=0.09)
THREE_STAGES = Scenario("three", (LoadStep(0.05), LoadStep(0.5, 0.04), LoadStep(0.5, 0.02)), descent_height_m=0.09)
PARAMS = RigParams()


def _reference(scenario: Scenario, duration_s: float) -> Trajectory:
    return simulate_reference(scenario, PARAMS, 1e-3, 1e-4, duration_s)


def _trajectory(time, height, velocity, accel, force, stage=None) -> Trajectory:
    stage = np.zeros(time.size, dtype=int) if stage is None else stage
    return Trajectory.from_channels(
        SCENARIO,
        9.8009,
        620.0,
        time_s=time,
        foot_height_m=height,
        lander_velocity_m_s=velocity,
        lander_accel_m_s2=accel,
        pad_force_n=force,
        stage=stage,
    )


def _free_contact(speed: float = 0.04, approach_s: float = 0.5, after_s: float = 2.0) -> Trajectory:
    """Flight at constant speed, the Section 2 contact, flight at the exit speed (no field)."""
    contact = SpringDamperContact(620.0, 4666.0, 200.0)
    t = np.arange(0.0, approach_s + contact.contact_time_s + after_s, DT)
    tc = t - approach_s
    during = (tc >= 0) & (tc <= contact.contact_time_s)
    after = tc > contact.contact_time_s
    d = np.where(during, contact.deformation(np.clip(tc, 0, None), speed), 0.0)
    rate = np.where(during, contact.deformation_rate(np.clip(tc, 0, None), speed), 0.0)
    exit_speed = contact.restitution * speed
    d_end = contact.deformation(contact.contact_time_s, speed)
    height = np.where(tc < 0, -speed * tc, -d)
    height = np.where(after, -d_end + exit_speed * (tc - contact.contact_time_s), height)
    velocity = np.where(tc < 0, -speed, -rate)
    velocity = np.where(after, exit_speed, velocity)
    force = np.where(during, np.maximum(contact.force(d, rate), 0.0), 0.0)
    return _trajectory(t, height, velocity, force / 620.0, force)


def test_descent_acceleration_of_a_parabola():
    t = np.arange(0.0, 3.0, DT)
    height = 0.09 + 0.001 * t - 0.5 * 0.00774 * t**2
    traj = _trajectory(t, height, np.gradient(height, t), np.zeros_like(t), np.zeros_like(t))
    assert descent_acceleration(traj, (100, t.size)) == pytest.approx(-0.00774, rel=1e-9)


def test_contact_metrics_of_the_section_2_contact():
    contact = SpringDamperContact(620.0, 4666.0, 200.0)
    traj = _free_contact(speed=0.04)
    (found,) = contacts(traj)
    assert found.touchdown_s == pytest.approx(0.5, abs=1e-9)
    first = landing(traj)
    assert first.contact_time_s == pytest.approx(contact.contact_time_s, abs=2 * DT)
    assert first.restitution == pytest.approx(contact.restitution, rel=1e-3)
    assert first.impact_speed_m_s == pytest.approx(0.04)
    assert first.max_deformation_m == pytest.approx(contact.max_deformation_m(0.04), rel=1e-4)
    assert first.collision_accel_m_s2 == pytest.approx(contact.max_deceleration_m_s2(0.04), rel=1e-4)
    assert math.isnan(first.rebound_apex_s)  # still rising when the trajectory ends
    assert math.isnan(first.rebound_height_m)
    assert "apex" in first.unavailable["rebound_height_m"]


def test_stage_windows_skip_the_settling_and_stop_at_touchdown():
    t = np.arange(0.0, 4.0, DT)
    stage = (t >= 1.0).astype(int)
    traj = _trajectory(t, np.full_like(t, 0.05), np.zeros_like(t), np.zeros_like(t), np.zeros_like(t), stage)
    (a0, a1), (b0, b1), never = stage_windows(replace(traj, scenario=THREE_STAGES), touchdown_index=3000)
    assert never is None
    assert t[a0] == pytest.approx(0.2)
    assert a1 == 1000
    assert t[b0] == pytest.approx(1.2)
    assert b1 == 3000


@pytest.mark.parametrize("number", [1, 2, 3])
@pytest.mark.slow
def test_reference_falls_at_the_ideal_acceleration_of_each_stage(number):
    scenario = CONDITIONS[number]
    reference = _reference(scenario, 20.0)
    metrics = compute_metrics(reference, reference)
    for measured, ideal in zip(metrics.descent_accel_m_s2, metrics.ideal_descent_accel_m_s2, strict=True):
        assert measured == pytest.approx(ideal, rel=1e-6)
    assert metrics.reference_rms_height_error_m == 0.0
    assert metrics.max_deformation_m == metrics.reference_max_deformation_m
    # The foot meets the pad at the speed of the ideal free fall: v^2 = 2 sum(a_i h_i).
    heights = [scenario.descent_height_m] + [load.height_m for load in scenario.loads[1:]] + [0.0]
    drops = -np.diff(heights)
    expected = math.sqrt(2.0 * sum(-a * h for a, h in zip(metrics.ideal_descent_accel_m_s2, drops, strict=True)))
    assert metrics.impact_speed_m_s == pytest.approx(expected, rel=1e-3)


def test_metrics_json_has_the_required_keys_and_no_nan(run_json_keys):
    reference = _reference(CONDITIONS[1], 3.0)  # ends before touchdown
    result = compute_metrics(reference, reference).as_dict()
    assert run_json_keys <= set(result)
    assert result["max_deformation_m"] is None  # never landed: null, not NaN
    assert result["unavailable"]["max_deformation_m"] == "the run ended before the first touchdown"
    assert isinstance(result["descent_accel_m_s2"], list)


def test_a_run_ending_on_the_pad_reports_no_landing_and_a_clean_descent():
    """A run cut off during the first contact: the descent is fitted up to the touchdown only, and
    every contact metric is null with its reason (it was -11.6 % and a wrong landing before)."""
    full = compute_metrics(_reference(CONDITIONS[1], 12.0), _reference(CONDITIONS[1], 12.0))
    cut = compute_metrics(_reference(CONDITIONS[1], 5.5), _reference(CONDITIONS[1], 5.5))
    assert cut.compensation_error_pct[0] == pytest.approx(full.compensation_error_pct[0], abs=1e-6)
    for name in ("max_deformation_m", "collision_accel_m_s2", "contact_time_s", "restitution"):
        assert math.isnan(getattr(cut, name))
        assert cut.unavailable[name] == "the run ended before the first lift-off"
    assert cut.impact_speed_m_s == pytest.approx(full.impact_speed_m_s)
    assert cut.unavailable["flexible_unit_excursion_collision_m"] == "the run ended before the first lift-off"


def test_a_free_fall_too_short_to_fit_is_null_with_its_reason():
    scenario = Scenario("low", (LoadStep(0.49),), descent_height_m=0.0005)  # 0.5 mm: on the pad in 0.36 s
    metrics = compute_metrics(_reference(scenario, 5.0), _reference(scenario, 5.0))
    assert math.isnan(metrics.compensation_error_pct[0])
    assert "under the 1 s a descent fit needs" in metrics.unavailable["descent_accel_m_s2[0]"]


def test_every_null_per_stage_metric_has_its_reason():
    scenario = Scenario("low", (LoadStep(0.49),), descent_height_m=0.0005)
    metrics = compute_metrics(_reference(scenario, 5.0), _reference(scenario, 5.0))
    for name in ("descent_accel_m_s2", "compensation_error_pct", "residual_gravity_g", "microgravity_level_g"):
        assert math.isnan(getattr(metrics, name)[0])
        assert "descent fit needs" in metrics.unavailable[f"{name}[0]"]


def test_weights_placed_together_are_not_called_never_reached():
    scenario = Scenario("together", (LoadStep(0.25), LoadStep(0.24)), descent_height_m=0.09)
    metrics = compute_metrics(_reference(scenario, 4.0), _reference(scenario, 4.0))
    assert "placed together with the next" in metrics.unavailable["descent_accel_m_s2[0]"]
    assert metrics.descent_accel_m_s2[1] == pytest.approx(metrics.ideal_descent_accel_m_s2[1], rel=1e-6)


def test_a_reference_cut_from_a_longer_one_is_the_one_simulated_alone():
    """References are kept and a shorter one cut from a longer one: bit for bit what simulating it
    alone gives, in new arrays (a caller writing into one cannot change the kept one)."""
    scenario = CONDITIONS[3]
    reference_module._kept.clear()
    alone = simulate_reference(scenario, PARAMS, 1e-3, 1e-4, 2.5)
    reference_module._kept.clear()
    longer = simulate_reference(scenario, PARAMS, 1e-3, 1e-4, 6.0)
    cut = simulate_reference(scenario, PARAMS, 1e-3, 1e-4, 2.5)
    assert len(cut) == len(alone) == 2501
    assert len(longer) == 6001
    for name in CHANNELS:
        assert np.array_equal(getattr(cut, name), getattr(alone, name)), name
    cut.x_m[:] = 1.0
    cut.foot_height_m[:] = 1.0
    again = simulate_reference(scenario, PARAMS, 1e-3, 1e-4, 2.5)
    assert np.array_equal(again.foot_height_m, alone.foot_height_m)


def test_a_run_cut_shorter_reuses_the_reference_of_its_whole_schedule(monkeypatch):
    """A run given a duration has a schedule of that duration; its reference is cut from the kept
    one of the whole schedule (microg reproduce re-simulated 4 of its 10 references)."""
    scenario = CONDITIONS[1]
    reference_module._kept.clear()
    whole = simulate_reference(scenario, PARAMS, 1e-3, 1e-4, 3.0)
    monkeypatch.setattr(reference_module, "_simulate", lambda *args: pytest.fail("simulated again"))
    cut = simulate_reference(replace(scenario, duration_s=2.0), PARAMS, 1e-3, 1e-4, 2.0)
    assert np.array_equal(cut.foot_height_m, whole.foot_height_m[:2001])


def test_the_reference_key_holds_every_parameter_the_reference_model_reads():
    """Parameters left out of the reference's key (the QZS but its stroke, the balancer, the drive,
    the sensors, the drift) must not change the lander-and-pad model; those in it must."""
    base = RigParams()
    others = replace(
        base,
        qzs=replace(base.qzs, residual_stiffness_n_per_m=-base.qzs.residual_stiffness_n_per_m, guide_friction_n=0.1),
        balancer=replace(base.balancer, placement="support_lander"),
        servo=replace(base.servo, cogging_torque_n_m=0.0, speed_loop_gain_hz=50.0),
        sensors=replace(base.sensors, ruler_noise_m=1e-7),
        drift=replace(base.drift, max_temperature_rate_k_per_s=0.0),
    )
    key = reference_module.reference_key
    assert key(CONDITIONS[1], others, 1e-3, 1e-4) == key(CONDITIONS[1], base, 1e-3, 1e-4)

    def saved(params: RigParams) -> bytes:
        path = Path(tempfile.mkdtemp()) / "pad.mjb"
        mujoco.mj_saveModel(build_pad_test(params).model, str(path))
        return path.read_bytes()

    assert saved(others) == saved(base)
    heavier = replace(base, lander=replace(base.lander, mass_kg=600.0))
    assert key(CONDITIONS[1], heavier, 1e-3, 1e-4) != key(CONDITIONS[1], base, 1e-3, 1e-4)
    assert saved(heavier) != saved(base)


def test_the_papers_instant_of_collision_change_is_read_from_the_touchdown():
    """x ramps at 1 um/ms from the touchdown on, after sitting at 3 um: the change over the first
    5 and 10 ms is 5 and 10 um whatever the offset (max |x| over the contact would be 3 um plus
    the whole ramp); a run that ends 7 ms after the touchdown has the 5 ms value only."""
    base = _free_contact()
    touchdown = contacts(base)[0].touchdown_s
    x = 3e-6 + np.clip(base.time_s - touchdown, 0.0, None) * 1e-3
    ramp = replace(base, x_m=x)
    metrics = compute_metrics(ramp, base)
    np.testing.assert_allclose(metrics.x_change_after_touchdown_m, [5e-6, 10e-6], rtol=1e-9)
    assert metrics.flexible_unit_excursion_collision_m > 1e-4
    keep = ramp.time_s <= touchdown + 7e-3
    short = Trajectory.from_channels(SCENARIO, 9.8009, 620.0, **{name: getattr(ramp, name)[keep] for name in CHANNELS})
    cut = compute_metrics(short, base)
    assert cut.x_change_after_touchdown_m[0] == pytest.approx(5e-6, rel=1e-9)
    assert math.isnan(cut.x_change_after_touchdown_m[1])
    assert "x_change_after_touchdown_m[1]" in cut.unavailable
