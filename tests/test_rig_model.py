"""The rig model: MJCF files, parameter plumbing, force balance, servo stage."""

from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from microg_env.params import GRAVITY_M_S2, LanderParams, PadParams, QZSParams, RigParams, ServoParams
from microg_env.sim.ideal import IdealFollower
from microg_env.sim.model import TEMPLATE_LOADS, build_rig, flexible_unit, mjcf_dir

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


def test_mjcf_folder_holds_scene_rig_and_readme():
    names = {p.name for p in Path(mjcf_dir()).iterdir()}
    assert {"scene.xml", "rig.xml", "README.md"} <= names


def test_built_rig_steps_without_warning():
    rig = build_rig(loads_kg=(0.05, 0.49, 1.0))
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    rng = np.random.default_rng(1)
    while data.time < 1.0:
        speed = rng.uniform(-1.25, 1.25)
        data.ctrl[:] = (data.ctrl[0] + speed * rig.gear * rig.model.opt.timestep, speed * rig.gear)
        mujoco.mj_step(rig.model, data)
    assert _warnings(data) == []


def test_template_matches_default_parameters():
    """rig.xml's geometry and masses are the params defaults (params.py is the source of truth)."""
    raw = mujoco.MjModel.from_xml_path(str(Path(mjcf_dir()) / "scene.xml"))
    built = build_rig(loads_kg=tuple(TEMPLATE_LOADS.values())).model
    for body in ("lander", "floating_support"):
        assert raw.body(body).mass == pytest.approx(built.body(body).mass)
    for geom in ("foot", "pad"):
        np.testing.assert_allclose(raw.geom(geom).size, built.geom(geom).size)
        np.testing.assert_allclose(raw.geom(geom).pos, built.geom(geom).pos)
    for joint in ("screw", "qzs"):
        np.testing.assert_allclose(raw.joint(joint).range, built.joint(joint).range)
    assert raw.opt.timestep == built.opt.timestep
    np.testing.assert_allclose(raw.opt.gravity, built.opt.gravity)
    assert sorted(raw.body(name).mass[0] for name in TEMPLATE_LOADS) == pytest.approx(sorted(TEMPLATE_LOADS.values()))


def test_parameters_reach_the_model():
    params = RigParams(
        lander=LanderParams(mass_kg=500.0),
        pad=PadParams(stiffness_n_per_m=9000.0),
        qzs=QZSParams(stiffness_n_per_m=20000.0),
    )
    default, changed = build_rig().model, build_rig(params).model
    assert changed.body("lander").mass[0] == 500.0
    assert changed.jnt_stiffness[changed.joint("qzs").id] == 20000.0
    ratio = changed.geom_solref[changed.geom("pad").id, 0] / default.geom_solref[default.geom("pad").id, 0]
    assert ratio == pytest.approx((9000.0 / 500.0) / (4666.0 / 620.0))


@pytest.mark.parametrize("loads", [(), (1.0,)])
def test_qzs_and_balancer_carry_the_lander_at_x_zero(loads):
    params = RigParams()
    rig = build_rig(params, loads_kg=loads)
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    weight = params.lander.mass_kg * GRAVITY_M_S2
    assert data.qfrc_passive[rig.qzs_dof] == pytest.approx(weight, rel=1e-12)
    # Displacing x shows the summed residual stiffness: QZS (Eq. 17) plus the gas spring k = n F A / V.
    data.qpos[rig.qzs_qpos] = 1e-3
    mujoco.mj_forward(rig.model, data)
    stiffness = (weight - data.qfrc_passive[rig.qzs_dof]) / 1e-3
    balancer_force = weight * (1 - params.qzs.weight_share) - params.qzs.force_offset_n
    gas_spring = params.balancer.polytropic_index * balancer_force * params.balancer.piston_area_m2
    expected = params.qzs.stiffness_n_per_m + gas_spring / params.balancer.gas_volume_m3
    assert stiffness == pytest.approx(expected, rel=1e-9)
    assert stiffness == pytest.approx(flexible_unit(params).stiffness_n_per_m, rel=1e-9)
    assert expected < 1.05 * params.qzs.stiffness_n_per_m  # the balancer is a small addition


@pytest.mark.parametrize("loads", [(0.49,), (1.0,), (0.05,), (0.05, 1.0)])
def test_ideal_following_gives_the_ideal_descent(loads):
    """x held at 0 by the support: the lander falls at m_ext g / (M + m_ext) (Table 2)."""
    rig = build_rig(loads_kg=loads)
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    rig.place_loads([True] * len(loads))
    follower = IdealFollower(rig)
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


def test_held_loads_leave_the_rig_balanced():
    rig = build_rig(loads_kg=(0.05, 0.49, 1.0))
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    assert rig.placed_load_kg == 0.0
    start = rig.foot_height(data)
    for _ in range(4000):  # 2 s with the servo holding position
        mujoco.mj_step(rig.model, data)
    assert abs(data.qpos[rig.qzs_qpos]) < 1e-6
    assert abs(rig.foot_height(data) - start) < 1e-5


def test_servo_tracks_a_speed_command():
    rig = build_rig()
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    speed = 0.1  # m/s upward
    dt = rig.model.opt.timestep
    for _ in range(1000):
        data.ctrl[:] = (data.ctrl[0] + speed * rig.gear * dt, speed * rig.gear)
        mujoco.mj_step(rig.model, data)
    assert data.qvel[rig.screw_dof] == pytest.approx(speed, rel=0.01)


def test_servo_torque_saturates_at_the_peak_torque():
    # Cogging and friction add to the motor's own torque; remove them to see the drive's limit.
    quiet = replace(ServoParams(), cogging_torque_n_m=0.0, bristle_stiffness_n_m_per_rad=0.0)
    params = replace(RigParams(), servo=quiet)
    rig = build_rig(params)
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    data.ctrl[:] = (data.ctrl[0] - 1.0 * rig.gear, -1.25 * rig.gear)  # a 1 m position step down
    peak = 0.0
    for _ in range(50):
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


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="mass_kg"):
        LanderParams(mass_kg=700.0)
    with pytest.raises(ValueError, match="stiffness_n_per_m"):
        replace(PadParams(), stiffness_n_per_m=0.0)
    with pytest.raises(ValueError, match="weight_share"):
        QZSParams(weight_share=1.5)


def test_placing_a_load_adds_its_mass_and_keeps_the_pad_law():
    params = RigParams()
    rig = build_rig(params, loads_kg=(0.05, 1.0))
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.055)
    carried = [rig.model.body("lander").id, *rig.load_bodies]
    assert rig.model.body_mass[carried].sum() == pytest.approx(620.0)
    rig.place_loads([True, False])
    assert rig.model.body_mass[carried].sum() == pytest.approx(620.05)
    # The pad's physical stiffness stays K: solref (acceleration units) times the mass it moves.
    solref = rig.model.geom_solref[rig.model.geom("pad").id, 0]
    n, d = rig.pad_contacts, params.pad.impedance
    assert -solref * n * 620.05 / (1 + (n - 1) * d) == pytest.approx(params.pad.stiffness_n_per_m)
