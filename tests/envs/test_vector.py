"""The vector environment on mujoco.batch: the single env's episodes exactly, Gymnasium's vector
contract (against SyncVectorEnv), stable-baselines3's VecEnv contract, batched comparisons."""

import copy
import gc
import os
import pickle
import time
from dataclasses import replace
from functools import partial

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import microg_env  # noqa: F401  (registers the environment)
from microg_env.controllers.registry import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.envs.vector import MicroGravityLandingVectorEnv
from microg_env.imperfections import DomainRandomization
from microg_env.interface import OBSERVATION_INDEX
from microg_env.rollout.batch import EpisodeSpec, run_batch
from microg_env.rollout.episode import run_episode
from microg_env.scenarios import LoadStep, Scenario, condition

ENV_ID = "microg_env:MicroGravityLanding-v1"
#: Short episodes, so that autoresets come within a test: 40 control periods.
SHORT = Scenario("short", (LoadStep(0.49), LoadStep(0.3, height_m=0.0898)), descent_height_m=0.09, duration_s=0.04)
#: A touchdown within 0.45 s (1.5 kg from 2 mm: about 0.4 s), inside 150 steps of 3 control periods.
TOUCH = Scenario("touch", (LoadStep(1.5),), descent_height_m=0.002, duration_s=0.6)
#: The gated residual on randomised plants, touching down inside the rollout.
GATED = {
    "scenario": TOUCH,
    "action_mode": "residual",
    "base_controller": "adaptive-dither",
    "decision_period": 3,
    "residual_gate_m": 0.0,
    "domain_randomization": True,
}


def _rollout(env, actions, seed):
    """Observations, rewards, terminations, truncations, x, setpoint and sensor set of one env under ``actions``."""
    out = {"obs": [], "reward": [], "terminated": [], "truncated": [], "x": [], "setpoint": [], "sensor_set": []}
    obs, info = env.reset(seed=seed)
    out["obs"].append(obs)
    out["x"].append(info["x_m"])
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        step = (obs, reward, terminated, truncated, info["x_m"], info["setpoint_m"], info["sensor_set"])
        for key, value in zip(out, step, strict=True):
            out[key].append(value)
    return {key: np.array(value) for key, value in out.items()}


@pytest.mark.parametrize(
    "kwargs",
    [
        {"condition": 3, "domain_randomization": True},  # every imperfection, randomised plants
        {"condition": 1, "domain_randomization": DomainRandomization.full()},  # and randomised drives
        {"condition": 1, "domain_randomization": DomainRandomization.full(), "drive_scheme": "mujoco"},
        {"condition": 2, "action_mode": "residual", "base_controller": "feedforward", "decision_period": 3},
        {  # past the descent window's start at 0.2 s: the descent term scored per rig
            "condition": 1,
            "action_mode": "residual",
            "base_controller": "adaptive-dither",
            "decision_period": 3,
            "reward_descent_weight": 0.5,
            "domain_randomization": True,
        },
        GATED,  # each rig's gate opens at its own touchdown (the plants differ)
        GATED | {"sensor_set": "mixed"},  # rig 0 draws the paper's sensors, rigs 1 and 2 the extended
    ],
    ids=[
        "speed-randomised",  # the default midpoint drive: the batch stepped a physics step a call, the env in a kernel
        "speed-randomised-drive",
        "speed-randomised-drive-mujoco",  # MuJoCo's own drive stepping, the batch nstep at once
        "residual-feedforward",
        "residual-descent-reward",
        "residual-gated",
        "residual-gated-mixed-sensors",
    ],
)
@pytest.mark.slow
def test_each_rig_runs_exactly_the_single_envs_episode(kwargs):
    """Rig i seeded s + i gives the single env's episode seeded s + i, bit for bit."""
    n, seed = 3, 40
    actions = np.random.default_rng(1).uniform(-0.02, 0.02, size=(150, n, 1)).astype(np.float32)
    vector = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    assert isinstance(vector, MicroGravityLandingVectorEnv)
    batched = _rollout(vector, actions, seed)
    for i in range(n):
        single = _rollout(gym.make(ENV_ID, **kwargs), actions[:, i], seed + i)
        for key, values in single.items():
            np.testing.assert_array_equal(batched[key][:, i], values, err_msg=f"rig {i} {key}")
    assert np.ptp(batched["x"][-1]) > 0  # the rigs differ (noise, drift, plants): the test can fail
    if "residual_gate_m" in kwargs:  # every rig's gate opened inside the run, none in its first 0.3 s
        assert (batched["setpoint"] != 0).any(axis=0).all()
        assert not batched["setpoint"][:100].any()
    if kwargs.get("sensor_set") == "mixed":  # the rigs drew both sets
        drawn = [episode.sensor_set for episode in vector.core.episodes]
        assert sorted(set(drawn)) == ["extended", "paper"], drawn
        assert batched["sensor_set"][-1].tolist() == drawn  # as info reports it


def test_a_forked_child_that_drops_an_inherited_batch_exits():
    """A forked child has none of its parent batch's threads; freeing the batch used to wait for them
    for ever (CI hung so, in a pool a training script forked from a test worker): now it exits."""
    vector = MicroGravityLandingVectorEnv(4, condition=3, nthread=2)
    vector.reset(seed=1)
    vector.step(np.zeros((4, 1), np.float32))
    child = os.fork()
    if child == 0:  # pragma: no cover (the child's coverage is not collected)
        try:
            del vector
            gc.collect()
        finally:
            os._exit(0)
    deadline = time.monotonic() + 60
    while (ended := os.waitpid(child, os.WNOHANG))[0] == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    if ended[0] == 0:
        os.kill(child, 9)
        os.waitpid(child, 0)
    assert ended[0] == child, "the child hung"
    assert os.waitstatus_to_exitcode(ended[1]) == 0
    vector.close()


def test_a_vector_env_of_one_rig_runs_on_the_batch_and_equals_the_single_env():
    actions = np.random.default_rng(6).uniform(-0.02, 0.02, size=(100, 1, 1)).astype(np.float32)
    vector = MicroGravityLandingVectorEnv(1, condition=3)
    assert type(vector.core.physics).__name__ == "BatchPhysics"
    batched = _rollout(vector, actions, 9)
    single = _rollout(MicroGravityLandingEnv(condition=3), actions[:, 0], 9)
    for key, values in single.items():
        np.testing.assert_array_equal(batched[key][:, 0], values, err_msg=key)


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="the platform has no CPU affinity")
@pytest.mark.parametrize("cores", [{0}, {0, 1, 2}])
def test_nthread_0_steps_on_one_thread_per_core_the_process_may_run_on(monkeypatch, cores):
    """Not MuJoCo's 0, every core of the machine: a process kept to fewer (a container, a test
    worker) then ran spinning threads that fought over them (an identification took 4x as long)."""
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: cores)
    assert MicroGravityLandingVectorEnv(4, condition=3).core.physics.batch.nthread == len(cores)
    assert MicroGravityLandingVectorEnv(2, condition=3, nthread=2).core.physics.batch.nthread == 2


def test_the_gain_scheduling_id_steps_exactly_as_a_sync_vector_env():
    """The gains action (three numbers a rig, gated at the foot's height) through the vector env is
    the single envs' through Gymnasium's SyncVectorEnv, bit for bit, past the gate's opening."""
    env_id, n = "MicroGravityLanding-GainScheduling-v1", 3
    ours = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
    theirs = SyncVectorEnv([partial(gym.make, env_id) for _ in range(n)])
    assert ours.action_space == theirs.action_space == gym.spaces.Box(-1.0, 1.0, (n, 3), np.float32)
    assert data_equivalence(ours.reset(seed=[4, 5, 6]), theirs.reset(seed=[4, 5, 6]), exact=True)
    rng = np.random.default_rng(0)
    scaled = []
    for step in range(300):  # 1.5 s
        actions = rng.uniform(-1, 1, size=(n, 3)).astype(np.float32)
        assert data_equivalence(ours.step(actions), theirs.step(actions), exact=True), f"step {step}"
        scaled.append(ours.unwrapped.core.base.kp_scale[:n].copy())
    scaled = np.array(scaled)
    assert (scaled == 1.0).any()  # the gate was shut
    assert (scaled != 1.0).any()  # then open


def test_the_command_id_steps_exactly_as_a_sync_vector_env_at_its_speed_limit():
    """The command id's speed action (+-1 for +-0.1 m/s, the hidden entries 0) through the vector env
    is the single envs' through SyncVectorEnv, bit for bit, and the drive gets the action times
    0.1 m/s one period late (the control delay), to float32's precision."""
    env_id, n = "MicroGravityLanding-Command-v1", 3
    ours = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
    theirs = SyncVectorEnv([partial(gym.make, env_id) for _ in range(n)])
    assert data_equivalence(ours.reset(seed=[4, 5, 6]), theirs.reset(seed=[4, 5, 6]), exact=True)
    hidden = [OBSERVATION_INDEX[name] for name in gym.spec(env_id).kwargs["hidden_observations"]]
    rng = np.random.default_rng(0)
    sent = np.zeros(n)
    for step in range(300):
        actions = rng.uniform(-1, 1, size=(n, 1)).astype(np.float32)
        mine = ours.step(actions)
        assert data_equivalence(mine, theirs.step(actions), exact=True), f"step {step}"
        assert not mine[0][:, hidden].any()
        np.testing.assert_allclose(mine[4]["command_m_s"], sent, rtol=1e-7, atol=0)  # the drive's float32 action
        sent = actions[:, 0].astype(np.float64) * 0.1


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_steps_exactly_as_a_sync_vector_env_of_single_envs_through_autoresets(mode):
    """Gymnasium's vector contract, checked against its own SyncVectorEnv: spaces, seeding,
    observations, rewards, terminations (large actions hit the guide's end), truncations, infos
    and autoresets, in both autoreset modes; the hidden entries read 0 in every observation,
    final ones included."""
    n = 3
    schedules = [replace(SHORT, duration_s=duration) for duration in (0.04, 0.023, 0.031)]  # rigs end apart
    settings = {"domain_randomization": True, "hidden_observations": ("height", "x_rate")}
    hidden = [OBSERVATION_INDEX["height"], OBSERVATION_INDEX["x_rate"]]
    ours = MicroGravityLandingVectorEnv(n, autoreset_mode=mode, scenarios=schedules, **settings)
    theirs = SyncVectorEnv(
        [partial(MicroGravityLandingEnv, scenario=s, **settings) for s in schedules],
        autoreset_mode=mode,
    )
    assert ours.single_observation_space == theirs.single_observation_space
    assert ours.action_space == theirs.action_space
    assert ours.observation_space == theirs.observation_space
    assert ours.metadata["autoreset_mode"] == theirs.metadata["autoreset_mode"] == mode
    assert data_equivalence(ours.reset(seed=7), theirs.reset(seed=7), exact=True)
    rng = np.random.default_rng(2)
    ended = partly = 0
    for step in range(130):
        scale = 1.0 if step % 50 < 20 else 0.001  # bursts at full speed drive x into the guide's end
        actions = (rng.uniform(-1, 1, size=(n, 1)) * scale).astype(np.float32)
        mine, sync = ours.step(actions), theirs.step(actions)
        assert data_equivalence(mine, sync, exact=True), f"step {step}"
        assert not mine[0][:, hidden].any()
        if "final_obs" in mine[4]:
            assert not any(final[hidden].any() for final in mine[4]["final_obs"][mine[4]["_final_obs"]])
        ended += int(np.sum(mine[2] | mine[3]))
        partly += bool(0 < np.sum(mine[2] | mine[3]) < n)
        if mode == AutoresetMode.SAME_STEP and "final_info" in mine[4]:
            assert set(mine[4]["final_info"]["termination_reason"][mine[4]["_final_info"]]) <= {
                None,
                "guide_stroke_limit",
                "screw_stroke_limit",
                "pad_bottomed_out",
            }
    assert ended >= 6  # several episodes ended and were reset
    assert partly >= 3  # some while the other rigs went on
    mask = np.array([False, True, False])
    assert data_equivalence(
        ours.reset(seed=[None, 3, None], options={"reset_mask": mask}),
        theirs.reset(seed=[None, 3, None], options={"reset_mask": mask}),
        exact=True,
    )


def test_autoreset_disabled_refuses_to_step_an_ended_rig():
    env = MicroGravityLandingVectorEnv(2, autoreset_mode="Disabled", scenario=SHORT)
    env.reset(seed=0)
    for _ in range(40):
        *_, truncated, _ = env.step(np.zeros((2, 1), dtype=np.float32))
    assert truncated.all()
    with pytest.raises(ValueError, match="reset_mask"):
        env.step(np.zeros((2, 1), dtype=np.float32))
    env.reset(options={"reset_mask": np.array([True, True])})
    env.step(np.zeros((2, 1), dtype=np.float32))


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda env: env.step(np.zeros((3, 1))), "shape"),
        (lambda env: env.step(np.full((2, 1), np.nan)), "finite"),
        (lambda env: env.step(np.array([["a"], ["b"]])), "real-valued"),
        (lambda env: env.reset(seed=[1]), "one seed per rig"),
        (lambda env: env.reset(seed=-1), "seed"),
        (lambda env: env.reset(options={"reset_mask": np.array([0, 1])}), "reset_mask"),
    ],
)
def test_bad_input_is_named(call, match):
    env = MicroGravityLandingVectorEnv(2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        call(env)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"num_envs": 0}, "num_envs"),
        ({"num_envs": 2, "scenarios": [SHORT]}, "one Scenario per rig"),
        ({"num_envs": 2, "autoreset_mode": "Sometimes"}, "autoreset_mode"),
        ({"num_envs": 2, "render_mode": "human"}, "render_mode"),
        ({"num_envs": 2, "render_mode": "rgb_array", "camera_name": "top"}, "camera_name"),
        ({"num_envs": 2, "control_period_s": 0.33e-3}, "control_period_s"),
    ],
)
def test_bad_settings_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MicroGravityLandingVectorEnv(**kwargs)


def test_rigs_run_their_own_scenarios_and_a_failed_reset_changes_nothing():
    scenarios = [condition(1), condition(3)]
    env = MicroGravityLandingVectorEnv(2, scenarios=scenarios)
    obs, info = env.reset(seed=5)
    for _ in range(5):
        obs, _, _, _, info = env.step(np.zeros((2, 1), dtype=np.float32))
    assert info["foot_height_m"][0] == pytest.approx(0.09, abs=1e-4)
    assert info["foot_height_m"][1] == pytest.approx(0.055, abs=1e-4)
    single = MicroGravityLandingEnv(scenario=condition(3))
    single.reset(seed=6)
    for _ in range(5):
        expected = single.step(np.zeros(1, dtype=np.float32))[0]
    np.testing.assert_array_equal(obs[1], expected)
    before = env.core.observation.copy(), [rng.bit_generator.state for rng in env._rngs]
    with pytest.raises(ValueError, match="seed"):
        env.reset(seed=[1, -3])
    assert np.array_equal(env.core.observation, before[0])
    assert [rng.bit_generator.state for rng in env._rngs] == before[1]


def test_vectorised_controllers_equal_one_controller_per_rig():
    """A controller given n observations acts as n controllers given one each."""
    rng = np.random.default_rng(3)
    observations = rng.normal(scale=0.3, size=(40, 4, 10)).astype(np.float32)
    baselines = ("pid", "pid-dom", "feedforward", "adaptive", "adaptive-dither", "adaptive-friction")
    for name in (*baselines, "residual-sac-setpoint"):
        together = make_controller(name, 1e-3)
        apart = [make_controller(name, 1e-3) for _ in range(4)]
        for rows in observations:
            batched = together(rows)
            assert batched.shape == (4, 1)
            for i, controller in enumerate(apart):
                np.testing.assert_allclose(batched[i], controller(rows[i]), rtol=1e-6, err_msg=name)
        together.reset(np.array([2]))
        apart[2].reset()
        np.testing.assert_allclose(together(observations[0])[2], apart[2](observations[0][2]), rtol=1e-6)


@pytest.mark.slow
def test_a_batch_of_episodes_is_the_single_env_episode_of_each():
    """The comparison's batch (controllers, scenarios and randomised plants mixed in one batch)
    records each case exactly as the single-env harness does."""
    cases = [
        ("pid", condition(2), 1000),
        ("feedforward", condition(3), 1001),
        ("residual-sac-setpoint", condition(1), 1002),
    ]
    cases += [("oracle", condition(1), 1003), ("oracle", condition(2), 1004)]  # told each rig's own plant
    cases += [("adaptive", condition(1), 1005), ("adaptive", condition(3), 1006)]  # each rig its own estimate
    cases += [("adaptive-dither", condition(2), 1007)]  # and its own dither's phase
    cases = [(name, replace(scenario, duration_s=0.6), seed) for name, scenario, seed in cases]
    drawn = DomainRandomization.full()
    runs = run_batch([EpisodeSpec(*case) for case in cases], {"domain_randomization": drawn})
    for (name, scenario, seed), (trajectory, params, error) in zip(cases, runs, strict=True):
        assert error is None
        env = MicroGravityLandingEnv(scenario=scenario, domain_randomization=drawn)
        single = run_episode(env, make_controller(name, 1e-3), seed=seed)
        assert params == env.params
        assert trajectory.scenario == env.active_scenario
        for channel in ("x_m", "support_position_m", "pad_force_n", "command_m_s", "reward", "time_s"):
            np.testing.assert_array_equal(getattr(trajectory, channel), getattr(single, channel), err_msg=channel)


def test_sb3_vec_env_contract_and_ppo_trains_on_it():
    """stable-baselines3's VecEnv contract, against make_vec_env's DummyVecEnv of single envs:
    seeding, observations, rewards, dones, terminal observations and TimeLimit.truncated; then PPO
    with VecNormalize learns on it."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecEnv, VecNormalize

    from microg_env.learning.vec_env import BatchedVecEnv

    kwargs = {"scenario": SHORT, "action_mode": "residual", "base_controller": "pid"}
    ours = BatchedVecEnv.make(2, **kwargs)
    theirs = make_vec_env("MicroGravityLanding-v1", n_envs=2, env_kwargs=kwargs)
    assert isinstance(ours, VecEnv)
    assert ours.num_envs == 2
    assert ours.observation_space == theirs.observation_space
    assert ours.action_space == theirs.action_space
    ours.seed(11)
    theirs.seed(11)
    np.testing.assert_array_equal(ours.reset(), theirs.reset())
    rng = np.random.default_rng(4)
    dones = 0
    for _ in range(90):
        actions = rng.uniform(-1, 1, size=(2, 1)).astype(np.float32)
        obs, rewards, done, infos = ours.step(actions)
        obs_, rewards_, done_, infos_ = theirs.step(actions)
        np.testing.assert_array_equal(obs, obs_)
        np.testing.assert_array_equal(rewards, rewards_)
        np.testing.assert_array_equal(done, done_)
        for mine, sync in zip(infos, infos_, strict=True):
            assert mine.keys() >= {k for k in sync if k != "episode"}
            assert data_equivalence(mine.get("terminal_observation"), sync.get("terminal_observation"), exact=True)
            assert mine.get("TimeLimit.truncated") == sync.get("TimeLimit.truncated")
            assert mine["x_m"] == sync["x_m"]
        dones += int(done.sum())
        for mine, sync in zip(ours.reset_infos, theirs.reset_infos, strict=True):  # the new episodes' infos
            assert {k: mine[k] for k in sync} == sync
    assert dones >= 4
    assert ours.get_attr("num_envs") == [2, 2]
    assert ours.env_is_wrapped(VecNormalize) == [False, False]
    model = PPO("MlpPolicy", VecNormalize(ours), n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(256)
    assert model.num_timesteps == 256


@pytest.mark.parametrize("duplicate", [copy.deepcopy, lambda env: pickle.loads(pickle.dumps(env))])
def test_a_copy_continues_exactly_as_the_original_under_changing_actions(duplicate):
    """The copy's drive takes its own slew rates (the per-period field lives in the copy's model)."""
    env = MicroGravityLandingEnv(condition=3)
    env.reset(seed=0)
    rng = np.random.default_rng(5)
    for _ in range(50):
        env.step(rng.uniform(-0.01, 0.01, size=1).astype(np.float32))
    twin = duplicate(env)
    for _ in range(300):
        action = rng.uniform(-0.01, 0.01, size=1).astype(np.float32)
        np.testing.assert_array_equal(env.step(action)[0], twin.step(action)[0])


@pytest.mark.slow
def test_rgb_array_render_gives_each_rig_the_single_envs_frame():
    """``gym.make_vec(..., render_mode="rgb_array")``: one frame per rig, each the frame the single
    environment renders for that rig's scenario and seed, after the same steps. The batch's model
    holds a body for each of the most weights any rig places; a rig of fewer weights has the others
    hidden, and its frame differs from its single environment's (built without them) in 2 of 6912
    pixels here, against thousands between the two rigs."""
    scenarios = [condition(1), condition(3)]
    env = gym.make_vec(ENV_ID, num_envs=2, render_mode="rgb_array", scenarios=scenarios, width=96, height=72)
    env.reset(seed=5)
    for _ in range(30):
        env.step(np.full((2, 1), 0.001, dtype=np.float32))
    # an offscreen renderer's first frame differs from its later ones in a few dozen edge pixels
    # (OpenGL state its first pass sets up): both sides compare a later frame
    try:
        env.render()
        frames = env.render()
    except Exception as error:  # no OpenGL context on this machine (set MUJOCO_GL=egl or osmesa)
        pytest.skip(f"offscreen rendering unavailable: {error}")
    finally:
        env.close()
    assert len(frames) == 2
    for rig, scenario in enumerate(scenarios):
        single = MicroGravityLandingEnv(scenario=scenario, render_mode="rgb_array", width=96, height=72)
        single.reset(seed=5 + rig)
        for _ in range(30):
            single.step(np.full(1, 0.001, dtype=np.float32))
        single.render()
        differ = (frames[rig] != single.render()).any(axis=2).sum()
        assert differ == 0 if len(scenario.loads) == 2 else differ <= 5, (rig, differ)
        single.close()
    assert (frames[0] != frames[1]).any(axis=2).sum() > 200  # 90 mm against 55 mm: the rigs differ


def test_make_vec_takes_the_ids_step_limit_as_gym_make_does():
    """gym.make_vec hands the vector env the id's max_episode_steps (it raised on it); a limit
    given ends each rig's episode at that many steps, as gym.make's TimeLimit ends the single env's."""
    default = gym.make_vec("microg_env:MicroGravityLanding-Residual-v6", num_envs=2)
    assert default.unwrapped.core.period_limit == 10**6  # no episode reaches it: the env ends first
    vector = gym.make_vec(ENV_ID, num_envs=2, max_episode_steps=7, vectorization_mode="vector_entry_point")
    single = gym.make(ENV_ID, max_episode_steps=7)
    vector.reset(seed=3)
    single.reset(seed=3)
    for step in range(7):
        *_, truncated, _ = vector.step(np.zeros((2, 1), dtype=np.float32))
        *_, alone, _ = single.step(np.zeros(1, dtype=np.float32))
        assert truncated.tolist() == [step == 6] * 2
        assert alone == (step == 6)
    with pytest.raises(ValueError, match="max_episode_steps"):
        gym.make_vec(ENV_ID, num_envs=2, max_episode_steps=0, vectorization_mode="vector_entry_point")
