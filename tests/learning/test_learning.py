"""Learned controllers: hyperparameter files, the NumPy export, the policy as a controller, the
training pipeline end to end (every artifact, resume, interrupt), and rl-baselines3-zoo as a client."""

import json
import math
import signal
import subprocess
import sys
import time
from dataclasses import fields, replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import microg_env  # registers the environments
from microg_env.analysis.metrics import RunMetrics
from microg_env.analysis.summary import control_cost, selection_cost
from microg_env.controllers import MLPPolicy, make_controller
from microg_env.controllers.registry import ACTING_KEYS, deployed_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.interface import OBSERVATION_INDEX, OBSERVATION_SCALES
from microg_env.learning import hyperparams as hp
from microg_env.learning.export import export_policy, write_policy_folder
from microg_env.learning.train import TrainingInterrupted, TrainSettings, resolve, resumed_run, session_seed, train
from microg_env.rollout.episode import run_episode

pytest.importorskip("stable_baselines3")
REPO = Path(__file__).resolve().parents[2]
ENV_ID = "MicroGravityLanding-Residual-v7"
RESIDUAL = {"action_mode": "residual", "base_controller": "feedforward", "decision_period": 5}


# -- hyperparameter files ----------------------------------------------------------------------


@pytest.mark.parametrize("algo", hp.ALGORITHMS)
def test_the_packaged_files_are_the_repositorys_and_parse(algo):
    params = hp.load(algo, ENV_ID)
    assert Path(params.source).read_bytes() == (REPO / "microg_env" / "hyperparams" / f"{algo}.yml").read_bytes()
    assert params.env_kwargs["action_mode"] == "residual"
    assert params.normalize is not None
    assert params.normalize["gamma"] == params.algo_kwargs["gamma"]
    arch = params.algo_kwargs["policy_kwargs"]["net_arch"]
    assert (arch["pi"] if algo == "crossq" else arch) == [64, 64]  # the actor: CrossQ's critics are its own
    assert "n_envs" not in params.algo_kwargs
    assert "env_kwargs" not in params.algo_kwargs


def test_the_zoos_string_forms_parse_without_evaluating_anything(tmp_path):
    path = tmp_path / "ppo.yml"
    path.write_text(
        f"{ENV_ID}:\n"
        "  n_timesteps: !!float 2e4\n"
        '  normalize: "dict(norm_obs=True, norm_reward=False)"\n'
        "  learning_rate: lin_3e-4\n"
        '  policy_kwargs: "dict(activation_fn=nn.ReLU, net_arch=dict(pi=[32], vf=[32]))"\n'
    )
    params = hp.load("ppo", ENV_ID, path)
    assert params.n_timesteps == 20000
    assert params.normalize == {"norm_obs": True, "norm_reward": False}
    arguments = hp.algo_arguments(params)
    assert arguments["learning_rate"](0.5) == pytest.approx(1.5e-4)
    import torch.nn as nn

    assert arguments["policy_kwargs"]["activation_fn"] is nn.ReLU
    assert arguments["policy_kwargs"]["net_arch"] == {"pi": [32], "vf": [32]}


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("policy_kwargs: \"__import__('os').system('true')\"", "only dict"),
        ('policy_kwargs: "dict(activation_fn=nn.Evil)"', "unknown activation"),
        ("learning_rate: cos_3e-4", "lin_<value>"),
        ("n_envs: 0", "n_envs"),
        ("env_wrapper: gymnasium.wrappers.TimeLimit", "env_wrapper"),
    ],
)
def test_bad_entries_are_named(tmp_path, entry, message):
    path = tmp_path / "ppo.yml"
    path.write_text(f"{ENV_ID}:\n  {entry}\n")
    with pytest.raises(ValueError, match=message):
        hp.load("ppo", ENV_ID, path)


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("top_quantiles_to_drop_per_net: 25", r"top_quantiles_to_drop_per_net must be .*\[0, 24\]"),  # none kept
        ("top_quantiles_to_drop_per_net: -1", "top_quantiles_to_drop_per_net"),
        ("top_quantiles_to_drop_per_net: 2.5", "top_quantiles_to_drop_per_net"),
        (
            'top_quantiles_to_drop_per_net: 5\n  policy_kwargs: "dict(n_quantiles=5)"',
            r"top_quantiles_to_drop_per_net must be .*\[0, 4\]",
        ),
    ],
)
def test_a_tqc_critic_that_would_keep_no_quantile_is_refused_before_a_run(tmp_path, entry, message):
    """TQC checks none of these itself: they failed at the first gradient step, 5000 steps in."""
    path = tmp_path / "tqc.yml"
    path.write_text(f"{ENV_ID}:\n  {entry}\n")
    with pytest.raises(ValueError, match=message):
        hp.load("tqc", ENV_ID, path)


def test_a_missing_entry_lists_the_entries(tmp_path):
    path = tmp_path / "ppo.yml"
    path.write_text("Other-v0:\n  n_envs: 1\n")
    with pytest.raises(ValueError, match=rf"no entry '{ENV_ID}' .*Other-v0"):
        hp.load("ppo", ENV_ID, path)


# -- the NumPy export and the policy as a controller -------------------------------------------


def _vec_env(**kwargs):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    venv = VecNormalize(
        make_vec_env("MicroGravityLanding-v1", n_envs=1, seed=0, env_kwargs=RESIDUAL | {"condition": 2})
    )
    venv.reset()
    for _ in range(50):  # statistics other than the identity
        venv.step(np.random.default_rng(0).uniform(-1, 1, (1, 1)).astype(np.float32))
    return venv


@pytest.mark.parametrize("algo", hp.ALGORITHMS)
@pytest.mark.slow
def test_the_numpy_export_acts_as_stable_baselines3_does(algo):
    import torch

    from microg_env.learning.train import algorithm

    venv = _vec_env()
    model = algorithm(algo)("MlpPolicy", venv, seed=1, device="cpu", policy_kwargs={"net_arch": [16, 16]})
    head = model.policy.action_net if algo == "ppo" else model.actor.mu
    with torch.no_grad():  # a head far from zero, so clipping and squashing show
        head.weight.mul_(300.0 if algo == "ppo" else 10.0)
    renorms = [layer for layer in getattr(model, "actor", model.policy).modules() if hasattr(layer, "ra_var")]
    assert len(renorms) == (3 if algo == "crossq" else 0)  # CrossQ's before each linear layer, folded in
    rng = np.random.default_rng(3)
    with torch.no_grad():  # running statistics and gains other than the identity, so the folding shows
        for layer in renorms:
            size = layer.num_features
            layer.ra_mean.copy_(torch.as_tensor(rng.normal(0.0, 1.0, size)))
            layer.ra_var.copy_(torch.as_tensor(rng.uniform(0.2, 3.0, size)))
            layer.scale.copy_(torch.as_tensor(rng.uniform(0.5, 2.0, size)))
            layer.bias.copy_(torch.as_tensor(rng.normal(0.0, 0.5, size)))
    exported = export_policy(model, venv)
    observations = np.random.default_rng(2).normal(0.0, 3.0, (200, 10)).astype(np.float32)
    ours = np.array([exported.predict(o)[0] for o in observations])
    theirs = np.array([model.predict(venv.normalize_obs(o), deterministic=True)[0] for o in observations])
    np.testing.assert_allclose(ours, theirs, atol=2e-6 if not renorms else 1e-5)  # torch's float32
    assert np.abs(ours).max() > 0.5  # the comparison reaches the limits, not only the linear middle
    if renorms:  # the folding exact: the actor in float64, in evaluation mode as deployed
        actor = model.actor.double().eval()
        with torch.no_grad():
            exact = actor(torch.as_tensor(venv.normalize_obs(observations), dtype=torch.float64), deterministic=True)
        assert np.all(np.abs(exact.numpy()) <= 1.0)  # the action space is [-1, 1]: predict's action as it is
        np.testing.assert_allclose(ours, exact.numpy().astype(np.float32), rtol=0.0, atol=1e-7)  # ours is float32


def test_batch_renormalisations_fold_into_the_linear_layer_they_feed_as_torch_computes_them():
    """Two in a row (composed), one without its affine gain and bias, and one before the head: the
    folded layers compute what the modules do in evaluation mode, in float64, to rounding."""
    import torch
    import torch.nn as nn
    from sb3_contrib.common.torch_layers import BatchRenorm1d

    from microg_env.learning.export import fold_batch_renorm

    torch.manual_seed(0)
    modules = [
        BatchRenorm1d(3),
        BatchRenorm1d(3, affine=False),
        nn.Linear(3, 5),
        nn.ReLU(),
        BatchRenorm1d(5),
        nn.Linear(5, 2),
    ]
    rng = np.random.default_rng(4)
    with torch.no_grad():  # statistics and gains far from the identity
        for layer in (m for m in modules if isinstance(m, BatchRenorm1d)):
            layer.ra_mean.copy_(torch.as_tensor(rng.normal(0.0, 2.0, layer.num_features)))
            layer.ra_var.copy_(torch.as_tensor(rng.uniform(0.1, 4.0, layer.num_features)))
            layer.scale.copy_(torch.as_tensor(rng.uniform(0.3, 3.0, layer.num_features)))
            layer.bias.copy_(torch.as_tensor(rng.normal(0.0, 1.0, layer.num_features)))
    network = nn.Sequential(*modules).double().eval()
    x = rng.normal(0.0, 3.0, (50, 3))
    with torch.no_grad():
        expected = network(torch.as_tensor(x)).numpy()
    layers, others = fold_batch_renorm(modules)
    assert others == {"ReLU"}
    assert [w.shape for w, _ in layers] == [(5, 3), (2, 5)]
    (w1, b1), (w2, b2) = layers
    np.testing.assert_allclose(np.maximum(x @ w1.T + b1, 0.0) @ w2.T + b2, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(
    ("layers", "message"),
    [
        (lambda nn, renorm: [nn.Linear(3, 4), renorm(4), nn.ReLU(), nn.Linear(4, 1)], "feeds a ReLU"),
        (
            lambda nn, renorm: [nn.Linear(3, 4), nn.ReLU(), nn.Linear(4, 2), renorm(2)],
            "ends with a batch renormalisation",
        ),
    ],
)
def test_a_batch_renormalisation_that_feeds_no_linear_layer_is_refused(layers, message):
    """Only a renormalisation feeding a linear layer folds into it (an activation between them does not
    commute with the affine map); sb3-contrib's CrossQ actor has only those."""
    import torch.nn as nn
    from sb3_contrib.common.torch_layers import BatchRenorm1d

    from microg_env.learning.export import fold_batch_renorm

    with pytest.raises(ValueError, match=message):
        fold_batch_renorm(layers(nn, BatchRenorm1d))


def _random_policy(seed: int, outputs: int = 1) -> MLPPolicy:
    rng = np.random.default_rng(seed)
    return MLPPolicy(
        (rng.normal(0, 0.5, (8, 10)), rng.normal(0, 0.5, (outputs, 8))),
        (rng.normal(0, 0.1, 8), np.zeros(outputs)),
        "tanh",
        False,
        np.zeros(10),
        np.ones(10),
        10.0,
    )


@pytest.mark.parametrize(
    ("highpass_hz", "order", "hidden", "gate", "gate_on"),
    [
        (0.0, 1, (), None, "action"),
        (2.0, 1, (), None, "action"),
        (2.0, 2, (), None, "action"),
        (2.0, 2, ("support_position", "height"), None, "action"),
        (2.0, 2, (), 0.053, "action"),  # condition 3 starts at 55 mm: the gate opens after about 2.2 s
        (2.0, 2, ("support_position", "height"), 0.053, "action"),  # the gate reads the height the policy is not shown
        (2.0, 2, (), 0.053, "setpoint"),  # the gate on the high-passed setpoint
        (2.0, 1, ("support_position", "height"), 0.053, "setpoint"),
    ],
)
def test_a_policy_controller_in_the_speed_env_is_the_residual_env_exactly(highpass_hz, order, hidden, gate, gate_on):
    """The deployed composition (policy + base, decision period, rebuilt observation, the
    residual's high-pass, the entries the policy is not shown, its gate) is the training
    environment's, bit for bit, for a policy that moves the setpoint every decision; the setpoints
    are the actions (0 while a gate reads the foot above it), or at 2 Hz the actions through
    y_n = a (y_(n-1) + (u_n - u_(n-1)) 1 um) with a = tau / (tau + 5 ms), tau = 1 / (2 pi 2 Hz),
    once or twice in cascade, the gate on the action before the filter or on its output."""
    policy = _random_policy(3)
    highpass = {"residual_highpass_hz": highpass_hz, "residual_highpass_order": order}
    if hidden:
        highpass["hidden_observations"] = hidden
    if gate is not None:
        highpass |= {"residual_gate_m": gate, "residual_gate_on": gate_on}
    residual_env = MicroGravityLandingEnv(condition=3, **RESIDUAL, **highpass)
    observation, info = residual_env.reset(seed=4)
    xs, commands, actions, passed, setpoints = [], [], [], [], []
    for _ in range(600):  # 3 s
        assert all(observation[OBSERVATION_INDEX[name]] == 0.0 for name in hidden)
        action = policy.predict(observation)[0]
        reading = residual_env.core.observation[0, OBSERVATION_INDEX["height"]]  # shown to the policy or not
        height_m = float(reading) * OBSERVATION_SCALES["height"]
        observation, _, _, _, info = residual_env.step(action)
        xs.append(info["x_m"])
        commands.append(info["command_m_s"])
        actions.append(float(action[0]))
        passed.append(gate is None or height_m <= gate)
        setpoints.append(info["setpoint_m"])
    if gate is not None:
        assert 0.1 < np.mean(passed) < 0.9  # the gate was shut, then open
    controller = deployed_controller(policy, RESIDUAL | highpass)
    deployed = run_episode(MicroGravityLandingEnv(condition=3), controller, seed=4, duration_s=3.0)
    np.testing.assert_array_equal(deployed.x_m[5::5], np.array(xs))
    np.testing.assert_array_equal(deployed.command_m_s[5::5], np.array(commands))
    assert np.ptp(np.array(xs)) > 1e-7  # the policy did move x
    expected, last_u, last_w, last_y = [], 0.0, 0.0, 0.0
    tau = 1.0 / (2.0 * math.pi * highpass_hz) if highpass_hz else math.inf
    for u, open_ in zip(actions, passed, strict=True):
        u = u if open_ or gate_on == "setpoint" else 0.0
        if highpass_hz == 0:
            last_y = u * 1e-6
        else:
            stage = tau / (tau + 5e-3) * (last_w + (u - last_u) * 1e-6)
            last_y = stage if order == 1 else tau / (tau + 5e-3) * (last_y + stage - last_w)
            last_w = stage
        last_u = u
        expected.append(last_y if open_ or gate_on == "action" else 0.0)
    np.testing.assert_allclose(setpoints, expected, rtol=1e-9, atol=1e-18)
    assert np.ptp(setpoints) > 1e-8  # the setpoint did move


@pytest.mark.parametrize(
    ("base", "gate", "hidden"),
    [
        ("pid", None, ()),
        ("pid-dom", None, ()),
        # condition 3 starts at 55 mm: the gate opens after about 2.2 s; the registered id's hidden entries
        ("pid-dom", 0.053, ("support_position", "lander_accel", "pad_force")),
    ],
)
def test_a_gains_policy_in_the_speed_env_is_the_gains_env_exactly(base, gate, hidden):
    """A gains policy deployed in the speed-action environment (its base PID's gains multiplied by
    2 ** action each decision while the foot reads at or below the gate, the mean of the action
    shown as the previous one, the hidden entries read 0) is the gains environment's, bit for bit;
    the gains it sets are the tuned ones times 2 ** action, or as tuned above the gate."""
    from microg_env.controllers.pid import load_gains

    policy = _random_policy(3, outputs=3)
    gains = {"action_mode": "gains", "base_controller": base, "decision_period": 5, "residual_gate_m": gate}
    if hidden:
        gains["hidden_observations"] = hidden
    env = MicroGravityLandingEnv(condition=3, **gains)
    assert env.action_space.shape == (3,)
    observation, info = env.reset(seed=4)
    xs, commands, shown, passed = [], [], [], []
    tuned = load_gains(base)
    for _ in range(600):  # 3 s
        assert all(observation[OBSERVATION_INDEX[name]] == 0.0 for name in hidden)
        action = policy.predict(observation)[0]
        height_m = float(env.core.observation[0, OBSERVATION_INDEX["height"]]) * OBSERVATION_SCALES["height"]
        observation, _, _, _, info = env.step(action)
        pid = env.core.base
        scaled = (tuned.kp_per_s * pid.kp_scale[0], tuned.ki_per_s2 * pid.ki_scale[0], tuned.kd * pid.kd_scale[0])
        open_ = gate is None or height_m <= gate
        a = action.astype(np.float64) if open_ else np.zeros(3)
        expected = (tuned.kp_per_s * 2.0 ** a[0], tuned.ki_per_s2 * 2.0 ** a[1], tuned.kd * 2.0 ** a[2])
        np.testing.assert_allclose(scaled, expected, rtol=1e-12)
        shown.append((observation[OBSERVATION_INDEX["previous_action"]], float(np.mean(action))))
        passed.append(open_)
        xs.append(info["x_m"])
        commands.append(info["command_m_s"])
    np.testing.assert_allclose(*zip(*shown, strict=True), rtol=1e-6)
    if gate is not None:
        assert 0.1 < np.mean(passed) < 0.9  # the gate was shut, then open
    controller = deployed_controller(policy, gains)
    deployed = run_episode(MicroGravityLandingEnv(condition=3), controller, seed=4, duration_s=3.0)
    np.testing.assert_array_equal(deployed.x_m[5::5], np.array(xs))
    np.testing.assert_array_equal(deployed.command_m_s[5::5], np.array(commands))
    zero = run_episode(MicroGravityLandingEnv(condition=3), make_controller(base, 1e-3), seed=4, duration_s=3.0)
    assert np.max(np.abs(np.array(xs) - zero.x_m[5::5])) > 1e-8  # the schedule moved x off the PID's


class _Follower:
    """A speed policy at 0.1 m/s an action that follows the lander: the support's measured speed
    plus a P and a D term on x, and a wobble that depends on the observation."""

    def predict(self, observation, deterministic=True):
        o = np.atleast_2d(observation).astype(np.float64)
        index = OBSERVATION_INDEX
        action = o[:, index["support_velocity"]] + 0.05 * o[:, index["x"]] + 0.01 * o[:, index["x_rate"]]
        action += 1e-3 * np.sin(1e4 * o[:, index["x"]])
        return action.reshape(-1, 1).astype(np.float32), None


def test_a_speed_policy_at_its_speed_limit_in_the_speed_env_is_the_command_env_exactly():
    """A policy of the command id (an action of 1 for 0.1 m/s, its hidden entries read 0) deployed
    in the default speed-action environment (whose action of 1 is 1.25 m/s) is the command
    environment's, bit for bit: the controller returns the action times 0.1 / 1.25."""
    acting = {
        key: value for key, value in gym.spec("MicroGravityLanding-Command-v1").kwargs.items() if key in ACTING_KEYS
    }
    assert acting["speed_limit_m_s"] == 0.1
    policy = _Follower()
    env = MicroGravityLandingEnv(condition=3, **acting)
    observation, info = env.reset(seed=4)
    xs, commands, shown = [], [], []
    for _ in range(3000):  # 3 s
        action = policy.predict(observation)[0][0]
        observation, _, terminated, _, info = env.step(action)
        assert not terminated
        shown.append((observation[OBSERVATION_INDEX["previous_action"]], action[0]))
        xs.append(info["x_m"])
        commands.append(info["command_m_s"])
    np.testing.assert_array_equal(*zip(*shown, strict=True))
    deployed = run_episode(
        MicroGravityLandingEnv(condition=3), deployed_controller(policy, acting), seed=4, duration_s=3.0
    )
    np.testing.assert_array_equal(deployed.x_m[1:], np.array(xs))
    np.testing.assert_array_equal(deployed.command_m_s[1:], np.array(commands))
    assert 1e-7 < np.max(np.abs(xs)) < 1e-3  # it followed, not perfectly
    actions = np.array([action for _, action in shown], dtype=np.float64)
    np.testing.assert_allclose(commands[1:], actions[:-1] * 0.1, rtol=1e-6)  # m/s, a period late (the delay)
    assert np.max(np.abs(commands)) > 1e-3  # the lander's descent


def test_a_gains_policy_controller_refuses_a_base_that_is_not_a_pid_and_a_network_of_another_width():
    from microg_env.controllers.policy import PolicyController
    from microg_env.task import ActingSettings

    acting = ActingSettings(action_mode="gains", base_controller="pid-dom", decision_period=5)
    with pytest.raises(ValueError, match="a gains policy schedules a PID's gains, got base AdaptiveFeedforward"):
        PolicyController(_random_policy(3, outputs=3), acting, make_controller("adaptive", 1e-3))
    with pytest.raises(ValueError, match="the policy gives 1 numbers an action, and action_mode 'gains' takes 3"):
        PolicyController(_random_policy(3), acting, make_controller("pid-dom", 1e-3))


def test_a_network_of_another_action_size_than_its_task_is_refused(tmp_path):
    """A residual card with a network of three outputs (a gains policy's) is named before it runs."""
    import shutil

    from microg_env.controllers.registry import check_policy_folder, shipped_policy_folder

    folder = tmp_path / "policy"
    shutil.copytree(shipped_policy_folder("residual-sac-setpoint"), folder)
    _random_policy(3, outputs=3).save(folder / "policy.npz")
    with pytest.raises(ValueError, match="its network gives 3 numbers an action, and action_mode 'residual' takes 1"):
        check_policy_folder(folder)


def test_a_zero_gains_action_is_the_pid_exactly():
    """An all-zero gains action multiplies every gain by exactly 1: the episode is the base PID's in
    the speed environment, bit for bit."""
    env = MicroGravityLandingEnv(condition=1, action_mode="gains", base_controller="pid", decision_period=5)
    env.reset(seed=2)
    xs = [env.step(np.zeros(3, dtype=np.float32))[4]["x_m"] for _ in range(400)]
    pid = run_episode(MicroGravityLandingEnv(condition=1), make_controller("pid", 1e-3), seed=2, duration_s=2.0)
    np.testing.assert_array_equal(pid.x_m[5::5], np.array(xs))


def test_an_exported_policy_round_trips_through_its_file(tmp_path):
    policy = _random_policy(5)
    policy.save(tmp_path / "policy.npz")
    loaded = MLPPolicy.load(tmp_path / "policy.npz")
    observation = np.linspace(-2, 2, 10)
    assert loaded.predict(observation)[0] == policy.predict(observation)[0]
    with pytest.raises(ValueError, match="chain"):
        MLPPolicy(
            (np.ones((4, 10)), np.ones((1, 5))),
            (np.ones(4), np.ones(1)),
            "tanh",
            False,
            np.zeros(10),
            np.ones(10),
            10.0,
        )


def test_a_policy_folder_runs_only_at_its_control_period(tmp_path):
    venv = _vec_env()
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", venv, seed=0, device="cpu")
    write_policy_folder(tmp_path / "policy", model, venv, {"env_kwargs": RESIDUAL})
    controller = make_controller(str(tmp_path / "policy"), 1e-3)
    assert controller.acting.decision_period == 5
    assert controller.base is not None
    with pytest.raises(ValueError, match="trained at 1000 us"):
        make_controller(str(tmp_path / "policy"), 5e-4)


# -- training end to end -----------------------------------------------------------------------


def _tiny_hyperparams(tmp_path: Path, algo: str) -> Path:
    """The packaged entry with a budget a test can afford."""
    entry = yaml.safe_load((REPO / "microg_env" / "hyperparams" / f"{algo}.yml").read_text())[ENV_ID]
    entry |= {"n_envs": 2, "policy_kwargs": "dict(net_arch=[16, 16])"}
    entry |= {"n_steps": 64, "batch_size": 64, "n_epochs": 2} if algo == "ppo" else {}
    entry |= {"learning_starts": 50, "buffer_size": 5000, "batch_size": 32} if algo != "ppo" else {}
    if algo == "tqc":  # not the defaults (25, 2), so a test sees the file's values reach the critic
        entry |= {"policy_kwargs": "dict(net_arch=[16, 16], n_quantiles=7)", "top_quantiles_to_drop_per_net": 1}
    if algo == "crossq":  # not the file's 3 or sb3-contrib's default, so a test sees the file's value reach it
        entry |= {"policy_delay": 2}
    path = tmp_path / f"{algo}.yml"
    path.write_text(yaml.safe_dump({ENV_ID: entry}))
    return path


def _settings(tmp_path, algo, timesteps, **kwargs):
    defaults = {"env_id": ENV_ID, "eval_freq": 128, "eval_episodes": 1, "checkpoint_freq": 128, "command": "pytest"}
    return TrainSettings(
        algo=algo,
        timesteps=timesteps,
        hyperparams=str(_tiny_hyperparams(tmp_path, algo)),
        log_folder=str(tmp_path / "logs"),
        **(defaults | kwargs),
    )


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory):
    """A tiny PPO run of 256 steps, then resumed to 384."""
    tmp_path = tmp_path_factory.mktemp("ppo")
    folder = train(_settings(tmp_path, "ppo", 256))
    first = json.loads((folder / "checkpoints" / "latest.json").read_text())
    from stable_baselines3.common.vec_env import VecNormalize

    count_before = VecNormalize.load(str(folder / "vecnormalize.pkl"), _vec_env()).obs_rms.count
    resumed = train(_settings(tmp_path, "ppo", 384), resume_folder=folder)
    return folder, resumed, first, count_before


@pytest.mark.slow
def test_a_finished_runs_total_wall_time_includes_its_final_evaluation(tmp_path):
    """The last model is evaluated after its checkpoint (no evaluation falls due in training here):
    the run's total wall time (latest.json, shipped as training.json) counts that evaluation, so it
    is never below the wall time at which the best model was saved, nor below the log's total."""
    folder = train(_settings(tmp_path, "ppo", 256, eval_freq=100_000))
    latest = json.loads((folder / "checkpoints" / "latest.json").read_text())
    card = json.loads((folder / "policy" / "policy.json").read_text())
    finished = (folder / "train.log").read_text().strip().splitlines()[-1]
    logged = float(finished.split(" steps in ")[1].split(" s wall")[0])
    assert card["timesteps"] == latest["timesteps"] == 256  # the best model is the last one
    assert latest["wall_s"] >= card["wall_s"]
    assert latest["wall_s"] == pytest.approx(logged, abs=0.15)


@pytest.mark.slow
def test_a_run_writes_every_artifact_of_the_zoos_layout(ppo_run):
    folder, _, _, _ = ppo_run
    assert folder.name == f"{ENV_ID}_1"
    assert folder.parent.name == "ppo"
    for name in (
        "config.yml",
        "args.yml",
        f"{ENV_ID}.zip",
        "vecnormalize.pkl",
        "best_model.zip",
        "best_vecnormalize.pkl",
        "evaluations.json",
        "train.log",
        "monitor/session-0.monitor.csv",
        "policy/policy.npz",
        "policy/policy.json",
        "policy/model.zip",
        "policy/vecnormalize.pkl",
        "checkpoints/latest.json",
        "checkpoints/rl_model_128_steps.zip",
        "checkpoints/rl_model_vecnormalize_128_steps.pkl",
    ):
        assert (folder / name).is_file(), name
    assert list((folder / "tb").rglob("events.out.tfevents.*"))
    config = yaml.safe_load((folder / "config.yml").read_text())
    assert hp.load("ppo", ENV_ID, folder / "config.yml").n_envs == 2  # itself a hyperparameter file
    assert config[ENV_ID]["env_kwargs"]["base_controller"] == "adaptive-dither"  # the id's keywords, in full
    evaluations = json.loads((folder / "evaluations.json").read_text())
    assert [row["timesteps"] for row in evaluations][:2] == [128, 256]
    for row in evaluations:  # the project's metrics, not only the return
        assert {"compensation_error_pct", "collision_excursion_um", "free_fall_excursion_um", "cost"} <= set(row)
        assert row["collision_excursion_um"] is not None
        assert row["collision_excursion_um"] > 0
    card = json.loads((folder / "policy" / "policy.json").read_text())
    assert card["command"] == "pytest"
    assert card["seed"] == 0
    assert card["algo"] == "ppo"
    assert card["timesteps"] in [row["timesteps"] for row in evaluations if row["best"]]


def test_resume_continues_the_step_count_the_statistics_and_the_log(ppo_run):
    folder, resumed, first, count_before = ppo_run
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    assert resumed == folder
    assert first["timesteps"] == 256
    latest = json.loads((folder / "checkpoints" / "latest.json").read_text())
    assert latest["timesteps"] == 384
    assert latest["sessions"] == 2
    assert PPO.load(folder / f"{ENV_ID}.zip", device="cpu").num_timesteps == 384
    statistics = VecNormalize.load(str(folder / "vecnormalize.pkl"), _vec_env())
    assert statistics.obs_rms.count > count_before  # kept and moved on, not restarted
    assert statistics.obs_rms.count > 384  # 384 steps plus the first session's resets
    log = (folder / "train.log").read_text()
    assert "resumed at 256 steps" in log
    assert "384 steps in" in log
    assert latest["wall_s"] >= first["wall_s"]
    first_session = (folder / "monitor" / "session-0.monitor.csv").read_text().splitlines()
    second_session = (folder / "monitor" / "session-1.monitor.csv").read_text().splitlines()
    assert first_session[0].startswith("#")  # the first session's file kept, not replaced
    assert second_session[0].startswith("#")  # the resumed session writes its own


@pytest.mark.slow
def test_tqc_trains_and_ships_a_policy_the_controllers_run(tmp_path):
    """sb3-contrib's TQC through microg train: SAC's actor, so the exported policy acts as the
    model does, and its card names the algorithm."""
    from sb3_contrib import TQC

    folder = train(_settings(tmp_path, "tqc", 128))
    card = json.loads((folder / "policy" / "policy.json").read_text())
    assert card["algo"] == "tqc"
    model = TQC.load(folder / "policy" / "model.zip", device="cpu")
    assert model.critic.n_quantiles == 7  # the file's critic
    assert model.top_quantiles_to_drop_per_net == 1
    exported = make_controller(str(folder / "policy"), 1e-3).policy
    observations = np.random.default_rng(0).normal(0.0, 1.0, (50, 10)).astype(np.float32)
    theirs = model.predict(exported.normalize(observations), deterministic=True)[0]
    np.testing.assert_allclose([exported.predict(o)[0] for o in observations], theirs, atol=2e-6)


@pytest.mark.slow
def test_crossq_trains_and_ships_a_policy_the_controllers_run(tmp_path):
    """sb3-contrib's CrossQ through microg train: the exported policy, its batch renormalisation
    folded in at the running statistics training left, acts as the model does, and its card names
    the algorithm."""
    import sb3_contrib
    from sb3_contrib import CrossQ

    folder = train(_settings(tmp_path, "crossq", 128))
    card = json.loads((folder / "policy" / "policy.json").read_text())
    assert card["algo"] == "crossq"
    model = CrossQ.load(folder / "policy" / "model.zip", device="cpu")
    assert model.policy_delay == 2  # the file's
    renorm = model.actor.latent_pi[0]
    assert renorm.steps > 0  # trained: running statistics other than the initial identity
    assert not np.allclose(renorm.ra_var.numpy(), 1.0)
    exported = make_controller(str(folder / "policy"), 1e-3).policy
    observations = np.random.default_rng(0).normal(0.0, 1.0, (50, 10)).astype(np.float32)
    theirs = model.predict(exported.normalize(observations), deterministic=True)[0]
    np.testing.assert_allclose([exported.predict(o)[0] for o in observations], theirs, atol=1e-5)  # torch's float32
    assert card["versions"]["sb3_contrib"] == sb3_contrib.__version__  # what the folded layers' meaning depends on


@pytest.mark.parametrize("algo", ["sac", "tqc", "crossq"])
@pytest.mark.slow
def test_an_off_policy_run_resumes_with_its_replay_buffer(tmp_path, algo):
    from microg_env.learning.train import algorithm

    folder = train(_settings(tmp_path, algo, 128))
    latest = json.loads((folder / "checkpoints" / "latest.json").read_text())
    buffer = folder / "checkpoints" / latest["replay_buffer"]
    assert buffer.is_file()
    train(_settings(tmp_path, algo, 192), resume_folder=folder)
    latest = json.loads((folder / "checkpoints" / "latest.json").read_text())
    assert latest["timesteps"] == 192
    model = algorithm(algo).load(folder / "checkpoints" / latest["model"], device="cpu")
    model.load_replay_buffer(folder / "checkpoints" / latest["replay_buffer"])
    assert model.replay_buffer.size() == 192 // 2  # every step of both sessions, per environment
    assert not buffer.exists()  # only the latest buffer is kept


@pytest.mark.slow
def test_ctrl_c_saves_a_checkpoint_that_resumes(tmp_path):
    def interrupt(done, total):
        if done >= 192:
            raise KeyboardInterrupt

    with pytest.raises(TrainingInterrupted, match="--resume"):
        train(_settings(tmp_path, "ppo", 512), progress=interrupt)
    folder = tmp_path / "logs" / "ppo" / f"{ENV_ID}_1"
    latest = json.loads((folder / "checkpoints" / "latest.json").read_text())
    assert latest["timesteps"] == 192
    train(_settings(tmp_path, "ppo", 256), resume_folder=folder)
    # On from 192 to at least 256, in PPO's whole rollouts of 2 x 64 steps.
    assert json.loads((folder / "checkpoints" / "latest.json").read_text())["timesteps"] == 192 + 128


def test_a_resumed_target_survives_a_second_interruption(ppo_run, tmp_path):
    """The run was resumed to 384 steps: that target, not the first 256, is what it continues to."""
    folder, _, _, _ = ppo_run
    _, settings, params, _ = resumed_run(folder, TrainSettings(timesteps=512))
    assert params.n_timesteps == settings.timesteps == 512
    with pytest.raises(ValueError, match="already has 384 steps"):
        resumed_run(folder, TrainSettings())  # args.yml holds 384 now


def test_resumed_sessions_never_draw_reserved_seeds():
    assert session_seed(7, 0) == 7
    seeds = {session_seed(0, steps) for steps in (500, 1000, 1001, 10**6)}
    assert len(seeds) == 4
    assert min(seeds) >= 2**20  # above the validation (500+) and test (1000+) seeds


@pytest.mark.slow
def test_a_run_shorter_than_the_evaluation_period_still_exports_its_policy(tmp_path):
    folder = train(replace(_settings(tmp_path, "ppo", 128), eval_freq=10**6))
    assert (folder / "policy" / "policy.json").is_file()
    assert len(json.loads((folder / "evaluations.json").read_text())) == 1


@pytest.mark.slow
def test_an_interrupted_policy_export_leaves_the_previous_one(tmp_path, monkeypatch):
    from microg_env.learning import export

    folder = train(_settings(tmp_path, "ppo", 128))
    policy = folder / "policy"
    before = {p.name: p.read_bytes() for p in policy.iterdir()}

    def fail(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(export, "export_policy", fail)
    with pytest.raises(KeyboardInterrupt):
        export.write_policy_folder(policy, None, None, {"env_kwargs": {}})
    assert {p.name: p.read_bytes() for p in policy.iterdir()} == before


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("  n_timesteps: 1000\n  env_kwargs: {foo: 1}\n", "env_kwargs"),
        ("  n_timesteps: 1000\n  n_stepz: 4\n", "'n_stepz' is not an argument of PPO"),
        # Each of these was a traceback or a late error that left an orphan run folder.
        ("  n_timesteps: 1000\n  n_steps: 0\n", "n_steps must be a positive integer"),
        ("  n_timesteps: 1000\n  device: cuda\n", "'device' is set by microg train"),
        ("  n_timesteps: 1000\n  seed: 3\n", "'seed' is set by microg train"),
        ("  n_timesteps: 1000\n  verbose: 1\n", "'verbose' is set by microg train"),
        ("  n_timesteps: 1000\n  tensorboard_log: /tmp/tb\n", "'tensorboard_log' is set by microg train"),
        ("  n_timesteps: 1000\n  env_kwargs: {max_episode_steps: 10}\n", "max_episode_steps"),
        ("  n_timesteps: 1000\n  env_kwargs: [1, 2]\n", "env_kwargs must be a mapping"),
    ],
)
def test_entries_the_environment_or_the_algorithm_refuse_are_named_before_a_run_folder(tmp_path, entry, message):
    path = tmp_path / "bad.yml"
    path.write_text(f"{ENV_ID}:\n  n_envs: 1\n{entry}")
    with pytest.raises(ValueError, match=message):
        resolve(TrainSettings(env_id=ENV_ID, hyperparams=str(path)))
    assert not (tmp_path / "logs").exists()


def test_a_crossq_entry_that_would_never_update_its_actor_is_refused_before_a_run(tmp_path):
    """CrossQ does not check policy_delay itself: 0 failed at the first update (a division by zero),
    with the run folder already written."""
    path = tmp_path / "crossq.yml"
    path.write_text(f"{ENV_ID}:\n  n_timesteps: 1000\n  policy_delay: 0\n")
    with pytest.raises(ValueError, match="policy_delay must be a positive integer"):
        resolve(TrainSettings(algo="crossq", env_id=ENV_ID, hyperparams=str(path)))
    assert not (tmp_path / "logs").exists()


def test_a_file_asking_for_more_environments_than_a_run_takes_is_refused(tmp_path):
    path = tmp_path / "bad.yml"
    path.write_text(f"{ENV_ID}:\n  n_envs: 5000\n  n_timesteps: 1000\n")
    with pytest.raises(ValueError, match="n_envs must be at most 256, got 5000"):
        resolve(TrainSettings(env_id=ENV_ID, hyperparams=str(path)))


@pytest.mark.slow
def test_resume_refuses_what_it_cannot_continue(tmp_path):
    with pytest.raises(ValueError, match="no checkpoint"):
        train(_settings(tmp_path, "ppo", 128), resume_folder=tmp_path)
    folder = train(_settings(tmp_path, "ppo", 128))
    with pytest.raises(ValueError, match="already has 128 steps"):
        train(_settings(tmp_path, "ppo", 128), resume_folder=folder)
    train(_settings(tmp_path, "sac", 256), resume_folder=folder)  # a run continues with its own settings
    assert yaml.safe_load((folder / "args.yml").read_text())["algo"] == "ppo"
    assert json.loads((folder / "checkpoints" / "latest.json").read_text())["timesteps"] == 256


@pytest.mark.slow
def test_the_control_cost_is_the_tuners():
    from microg_env.rollout.episode import run_with_metrics

    env = MicroGravityLandingEnv(condition=2)
    run = run_with_metrics(env, make_controller("pid", 1e-3), seed=0, duration_s=6.0)[2]
    errors = [abs(e) for e in run.compensation_error_pct if math.isfinite(e)]
    assert control_cost([run]) == pytest.approx(np.mean(errors) + run.flexible_unit_excursion_collision_m * 1e6 / 10)
    failed = type(run)(**{**run.__dict__, "termination_reason": "guide_stroke_limit"})
    assert control_cost([run, failed]) == math.inf


def test_learned_policies_are_selected_by_the_mean_excursion_at_the_collision():
    """selection_cost: the tuner's cost with the mean of the runs' excursions at the collision in
    place of the worst (here 1 and 3 um: mean 2, worst 3); a failed run still costs infinity."""
    run = RunMetrics(
        **{f.name: math.nan for f in fields(RunMetrics) if f.name != "unavailable"} | {"termination_reason": None}
    )
    runs = [
        replace(run, compensation_error_pct=(0.1, -0.3), flexible_unit_excursion_collision_m=1e-6),
        replace(run, compensation_error_pct=(0.2, math.nan), flexible_unit_excursion_collision_m=3e-6),
    ]
    assert selection_cost(runs) == pytest.approx(0.2 + 2.0 / 10)
    assert control_cost(runs) == pytest.approx(0.2 + 3.0 / 10)
    assert selection_cost([*runs, replace(run, termination_reason="guide_stroke_limit")]) == math.inf


# -- rl-baselines3-zoo as a client -------------------------------------------------------------


@pytest.mark.slow
def test_rl_zoo3_trains_from_the_same_hyperparameter_file(tmp_path):
    pytest.importorskip("rl_zoo3")
    command = [
        sys.executable,
        "-m",
        "rl_zoo3.train",
        "--algo",
        "ppo",
        "--env",
        ENV_ID,
        "--gym-packages",
        "microg_env",
        "-conf",
        str(REPO / "microg_env" / "hyperparams" / "ppo.yml"),
        "-n",
        "2048",
        "--eval-freq",
        "-1",
        "-f",
        str(tmp_path),
        "--seed",
        "0",
        "--n-eval-envs",
        "1",
    ]
    done = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    run = tmp_path / "ppo" / f"{ENV_ID}_1"
    assert (run / f"{ENV_ID}.zip").is_file()
    assert (run / ENV_ID / "vecnormalize.pkl").is_file()
    config = (run / ENV_ID / "config.yml").read_text()
    assert "log_std_init=-1.5" in config  # the entry's own keys


@pytest.mark.slow
def test_the_cli_progress_bar_names_the_default_algorithm_and_ends_where_the_run_does(tmp_path, capsys):
    """Without --algo the bar used to read 'train None', args.yml stored n_envs: null, and a target
    that is not a whole number of rollouts overran the bar (200 steps asked, 256 run: '256step')."""
    from microg_env.cli import main

    args = ["train", "--env", ENV_ID, "--timesteps", "100", "--hyperparams", str(_tiny_hyperparams(tmp_path, "ppo"))]
    args += ["--log-folder", str(tmp_path / "logs"), "--eval-freq", "128", "--eval-episodes", "1"]
    assert main(args) == 0
    out, err = capsys.readouterr()
    assert "train ppo" in err
    assert "train None" not in err
    assert "128/128" in err.replace("\r", "\n").splitlines()[-1]  # 2 envs x 64 steps: one rollout
    assert "target 100 steps (runs to 128: whole rollouts)" in out
    run = tmp_path / "logs" / "ppo" / f"{ENV_ID}_1"
    assert yaml.safe_load((run / "args.yml").read_text())["n_envs"] == 2
    assert json.loads((run / "checkpoints" / "latest.json").read_text())["timesteps"] == 128


@pytest.mark.parametrize(
    ("algo", "n_envs", "n_steps", "start", "planned"),
    [
        ("ppo", 8, 256, 0, 2048),  # 2000 asked: one rollout of 8 x 256
        ("ppo", 8, 256, 1000, 3048),  # a resumed session counts its rollouts from where it starts
        ("ppo", 1, None, 0, 2048),  # stable-baselines3's default n_steps
        ("sac", 3, None, 0, 2001),  # whole environment steps of 3
        ("sac", 2, 64, 0, 2048),  # train_freq 64: rollouts of 2 x 64
        ("sac", 2, (5, "step"), 0, 2000),
        ("sac", 2, (1, "episode"), 0, None),  # episodes: not known ahead
        ("ppo", 8, 256, 5000, 5000),  # past the target: nothing left to run
    ],
)
def test_planned_steps_is_where_stable_baselines3_stops(algo, n_envs, n_steps, start, planned):
    """Checked against stable-baselines3 2.9: SAC with train_freq 64 on 2 envs asked for 100 steps
    stops at 128 (the bar overran a total of 100)."""
    from microg_env.learning.train import planned_steps

    kwargs = {} if n_steps is None else {"n_steps" if algo == "ppo" else "train_freq": n_steps}
    params = hp.Hyperparams(algo, ENV_ID, n_envs, 2000, "MlpPolicy", None, {}, kwargs)
    assert planned_steps(params, start) == planned


@pytest.mark.slow
def test_a_run_stopped_in_its_final_evaluation_is_finished_by_a_resume(tmp_path, monkeypatch):
    """Ctrl-C in the end-of-run evaluation used to escape as a traceback, and the run (checkpointed
    at its target) could not be resumed: 'already has 128 steps'. Now it stops like any Ctrl-C and a
    resume at the target only evaluates and exports; a finished run still refuses."""
    from microg_env.learning import train as training

    def interrupted(self, model):
        raise KeyboardInterrupt

    settings = _settings(tmp_path, "ppo", 128, eval_freq=100_000)  # the only evaluation is the final one
    monkeypatch.setattr(training._Run, "evaluate", interrupted)
    with pytest.raises(TrainingInterrupted, match="--resume"):
        train(settings)
    monkeypatch.undo()
    folder = tmp_path / "logs" / "ppo" / f"{ENV_ID}_1"
    assert not (folder / "policy").exists()
    train(settings, resume_folder=folder)
    assert [row["timesteps"] for row in json.loads((folder / "evaluations.json").read_text())] == [128]
    assert json.loads((folder / "policy" / "policy.json").read_text())["timesteps"] == 128
    assert json.loads((folder / "checkpoints" / "latest.json").read_text())["finished"] is True
    with pytest.raises(ValueError, match="already has 128 steps"):
        train(settings, resume_folder=folder)


@pytest.mark.slow
def test_a_resumed_run_evaluates_its_last_model_even_under_the_evaluation_period(tmp_path):
    """A run evaluated at 128 steps and resumed to 256 with evaluations every 100 000 steps used to
    keep the 128-step evaluation as its last: the second session's training was never evaluated."""
    folder = train(_settings(tmp_path, "ppo", 128))  # evaluates at 128 (its --eval-freq)
    train(_settings(tmp_path, "ppo", 256, eval_freq=100_000), resume_folder=folder)
    rows = json.loads((folder / "evaluations.json").read_text())
    assert [row["timesteps"] for row in rows] == [128, 256]


def _card(folder):
    return json.loads((folder / "policy.json").read_text())


def _set_env(key, value):
    def change(folder):
        card = _card(folder)
        card["env_kwargs"][key] = str(folder) if value == "{folder}" else value
        (folder / "policy.json").write_text(json.dumps(card))

    return change


def _set_array(key, value):
    def change(folder):
        arrays = dict(np.load(folder / "policy.npz"))
        arrays[key] = value
        np.savez(folder / "policy.npz", **arrays)

    return change


def _inflating(folder):
    arrays = dict(np.load(folder / "policy.npz"))
    arrays["padding"] = np.zeros(70 * 2**20, dtype=np.uint8)  # 70 MB of zeros: a 70 kB archive
    np.savez_compressed(folder / "policy.npz", **arrays)


def _fifo(folder):
    import os

    (folder / "policy.npz").unlink()
    os.mkfifo(folder / "policy.npz")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (_set_env("base_controller", "{folder}"), "base_controller"),  # itself: was a RecursionError
        (_set_env("base_controller", "residual-sac-setpoint"), "base_controller"),  # a policy: was an AttributeError
        (_set_env("base_controller", None), "base_controller"),
        (_set_env("decision_period", 2.5), "decision_period"),
        (_set_env("decision_period", [5]), "decision_period"),
        (_set_env("control_period_s", float("nan")), "control_period_s"),
        (_set_env("residual_limit_m", None), "residual_limit_m"),
        (_set_array("weight_0", np.full((64, 10), "a")), "finite float"),  # was a failure at the first step
        (_set_array("weight_2", np.zeros((2, 64))), "layer shapes do not chain"),
        (_set_array("obs_mean", np.zeros(9)), "obs_mean"),
        (_inflating, "unpacks to"),
        (_fifo, "not a regular file"),
    ],
)
def test_a_bad_policy_folder_is_named_before_it_runs(tmp_path, change, message):
    import shutil

    from microg_env.controllers.registry import check_controller_name, shipped_policy_folder

    folder = tmp_path / "policy"
    shutil.copytree(shipped_policy_folder("residual-sac-setpoint"), folder)
    change(folder)
    with pytest.raises(ValueError, match=message) as error:
        check_controller_name(str(folder))
    assert str(folder) in str(error.value)


def test_the_log_states_the_base_controllers_cost_as_the_line_to_beat(ppo_run):
    """A residual run evaluates its base controller alone once (the same validation episodes and
    cost as every evaluation), logs it, and says at the end whether its best beat it."""
    from microg_env.learning.train import VALIDATION_SEED, validation_settings
    from microg_env.rollout.episode import evaluate

    folder = ppo_run[0]
    entry = yaml.safe_load((folder / "config.yml").read_text())[ENV_ID]
    base = make_controller(entry["env_kwargs"]["base_controller"], 1e-3)
    settings = validation_settings(entry["env_kwargs"])  # the single env's episodes: the batch's, one by one
    runs, _ = evaluate(lambda: MicroGravityLandingEnv(**settings), base, [VALIDATION_SEED])
    state = json.loads((folder / "checkpoints" / "latest.json").read_text())
    assert state["base_cost"] == pytest.approx(selection_cost(runs), rel=1e-12)
    log = (folder / "train.log").read_text()
    assert log.count("the line to beat") == 1  # once per run, not per session
    best = min(row["cost"] for row in json.loads((folder / "evaluations.json").read_text()) if row["best"])
    verdict = "it beats" if best < state["base_cost"] else "it does NOT beat"
    assert f"; {verdict} the base controller alone ({state['base_cost']:.4g})" in log.splitlines()[-1]


@pytest.mark.slow
def test_a_speed_policys_line_to_beat_is_the_papers_pid(tmp_path):
    """A run of the command task (no base controller) logs the paper's PID's validation cost as its
    line to beat; it named a base controller, a zero action, that a speed policy does not have."""
    from microg_env.learning.train import VALIDATION_SEED, validation_settings
    from microg_env.rollout.episode import evaluate

    env_id = "MicroGravityLanding-Command-v1"
    entry = yaml.safe_load((REPO / "microg_env" / "hyperparams" / "ppo.yml").read_text())[env_id]
    entry |= {"n_envs": 2, "n_steps": 64, "batch_size": 64, "n_epochs": 1}
    conf = tmp_path / "ppo.yml"
    conf.write_text(yaml.safe_dump({env_id: entry}))
    folder = train(
        TrainSettings(
            env_id=env_id,
            timesteps=128,
            hyperparams=str(conf),
            log_folder=str(tmp_path / "logs"),
            eval_episodes=1,
            command="pytest",
        )
    )
    settings = validation_settings(gym.spec(env_id).kwargs)
    runs, _ = evaluate(lambda: MicroGravityLandingEnv(**settings), make_controller("pid", 1e-3), [VALIDATION_SEED])
    state = json.loads((folder / "checkpoints" / "latest.json").read_text())
    assert state["base_cost"] == pytest.approx(selection_cost(runs), rel=1e-12)
    log = (folder / "train.log").read_text()
    assert f"the paper's PID: cost {state['base_cost']:.4g}, the line to beat" in log
    assert "a zero action" not in log
    # 128 steps leave the network's action at about 0: the support held still fails every evaluation
    assert log.splitlines()[-1].endswith("best evaluation cost none (every evaluation failed)")


def test_ctrl_c_before_the_first_checkpoint_leaves_no_run_folder(tmp_path, monkeypatch):
    """Ctrl-C while a new run is built (here: in its base controller's evaluation) used to escape
    as a traceback and leave a run folder that takes a run number and holds nothing to resume."""
    from microg_env.learning import train as training

    def interrupted(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(training._Run, "base_cost", interrupted)
    with pytest.raises(TrainingInterrupted, match="nothing was kept"):
        train(_settings(tmp_path, "ppo", 128))
    assert not list((tmp_path / "logs" / "ppo").iterdir())


def test_a_second_process_cannot_resume_a_run_folder_being_written(ppo_run, tmp_path):
    """Two resumes of one folder used to both proceed (two sessions recorded where three ran)."""
    from microg_env.files import folder_lock

    folder = ppo_run[0]
    before = (folder / "args.yml").read_text()
    with folder_lock(folder, "run folder"), pytest.raises(ValueError, match="being written by another process"):
        train(_settings(tmp_path, "ppo", 512), resume_folder=folder)
    assert (folder / "args.yml").read_text() == before  # the refused resume changed nothing


def _edit_latest(change):
    def edit(folder):
        path = folder / "checkpoints" / "latest.json"
        state = json.loads(path.read_text())
        path.write_text(json.dumps(change(state)))

    return edit


def _damage(key, damage):
    def edit(folder):
        state = json.loads((folder / "checkpoints" / "latest.json").read_text())
        path = folder / "checkpoints" / state[key]
        path.write_bytes(damage(path.read_bytes()))

    return edit


_empty_vecnormalize = _damage("vecnormalize", lambda data: b"")


def _old_rule_evaluations(folder):
    """A row scored by 0.11's rule: its cost with the worst x at the collision (2 um), its own
    figures the mean's (1 um; 0.1007 by this rule); a resume used to take its cost as the best."""
    path = folder / "evaluations.json"
    rows = json.loads(path.read_text())
    rows[0] |= {"cost": 0.2007, "compensation_error_pct": 0.0007, "collision_excursion_um": 1.0}
    path.write_text(json.dumps(rows))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (_edit_latest(lambda s: s | {"model": "../../../etc/passwd"}), "model must name a file in"),
        (_edit_latest(lambda s: s | {"timesteps": "many"}), "timesteps must be a number"),
        (_edit_latest(lambda s: [s]), "not a checkpoint record"),
        (_edit_latest(lambda s: s | {"model": "rl_model_0_steps.zip"}), "missing or empty"),
        (_empty_vecnormalize, "vecnormalize .* is missing or empty"),
        (_damage("vecnormalize", lambda data: b"\x80\x04garbage" + data[:40]), "vecnormalize .* cannot be read"),
        (_damage("model", lambda data: data[: len(data) // 2]), "model .* is not a whole stable-baselines3 archive"),
        (lambda folder: (folder / "checkpoints" / "latest.json").write_text("{garbage"), "cannot read the run"),
        (lambda folder: (folder / "args.yml").write_text(""), "not a mapping"),
        (lambda folder: (folder / "args.yml").write_text("algo: ppo\nwings: 2\n"), "unknown keys wings"),
        (lambda folder: (folder / "args.yml").write_text("algo: dqn\n"), "algo must be one of"),
        (lambda folder: (folder / "evaluations.json").write_text("[{"), "cannot read the run's evaluations"),
        (lambda folder: (folder / "evaluations.json").write_text("[1]"), "not a list of evaluations"),
        (lambda folder: (folder / "evaluations.json").write_text('[{"best": true}]'), "each with a cost"),
        (_old_rule_evaluations, r"costs 0\.2007.*before 0\.12\.0\) cannot be resumed"),
    ],
)
def test_a_broken_run_folder_is_named_and_left_as_it_was(ppo_run, tmp_path, change, message):
    """Each used to give a traceback, after the failed resume had rewritten args.yml and opened a
    monitor file; a path out of the run folder was followed."""
    import shutil

    folder = tmp_path / "run"
    shutil.copytree(ppo_run[0], folder)
    change(folder)
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    with pytest.raises(ValueError, match=message):
        train(_settings(tmp_path, "ppo", 1024), resume_folder=folder)
    after = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file() and p.name != ".lock"}
    assert after == {p: b for p, b in before.items() if p.name != ".lock"}


# -- the registered learning task ----------------------------------------------------------------

#: The residual task's versions and what each sets beyond a residual's settings (RESIDUAL); v1-v5 are
#: retired (test_a_retired_id_raises_naming_the_release_that_has_it).
RESIDUAL_IDS = {
    "MicroGravityLanding-Residual-v6": {
        "base_controller": "adaptive-dither",
        "residual_limit_m": 3e-6,
        "residual_highpass_hz": 2.0,
        "residual_highpass_order": 2,
        "residual_gate_m": 0.0,
        "residual_gate_on": "setpoint",
        "hidden_observations": ("support_position", "lander_accel", "pad_force"),
    },
}
RESIDUAL_IDS["MicroGravityLanding-Residual-v7"] = RESIDUAL_IDS["MicroGravityLanding-Residual-v6"] | {
    "reward_scale_m": 1e-6
}
#: The packaged files (by algorithm) whose entry for a residual version is checked against the id.
PACKAGED_ENTRIES = {
    "MicroGravityLanding-Residual-v6": ("sac",),
    "MicroGravityLanding-Residual-v7": hp.ALGORITHMS,
}
#: Each version's reward_threshold: its zero residual's mean return (its base controller's).
THRESHOLDS = {
    "MicroGravityLanding-Residual-v6": microg_env.GATED_REWARD_THRESHOLD,
    "MicroGravityLanding-Residual-v7": microg_env.ALIGNED_REWARD_THRESHOLD,
}


@pytest.mark.parametrize("version", range(1, 6))
def test_a_retired_id_raises_naming_the_release_that_has_it(version):
    """Residual-v1 to v5 retired in 0.26.0, Gymnasium's way: the id is known and refuses, naming
    the release that has it and the id that follows it, for the single and the vector env."""
    from gymnasium.error import DeprecatedEnv

    env_id = f"MicroGravityLanding-Residual-v{version}"
    words = f"^{env_id} is retired: microg-env 0.25.0 has it .* its successor is MicroGravityLanding-Residual-v7$"
    with pytest.raises(DeprecatedEnv, match=words):
        gym.make(env_id)
    with pytest.raises(DeprecatedEnv, match=words):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")


@pytest.mark.parametrize("env_id", RESIDUAL_IDS)
def test_the_residual_task_is_registered_with_its_defaults_and_passes_check_env(env_id):
    from gymnasium.utils.env_checker import check_env

    spec = gym.spec(env_id)
    assert (
        spec.kwargs
        == RESIDUAL
        | {
            "base_controller": "adaptive",
            "scenario_sampler": "training",
            "domain_randomization": "full",
        }
        | RESIDUAL_IDS[env_id]
    )
    assert spec.reward_threshold == THRESHOLDS[env_id] > 0
    check_env(gym.make(env_id).unwrapped, skip_render_check=True)
    # a run's settings are the id's defaults updated by the file's entry: the card says the whole task
    for algo in PACKAGED_ENTRIES.get(env_id, ("ppo",)):
        assert hp.load(algo, env_id).env_kwargs == spec.kwargs, algo


def test_a_zero_action_is_the_base_controller_on_every_version_of_the_residual_task():
    """The high-pass and the gate pass a zero residual as zero and the base controller reads every
    sensor whatever the agent is shown, so every version's zero action is a plain residual's (no
    high-pass, no gate, every entry shown) on the same base controller, bit for bit (the agent sees 0
    in its hidden entries)."""

    def run(env: gym.Env) -> tuple[np.ndarray, list[float]]:
        observations, rewards = [env.reset(seed=7)[0]], []
        for _ in range(300):
            observation, reward, *_ = env.step(np.zeros(1, dtype=np.float32))
            observations.append(observation)
            rewards.append(reward)
        return np.array(observations), rewards

    references = {}
    for env_id in RESIDUAL_IDS:
        base = gym.spec(env_id).kwargs["base_controller"]
        scale = gym.spec(env_id).kwargs.get("reward_scale_m", 1e-8)  # v7 scores x from 1 um
        if (base, scale) not in references:
            plain = RESIDUAL | {"base_controller": base, "reward_scale_m": scale, "residual_limit_m": 3e-6}
            plain |= {"scenario_sampler": "training", "domain_randomization": "full"}
            references[base, scale] = run(gym.make("MicroGravityLanding-v1", **plain))
        observations, rewards = run(gym.make(env_id))
        plain_observations, plain_rewards = references[base, scale]
        assert rewards == plain_rewards, env_id
        hidden = [OBSERVATION_INDEX[name] for name in RESIDUAL_IDS[env_id].get("hidden_observations", ())]
        shown = plain_observations.copy()
        shown[:, hidden] = 0.0
        np.testing.assert_array_equal(observations, shown, err_msg=env_id)
        assert plain_observations[:, hidden].any(axis=0).all(), env_id  # what it hides is there to hide
    assert set(references) == {("adaptive-dither", 1e-8), ("adaptive-dither", 1e-6)}


@pytest.mark.parametrize("env_id", RESIDUAL_IDS)
def test_validation_on_the_residual_task_drives_a_speed_environment(env_id):
    """The validation episodes are a speed environment whatever the id's registered defaults: a
    residual default coming back would have the controller's speed commands read as x setpoints,
    and a hidden entry would reach the base controller as 0 (the deployed controller hides what its
    policy is not shown itself)."""

    from microg_env.learning.train import validation_settings

    env = MicroGravityLandingEnv(**validation_settings(gym.spec(env_id).kwargs))
    assert (
        env.core.settings.action_mode,
        env.core.settings.decision_period,
        env.core.settings.hidden_observations,
    ) == ("speed", 1, ())
    assert env.settings.domain_randomization == microg_env.DomainRandomization.full()


@pytest.mark.slow
def test_a_run_killed_in_its_final_evaluation_is_finished_by_a_resume(tmp_path):
    """SIGKILL (no handler runs) while the run, checkpointed at its target, evaluates its last
    model: ``--resume`` at the same target evaluates and exports what is missing. (SIGTERM is the
    command line's Ctrl-C, tests/rollout/test_processes.py; a Ctrl-C in that evaluation is
    test_a_run_stopped_in_its_final_evaluation_is_finished_by_a_resume.)"""
    logs = tmp_path / "logs"
    command = [sys.executable, "-m", "microg_env.cli", "train", "--env", ENV_ID]
    command += ["-conf", str(_tiny_hyperparams(tmp_path, "ppo"))]
    command += ["--timesteps", "128", "--eval-freq", "100000", "--eval-episodes", "1", "--checkpoint-freq", "100000"]
    command += ["--log-folder", str(logs), "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    latest = logs / "ppo" / f"{ENV_ID}_1" / "checkpoints" / "latest.json"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        try:
            state = json.loads(latest.read_text())
        except (OSError, ValueError):
            state = {}
        if state.get("timesteps", 0) >= 128 and not state.get("finished", True):
            break  # in the end-of-run evaluation
        time.sleep(0.01)
    assert process.poll() is None, "the run ended before it could be stopped in its final evaluation"
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=60)
    folder = latest.parents[1]
    assert not (folder / "policy").exists()
    resumed = subprocess.run(
        [sys.executable, "-m", "microg_env.cli", "train", "--resume", str(folder), "--timesteps", "128", "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads(latest.read_text())["finished"] is True
    assert (folder / "policy" / "policy.json").is_file()
    assert json.loads((folder / "evaluations.json").read_text())[-1]["timesteps"] >= 128


def test_an_entry_is_checked_on_as_many_environments_as_the_run_steps(tmp_path):
    """n_steps 1 is a rollout of 8 transitions on 8 environments: the check, once built on one
    environment, refused it as SB3 refuses a rollout of one."""
    entry = yaml.safe_load((REPO / "microg_env" / "hyperparams" / "ppo.yml").read_text())[ENV_ID]
    path = tmp_path / "ppo.yml"
    path.write_text(yaml.safe_dump({ENV_ID: entry | {"n_envs": 8, "n_steps": 1, "batch_size": 8}}))
    assert resolve(TrainSettings(env_id=ENV_ID, hyperparams=str(path))).algo_kwargs["n_steps"] == 1
    path.write_text(yaml.safe_dump({ENV_ID: entry | {"n_envs": 1, "n_steps": 1, "batch_size": 1}}))
    with pytest.raises(ValueError, match="PPO refuses it"):
        resolve(TrainSettings(env_id=ENV_ID, hyperparams=str(path)))


@pytest.mark.parametrize("algo", hp.ALGORITHMS)
def test_every_algorithm_trains_the_default_task_as_registered_with_no_env_given(algo):
    """microg train --algo ALGO with no --env: the command task, from its packaged entry, whose
    env_kwargs are the id's registered ones (tqc.yml and crossq.yml had no entry for it)."""
    from microg_env.learning.settings import ENV_IDS

    params = resolve(TrainSettings(algo=algo))
    assert params.env_id == ENV_IDS[0] == "MicroGravityLanding-Command-v1"
    assert params.env_kwargs == gym.spec(params.env_id).kwargs


@pytest.mark.parametrize(("algo", "kwargs"), [("ppo", {"n_steps": 48, "batch_size": 32}), ("sac", {"train_freq": 64})])
def test_planned_steps_agrees_with_stable_baselines3_itself(algo, kwargs):
    """The rule, held against the library on a small standard env (2 envs, 100 steps asked)."""
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.env_util import make_vec_env

    from microg_env.learning.train import planned_steps

    venv = make_vec_env("Pendulum-v1", n_envs=2, seed=0)
    extra = {"learning_starts": 1000, "buffer_size": 1000} if algo == "sac" else {}
    model = {"ppo": PPO, "sac": SAC}[algo]("MlpPolicy", venv, seed=0, device="cpu", **kwargs, **extra)
    model.learn(100)
    params = hp.Hyperparams(algo, ENV_ID, 2, 100, "MlpPolicy", None, {}, kwargs)
    assert planned_steps(params, 0) == model.num_timesteps > 100
