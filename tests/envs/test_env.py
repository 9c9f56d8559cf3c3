"""The Gymnasium environment: conformance, determinism, copies, vectorisation, bad input, failures."""

import copy
import dataclasses
import inspect
import itertools
import math
import os
import pickle
import subprocess
import sys

import cloudpickle
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.utils.env_checker import check_env

from microg_env import Imperfections, LoadStep, Scenario
from microg_env.controllers.registry import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.envs.vector import MicroGravityLandingVectorEnv
from microg_env.imperfections import DomainRandomization
from microg_env.interface import OBSERVATION_INDEX, OBSERVATION_SCALES, Readings, gated_actions, highpass_gain
from microg_env.params import MAX_CONTROL_STEPS, RigParams
from microg_env.sim.model import drive_inertia_kg_m2
from microg_env.task import TaskSettings

ENV_ID = "microg_env:MicroGravityLanding-v1"
CONDITIONS_1 = Scenario("condition 1", (LoadStep(0.49),), descent_height_m=0.09)


def _rollout(env: gym.Env, seed: int | None, steps: int, action: float = 0.1) -> tuple[np.ndarray, list[dict]]:
    obs, info = env.reset(seed=seed)
    observations, infos = [obs], [info]
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        observations.append(obs)
        infos.append(info)
        if terminated or truncated:
            break
    return np.array(observations), infos


def _steps(env: gym.Env, steps: int, action: float = -0.01) -> np.ndarray:
    return np.array([env.step(np.array([action], dtype=np.float32))[0] for _ in range(steps)])


def test_registered_and_made_by_id():
    env = gym.make(ENV_ID)
    assert isinstance(env.unwrapped, MicroGravityLandingEnv)
    assert env.spec.max_episode_steps == MAX_CONTROL_STEPS  # the env truncates itself before TimeLimit can
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    assert env.observation_space.shape == (len(OBSERVATION_SCALES),)


@pytest.mark.parametrize("condition", [1, 3])
def test_gymnasium_check_env(condition):
    check_env(gym.make(ENV_ID, condition=condition).unwrapped, skip_render_check=True)


def test_stable_baselines3_check_env():
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    sb3_checker.check_env(MicroGravityLandingEnv(condition=2), warn=False)


@pytest.mark.parametrize(
    ("env_id", "width"), [("MicroGravityLanding-GainScheduling-v1", 3), ("MicroGravityLanding-Command-v1", 1)]
)
def test_the_gain_scheduling_and_command_ids_pass_both_checkers(env_id, width):
    """Gymnasium's checker passes the gains id (its three-number action included) and the command id
    (its speed limit); SB3's checker warns of nothing either."""
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    env = gym.make(env_id).unwrapped
    assert env.action_space.shape == (width,)
    check_env(env, skip_render_check=True)
    sb3_checker.check_env(env, warn=True)


def test_same_seed_same_trajectory_other_seed_other_noise():
    env = MicroGravityLandingEnv(condition=1)
    first, infos_a = _rollout(env, seed=7, steps=300)
    second, infos_b = _rollout(env, seed=7, steps=300)
    other, _ = _rollout(env, seed=8, steps=300)
    np.testing.assert_array_equal(first, second)
    assert [i["x_m"] for i in infos_a] == [i["x_m"] for i in infos_b]
    assert not np.array_equal(first, other)


@pytest.mark.parametrize(
    "copier",
    [lambda env: pickle.loads(pickle.dumps(env)), lambda env: cloudpickle.loads(cloudpickle.dumps(env)), copy.deepcopy],
    ids=["pickle", "cloudpickle", "deepcopy"],
)
@pytest.mark.parametrize("made", [True, False], ids=["gym.make", "raw"])
def test_a_copy_made_mid_episode_continues_exactly_as_the_original(copier, made):
    env = gym.make(ENV_ID, condition=3) if made else MicroGravityLandingEnv(condition=3)
    env.reset(seed=3)
    _steps(env, 40)
    clone = copier(env)
    np.testing.assert_array_equal(_steps(env, 60), _steps(clone, 60))
    assert clone.unwrapped.data.time == env.unwrapped.data.time


def test_stepping_before_reset_asks_for_a_reset():
    with pytest.raises(ResetNeeded, match="reset"):
        MicroGravityLandingEnv().step(np.zeros(1, dtype=np.float32))


@pytest.mark.slow
def test_runs_under_subproc_vec_env():
    vec_env = pytest.importorskip("stable_baselines3.common.vec_env")
    envs = vec_env.SubprocVecEnv([lambda c=c: gym.make(ENV_ID, condition=c) for c in (1, 3)])
    try:
        envs.seed(0)
        obs = envs.reset()
        assert obs.shape == (2, len(OBSERVATION_SCALES))
        for _ in range(20):
            obs, rewards, _dones, infos = envs.step(np.zeros((2, 1), dtype=np.float32))
        assert np.all(np.isfinite(obs))
        assert rewards.shape == (2,)
        assert all("x_m" in info for info in infos)
    finally:
        envs.close()


@pytest.mark.parametrize("period", [1e-3, 5e-4, 2e-4, 1e-4])
def test_control_periods_of_the_paper_share_one_physics_step(period):
    env = MicroGravityLandingEnv(condition=1, control_period_s=period)
    assert env.model.opt.timestep == env.settings.physics_step_s == 1e-4
    assert env.settings.frame_skip * env.settings.physics_step_s == pytest.approx(period)
    _, infos = _rollout(env, seed=0, steps=10, action=0.0)
    assert infos[-1]["time_s"] == pytest.approx(10 * period)


def test_physics_step_is_a_keyword():
    env = MicroGravityLandingEnv(condition=1, physics_step_s=5e-5)
    assert env.model.opt.timestep == 5e-5
    assert env.settings.frame_skip == 20


def test_episode_is_truncated_at_the_scenario_duration_at_any_period():
    scenario = Scenario("short", (LoadStep(0.49),), descent_height_m=0.09, duration_s=0.05)
    for period in (1e-3, 1e-4):
        env = gym.make(ENV_ID, scenario=scenario, control_period_s=period)
        _, infos = _rollout(env, seed=0, steps=10_000, action=0.0)
        assert len(infos) - 1 == round(0.05 / period)
        assert infos[-1]["time_s"] == pytest.approx(0.05)


@pytest.mark.slow
def test_starts_balanced_and_places_loads_on_schedule():
    env = MicroGravityLandingEnv(condition=3, imperfections=Imperfections.none())
    from microg_env.controllers import make_controller
    from microg_env.rollout.episode import run_episode

    trajectory = run_episode(env, make_controller("pid", env.settings.control_period_s), seed=0, duration_s=11.0)
    assert trajectory.foot_height_m[0] == pytest.approx(0.055, abs=1e-12)
    assert trajectory.x_m[0] == 0.0
    assert trajectory.placed_load_kg[0] == pytest.approx(0.05)  # the 50 g weight goes on at t = 0
    second = int(np.argmax(trajectory.placed_load_kg > 0.06))  # 1 kg more at 25 mm (Section 3.2)
    assert trajectory.placed_load_kg[second] == pytest.approx(1.05)
    assert trajectory.foot_height_m[second] <= 0.025 < trajectory.foot_height_m[second - 1]
    assert list(np.unique(trajectory.stage)) == [0, 1]


def test_observation_is_the_sensors_scaled():
    env = MicroGravityLandingEnv(condition=1, imperfections=Imperfections.none())
    obs, info = env.reset(seed=0)
    scales = OBSERVATION_SCALES
    assert obs[2] * scales["support_position"] == pytest.approx(info["support_position_m"], rel=1e-6)
    assert obs[6] * scales["height"] == pytest.approx(info["foot_height_m"], rel=1e-6)
    # The accelerometer, with g removed, sees the lander start to fall at m g / (M + m).
    assert obs[4] * scales["lander_accel"] == pytest.approx(-0.49 * 9.8009 / 620.49, rel=1e-3)
    obs, _, _, _, info = env.step(np.array([0.2], dtype=np.float32))
    assert obs[8] == pytest.approx(0.2)
    assert obs[9] == 0.0  # no base controller in speed mode


def test_task_settings_own_every_default_and_both_envs_pass_them_through():
    """One owner: the envs' signatures hold no task default; what they run with is TaskSettings'."""
    env_parameters = inspect.signature(MicroGravityLandingEnv).parameters
    assert set(env_parameters) == {"render_mode", "width", "height", "camera_name", "settings"}
    vector_parameters = inspect.signature(MicroGravityLandingVectorEnv).parameters
    assert set(vector_parameters) == {
        "num_envs", "autoreset_mode", "scenarios", "nthread", "render_mode", "width", "height", "camera_name",
        "max_episode_steps", "kwargs",
    }  # fmt: skip
    defaults, env = TaskSettings(), MicroGravityLandingEnv()
    vector = MicroGravityLandingVectorEnv(num_envs=2, decision_period=3)
    for field in dataclasses.fields(TaskSettings):
        expected = getattr(defaults, field.name)
        assert getattr(env.settings, field.name) == expected, field.name
        if field.name != "decision_period":
            assert getattr(vector.core.settings, field.name) == expected, field.name
    assert vector.core.settings.decision_period == 3
    assert env.settings.control_period_s == defaults.control_period_s
    assert env.settings.frame_skip == defaults.frame_skip
    with pytest.raises(TypeError, match="not_a_setting"):
        MicroGravityLandingEnv(not_a_setting=1)
    with pytest.raises(ValueError, match="xml_file"):  # checked once, for the vector env too
        MicroGravityLandingVectorEnv(num_envs=2, xml_file="missing.xml")


def test_readings_decode_observations_into_the_infos_si_values():
    """The contract's Readings, for n rigs at once, against what the step reports in SI units."""
    env = MicroGravityLandingEnv(condition=1, imperfections=Imperfections.none())
    env.reset(seed=0)
    rows = [env.step(np.array([0.01], dtype=np.float32)) for _ in range(3)]
    readings = Readings.of(np.array([obs for obs, *_ in rows]))
    infos = [info for *_, info in rows]
    for field, key in [
        ("support_position_m", "support_position_m"),
        ("foot_height_m", "foot_height_m"),
        ("placed_load_kg", "placed_load_kg"),
    ]:
        np.testing.assert_allclose(getattr(readings, field), [i[key] for i in infos], rtol=1e-6)
    np.testing.assert_allclose(readings.x_m, [i["x_m"] for i in infos], atol=1e-8)  # the ruler: 5 nm steps
    assert readings.pad_force_n.shape == (3,)


def test_sensor_noise_and_quantisation():
    env = MicroGravityLandingEnv(condition=1)
    sensors = env.params.sensors
    observations, infos = _rollout(env, seed=1, steps=200, action=0.0)
    ruler = observations[:, 0].astype(float) * OBSERVATION_SCALES["x"]
    steps = ruler / sensors.ruler_resolution_m
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-3)  # quantised to the ruler's step
    truth = np.array([i["x_m"] for i in infos])
    assert 0 < np.std(ruler - truth) < 5 * sensors.ruler_noise_m


def test_reward_keeps_a_gradient_from_millimetres_to_nanometres_and_never_pays_for_ending():
    from microg_env.envs.landing import x_reward

    limit = 0.0249
    rewards = [x_reward(x, 1e-8, limit) for x in (0.0, 1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, limit)]
    assert rewards[0] == 1.0
    assert rewards[-1] == pytest.approx(0.0, abs=1e-12)
    assert all(a > b for a, b in itertools.pairwise(rewards))  # strictly better the smaller x
    decades = np.diff(rewards[3:9])  # 1e-7 ... 1e-2: the same step per decade
    np.testing.assert_allclose(decades, decades[0], rtol=0.02)
    assert min(rewards) >= 0.0  # ending early forgoes reward, never gains it
    env = MicroGravityLandingEnv(condition=1, imperfections=Imperfections.none())
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([0.0], dtype=np.float32))
    assert reward == pytest.approx(x_reward(info["x_m"], 1e-8, 0.025 - 1e-4))
    assert reward == pytest.approx(info["reward_x"])


def test_the_step_that_overruns_the_guide_pays_nothing_not_less():
    """Random speed commands end on a stroke limit with x beyond the guide's half stroke: that last
    step's reward is 0, as every other step's lies in [0, 1] (it was negative, down to -0.01)."""
    from microg_env.envs.landing import x_reward

    assert x_reward(0.05, 1e-8, 0.0249) == 0.0
    env = gym.make("microg_env:MicroGravityLanding-v1", condition=3)
    env.action_space.seed(0)
    env.reset(seed=0)
    rewards, terminated, truncated = [], False, False
    while not (terminated or truncated):
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        rewards.append(reward)
    assert terminated
    assert info["termination_reason"] == "guide_stroke_limit"
    assert rewards[-1] == 0.0
    assert min(rewards) >= 0.0
    assert max(rewards) <= 1.0


def test_the_descent_term_scores_the_velocity_error_against_the_ideal_descent():
    """reward_descent_weight: in each stage's descent window (SETTLE_S after its weight is placed,
    until the first pad contact) info's descent_velocity_error_m_s is v - v(t0) - a_ideal (t - t0),
    a_ideal = -m g / (M + m) of the weight placed, exactly, and 0 outside; the reward is
    (1 - w) reward_x + w x_reward(error, scale, limit). Condition 3 places its second weight in
    flight: two windows. The error's slope is the descent fit's acceleration error (the
    compensation error's numerator), within 10 % (measured 3-4 %)."""
    from microg_env.envs.landing import x_reward
    from microg_env.interface import DESCENT_LIMIT_M_S, DESCENT_SCALE_M_S
    from microg_env.scenarios import SETTLE_S

    weight = 0.4
    env = MicroGravityLandingEnv(
        condition=3, action_mode="residual", base_controller="adaptive", reward_descent_weight=weight
    )
    _, info = env.reset(seed=3)
    infos, rewards = [info], [math.nan]
    for _ in range(12_000):  # past the touchdown at 10.08 s
        _, reward, _, _, info = env.step(np.zeros(1, dtype=np.float32))
        infos.append(info)
        rewards.append(reward)

    def channel(key):
        return np.array([each[key] for each in infos])

    time, error, stage = channel("time_s"), channel("descent_velocity_error_m_s"), channel("stage")
    velocity, height, load = channel("lander_velocity_m_s"), channel("foot_height_m"), channel("placed_load_kg")
    touchdown = int(np.flatnonzero(channel("pad_force_n") > 0)[0])
    mass, g = env.unwrapped.params.lander.mass_kg, env.unwrapped.params.gravity_m_s2
    scored = np.zeros(len(infos), dtype=bool)
    for k in (0, 1):
        rows = np.flatnonzero(stage == k)
        window = rows[(time[rows] >= time[rows[0]] + SETTLE_S) & (rows < touchdown)]
        assert window.size > 1000  # seconds of free fall each
        start, ideal = window[0], -load[window[0]] * g / (mass + load[window[0]])
        expected = velocity[window] - velocity[start] - ideal * (time[window] - time[start])
        np.testing.assert_array_equal(error[window], expected)
        since = time[window] - time[start]
        fitted = 2.0 * np.polyfit(since, height[window], 2)[0]
        assert np.polyfit(since, error[window], 1)[0] == pytest.approx(fitted - ideal, rel=0.1)
        scored[window] = True
    assert np.all(error[~scored] == 0.0)
    assert np.count_nonzero(error[scored]) == scored.sum() - 2  # 0 at each window's start only
    score = np.maximum(x_reward(error, DESCENT_SCALE_M_S, DESCENT_LIMIT_M_S), 0.0)
    np.testing.assert_allclose(rewards[1:], (1 - weight) * channel("reward_x")[1:] + weight * score[1:], rtol=1e-12)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("reward_descent_weight", -0.1),
        ("reward_descent_weight", 1.5),
        ("reward_descent_weight", "half"),
        ("reward_descent_scale_m_s", 0.0),
        ("reward_descent_scale_m_s", math.inf),
        ("reward_descent_scale_m_s", math.nan),
    ],
)
def test_a_bad_descent_term_is_named(field, value):
    with pytest.raises(ValueError, match=field):
        MicroGravityLandingEnv(**{field: value})


@pytest.mark.parametrize("name", ["feedforward", "adaptive", "adaptive-dither", "oracle"])
@pytest.mark.slow
def test_a_zero_residual_is_its_base_controller_exactly(name):
    """action_mode="residual": an action of 0 leaves the base controller alone (the oracle base is
    told each drawn plant by the environment, as the harness tells the oracle)."""
    from microg_env.controllers import PolicyController, make_controller
    from microg_env.rollout.episode import run_episode

    class Zero:
        def predict(self, observation, deterministic=True):
            return np.zeros(1, dtype=np.float32), None

    drawn = DomainRandomization.full()
    base = run_episode(
        MicroGravityLandingEnv(condition=2, domain_randomization=drawn),
        make_controller(name, 1e-3),
        seed=3,
        duration_s=5.0,
    )
    env = MicroGravityLandingEnv(condition=2, action_mode="residual", base_controller=name, domain_randomization=drawn)
    residual = run_episode(env, PolicyController(Zero()), seed=3, duration_s=5.0)
    np.testing.assert_array_equal(base.x_m, residual.x_m)
    np.testing.assert_array_equal(base.command_m_s, residual.command_m_s)


def test_a_residual_moves_the_base_controllers_setpoint():
    env = MicroGravityLandingEnv(
        condition=2, action_mode="residual", base_controller="feedforward", residual_limit_m=3e-6
    )
    env.reset(seed=0)
    xs = []
    for _ in range(1000):
        _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
        xs.append(info["x_m"])
    assert info["setpoint_m"] == pytest.approx(1.5e-6)
    assert np.mean(xs[500:]) == pytest.approx(1.5e-6, abs=0.1e-6)  # the loop holds x at the setpoint


def test_a_high_passed_residual_decays_to_the_base_controllers_steady_state():
    """With ``residual_highpass_hz`` a held action is a step through a first-order high-pass: its
    setpoint decays as a^(n+1) (a = tau / (tau + T), tau = 1 / (2 pi f), T the decision period),
    so the base controller brings x back to 0; the filter starts again at every reset."""
    env = MicroGravityLandingEnv(
        condition=2, action_mode="residual", base_controller="feedforward", decision_period=5, residual_highpass_hz=2.0
    )
    tau = 1.0 / (2.0 * math.pi * 2.0)
    gain = tau / (tau + 5e-3)
    for _ in range(2):
        env.reset(seed=0)
        xs, setpoints = [], []
        for _ in range(200):  # 1 s
            _, _, _, _, info = env.step(np.array([1.0], dtype=np.float32))
            xs.append(info["x_m"])
            setpoints.append(info["setpoint_m"])
        np.testing.assert_allclose(setpoints, 1e-6 * gain ** np.arange(1, 201), rtol=1e-12)
        assert max(xs[:20]) > 0.3e-6  # the step moved x at first
        assert abs(np.mean(xs[100:])) < 0.05e-6  # and x is back at the base's 0 within 0.5 s


def test_a_second_order_high_pass_lets_neither_a_held_nor_a_ramping_action_hold_x():
    """``residual_highpass_order=2``: two first-order stages in cascade. A ramping action (as a
    policy's, whose observations drift through a free fall) leaves a steady setpoint of
    r tau limit through one stage (v2's shipped policy held x +6 nm off on condition 1) and a
    decaying one through two; each setpoint is the cascade's recursion computed here."""
    gain = highpass_gain(2.0, 5e-3)
    rate = 0.002  # per decision (0.4 per second)
    late = {}
    for order in (1, 2):
        env = MicroGravityLandingEnv(
            condition=2, action_mode="residual", base_controller="feedforward", decision_period=5,
            residual_highpass_hz=2.0, residual_highpass_order=order, residual_limit_m=3e-6,
        )  # fmt: skip
        env.reset(seed=0)
        setpoints, expected, u, w, y = [], [], 0.0, 0.0, 0.0
        for k in range(1, 401):  # 2 s
            action = np.float32(rate * k)
            setpoints.append(env.step(np.array([action]))[4]["setpoint_m"])
            stage = gain * (w + (float(action) - u) * 3e-6)
            y = stage if order == 1 else gain * (y + stage - w)
            u, w = float(action), stage
            expected.append(y)
        np.testing.assert_allclose(setpoints, expected, rtol=1e-12, atol=1e-21)
        late[order] = np.mean(setpoints[300:])
    tau = 1.0 / (2.0 * math.pi * 2.0)
    assert late[1] == pytest.approx(rate / 5e-3 * tau * 3e-6, rel=0.05)  # r tau limit: 95 nm
    assert abs(late[2]) < 0.01 * late[1]


def test_a_gate_passes_each_rigs_action_while_its_foot_reads_at_or_below_the_gate():
    observations = np.zeros((4, len(OBSERVATION_SCALES)), dtype=np.float32)
    observations[:, OBSERVATION_INDEX["height"]] = np.array([0.02, 0.0, -0.01, 0.0101]) / OBSERVATION_SCALES["height"]
    actions = np.array([0.5, -0.25, 1.0, 0.75])
    np.testing.assert_array_equal(gated_actions(actions, observations, 0.0), [0.0, -0.25, 1.0, 0.0])
    np.testing.assert_array_equal(gated_actions(actions, observations, 0.03), [0.5, -0.25, 1.0, 0.75])
    np.testing.assert_array_equal(gated_actions(actions, observations, 0.015), [0.0, -0.25, 1.0, 0.75])
    assert gated_actions(actions, observations, None) is actions  # no gate


def test_a_foot_exactly_at_the_gate_reads_at_it():
    """The env writes the height reading as float32(height / scale); a foot exactly at a gate
    (every mm from 1 to 99) passes it, held as float32 or widened to float64, and a reading one
    float32 step above does not: the gate is compared in those units. Converted back to metres in
    float32, 24 of these readings were shut out and 12 readings a step above passed."""
    gates_m = np.arange(1, 100) * 1e-3
    observations = np.zeros((gates_m.size, len(OBSERVATION_SCALES)), dtype=np.float32)
    observations[:, OBSERVATION_INDEX["height"]] = [np.float32(g / OBSERVATION_SCALES["height"]) for g in gates_m]
    for gate_m, row in zip(gates_m, observations, strict=True):
        assert gated_actions(np.ones(1), row[None], float(gate_m))[0] == 1.0, gate_m
        assert gated_actions(np.ones(1), row[None].astype(np.float64), float(gate_m))[0] == 1.0, gate_m  # widened
        above = row.copy()
        above[OBSERVATION_INDEX["height"]] = np.nextafter(row[OBSERVATION_INDEX["height"]], np.float32(1))
        assert gated_actions(np.ones(1), above[None], float(gate_m))[0] == 0.0, gate_m  # a float32 step above


def test_a_residual_gated_to_the_contact_leaves_the_free_fall_to_the_base_controller():
    """``residual_gate_m=0``: until the first decision whose foot reading (encoder + ruler) is at
    or below the pad, a held action of 1 moves nothing, and the episode is the zero action's bit for
    bit; at that decision the action passes into the two-stage high-pass, y = a^2 3 um."""
    scenario = Scenario("touch", (LoadStep(1.5),), descent_height_m=0.002, duration_s=0.6)
    kwargs = {
        "scenario": scenario, "action_mode": "residual", "base_controller": "adaptive-dither", "decision_period": 5,
        "residual_limit_m": 3e-6, "residual_highpass_hz": 2.0, "residual_highpass_order": 2, "residual_gate_m": 0.0,
    }  # fmt: skip
    runs = {}
    for action in (0.0, 1.0):
        env = MicroGravityLandingEnv(**kwargs)
        observation, _ = env.reset(seed=3)
        heights, xs, setpoints = [], [], []
        for _ in range(110):
            heights.append(float(observation[OBSERVATION_INDEX["height"]]) * OBSERVATION_SCALES["height"])
            observation, _, _, _, info = env.step(np.array([action], dtype=np.float32))
            xs.append(info["x_m"])
            setpoints.append(info["setpoint_m"])
        runs[action] = np.array(heights), np.array(xs), np.array(setpoints)
    heights, xs, setpoints = runs[1.0]
    opened = int(np.argmax(heights <= 0.0))
    assert 20 < opened < 100  # the foot reached the pad inside the run
    np.testing.assert_array_equal(xs[:opened], runs[0.0][1][:opened])
    np.testing.assert_array_equal(heights[: opened + 1], runs[0.0][0][: opened + 1])
    assert not setpoints[:opened].any()
    assert setpoints[opened] == pytest.approx(highpass_gain(2.0, 5e-3) ** 2 * 3e-6, rel=1e-12)
    assert abs(xs[opened + 2] - runs[0.0][1][opened + 2]) > 1e-8  # and it moves x from there
    # the gate on the setpoint: the held action went through the filter all along and has decayed
    env = MicroGravityLandingEnv(**kwargs, residual_gate_on="setpoint")
    env.reset(seed=3)
    setpoints = [env.step(np.ones(1, dtype=np.float32))[4]["setpoint_m"] for _ in range(opened + 1)]
    assert not any(setpoints[:opened])
    a = highpass_gain(2.0, 5e-3)
    expected = _step_response(a, opened + 1) * 3e-6
    assert setpoints[opened] == pytest.approx(expected, rel=1e-9)
    assert abs(setpoints[opened]) < 0.05 * a**2 * 3e-6  # not the step the gate on the action lets in


def _step_response(a: float, n: int) -> float:
    """The two-stage high-pass's output n samples after a unit step (both stages start at rest)."""
    u_prev, w, y = 0.0, 0.0, 0.0
    for _ in range(n):
        w_new = a * (w + 1.0 - u_prev)
        y = a * (y + w_new - w)
        u_prev, w = 1.0, w_new
    return y


def test_the_decision_period_holds_the_action_and_steps_the_control_periods():
    env = MicroGravityLandingEnv(condition=1, decision_period=5, action_mode="residual", base_controller="pid")
    _, info = env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))
    assert info["time_s"] == pytest.approx(5e-3)
    scenario = Scenario("short", (LoadStep(0.49),), descent_height_m=0.09, duration_s=0.012)
    env = MicroGravityLandingEnv(scenario=scenario, decision_period=5, action_mode="residual")
    env.reset(seed=0)
    steps = [env.step(np.zeros(1, dtype=np.float32)) for _ in range(3)]
    assert [s[3] for s in steps] == [False, False, True]  # truncated inside the third decision
    assert steps[-1][4]["time_s"] == pytest.approx(0.012)


def test_training_schedules_are_drawn_at_reset_with_a_placement_and_a_touchdown():
    from microg_env.scenarios import ScenarioSampler

    env = gym.make(ENV_ID, scenario_sampler="training", domain_randomization=True)
    for seed in range(5):
        env.reset(seed=seed)
        scenario = env.unwrapped.active_scenario
        touchdown = scenario.ideal_touchdown_s(env.unwrapped.params.lander.mass_kg, 9.8009)
        assert len(scenario.loads) == 2
        assert scenario.loads[1].height_m is not None
        assert touchdown <= ScenarioSampler().max_touchdown_s
        assert scenario.duration_s == pytest.approx(touchdown + ScenarioSampler().after_touchdown_s, rel=0.06)
    env.reset(seed=1)
    first = env.unwrapped.active_scenario
    env.reset(seed=1)
    assert env.unwrapped.active_scenario == first
    with pytest.raises(ValueError, match="scenario_sampler"):
        MicroGravityLandingEnv(scenario=CONDITIONS_1, scenario_sampler="training")
    with pytest.raises(ValueError, match="max_touchdown_s"):
        MicroGravityLandingEnv(scenario_sampler={"descent_height_m": [0.05, 0.06], "max_touchdown_s": 1.0})


def test_guide_stroke_limit_terminates_with_a_reason():
    env = MicroGravityLandingEnv(condition=1)
    _, infos = _rollout(env, seed=0, steps=2000, action=1.0)  # drive the support up at full speed
    assert infos[-1]["termination_reason"] == "guide_stroke_limit"
    assert len(infos) < 2001


def test_the_foot_never_tunnels_through_the_pad():
    """Driving the support down at 125 mm/s sinks the foot to the pad's full depth: the pad pushes
    back at every depth (the old box pad pulled the lander through past 75 mm) and the episode
    ends where the foot bottoms out on the floor. (A restoring QZS makes the uncontrolled lander go
    down with the support; with Eq. 17's literal sign it would leave the guide first.)"""
    from microg_env.params import QZSParams

    params = RigParams(qzs=QZSParams(residual_stiffness_n_per_m=35510.0))
    env = MicroGravityLandingEnv(condition=1, params=params, imperfections=Imperfections(control_delay=False))
    _, infos = _rollout(env, seed=0, steps=5000, action=-0.1)
    heights = np.array([i["foot_height_m"] for i in infos])
    forces = np.array([i["pad_force_n"] for i in infos])
    deep = heights < -0.07
    assert heights.min() < -0.076  # past the depth where the old pad's contact normal flipped
    assert np.all(forces[heights < -1e-4] > 0.0)  # the pad pushes whenever the foot is in it
    assert np.all(np.diff(forces[deep]) > 0.0)  # and harder the deeper it goes
    assert infos[-1]["termination_reason"] in ("pad_bottomed_out", "screw_stroke_limit")
    assert heights.min() > -0.1


def test_out_of_range_actions_are_clipped():
    env = MicroGravityLandingEnv(condition=1, imperfections=Imperfections.none())
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([7.0], dtype=np.float32))
    assert info["command_m_s"] == pytest.approx(1.25)


@pytest.mark.parametrize(
    "action",
    [
        np.array([np.nan]),
        np.array([np.inf]),
        np.array([0.1, 0.2]),
        np.array([[0.1]]),
        0.3,
        "up",
        None,
        np.array([True]),
        np.array(["0.5"]),
        np.array([0.5 + 0j]),
    ],
)
def test_bad_actions_raise(action):
    env = MicroGravityLandingEnv(condition=1)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(action)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"condition": 4}, "condition"),
        ({"condition": True}, "condition"),
        ({"control_period_s": 0.0}, "control_period_s"),
        ({"control_period_s": float("nan")}, "control_period_s"),
        ({"control_period_s": 1e-9}, "control_period_s"),
        ({"control_period_s": 1.0}, "control_period_s"),
        ({"control_period_s": 1.5e-4}, "whole number of physics steps"),
        ({"physics_step_s": 1e-9}, "physics_step_s"),
        ({"physics_step_s": 2e-3}, "physics_step_s"),
        ({"drive_scheme": "rk4"}, "drive_scheme"),
        ({"reward_scale_m": -1.0}, "reward_scale_m"),
        ({"reward_scale_m": 1e-200}, "reward_scale_m"),
        ({"decision_period": 0}, "decision_period"),
        ({"action_mode": "torque"}, "action_mode"),
        ({"base_controller": "lqr"}, "base_controller"),
        ({"residual_limit_m": 1.0}, "residual_limit_m"),
        ({"residual_highpass_hz": -1.0}, "residual_highpass_hz"),
        ({"residual_highpass_hz": 500.0}, "residual_highpass_hz"),
        ({"residual_highpass_order": 3}, "residual_highpass_order"),
        ({"residual_highpass_order": 2.0}, "residual_highpass_order"),
        ({"residual_highpass_order": True}, "residual_highpass_order"),
        ({"residual_gate_m": -1e-3}, "residual_gate_m"),
        ({"residual_gate_m": 0.5}, "residual_gate_m"),
        ({"residual_gate_m": "0"}, "residual_gate_m"),
        ({"residual_gate_m": True}, "residual_gate_m"),
        ({"residual_gate_m": float("nan")}, "residual_gate_m"),
        ({"residual_gate_m": 0.0}, r"residual_gate_m 0.0: only action_mode 'residual' or 'gains' has it"),
        # each of these was ignored while its siblings were refused
        ({"base_controller": "adaptive"}, r"base_controller 'adaptive': only action_mode 'residual' or 'gains' has it"),
        ({"gain_limit": 3.0}, r"gain_limit 3.0: only action_mode 'gains' has it"),
        (
            {"action_mode": "gains", "base_controller": "adaptive"},
            r"base_controller 'adaptive': action_mode='gains' schedules the gains of pid or pid-dom",
        ),
        ({"action_mode": "gains", "gain_limit": 1.0}, r"gain_limit 1.0: the action would move no gain"),
        ({"action_mode": "gains", "gain_limit": 20.0}, r"gain_limit must be in \[1, 10\], got 20.0"),
        ({"action_mode": "gains", "gain_limit": "2"}, r"gain_limit"),
        (
            {"action_mode": "residual", "speed_limit_m_s": 0.1},
            r"speed_limit_m_s 0.1: only action_mode 'speed' has it \(action_mode is 'residual'\)",
        ),
        ({"speed_limit_m_s": 2.0}, r"speed_limit_m_s must be in \[0.001, 1.25\] m/s, got 2.0"),
        ({"speed_limit_m_s": 0.0}, r"speed_limit_m_s must be in \[0.001, 1.25\] m/s, got 0.0"),
        ({"speed_limit_m_s": float("nan")}, r"speed_limit_m_s"),
        (
            {"action_mode": "gains", "residual_limit_m": 2e-6},
            r"residual_limit_m 2e-06: only action_mode 'residual' has it",
        ),
        ({"condition": 2, "scenario_sampler": "training"}, "condition 2: scenario_sampler gives the schedule"),
        (
            {"condition": 3, "scenario": Scenario("s", (LoadStep(0.49),), 0.03)},
            "condition 3: scenario gives the schedule",
        ),
        (
            {"action_mode": "residual", "residual_highpass_order": 2},
            "residual_highpass_order 2: there is no high-pass to cascade",
        ),
        (
            {"reward_descent_scale_m_s": 1e-5},
            "reward_descent_scale_m_s 1e-05: the descent term it scales has no weight",
        ),
        ({"residual_highpass_hz": 2.0}, r"residual_highpass_hz 2.0: only action_mode 'residual' has it"),
        (
            {"action_mode": "residual", "residual_gate_on": "filter"},
            r"residual_gate_on must be one of 'action', 'setpoint'",
        ),
        ({"residual_highpass_order": 2}, r"residual_highpass_order 2: only action_mode 'residual' has it"),
        ({"residual_limit_m": 3e-6}, r"residual_limit_m 3e-06: only action_mode 'residual' has it"),
        ({"action_mode": "residual", "residual_gate_on": "setpoint"}, "there is no gate to place"),
        ({"hidden_observations": "height"}, "hidden_observations must be a list"),
        ({"hidden_observations": ["heights"]}, r"hidden_observations\[0\] must be one of .*got 'heights'"),
        ({"hidden_observations": ["x", ["x"]]}, r"hidden_observations\[1\] must be one of"),
        ({"hidden_observations": ["x", "x"]}, r"hidden_observations\[1\]: 'x' is given twice"),
        ({"scenario_sampler": "testing"}, "scenario_sampler"),
        ({"domain_randomization": {"pad_stiffness": 2.0}}, "pad_stiffness"),
        ({"domain_randomization": "drive"}, "domain_randomization"),
        ({"imperfections": {"friction": "yes"}}, "friction"),
        ({"condition": np.array(3)}, "condition"),
        ({"condition": [3]}, "condition"),
        ({"camera_name": ["side"]}, "camera_name"),
        ({"xml_file": "/etc/hostname"}, "xml_file"),
        ({"reset_noise_scale": 0.3}, "reset_noise_scale"),
        ({"reset_noise_scale": -0.01}, "reset_noise_scale"),
        ({"scenario_sampler": "training", "reset_noise_scale": 0.02}, "reset_noise_scale"),  # foot in the pad
        ({"render_mode": "ascii"}, "render_mode"),
        ({"imperfections": "all"}, "imperfections"),
        ({"params": {"pad": 1}}, "params"),
        ({"width": 0}, "width"),
        ({"height": -5}, "height"),
        ({"camera_name": "nope"}, "camera_name"),
        ({"xml_file": "/nonexistent/scene.xml"}, "xml_file"),
        ({"scenario": Scenario("tall", (LoadStep(0.49),), descent_height_m=0.5)}, "descent_height_m"),
        ({"scenario": Scenario("long", (LoadStep(0.49),), 0.09, duration_s=600.0), "control_period_s": 1e-4}, "steps"),
    ],
)
def test_bad_arguments_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        MicroGravityLandingEnv(**kwargs)


def test_reset_noise_keeps_the_start_above_the_pad_and_every_switch_height():
    """Condition 3 with 0.06 m of noise started the foot 4.5 mm inside the pad (seed 34); the bound
    is now the room above the 25 mm switch height, and every start respects it."""
    with pytest.raises(ValueError, match="reset_noise_scale"):
        MicroGravityLandingEnv(condition=3, reset_noise_scale=0.06)
    env = MicroGravityLandingEnv(condition=3, reset_noise_scale=0.028)
    for seed in range(60):
        _, info = env.reset(seed=seed)
        assert info["foot_height_m"] > 0.025
        assert info["placed_load_kg"] == pytest.approx(0.05)  # the 1 kg is not placed at the start
        assert info["pad_force_n"] == 0.0


def test_bad_seed_is_named():
    with pytest.raises(ValueError, match="seed"):
        MicroGravityLandingEnv().reset(seed=-1)


@pytest.mark.parametrize(
    ("build", "field"),
    [
        (lambda: Scenario("s", (), 0.09), "loads"),
        (lambda: Scenario("s", (LoadStep(0.49),), -0.09), "descent_height_m"),
        (lambda: Scenario("s", (LoadStep(0.49),), 0.09, duration_s=601.0), "duration_s"),
        (lambda: Scenario("s", (LoadStep(0.49),), 0.09, overrides={"pad.softness": 1.0}), "pad.softness"),
        (lambda: Scenario("s", (LoadStep(0.05), LoadStep(1.0, 0.1)), 0.09), "descent height"),
        (lambda: Scenario("s", (LoadStep(0.05, 0.02),), 0.09), "t = 0"),
        (lambda: LoadStep(-1.0), "mass_kg"),
        (lambda: LoadStep(True), "mass_kg"),
        (lambda: LoadStep(1.0, float("inf")), "height_m"),
    ],
)
def test_bad_scenarios_name_the_field(build, field):
    with pytest.raises(ValueError, match=field):
        build()


def test_domain_randomization_changes_the_rig_each_reset_without_recompiling():
    env = MicroGravityLandingEnv(condition=1, domain_randomization=DomainRandomization())
    model = env.model
    env.reset(seed=0)
    first = (env.params.pad.stiffness_n_per_m, env.active_scenario.loads[0].mass_kg, env.params.lander.mass_kg)
    env.reset(seed=1)
    second = (env.params.pad.stiffness_n_per_m, env.active_scenario.loads[0].mass_kg, env.params.lander.mass_kg)
    assert first != second
    assert env.params.lander.mass_kg <= 620.0
    assert env.model is model  # the same compiled model, its field values changed
    assert env.model.body("lander").mass[0] == env.params.lander.mass_kg
    env.reset(seed=0)
    assert (env.params.pad.stiffness_n_per_m, env.active_scenario.loads[0].mass_kg, env.params.lander.mass_kg) == first


def test_a_seed_draws_one_plant_whatever_its_schedule():
    """The plant comes from a stream of its own: schedules of one, three and four weights, and the
    training sampler's draws, meet the same plant from one seed, and only the weights differ (the
    plant once followed the weights' draws: one-weight schedules shared every plant, the others
    each met another)."""
    from microg_env.scenarios import HELD_OUT

    plants = []
    for name in ("light-long", "three-stage", "four-stage"):
        env = MicroGravityLandingEnv(scenario=HELD_OUT[name], domain_randomization="wider")
        env.reset(seed=7)
        plants.append(env.params)
    env = MicroGravityLandingEnv(scenario_sampler="training", domain_randomization="wider")
    env.reset(seed=7)
    plants.append(env.params)
    assert plants[0] != RigParams()
    assert all(plant == plants[0] for plant in plants)
    env.reset(seed=8)
    assert env.params != plants[0]


def test_the_full_randomisation_draws_the_drive_after_the_plant_and_writes_it_into_the_model():
    """The drive's draws come after the older ones (a plant drawn by the defaults is unchanged), and
    every drawn drive parameter reaches the compiled model of the running episode."""
    plain, full = DomainRandomization(), DomainRandomization.full()
    params, loads = RigParams(), (0.05, 1.0)
    old, _ = plain.sample(params, loads, np.random.default_rng(3))
    new, _ = full.sample(params, loads, np.random.default_rng(3))
    assert (new.lander, new.pad, new.qzs) == (old.lander, old.pad, old.qzs)
    assert new.servo.coulomb_torque_n_m == old.servo.coulomb_torque_n_m
    assert old.servo.cogging_phase_rad == 0.0
    assert old.servo.speed_loop_gain_hz == 100.0
    env = MicroGravityLandingEnv(condition=1, domain_randomization="full")  # as a YAML file names it
    assert env.settings.domain_randomization == full
    phases = set()
    for seed in range(4):
        env.reset(seed=seed)
        servo, motor = env.params.servo, env.model.actuator("servo")
        phases.add(servo.cogging_phase_rad)
        assert motor.biasprm[0] == servo.cogging_torque_n_m
        assert motor.biasprm[2] == servo.cogging_phase_rad
        assert motor.biasprm[5] == servo.stribeck_speed_rad_s
        assert motor.dynprm[0] == servo.torque_filter_s
        assert motor.dynprm[5] == servo.bristle_stiffness_n_m_per_rad
        assert motor.gainprm[6] == pytest.approx(2 * np.pi * servo.speed_loop_gain_hz * drive_inertia_kg_m2(env.params))
    assert len(phases) == 4
    assert max(map(abs, phases)) <= np.pi


@pytest.mark.slow
def test_the_papers_sensor_set_hides_the_pad_force_and_accelerometer_and_nothing_else():
    """On the paper's sensors the pad force and accelerometer entries read 0 while the pad pushes;
    a controller that reads neither (the PID) runs the same episode bit for bit on either set, one
    that reads the pad force (the feed-forward) does not."""
    runs = {}
    for sensors in ("extended", "paper"):
        for name in ("pid", "feedforward"):
            env = MicroGravityLandingEnv(condition=2, sensor_set=sensors)
            controller = make_controller(name, env.settings.control_period_s)
            observation, _ = env.reset(seed=4)
            controller.reset()
            rows, forces = [], []
            for _ in range(4000):  # condition 2 touches down at ~3.4 s
                observation, _, _, _, info = env.step(controller(observation))
                rows.append(observation)
                forces.append(info["pad_force_n"])
            runs[sensors, name] = np.array(rows), np.array(forces)
    hidden = [OBSERVATION_INDEX["pad_force"], OBSERVATION_INDEX["lander_accel"]]
    rows, forces = runs["paper", "pid"]
    assert forces.max() > 50  # the lander is on the pad
    assert not rows[:, hidden].any()
    assert runs["extended", "pid"][0][:, hidden].any()
    shown = [i for i in range(rows.shape[1]) if i not in hidden]
    np.testing.assert_array_equal(rows[:, shown], runs["extended", "pid"][0][:, shown])
    assert not np.array_equal(runs["paper", "feedforward"][0][:, 0], runs["extended", "feedforward"][0][:, 0])
    with pytest.raises(ValueError, match="sensor_set"):
        MicroGravityLandingEnv(sensor_set="ruler")


def test_a_mixed_sensor_set_draws_each_episodes_set_with_equal_odds_leaving_every_other_draw():
    """``sensor_set="mixed"`` draws the paper's set or the extended one at each reset, about as
    often each, from a child of the episode's generator: the plant, schedule and drift of a seed
    are those of the fixed sets (and so is its sensor noise, by the next test)."""
    mixed = MicroGravityLandingEnv(sensor_set="mixed", scenario_sampler="training", domain_randomization="full")
    fixed = MicroGravityLandingEnv(scenario_sampler="training", domain_randomization="full")
    drawn = []
    for seed in range(400):
        episode = mixed.core.draw_episode(0, np.random.default_rng(seed))
        same = fixed.core.draw_episode(0, np.random.default_rng(seed))
        assert (episode.params, episode.scenario, episode.height_m) == (same.params, same.scenario, same.height_m)
        assert episode.drift_rate_k_per_s == same.drift_rate_k_per_s
        assert same.sensor_set == "extended"
        drawn.append(episode.sensor_set)
    assert set(drawn) == {"paper", "extended"}
    assert 160 <= drawn.count("paper") <= 240  # 200 +- 4 standard deviations of 400 fair draws
    assert not mixed.core.can_run_pid(make_controller("pid", mixed.settings.control_period_s))
    # resets without a seed draw afresh, and a copy draws what the original does
    mixed.reset(seed=3)
    twin = copy.deepcopy(mixed)
    sets = {env: [] for env in (mixed, twin)}
    for _ in range(12):
        for env, seen in sets.items():
            _, info = env.reset()
            assert info["sensor_set"] == env.core.episodes[0].sensor_set  # the drawn set, reported
            seen.append(info["sensor_set"])
    assert sets[mixed] == sets[twin]
    assert set(sets[mixed]) == {"paper", "extended"}


@pytest.mark.slow
def test_a_mixed_sensor_set_runs_each_episode_bit_for_bit_as_its_drawn_set():
    """An episode of the mixed set is the fixed drawn set's episode of the same seed, observation
    for observation, with a controller that reads the pad force (so the sets' episodes differ)."""
    touch = Scenario("touch", (LoadStep(1.5),), descent_height_m=0.002, duration_s=0.6)
    runs = {}
    for sensors in ("mixed", "paper", "extended"):
        env = MicroGravityLandingEnv(scenario=touch, sensor_set=sensors)
        controller = make_controller("feedforward", env.settings.control_period_s)
        for seed in range(6):
            observation, _ = env.reset(seed=seed)
            controller.reset()
            rows = [observation]
            for _ in range(600):
                observation, _, terminated, truncated, info = env.step(controller(observation))
                rows.append(observation)
                if terminated or truncated:
                    break
            runs[sensors, seed] = np.array(rows), env.core.episodes[0].sensor_set, info["pad_force_n"]
    assert {runs["mixed", seed][1] for seed in range(6)} == {"paper", "extended"}
    for seed in range(6):
        rows, drawn, force = runs["mixed", seed]
        assert force > 1.0  # the lander is on the pad
        np.testing.assert_array_equal(rows, runs[drawn, seed][0])
        other = "paper" if drawn == "extended" else "extended"
        assert not np.array_equal(rows, runs[other, seed][0])


@pytest.mark.parametrize(("decision_period", "fps"), [(1, 1000), (5, 200)])
def test_dt_and_render_fps_are_one_step_of_simulated_time(decision_period, fps):
    """A step holds the action ``decision_period`` control periods: ``dt`` is that time (as
    Gymnasium's MuJoCo envs define it) and frames rendered once a step play in real time."""
    env = MicroGravityLandingEnv(condition=1, action_mode="residual", decision_period=decision_period)
    _, info = env.reset(seed=0)
    _, _, _, _, after = env.step(np.zeros(1, dtype=np.float32))
    assert after["time_s"] - info["time_s"] == pytest.approx(env.dt)
    assert env.dt == pytest.approx(decision_period * 1e-3)
    assert env.metadata["render_fps"] == fps


def test_impossible_randomisation_is_rejected_at_construction():
    """A 99 % lander-mass range could draw a 6 kg lander under 0.5 kg of weights: reset used to fail
    on some seeds and leave the environment half-updated."""
    with pytest.raises(ValueError, match="lander_mass"):
        MicroGravityLandingEnv(condition=1, domain_randomization=DomainRandomization(lander_mass=0.99))
    with pytest.raises(ValueError, match="domain_randomization: pad stiffness"):  # a 47 N/m pad sinks 191 mm
        MicroGravityLandingEnv(condition=1, domain_randomization=DomainRandomization(pad_stiffness=0.99))


def test_a_failed_reset_leaves_the_environment_exactly_as_it_was(monkeypatch):
    env = MicroGravityLandingEnv(condition=1, domain_randomization=DomainRandomization())
    env.reset(seed=5)
    _steps(env, 20)
    before = pickle.dumps(env)
    expected = _steps(copy.deepcopy(env), 30)

    def failing_sample(*args, **kwargs):
        raise ValueError("a draw the rig cannot take")

    monkeypatch.setattr(DomainRandomization, "sample", failing_sample)
    with pytest.raises(ValueError, match="draw"):
        env.reset(seed=6)
    monkeypatch.undo()
    assert pickle.dumps(env) == before
    np.testing.assert_array_equal(_steps(env, 30), expected)


def test_every_parameter_passed_in_reaches_the_episode_the_model_and_the_reference():
    from dataclasses import replace

    from microg_env.controllers import make_controller
    from microg_env.params import LanderParams, PadParams, RigParams
    from microg_env.rollout.episode import reference_for, run_episode

    params = replace(RigParams(), pad=PadParams(stiffness_n_per_m=8000.0), lander=LanderParams(mass_kg=500.0))
    env = gym.make(ENV_ID, params=params)
    trajectory = run_episode(env, make_controller("pid", 1e-3), seed=0, duration_s=6.0)
    rig_env = env.unwrapped
    assert rig_env.params.pad.stiffness_n_per_m == 8000.0
    assert rig_env.params.lander.mass_kg == 500.0
    assert rig_env.model.body("lander").mass[0] == 500.0
    model, pad = rig_env.model, rig_env.model.geom("pad").id
    n, d = rig_env.rig.pad_contacts, params.pad.impedance
    carried = 500.0 + 0.49
    assert -model.geom_solref[pad, 0] * n * carried / (1 + (n - 1) * d) == pytest.approx(8000.0)
    assert trajectory.lander_mass_kg == 500.0
    reference = reference_for(env, trajectory)
    assert reference.lander_mass_kg == 500.0
    # The reference falls at m g / (M + m) of the 500 kg lander.
    t, h = reference.time_s[500:4000], reference.foot_height_m[500:4000]  # the free fall
    assert 2 * np.polyfit(t, h, 2)[0] == pytest.approx(-0.49 * 9.8009 / 500.49, rel=1e-6)


def test_scenario_overrides_are_explicit_and_apply_on_top_of_params():
    scenario = Scenario("stiff pad", (LoadStep(0.49),), 0.09, overrides={"pad.stiffness_n_per_m": 9000.0})
    env = MicroGravityLandingEnv(scenario=scenario)
    assert env.params.pad.stiffness_n_per_m == 9000.0
    assert env.params.pad.damping_n_s_per_m == 200.0  # nothing else changes
    assert env.params.lander.mass_kg == 620.0


@pytest.mark.slow
def test_rgb_array_render():
    env = gym.make(ENV_ID, render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0)
    try:
        frame = env.render()
    except Exception as error:  # no OpenGL context on this machine (set MUJOCO_GL=egl or osmesa)
        pytest.skip(f"offscreen rendering unavailable: {error}")
    finally:
        env.close()
    assert frame.shape == (120, 160, 3)
    assert frame.dtype == np.uint8
    assert frame.std() > 0


@pytest.mark.slow
def test_human_render_without_a_display_is_a_clear_error_not_an_abort():
    code = "import microg_env; microg_env.MicroGravityLandingEnv(render_mode='human')"
    environment = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment, check=False)
    assert result.returncode == 1  # a Python exception, not SIGABRT (-6)
    assert "render_mode='human' needs a display" in result.stderr


@pytest.mark.slow
def test_a_long_episode_made_by_id_runs_to_its_scenario_duration():
    """Registered with max_episode_steps=30000, gym.make cut 100 us episodes off at 3 s."""
    scenario = Scenario("long", (LoadStep(0.49),), descent_height_m=0.09, duration_s=3.2)
    env = gym.make(ENV_ID, scenario=scenario, control_period_s=1e-4)
    from microg_env.controllers import make_controller
    from microg_env.rollout.episode import run_episode

    trajectory = run_episode(env, make_controller("pid", 1e-4), seed=0)
    assert len(trajectory) - 1 == 32_000
    assert trajectory.time_s[-1] == pytest.approx(3.2)
    assert trajectory.termination_reason is None


def test_gymnasiums_time_aware_observation_wraps_every_id():
    """Every id registers a step limit (the most control periods a run may take), so Gymnasium's
    wrappers that need one work; the episode still ends at its own duration."""
    from gymnasium.wrappers import TimeAwareObservation

    for env_id in [name for name in gym.registry if name.startswith("microg_env:")]:
        env = TimeAwareObservation(gym.make(env_id))
        obs, _ = env.reset(seed=0)
        assert obs.shape == (env.unwrapped.observation_space.shape[0] + 1,), env_id
        assert obs[-1] == 0
        obs, *_ = env.step(env.action_space.sample() * 0)
        assert obs[-1] == 1
    env = gym.make(ENV_ID, scenario=Scenario("short", (LoadStep(0.49),), 0.09, duration_s=0.01))
    steps, truncated = 0, False
    env.reset(seed=0)
    while not truncated:
        *_, truncated, _ = env.step(np.zeros(1, dtype=np.float32))
        steps += 1
    assert steps == 10  # 10 ms at 1 ms


def test_numpy_integer_seeds_are_seeds():
    env = MicroGravityLandingEnv(condition=1)
    first, _ = env.reset(seed=np.int64(5))
    second, _ = env.reset(seed=5)
    np.testing.assert_array_equal(first, second)


def test_templates_are_checked_and_an_exported_model_is_one(tmp_path):
    from microg_env.cli import main

    empty = tmp_path / "empty.xml"
    empty.write_text("<mujoco/>")
    with pytest.raises(ValueError, match="lacks the body"):
        MicroGravityLandingEnv(xml_file=str(empty))
    exported = tmp_path / "exported.xml"
    assert main(["export-mjcf", str(exported), "--load", "0.05"]) == 0
    env = MicroGravityLandingEnv(xml_file=str(exported))
    obs, _ = env.reset(seed=0)
    assert np.all(np.isfinite(obs))


def test_reset_noise_enters_the_pad_check():
    """A soft pad that takes a 100 mm start (70 mm deep) but not a 190 mm one (90 mm, beyond the
    screw's 80 mm below touchdown), the top of 90 mm of start noise, is refused."""
    from microg_env.params import PadParams, RigParams

    soft = RigParams(pad=PadParams(stiffness_n_per_m=300.0, damping_n_s_per_m=30.0))
    scenario = Scenario("soft", (LoadStep(0.49),), descent_height_m=0.1)
    MicroGravityLandingEnv(scenario=scenario, params=soft)
    with pytest.raises(ValueError, match="travel below touchdown"):
        MicroGravityLandingEnv(scenario=scenario, params=soft, reset_noise_scale=0.09)


def test_every_test_scenario_lies_outside_the_training_and_validation_draws():
    """Held out means held out: every comparison scenario starts outside both samplers' starts and
    differs in at least one more way; together the held-out ones cover impact speed, load and the
    number of weights. The check itself sees a drawn schedule as inside."""
    from microg_env.scenarios import CONDITIONS, HELD_OUT, VALIDATION_SAMPLER, ScenarioSampler, comparison_scenarios

    mass, g = RigParams().lander.mass_kg, RigParams().gravity_m_s2
    spread = DomainRandomization.wider().load_mass
    covered = set()
    for sampler in (ScenarioSampler(), VALIDATION_SAMPLER):
        for name, scenario in comparison_scenarios().items():
            outside = sampler.outside(scenario, mass, g, spread)
            assert ("start height" in outside and len(outside) >= 2) or name == "condition-3", (name, outside)
            if name in HELD_OUT:
                covered |= set(outside)
        drawn = sampler.sample(np.random.default_rng(0), mass, g)
        assert sampler.outside(drawn, mass, g) == ()
    assert ScenarioSampler().outside(CONDITIONS[3], mass, g) == ("start height",)  # 55 mm, two weights like training
    assert covered == {"impact speed", "load", "start height", "stages"}
    # eight held-out schedules spanning each axis beyond the training draws on both sides where it can
    speeds = [s.impact_speed_m_s(mass, g) for s in HELD_OUT.values()]
    loads = [kg for s in HELD_OUT.values() for kg in s.loads_kg]
    assert len(HELD_OUT) >= 8
    assert min(speeds) < 0.02
    assert max(speeds) > 0.06  # training's fastest: 48 mm/s
    assert min(loads) <= 0.1
    assert max(loads) >= 2.0
    assert {len(s.loads) for s in HELD_OUT.values()} == {1, 2, 3, 4}
    assert max(s.descent_height_m for s in HELD_OUT.values()) >= 0.12


def test_the_wider_test_plants_draw_every_range_half_again_as_wide():
    full, wider = DomainRandomization.full(), DomainRandomization.wider()
    for name in ("lander_mass", "load_mass", "pad_stiffness", "friction", "cogging", "lugre", "speed_loop"):
        assert getattr(wider, name) == pytest.approx(1.5 * getattr(full, name))
    assert wider.cogging_phase == 1.0
    env = MicroGravityLandingEnv(condition=2, domain_randomization="wider")  # as a YAML file or a RunSpec names it
    assert env.settings.domain_randomization == wider
    stiffness = []
    for seed in range(40):
        env.reset(seed=seed)
        stiffness.append(env.params.pad.stiffness_n_per_m / RigParams().pad.stiffness_n_per_m)
    assert max(abs(s - 1.0) for s in stiffness) > full.pad_stiffness  # beyond any training draw
