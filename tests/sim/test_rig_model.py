"""The rig model: MJCF files, parameter plumbing, flexible unit, drive, per-episode field values."""

from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from microg_env.params import (
    GRAVITY_M_S2,
    PHYSICS_STEP_S,
    BalancerParams,
    LanderParams,
    PadParams,
    QZSParams,
    RigParams,
    ServoParams,
)
from microg_env.sim.follower import PerfectFollower
from microg_env.sim.model import (
    DRIVE_SCHEMES,
    EPISODE_PARAMETERS,
    TEMPLATE_LOADS,
    build_rig,
    flexible_unit,
    mjcf_dir,
    speed_loop_gains,
)
from microg_env.validate import FieldError

MJCF_FILES = sorted(Path(mjcf_dir()).glob("*.xml"))


def _step_randomly(model: mujoco.MjModel, seconds: float, seed: int = 0) -> mujoco.MjData:
    data = mujoco.MjData(model)
    if model.nkey:
        mujoco.mj_resetDataKeyframe(model, data, 0)
    rng = np.random.default_rng(seed)
    while data.time < seconds:
        data.ctrl[:] = data.ctrl + rng.normal(0.0, 1.0, model.nu)
        mujoco.mj_step(model, data)
    return data


def _warnings(data: mujoco.MjData) -> list[str]:
    return [mujoco.mjtWarning(i).name for i, w in enumerate(data.warning) if w.number]


@pytest.mark.parametrize("path", MJCF_FILES, ids=lambda p: p.name)
def test_mjcf_file_compiles_and_steps_without_warning(path):
    model = mujoco.MjModel.from_xml_path(str(path))
    data = _step_randomly(model, 1.0)
    assert _warnings(data) == []
    assert np.all(np.isfinite(data.qpos))


def test_mjcf_folder_holds_scene_and_rig():
    names = {p.name for p in Path(mjcf_dir()).iterdir()}
    assert {"scene.xml", "rig.xml"} <= names


def test_built_rig_steps_without_warning():
    rig = build_rig(loads_kg=(0.05, 0.49, 1.0))
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    rng = np.random.default_rng(1)
    reference = float(data.ctrl[0])
    while data.time < 1.0:
        reference = rig.drive(data, reference, rng.uniform(-1.25, 1.25) * rig.gear, 10)
    assert _warnings(data) == []


def test_template_matches_default_parameters():
    """rig.xml's geometry and masses are the params defaults (params.py is the source of truth)."""
    raw = mujoco.MjModel.from_xml_path(str(Path(mjcf_dir()) / "scene.xml"))
    built = build_rig(loads_kg=tuple(TEMPLATE_LOADS.values())).model
    for body in ("lander", "floating_support"):
        assert raw.body(body).mass == pytest.approx(built.body(body).mass)
    for geom in ("foot", "foot_plate", "pad", "pad_block"):
        np.testing.assert_allclose(raw.geom(geom).size, built.geom(geom).size)
        np.testing.assert_allclose(raw.geom(geom).pos, built.geom(geom).pos)
    for joint in ("screw", "qzs"):
        np.testing.assert_allclose(raw.joint(joint).range, built.joint(joint).range)
    assert raw.opt.timestep == built.opt.timestep == PHYSICS_STEP_S
    np.testing.assert_allclose(raw.opt.gravity, built.opt.gravity)
    assert raw.tendon("balancer").id == built.tendon("balancer").id
    assert raw.wrap_objid[raw.tendon_adr[0]] == raw.joint("screw").id  # frame-support placement
    assert sorted(raw.body(name).mass[0] for name in TEMPLATE_LOADS) == pytest.approx(sorted(TEMPLATE_LOADS.values()))


def test_parameters_reach_the_model():
    params = RigParams(
        lander=LanderParams(mass_kg=500.0),
        pad=PadParams(stiffness_n_per_m=9000.0),
        qzs=QZSParams(residual_stiffness_n_per_m=20000.0, guide_friction_n=0.3, guide_static_friction_n=0.4),
    )
    default, changed = build_rig().model, build_rig(params).model
    assert changed.body("lander").mass[0] == 500.0
    assert changed.jnt_stiffness[changed.joint("qzs").id] == 20000.0
    guide = changed.actuator("guide_friction").id
    assert changed.actuator_biasprm[guide, 3:5] == pytest.approx([0.3, 0.4])
    ratio = changed.geom_solref[changed.geom("pad").id, 0] / default.geom_solref[default.geom("pad").id, 0]
    assert ratio == pytest.approx((9000.0 / 500.0) / (4666.0 / 620.0))


@pytest.mark.parametrize("placement", ["frame_support", "support_lander"])
@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_flexible_unit_carries_the_lander_at_x_zero_with_eq17_stiffness(placement, sign):
    """QZS (and the balancer where it acts on x) carry M g at x = 0; the screw carries the rest."""
    params = replace(
        RigParams(),
        qzs=QZSParams(residual_stiffness_n_per_m=sign * 35510.0),
        balancer=BalancerParams(placement=placement),
    )
    rig = build_rig(params, loads_kg=(1.0,))
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    weight = params.lander.mass_kg * GRAVITY_M_S2
    support_weight = params.screw.support_mass_kg * GRAVITY_M_S2
    assert data.qfrc_passive[rig.qzs_dof] == pytest.approx(weight, rel=1e-9)
    unit = flexible_unit(params)
    # The screw dof carries lander and support; the balancer takes all of it in the frame-support placement.
    screw_passive = data.qfrc_passive[rig.screw_dof] + data.qfrc_passive[rig.qzs_dof] - weight
    expected = weight + support_weight if placement == "frame_support" else 0.0
    assert screw_passive + weight == pytest.approx(expected + weight, rel=1e-9)
    assert unit.screw_load_n == pytest.approx(weight + support_weight - expected, abs=1e-9)
    # Displacing x shows the signed residual stiffness: Eq. (17), plus the gas spring if in parallel.
    data.qpos[rig.qzs_qpos] = 1e-3
    mujoco.mj_forward(rig.model, data)
    stiffness = (weight - data.qfrc_passive[rig.qzs_dof]) / 1e-3
    gas = unit.balancer_stiffness_n_per_m if placement == "support_lander" else 0.0
    assert stiffness == pytest.approx(sign * 35510.0 + gas, rel=1e-6)
    assert stiffness == pytest.approx(unit.x_stiffness_n_per_m, rel=1e-6)


def test_screw_continuous_torque_by_balancer_placement():
    """Between frame and support the balancer leaves the screw almost nothing to hold; in parallel
    with the QZS the screw holds lander and support, 107 % of the 48 N m rated torque."""
    for placement, low, high in (("frame_support", 0.0, 0.01), ("support_lander", 1.06, 1.08)):
        params = replace(RigParams(), balancer=BalancerParams(placement=placement))
        rig = build_rig(params, loads_kg=(0.49,))
        data = mujoco.MjData(rig.model)
        rig.reset(data, 0.09)
        reference = float(data.ctrl[0])
        for _ in range(500):  # hold still for 0.5 s
            reference = rig.drive(data, reference, 0.0, 10)
        assert low <= abs(data.actuator_force[0]) / params.servo.rated_torque_n_m <= high


@pytest.mark.parametrize("loads", [(0.49,), (1.0,), (0.05,), (0.05, 1.0)])
@pytest.mark.slow
def test_ideal_following_gives_the_ideal_descent(loads):
    """x held at 0 by the support: the lander falls at m_ext g / (M + m_ext) (Table 2)."""
    rig = build_rig(loads_kg=loads)
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    rig.place_loads([True] * len(loads))
    follower = PerfectFollower(rig)
    times, heights = [], []
    while data.time < 3.0 and rig.foot_height(data) > 0.005:
        follower.step(data)
        times.append(data.time)
        heights.append(rig.foot_height(data))
        assert data.qpos[rig.qzs_qpos] == 0.0
    accel = 2.0 * np.polyfit(times, heights, 2)[0]
    mass = sum(loads)
    ideal = -mass * GRAVITY_M_S2 / (620.0 + mass)
    assert accel == pytest.approx(ideal, rel=0.005)


def test_drive_interpolates_its_position_reference_without_dither():
    """At a constant speed the drive's reference ramps through the control period and its torque
    changes smoothly between physics steps. Holding the reference at the period's mean (the old
    drive) made the torque alternate at every physics step (+-0.14 N m in condition 3)."""
    rig = build_rig(loads_kg=(0.05,))
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.2)
    speed, dt = -0.02 * rig.gear, rig.model.opt.timestep  # 20 mm/s down
    reference = float(data.ctrl[0])
    for _ in range(300):  # 0.3 s: settle into the ramp
        reference = rig.drive(data, reference, speed, 10)
    torques, lags = [], []
    for _ in range(300):  # one physics step per call: the reference at the end of every step
        reference = rig.drive(data, reference, speed, 1)
        lags.append(float(data.act[rig.reference_act]) - reference)
        torques.append(float(data.actuator_force[0]))
    assert np.max(np.abs(lags)) < 1e-6 * abs(speed * dt)  # the ramp: exactly speed x step per step
    signs = np.sign(np.diff(torques))
    assert np.mean(signs[1:] != signs[:-1]) < 0.2  # no alternation between consecutive steps
    assert np.max(np.abs(np.diff(torques, 2))) < 0.02  # N m


def test_ideal_drive_follows_the_speed_reference_exactly():
    # A restoring QZS keeps the uncontrolled lander near x = 0 (Eq. 17's literal sign would let it
    # drift to the guide's end stop, whose impact would load the drive).
    params = replace(RigParams(), qzs=QZSParams(residual_stiffness_n_per_m=35510.0))
    rig = build_rig(params, loads_kg=(0.49,), ideal_drive=True)
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.2)
    start = data.qpos[rig.screw_qpos]
    speeds = np.concatenate([np.full(300, -0.02), np.full(300, 0.015), np.zeros(300)])
    torques = []
    for speed in speeds:
        rig.drive(data, 0.0, speed * rig.gear, 10)
        assert data.qvel[rig.screw_dof] == pytest.approx(speed, abs=1e-7)
        torques.append(float(data.actuator_force[0]))
    travelled = data.qpos[rig.screw_qpos] - start
    assert travelled == pytest.approx(np.sum(speeds) * 1e-3, abs=1e-7)  # the reference, integrated
    # No chatter: within a constant-speed stretch the torque does not alternate.
    steady = np.diff(torques[350:590])
    assert np.mean(np.sign(steady[1:]) != np.sign(steady[:-1])) < 0.5


def test_torque_filter_is_a_first_order_lag():
    params = replace(
        RigParams(), servo=replace(ServoParams(), cogging_torque_n_m=0.0, bristle_stiffness_n_m_per_rad=0.0)
    )
    rig = build_rig(params)
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.2)
    kp, _ = speed_loop_gains(params)
    data.qpos[rig.screw_qpos] += 1e-4 / rig.gear  # a step of position error: commanded torque kp * 1e-4
    commanded = -kp * 1e-4
    torques = []
    for _ in range(30):
        mujoco.mj_step(rig.model, data)
        torques.append(float(data.actuator_force[0]))
    # After one time constant (1 ms = 10 steps) the torque has reached ~63 % of its (moving) command.
    assert 0.5 < torques[9] / commanded < 0.75
    assert abs(torques[0]) < 0.15 * abs(commanded)


def test_servo_torque_saturates_at_the_peak_torque():
    # Cogging and friction add to the motor's own torque; remove them to see the drive's limit.
    quiet = replace(ServoParams(), cogging_torque_n_m=0.0, bristle_stiffness_n_m_per_rad=0.0)
    params = replace(RigParams(), servo=quiet)
    rig = build_rig(params)
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    step = float(data.ctrl[0]) - 1.0 * rig.gear  # a 1 m position step down
    data.ctrl[0] = data.act[rig.reference_act] = step
    peak = 0.0
    for _ in range(300):
        mujoco.mj_step(rig.model, data)
        peak = max(peak, abs(data.actuator_force[0]))
    assert peak == pytest.approx(params.servo.peak_torque_n_m, rel=1e-9)


@pytest.mark.parametrize(
    ("loads", "word"),
    [((-0.05,), "load 0"), ((float("nan"),), "load 0"), ((0.05, 7.0), "1e-2 g")],
)
def test_bad_loads_are_named(loads, word):
    with pytest.raises(ValueError, match=word):
        build_rig(loads_kg=loads)


def test_placing_a_load_adds_its_mass_and_keeps_the_pad_law():
    params = RigParams()
    rig = build_rig(params, loads_kg=(0.05, 1.0))
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.055)
    carried = [rig.model.body("lander").id, *rig.load_bodies]
    assert rig.model.body_mass[carried].sum() == pytest.approx(620.0)
    rig.place_loads([True, False])
    assert rig.model.body_mass[carried].sum() == pytest.approx(620.05)
    assert rig.placed_load_kg == pytest.approx(0.05)
    # The pad's physical stiffness stays K: solref (acceleration units) times the mass it moves.
    solref = rig.model.geom_solref[rig.model.geom("pad").id, 0]
    n, d = rig.pad_contacts, params.pad.impedance
    assert -solref * n * 620.05 / (1 + (n - 1) * d) == pytest.approx(params.pad.stiffness_n_per_m)


def test_episode_fields_equal_a_fresh_build():
    """Reconfiguring a built rig (what a reset does) gives exactly the model built for those values."""
    base = RigParams()
    drawn = replace(
        base,
        lander=replace(base.lander, mass_kg=611.0),
        pad=replace(base.pad, stiffness_n_per_m=5100.0, damping_n_s_per_m=170.0),
        qzs=replace(base.qzs, guide_friction_n=0.17, guide_static_friction_n=0.21, guide_damping_n_s_per_m=40.0),
        servo=replace(
            base.servo,
            coulomb_torque_n_m=0.5,
            static_torque_n_m=0.7,
            stribeck_speed_rad_s=0.4,
            bristle_stiffness_n_m_per_rad=7000.0,
            bristle_damping_n_m_s_per_rad=8.0,
            cogging_torque_n_m=0.3,
            cogging_phase_rad=1.1,
            speed_loop_gain_hz=90.0,
            torque_filter_s=1.2e-3,
        ),
    )
    changed = {path.split(".")[0] for path in EPISODE_PARAMETERS}
    assert changed <= {"lander", "pad", "qzs", "servo"}
    held = np.zeros(2, dtype=bool)
    rig = build_rig(base, loads_kg=(0.05, 1.0))
    rig.write(rig.episode_fields(drawn, (0.052, 0.97), held, 0.0))
    fresh = build_rig(drawn, loads_kg=(0.052, 0.97))
    fresh.write(fresh.episode_fields(drawn, (0.052, 0.97), held, 0.0))  # both with their weights held
    for name in ("body_mass", "body_inertia", "geom_solref", "qpos_spring", "tendon_stiffness", "tendon_lengthspring"):
        np.testing.assert_allclose(getattr(rig.model, name), getattr(fresh.model, name), rtol=1e-12, err_msg=name)
    for name in ("dof_damping", "actuator_biasprm", "actuator_dynprm", "actuator_gainprm", "jnt_stiffness"):
        np.testing.assert_allclose(getattr(rig.model, name), getattr(fresh.model, name), rtol=1e-12, err_msg=name)
    assert rig.model.actuator_biasprm[rig.servo, 2] == 1.1  # the drive's own fields did change
    with pytest.raises(ValueError, match="support_mass_kg"):
        rig.episode_fields(replace(drawn, screw=replace(drawn.screw, support_mass_kg=50.0)), (0.05, 1.0), held, 0.0)
    with pytest.raises(ValueError, match="torque_filter_s"):  # 0 removes the current's state: a new model
        rig.episode_fields(replace(drawn, servo=replace(drawn.servo, torque_filter_s=0.0)), (0.05, 1.0), held, 0.0)


@pytest.mark.parametrize(
    ("path", "value"),
    [
        ("screw.lead_m", 1e300),
        ("screw.lead_m", 1e-300),
        ("screw.belt_ratio", 1e300),
        ("balancer.piston_area_m2", 1e300),
        ("qzs.residual_stiffness_n_per_m", 1e-300),
        ("sensors.ruler_noise_m", 1e300),
        ("screw.support_mass_kg", 1e-300),
        ("gravity_m_s2", 1e9),
    ],
)
def test_parameters_outside_any_plausible_rig_are_named(path, value):
    """Values that made the model overflow, divide by zero or return NaN observations."""
    from microg_env.params import with_overrides

    with pytest.raises(ValueError, match=path.split(".")[-1]):
        with_overrides(RigParams(), {path: value})


def test_modes_too_fast_for_the_physics_step_are_refused():
    fast = replace(RigParams(), servo=replace(ServoParams(), speed_loop_gain_hz=5000.0))
    with pytest.raises(ValueError, match="speed_loop_gain_hz"):
        build_rig(fast)  # 2 pi 5000 Hz x 100 us = 3.1
    build_rig(fast, physics_step_s=2e-5)  # resolved at 20 us


def test_overrides_must_be_a_mapping():
    from microg_env.params import with_overrides

    with pytest.raises(ValueError, match="overrides"):
        with_overrides(RigParams(), [("pad.stiffness_n_per_m", 1.0)])


def test_the_midpoint_drive_converges_where_mujocos_stepping_does_not():
    """``drive_scheme="midpoint"`` (docs/model.md, "Drive scheme"): the feed-forward's free-fall x,
    a cancellation residual that amplifies the drive's step error about eight times, moves by
    under 0.5 % from 100 to 25 µs (measured: 0.03 % over 30 s); under MuJoCo's own stepping of the
    dcmotor it moves by 10 % (measured 11.5 %). Condition 1 to its largest free-fall x, near 3 s."""
    from microg_env.controllers import make_controller
    from microg_env.envs.landing import MicroGravityLandingEnv
    from microg_env.rollout.episode import run_with_metrics

    def free_fall_x(scheme: str, step_s: float) -> float:
        env = MicroGravityLandingEnv(condition=1, physics_step_s=step_s, drive_scheme=scheme)
        controller = make_controller("feedforward", env.settings.control_period_s)
        return run_with_metrics(env, controller, seed=0, duration_s=3.5)[2].flexible_unit_excursion_free_fall_m

    change = {scheme: free_fall_x(scheme, 1e-4) / free_fall_x(scheme, 2.5e-5) - 1.0 for scheme in DRIVE_SCHEMES}
    assert abs(change["midpoint"]) < 0.005, change
    assert abs(change["mujoco"]) > 0.10, change


def test_the_midpoint_drive_is_built_for_the_drive_alone():
    """The midpoint drive: MuJoCo's euler integrator and the current at the step's start (actearly
    off) on the servo; the ideal drive, a stiff velocity actuator, keeps implicitfast."""
    midpoint = build_rig(drive_scheme="midpoint")
    assert midpoint.midpoint_drive
    assert midpoint.model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert not midpoint.model.actuator_actearly[midpoint.servo]
    shipped = build_rig()
    assert not shipped.midpoint_drive
    assert shipped.model.actuator_actearly[shipped.servo]
    assert shipped.model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    ideal = build_rig(ideal_drive=True, drive_scheme="midpoint")
    assert not ideal.midpoint_drive
    assert ideal.model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    with pytest.raises(FieldError, match="drive_scheme must be one of 'mujoco', 'midpoint', got 'rk4'"):
        build_rig(drive_scheme="rk4")


def test_the_midpoint_drive_refuses_damping_its_integrator_takes_explicitly():
    """Under the midpoint drive's euler integrator the bristle damping and the transmission's
    damping are explicit: a rate the step cannot integrate is refused, naming the parameter (with
    1000 N m s/rad the motor ran away to 650 m/s before); ``implicitfast`` takes both. And
    ``Rig.drive``, which steps MuJoCo's own inputs, refuses a midpoint rig."""
    damped = replace(RigParams(), servo=replace(RigParams().servo, bristle_damping_n_m_s_per_rad=1000.0))
    build_rig(damped)
    with pytest.raises(FieldError, match=r"ServoParams.bristle_damping_n_m_s_per_rad makes .* physics_step_s <="):
        build_rig(damped, drive_scheme="midpoint")
    build_rig(damped, physics_step_s=1e-5, drive_scheme="midpoint")
    stiff = replace(
        RigParams(),
        screw=replace(RigParams().screw, transmission_stiffness_n_per_m=3.0e9, transmission_damping_ratio=1.0),
    )
    build_rig(stiff)
    with pytest.raises(FieldError, match=r"ScrewStageParams\.transmission_damping_ratio"):
        build_rig(stiff, drive_scheme="midpoint")
    rig = build_rig(drive_scheme="midpoint")
    with pytest.raises(ValueError, match="a midpoint drive is stepped by LandingCore"):
        rig.drive(mujoco.MjData(rig.model), 0.0, 0.0, 10)


def test_the_environments_step_the_midpoint_drive_by_default_and_a_bare_rig_mujocos():
    """0.22.0: every environment id runs the converged drive unless told; ``build_rig`` alone keeps
    MuJoCo's own stepping, the one ``mujoco.mj_step`` can step without the speed-input kernel."""
    import gymnasium as gym

    import microg_env  # noqa: F401  (registers the environments)

    for env_id in ("MicroGravityLanding-v1", "MicroGravityLanding-Residual-v7"):
        env = gym.make(env_id)
        assert env.unwrapped.rig.midpoint_drive, env_id
        env.close()
    assert gym.make("MicroGravityLanding-v1", drive_scheme="mujoco").unwrapped.rig.midpoint_drive is False
    assert build_rig().midpoint_drive is False
