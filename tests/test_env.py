"""The Gymnasium environment: conformance, determinism, pickling, vectorisation, bad input."""

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import microg_env
from microg_env import Imperfections, LoadStep, Scenario
from microg_env.analysis.evaluate import run_episode
from microg_env.controllers import make_controller
from microg_env.envs.landing import OBSERVATION_SCALES, MicroGravityLandingEnv
from microg_env.imperfections import DomainRandomization

ENV_ID = "microg_env:MicroGravityLanding-v0"


@pytest.fixture(autouse=True)
def _quiet_gymnasium_warnings():
    # Unbounded observation boxes draw a Gymnasium warning; physical quantities are unbounded.
    gym.logger.min_level = 40
    yield
    gym.logger.min_level = 30


def _rollout(env: gym.Env, seed: int, steps: int, action: float = 0.1) -> tuple[np.ndarray, list[dict]]:
    obs, info = env.reset(seed=seed)
    observations, infos = [obs], [info]
    for _ in range(steps):
        obs, _, terminated, _, info = env.step(np.array([action], dtype=np.float32))
        observations.append(obs)
        infos.append(info)
        if terminated:
            break
    return np.array(observations), infos


def test_registered_and_made_by_id():
    env = gym.make(ENV_ID)
    assert isinstance(env.unwrapped, MicroGravityLandingEnv)
    assert env.spec.max_episode_steps == microg_env.MAX_EPISODE_STEPS == 30_000
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    assert env.observation_space.shape == (len(OBSERVATION_SCALES),)


@pytest.mark.parametrize("condition", [1, 3])
def test_gymnasium_check_env(condition):
    check_env(gym.make(ENV_ID, condition=condition).unwrapped, skip_render_check=True)


def test_stable_baselines3_check_env():
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    sb3_checker.check_env(MicroGravityLandingEnv(condition=2), warn=False)


def test_same_seed_same_trajectory_other_seed_other_noise():
    env = MicroGravityLandingEnv(condition=1)
    first, infos_a = _rollout(env, seed=7, steps=300)
    second, infos_b = _rollout(env, seed=7, steps=300)
    other, _ = _rollout(env, seed=8, steps=300)
    np.testing.assert_array_equal(first, second)
    assert [i["x_m"] for i in infos_a] == [i["x_m"] for i in infos_b]
    assert not np.array_equal(first, other)


def test_pickles_and_runs_after_unpickling():
    env = gym.make(ENV_ID, condition=3, control_period_s=5e-4)
    clone = pickle.loads(pickle.dumps(env))
    a, _ = _rollout(env, seed=3, steps=50)
    b, _ = _rollout(clone, seed=3, steps=50)
    np.testing.assert_array_equal(a, b)
    assert clone.unwrapped.control_period_s == 5e-4


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
def test_control_periods_of_the_paper(period):
    env = MicroGravityLandingEnv(condition=1, control_period_s=period)
    assert env.frame_skip * env.model.opt.timestep == pytest.approx(period)
    assert env.model.opt.timestep <= env.base_params.timestep_s
    _, infos = _rollout(env, seed=0, steps=10, action=0.0)
    assert infos[-1]["time_s"] == pytest.approx(10 * period)


def test_starts_balanced_and_places_loads_on_schedule():
    env = MicroGravityLandingEnv(condition=3, imperfections=Imperfections.none())
    trajectory = run_episode(env, make_controller("pid", env.control_period_s), seed=0, duration_s=11.0)
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


def test_sensor_noise_and_quantisation():
    env = MicroGravityLandingEnv(condition=1)
    sensors = env.params.sensors
    observations, infos = _rollout(env, seed=1, steps=200, action=0.0)
    ruler = observations[:, 0].astype(float) * OBSERVATION_SCALES["x"]
    steps = ruler / sensors.ruler_resolution_m
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-3)  # quantised to the ruler's step
    truth = np.array([i["x_m"] for i in infos])
    assert 0 < np.std(ruler - truth) < 5 * sensors.ruler_noise_m


def test_reward_is_the_compensation_error_with_action_rate_penalty():
    env = MicroGravityLandingEnv(condition=1, imperfections=Imperfections.none())
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([0.0], dtype=np.float32))
    assert reward == pytest.approx(info["reward_compensation"] + info["reward_action_rate"])
    expected_error = info["support_force_deviation_n"] / (0.49 * 9.8009)
    assert info["compensation_error"] == pytest.approx(expected_error)
    assert info["reward_compensation"] == pytest.approx(np.exp(-((expected_error / 0.05) ** 2)))
    _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
    assert info["reward_action_rate"] == pytest.approx(-0.1 * 0.25)


def test_guide_stroke_limit_terminates_with_a_reason():
    env = MicroGravityLandingEnv(condition=1)
    _, infos = _rollout(env, seed=0, steps=2000, action=1.0)  # drive the support up at full speed
    assert infos[-1]["termination_reason"] == "guide_stroke_limit"
    assert len(infos) < 2001


def test_out_of_range_actions_are_clipped():
    env = MicroGravityLandingEnv(condition=1, imperfections=Imperfections.none())
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([7.0], dtype=np.float32))
    assert info["command_m_s"] == pytest.approx(1.25)


@pytest.mark.parametrize(
    "action", [np.array([np.nan]), np.array([np.inf]), np.array([0.1, 0.2]), np.array([[0.1]]), 0.3]
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
        ({"control_period_s": 0.0}, "control_period_s"),
        ({"control_period_s": float("nan")}, "control_period_s"),
        ({"compensation_scale": -1.0}, "compensation_scale"),
        ({"render_mode": "ascii"}, "render_mode"),
        ({"imperfections": "all"}, "imperfections"),
        ({"scenario": Scenario("tall", (LoadStep(0.49),), descent_height_m=0.5)}, "descent_height_m"),
    ],
)
def test_bad_arguments_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        MicroGravityLandingEnv(**kwargs)


@pytest.mark.parametrize(
    ("build", "field"),
    [
        (lambda: Scenario("s", (), 0.09), "loads"),
        (lambda: Scenario("s", (LoadStep(0.49),), -0.09), "descent_height_m"),
        (lambda: Scenario("s", (LoadStep(0.49),), 0.09, pad_damping_n_s_per_m=0.0), "pad_damping_n_s_per_m"),
        (lambda: Scenario("s", (LoadStep(0.05), LoadStep(1.0, 0.1)), 0.09), "descent height"),
        (lambda: Scenario("s", (LoadStep(0.05, 0.02),), 0.09), "t = 0"),
        (lambda: LoadStep(-1.0), "mass_kg"),
        (lambda: LoadStep(1.0, float("inf")), "height_m"),
    ],
)
def test_bad_scenarios_name_the_field(build, field):
    with pytest.raises(ValueError, match=field):
        build()


def test_domain_randomization_changes_the_rig_each_reset():
    env = MicroGravityLandingEnv(condition=1, domain_randomization=DomainRandomization())
    env.reset(seed=0)
    first = (env.active_scenario.pad_stiffness_n_per_m, env.active_scenario.loads[0].mass_kg)
    env.reset(seed=1)
    second = (env.active_scenario.pad_stiffness_n_per_m, env.active_scenario.loads[0].mass_kg)
    assert first != second
    assert env.active_scenario.lander_mass_kg <= 620.0
    env.reset(seed=0)
    assert (env.active_scenario.pad_stiffness_n_per_m, env.active_scenario.loads[0].mass_kg) == first


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
