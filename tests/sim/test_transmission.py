"""The belt and screw as a spring between the motor and the support
(``ScrewStageParams.transmission_stiffness_n_per_m``; rigid by default)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from microg_env.params import RigParams, with_overrides
from microg_env.rollout.runner import run
from microg_env.rollout.spec import RunSpec
from microg_env.sim.limits import transmission_omega
from microg_env.sim.model import MOTOR_JOINT, build_rig, export_spec, flexible_unit

ESTIMATE_N_PER_M = 1e8


def _compliant(**overrides) -> RigParams:
    return with_overrides(RigParams(), {"screw.transmission_stiffness_n_per_m": ESTIMATE_N_PER_M, **overrides})


def test_a_rigid_transmission_adds_no_coordinate():
    rig = build_rig(RigParams())
    assert math.isinf(RigParams().screw.transmission_stiffness_n_per_m)
    assert rig.model.nq == 2
    assert rig.motor_qpos == rig.screw_qpos
    assert mujoco.mj_name2id(rig.model, mujoco.mjtObj.mjOBJ_JOINT, MOTOR_JOINT) == -1


def test_the_transmission_mode_has_its_closed_form_frequency():
    """Motor side (rotor and screw, J gear^2 = 199 kg at the support) against the 40 kg support on
    the spring: with the actuators off (the drive's torque and back-EMF, its cogging and LuGre,
    the guide's friction) and the dampers off, a 1 um twist rings at
    sqrt(k (1/m_motor + 1/m_support)) (276 Hz at 1e8 N/m)."""
    params = _compliant(**{"screw.transmission_damping_ratio": 0.0, "screw.viscous_n_s_per_m": 0.0})
    rig = build_rig(params)
    model = rig.model
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_ACTUATION
    data = mujoco.MjData(model)
    rig.reset(data, 0.09)
    data.qpos[rig.motor_qpos] += 1e-6
    twist = []
    for _ in range(400):  # 40 ms: about 11 periods
        mujoco.mj_step(model, data)
        twist.append(data.qpos[rig.motor_qpos] - data.qpos[rig.screw_qpos])
    twist = np.array(twist) - np.mean(twist)
    crossings = np.flatnonzero(np.diff(np.sign(twist)) != 0)
    measured_hz = (len(crossings) - 1) / 2.0 / ((crossings[-1] - crossings[0]) * model.opt.timestep)
    expected_hz = transmission_omega(params) / (2.0 * math.pi)
    assert expected_hz == pytest.approx(276.0, rel=0.01)
    assert measured_hz == pytest.approx(expected_hz, rel=0.01)


def test_the_spring_carries_the_screws_static_load_at_rest():
    """With the balancer between support and lander the screw carries the lander and the support
    (6.5 kN): the motor side stands load/k = 65 um above the support, and the rig holds still."""
    params = _compliant(**{"balancer.placement": "support_lander"})
    rig = build_rig(params)
    data = mujoco.MjData(rig.model)
    rig.reset(data, 0.09)
    load = flexible_unit(params).screw_load_n
    assert data.qpos[rig.motor_qpos] - data.qpos[rig.screw_qpos] == pytest.approx(load / ESTIMATE_N_PER_M, rel=1e-12)
    mujoco.mj_step(rig.model, data, nstep=2000)  # 0.2 s, the drive holding
    assert data.qpos[rig.motor_qpos] - data.qpos[rig.screw_qpos] == pytest.approx(load / ESTIMATE_N_PER_M, rel=1e-3)
    assert abs(data.qpos[rig.screw_qpos] - 0.09) < 1e-6  # the support settles as the rigid rig's (0.17 um)


def test_the_exported_compliant_rig_holds_still_at_its_home_keyframe():
    model = export_spec(_compliant(**{"balancer.placement": "support_lander"}), (1.0,)).compile()
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_step(model, data, nstep=5000)
    assert np.abs(data.qacc).max() < 1e-3
    assert abs(data.qpos[1]) < 1e-6  # x


@pytest.mark.slow
def test_the_encoder_reads_the_motor_and_a_stiffer_transmission_approaches_the_rigid_rig():
    """Condition 1's first 6 s with the PID: the compliant rig's encoder reads the motor's
    coordinate, not the support's; x at the collision moves by about 1.4 % at the estimate
    (1e8 N/m) and by less at 1e9 N/m, toward the rigid rig's."""

    def collision_um(stiffness: float | None) -> float:
        overrides = {} if stiffness is None else {"screw.transmission_stiffness_n_per_m": stiffness}
        spec = RunSpec("condition-1", "pid", 0, overrides, duration_s=6.0, imperfections={"sensor_noise": False})
        return run(spec).metrics.flexible_unit_excursion_collision_m * 1e6

    rigid, estimate, stiffer = collision_um(None), collision_um(1e8), collision_um(1e9)
    assert abs(estimate - rigid) > abs(stiffer - rigid)
    assert 0.005 < abs(estimate / rigid - 1) < 0.05
    assert abs(stiffer / rigid - 1) < 0.005

    from microg_env.envs.landing import MicroGravityLandingEnv
    from microg_env.interface import SCALES

    placement = {"balancer.placement": "support_lander"}  # the spring carries 6.5 kN: 65 um of twist
    env = MicroGravityLandingEnv(params=_compliant(**placement), imperfections={"sensor_noise": False}, condition=1)
    env.reset(seed=0)
    for _ in range(200):
        observation = env.step(np.zeros(1))[0]
    rig, data = env.unwrapped.rig, env.unwrapped.data
    encoder = observation[2] * SCALES[2]
    motor, support = data.qpos[rig.motor_qpos], data.qpos[rig.screw_qpos]
    assert abs(motor - support) > 1e-8
    assert abs(encoder - motor) < abs(encoder - support)


@pytest.mark.slow
def test_a_compliant_rig_in_a_batch_is_bit_for_bit_its_single_environment():
    from microg_env.rollout.runner import run_many

    specs = [
        RunSpec(
            "condition-2", controller, seed, {"screw.transmission_stiffness_n_per_m": ESTIMATE_N_PER_M}, duration_s=0.5
        )
        for controller in ("pid", "adaptive")
        for seed in (0, 1)
    ]
    batched = {i: result for batch in run_many(specs, keep_trajectories=True) for i, result in batch}
    for i, spec in enumerate(specs):
        alone = run(spec)
        assert repr(batched[i].metrics) == repr(alone.metrics)
        assert np.array_equal(batched[i].trajectory.x_m, alone.trajectory.x_m)
        assert np.array_equal(batched[i].trajectory.support_position_m, alone.trajectory.support_position_m)
