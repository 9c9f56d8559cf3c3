"""The research probes behind docs/research-log.md: the partial oracles, the dither probe, the
recipe and fine-tuning probes, the gain and reward breakdowns, and the probes' asymmetric critic and
export hold. Run with ``pytest research`` (the default suite collects ``tests/`` only)."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

RESEARCH = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _probe_paths(monkeypatch):
    """The probes import each other by module name (and the returns table, a training tool, from its folder)."""
    monkeypatch.syspath_prepend(str(RESEARCH))


@pytest.mark.parametrize(
    ("name", "args", "expected"),
    [
        ("dither_probe", ["--amplitudes", "0.05,sac", "--seeds", "1", "--workers", "1"], "| sac | "),
        ("partial_oracles", ["--seeds", "1000", "--duration", "0.3"], "cogging and speed loop"),
        ("fifty_gram_joint_fit", [], "| joint, relative | -7.08 |"),
        ("plain_sb3", ["--seeds", "0", "--steps", "64", "--episodes", "1"], "| 0 | 64 | "),
        (
            "drive_scheme_held_out",
            ["--scenarios", "heavy-second", "--seeds", "1000", "--duration", "0.3"],
            "learned / dither",
        ),
        (
            "drive_timing",
            [
                "--scheme",
                "midpoint",
                "--controllers",
                "pid",
                "--conditions",
                "1",
                "--duration",
                "0.3",
                "--steps-us",
                "100",
                "50",
            ],
            "pid                    c1  ",
        ),
        (
            "finetune_probe",
            ["--timesteps", "64", "--episodes", "1", "--set", "sensor_set=mixed"],
            "| fine-tuned 64 steps, seed 0 | ",
        ),
        (
            "sac_probes",
            ["--peak-weight", "20", "--set", "sensor_set=paper", "--timesteps", "64", "--episodes", "1"],
            "| 64 | ",
        ),
        (
            "recipe_probe",
            ["--stack", "2", "--timesteps", "256", "--seeds", "2", "--scenarios", "training"],
            "| training | ",
        ),
        (
            "recipe_probe",
            ["--privileged", "--blind", "height", "--timesteps", "256", "--seeds", "1", "--held-out-seeds", "0"],
            "| training | ",
        ),
        (
            "recipe_probe",
            ["--algo", "sac", "--blind", "height", "--timesteps", "256", "--seeds", "1", "--held-out-seeds", "0"],
            "sac, stack 1, privileged False, blind ['height'], seed 0: 256 steps",
        ),
    ],
)
@pytest.mark.slow
def test_probe_runs(name, args, expected, monkeypatch, capsys):
    module = importlib.import_module(name)
    assert module.main(args) == 0
    assert expected in capsys.readouterr().out


@pytest.fixture
def recipe_probe(monkeypatch):
    return importlib.import_module("recipe_probe")


@pytest.mark.slow
@pytest.mark.parametrize(("algo", "privileged"), [("ppo", True), ("sac", False)])
def test_probe_export_acts_as_the_trained_actor(recipe_probe, tmp_path, algo, privileged):
    """The exported folder (privileged columns dropped, blind ones zeroed; SAC's output squashed)
    gives the trained actor's actions on the environment's own observations, whatever a blind
    entry reads. (SAC's 512 steps come before its first update at 5000: the exported actor is its
    initial one, which is what the check needs.)"""
    import gymnasium as gym
    import numpy as np

    from microg_env.controllers.registry import check_policy_folder
    from microg_env.interface import OBSERVATION_INDEX

    blind = [OBSERVATION_INDEX["support_position"], OBSERVATION_INDEX["height"]]
    model, normalized = recipe_probe.train(algo, 1, privileged, blind, seed=3, timesteps=512)
    recipe_probe.export(model, normalized, blind, tmp_path, {"env_kwargs": gym.spec(recipe_probe.ENV_ID).kwargs})
    _, network = check_policy_folder(tmp_path)
    assert network.weights[0].shape[1] == len(OBSERVATION_INDEX)
    assert network.squash == (algo == "sac")
    act = recipe_probe.actor(model, normalized, 1, blind)
    env = gym.make(recipe_probe.ENV_ID)
    obs, _ = env.reset(seed=1000)
    actions = []
    for _ in range(50):
        expected = act(obs)
        shifted = obs.copy()
        shifted[blind] += 1.0  # a blind entry moves nothing
        for seen in (obs, shifted):
            assert np.allclose(network.predict(seen)[0], expected, atol=1e-5)
        actions.append(expected)
        obs, *_ = env.step(expected)
    assert np.ptp(actions) > 0  # the check saw the actor act, not a constant
    if privileged:  # the critic reads the privileged entries, the actor does not
        import torch

        zero = np.zeros(normalized.observation_space.shape, np.float32)
        full = torch.as_tensor(normalized.normalize_obs(zero))[None]
        told = full.clone()
        told[0, len(OBSERVATION_INDEX) :] += 1.0
        with torch.no_grad():
            assert not torch.allclose(model.policy.predict_values(full), model.policy.predict_values(told))
            assert torch.equal(model.policy.get_distribution(full).mode(), model.policy.get_distribution(told).mode())


def test_probe_refuses_a_privileged_or_stacked_sac(recipe_probe, capsys):
    """The asymmetric critic is PPO's: ``--privileged`` with ``--algo sac`` is refused, naming both;
    so is a stacked SAC (its replay buffer would get VecNormalize's unstacked observations), which
    names the probe that stacks it."""
    for args, message in [
        (["--algo", "sac", "--privileged"], "--privileged is PPO's asymmetric actor-critic: --algo ppo"),
        (["--algo", "sac", "--stack", "4"], "research/sac_probes.py --stack"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            recipe_probe.main(args)
        assert exit_.value.code == 2
        assert message in capsys.readouterr().err


def test_sac_probes_refuse_what_they_cannot_run(monkeypatch, capsys):
    """A privileged stack, a bad count or a bad env keyword: one line each, before any training."""
    probes = importlib.import_module("sac_probes")
    for args, message in [
        (["--privileged", "--stack", "2"], "--privileged pads one observation"),
        (["--stack", "0"], "--stack must be 1 to 16, got 0"),
        (["--peak-weight", "nan"], "--peak-weight must be at least 0, got nan"),
        (["--episodes", "0"], "--episodes must be 1 to 500, got 0"),
        (["--set", "sensor_set=ruler"], "sensor_set must be one of"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            probes.main(args)
        assert exit_.value.code == 2
        assert message in capsys.readouterr().err


@pytest.mark.slow
def test_privileged_observation_follows_the_episode(recipe_probe):
    """The critic's features are those of the episode an observation belongs to: an ended
    episode's terminal observation carries its own, the next episode's first observation the new
    one's. The live entries, after them, are the last step's readings over their scales: the
    ending step's in a terminal observation, zeros in an episode's first."""
    import numpy as np

    from microg_env.interface import OBSERVATION_INDEX
    from microg_env.learning import hyperparams
    from microg_env.learning.vec_env import BatchedVecEnv

    params = hyperparams.load("ppo", recipe_probe.ENV_ID)
    height = OBSERVATION_INDEX["height"]
    live = {"x_m": 1e-6, "foot_height_m": 0.01}
    env = recipe_probe.ProbeObservation(BatchedVecEnv.make(2, **params.env_kwargs), [height], True, live)
    env.seed(7)
    obs = env.reset()
    end = obs.shape[1] - len(live)  # the privileged features end here
    size = end - recipe_probe.privileged_features(env.venv.env.core.episodes[0]).size
    before = obs[:, size:end].copy()
    assert (obs[:, height] == 0.0).all()
    assert (obs[:, end:] == 0.0).all()
    assert not np.allclose(before[0], before[1])  # two rigs, two drawn plants
    for _ in range(2000):
        obs, _, dones, infos = env.step(np.zeros((2, 1), dtype=np.float32))
        readings = np.array([[info[key] / scale for key, scale in live.items()] for info in infos], np.float32)
        if dones.any():
            break
        np.testing.assert_array_equal(obs[:, end:], readings)
    i = int(np.flatnonzero(dones)[0])
    assert (readings[i] != 0.0).all()  # readings a zero (an episode's first) cannot pass for
    terminal = infos[i]["terminal_observation"]
    assert np.array_equal(terminal[size:end], before[i])
    np.testing.assert_array_equal(terminal[end:], readings[i])
    assert terminal[height] == 0.0  # blind, before the reset and after it
    assert (obs[:, height] == 0.0).all()
    assert (obs[i, end:] == 0.0).all()  # the next episode's first observation
    assert not np.allclose(obs[i, size:end], before[i])
    current = recipe_probe.privileged_features(env.venv.env.core.episodes[i]).astype(np.float32)
    assert np.array_equal(obs[i, size:end], current)
    env.close()


def test_the_dither_probe_recipe_is_the_packaged_sac_recipe_on_the_dithered_base():
    """research/sac_on_dither.yml (docs/research-log.md's SAC on `adaptive-dither`) differs from the
    packaged v4 SAC recipe in its base controller only."""
    from microg_env.learning import hyperparams

    env_id = "MicroGravityLanding-Residual-v4"
    probe = hyperparams.load("sac", env_id, RESEARCH / "sac_on_dither.yml").as_config()
    packaged = hyperparams.load("sac", env_id).as_config()
    assert probe["env_kwargs"].pop("base_controller") == "adaptive-dither"
    assert packaged["env_kwargs"].pop("base_controller") == "adaptive"
    assert probe == packaged


def test_the_descent_reward_probe_recipe_is_the_dither_probe_paid_for_its_descent():
    """training/sac_descent_reward.yml differs from training/sac_on_dither.yml in the reward's
    descent share only."""
    from microg_env.learning import hyperparams

    env_id = "MicroGravityLanding-Residual-v4"
    probe = hyperparams.load("sac", env_id, RESEARCH / "sac_descent_reward.yml").as_config()
    dither = hyperparams.load("sac", env_id, RESEARCH / "sac_on_dither.yml").as_config()
    assert probe["env_kwargs"].pop("reward_descent_weight") == 0.5
    assert "reward_descent_weight" not in dither["env_kwargs"]
    assert probe == dither


def test_gain_by_base_error_bins_paired_episodes_by_the_references_own_value(monkeypatch, tmp_path, capsys):
    """Hand-made pairs: bins by the reference's value (edges in µm), the bins' means, ratio and
    share won; an episode the controller did not run, or one without a value, is left out (the
    latter counted), an empty bin is not printed; a missing file, bad edges, an unknown quantity or
    controller are one line on stderr with exit 2."""
    import json

    gain = importlib.import_module("gain_by_base_error")
    values = {  # (scenario, seed): (reference, controller), µm
        ("a", 1): (0.2, 0.4),
        ("a", 2): (0.4, 0.3),
        ("b", 1): (3.0, 2.0),
        ("b", 2): (5.0, 3.0),
    }
    cases = [
        {"controller": name, "scenario": scenario, "seed": seed, "values": {"collision_excursion_m": v[k] * 1e-6}}
        for (scenario, seed), v in values.items()
        for k, name in enumerate(("ref", "mine"))
    ]
    cases.append({"controller": "ref", "scenario": "c", "seed": 1, "values": {"collision_excursion_m": 9e-6}})
    for name, value in (("ref", 1e-6), ("mine", None)):  # a run that ended before its value
        cases.append({"controller": name, "scenario": "d", "seed": 1, "values": {"collision_excursion_m": value}})
    quantity = {"label": "x at the collision", "unit": "µm", "si_unit_times": 1e6}
    path = tmp_path / "comparison.json"
    path.write_text(json.dumps({"cases": cases, "quantities": {"collision_excursion_m": quantity}}))
    args = [str(path), "--controller", "mine", "--reference", "ref", "--edges", "1,2"]
    assert gain.main(args) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == "(1 episodes without a value of either left out)"
    assert lines[4:] == [
        "| 0 to 1 | 2 | 0.300 | 0.350 | 1.17x | 50% |",
        "| 2 to inf | 2 | 4.000 | 2.500 | 0.62x | 100% |",
    ]
    for bad, message in [
        ([str(tmp_path / "missing.json")], "missing.json: FileNotFoundError"),
        ([*args[:-1], "2,1"], "--edges must be positive, finite and increasing, got '2,1'"),
        ([*args[:-1], "1,nan"], "--edges must be positive, finite and increasing, got '1,nan'"),
        ([*args[:-1], "one"], "--edges must be comma-separated numbers, got 'one'"),
        ([*args, "--quantity", "x"], "--quantity 'x': not one of collision_excursion_m"),
        ([str(path), "--reference", "ref"], "no controller 'residual-sac-gated' in it"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            gain.main(bad)
        assert exit_.value.code == 2
        assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("recipe", "packaged_id", "key", "value"),
    [
        ("sac_on_both_rigs.yml", "MicroGravityLanding-Residual-v5", "sensor_set", "mixed"),
        ("sac_gate_on_setpoint.yml", "MicroGravityLanding-Residual-v5", "residual_gate_on", "setpoint"),
        ("sac_setpoint_on_both_rigs.yml", "MicroGravityLanding-Residual-v6", "sensor_set", "mixed"),
    ],
)
def test_a_probe_recipe_is_the_packaged_gated_recipe_with_one_change(recipe, packaged_id, key, value):
    """Each probe recipe (on v5) differs from a packaged gated SAC recipe in its one env keyword only."""
    from microg_env.learning import hyperparams

    probe = hyperparams.load("sac", "MicroGravityLanding-Residual-v5", RESEARCH / recipe).as_config()
    packaged = hyperparams.load("sac", packaged_id).as_config()
    assert probe["env_kwargs"].pop(key) == value
    assert key not in packaged["env_kwargs"]
    assert probe == packaged


def test_the_setpoint_probe_on_v5_is_v6s_packaged_task_and_recipe():
    """The five seeds `residual-sac-setpoint` was chosen from were trained on v5 by
    training/sac_gate_on_setpoint.yml: the same environment and recipe as sac.yml's v6 entry, whose
    command trains the shipped seed (its card's)."""
    import gymnasium as gym

    from microg_env.learning import hyperparams

    probe = hyperparams.load("sac", "MicroGravityLanding-Residual-v5", RESEARCH / "sac_gate_on_setpoint.yml")
    packaged = hyperparams.load("sac", "MicroGravityLanding-Residual-v6")
    assert probe.env_kwargs == packaged.env_kwargs == gym.spec("MicroGravityLanding-Residual-v6").kwargs
    assert packaged.env_kwargs["residual_gate_on"] == "setpoint"
    assert probe.as_config() == packaged.as_config()


def test_reward_by_phase_splits_the_gated_policys_return_where_its_gate_opens(monkeypatch, capsys):
    """The gated policy acts from the first contact on, so its return before it is the zero
    residual's exactly, on both rigs, while it moves the first contact's peak; the table has a row
    per rig; a count of no episodes is refused."""
    import gymnasium as gym
    import numpy as np

    phases = importlib.import_module("reward_by_phase")
    env_id = "MicroGravityLanding-Residual-v5"
    act = phases.policy_actor(env_id, "residual-sac-gated")
    for sensors in ("extended", "paper"):
        env = gym.make(env_id, sensor_set=sensors)
        (mine, peak, opening), (base, base_peak, zero) = (
            phases.phase_returns(env, a, 1000) for a in (act, phases.zero_residual)
        )
        assert mine[0] == base[0] > 0
        assert mine[1] != base[1]
        assert peak != base_peak > 0
        assert zero == 0.0  # the gate opened in the episode (NaN if not) ...
        assert np.isfinite(opening)
        assert opening != 0.0  # ... and passed the policy's action
    assert phases.main(["--seeds", "1"]) == 0
    rows = capsys.readouterr().out.splitlines()[3:]
    assert [row.split(" | ")[0] for row in rows] == ["| extended", "| paper"]
    with pytest.raises(SystemExit):
        phases.main(["--seeds", "0"])
    assert "--seeds must be at least 1, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        phases.main(["--reward-scale-m", "-1"])
    assert "reward_scale_m" in capsys.readouterr().err


def test_finetune_probe_refuses_what_it_cannot_fine_tune(monkeypatch, capsys):
    """A change that is not KEY=VALUE, a PPO policy and a bad env keyword are refused in one line
    each, before any training."""
    probe = importlib.import_module("finetune_probe")
    for args, message in [
        (["--set", "sensor_set"], "--set takes KEY=VALUE, got 'sensor_set'"),
        (["--policy", "residual-ppo"], "policy 'residual-ppo' was trained with 'ppo', not sac"),
        (["--set", "sensor_set=ruler"], "sensor_set"),
        (["--episodes", "501"], "--episodes 1 to 500"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            probe.main(args)
        assert exit_.value.code == 2
        assert message in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize(("stack", "privileged"), [(3, False), (1, True)])
def test_a_sac_probe_is_deployed_as_it_was_trained(monkeypatch, stack, privileged):
    """The probe's deployed controller (the speed environment, a base controller, its memory) acts
    as the model does on the residual environment's stacked (or padded) observations, bit for bit,
    through a touchdown, episode after episode."""
    import gymnasium as gym
    import numpy as np

    from microg_env.envs.landing import MicroGravityLandingEnv
    from microg_env.learning.train import validation_settings
    from microg_env.rollout.episode import run_episode
    from microg_env.scenarios import LoadStep, Scenario

    probes = importlib.import_module("sac_probes")
    touch = {"scenario_sampler": None, "scenario": Scenario("touch", (LoadStep(1.5),), 0.002, duration_s=0.6)}
    # ungated, so that the first decisions, where a stale history would show, move x
    kwargs = gym.spec(probes.ENV_ID).kwargs | {"domain_randomization": False, "residual_gate_m": None}
    model, normalized, visible = probes.build(kwargs, stack, privileged, 0.0, seed=2)
    size = normalized.observation_space.shape[0] // stack
    statistics = np.random.default_rng(0).uniform(0.5, 2.0, (2, size * stack))  # not the identity
    normalized.obs_rms.mean, normalized.obs_rms.var = statistics[0] - 1.0, statistics[1]
    env = MicroGravityLandingEnv(**kwargs | touch)
    history = np.zeros((stack, size), dtype=np.float32)
    history[-1, :visible], _ = env.reset(seed=5)
    xs, setpoints = [], []
    for _ in range(120):
        action, _ = model.predict(normalized.normalize_obs(history.reshape(1, -1)), deterministic=True)
        observation, _, _, _, info = env.step(action[0])
        history = np.roll(history, -1, axis=0)
        history[-1] = 0.0
        history[-1, :visible] = observation
        xs.append(info["x_m"])
        setpoints.append(info["setpoint_m"])
    assert np.ptp(setpoints[:3]) > 1e-9  # the policy moved the setpoint from its first decisions
    controller = probes.probe_controller(model, normalized, stack, visible, kwargs)
    speed_env = MicroGravityLandingEnv(**validation_settings(kwargs) | touch)
    for _ in range(2):  # a second episode: the controller forgot the first one's history at its reset
        deployed = run_episode(speed_env, controller, seed=5, duration_s=0.6)
        np.testing.assert_array_equal(deployed.x_m[5::5], np.array(xs))


def test_the_peak_reward_charges_the_first_contacts_peak_as_reward_by_phase_reads_it(monkeypatch):
    """Over each episode, sac_probes' PeakReward takes ``weight`` per micrometre of that episode's
    first-contact peak |x| from the return: the peak ``reward_by_phase.phase_returns`` reads on the
    single env of the same seed (the vector env's rig i is it, bit for bit), for each rig's second
    episode too (the peak and the contact start again where a rig's episode ends)."""
    import gymnasium as gym
    import numpy as np

    from microg_env.learning.vec_env import BatchedVecEnv

    probes = importlib.import_module("sac_probes")
    phases = importlib.import_module("reward_by_phase")
    kwargs = gym.spec(probes.ENV_ID).kwargs
    venv = probes.PeakReward(BatchedVecEnv.make(2, **kwargs), weight=20.0)
    venv.seed(1000)
    venv.reset()
    returns, episode = np.zeros((2, 2)), np.zeros(2, dtype=np.int64)  # each rig's first two episodes
    while (episode < 2).any():
        _, rewards, dones, _ = venv.step(np.zeros((2, 1), dtype=np.float32))
        for rig in np.flatnonzero(episode < 2):
            returns[rig, episode[rig]] += rewards[rig]
        episode += dones
    env = gym.make(probes.ENV_ID)
    for rig in range(2):
        for number, seed in enumerate((1000 + rig, None)):  # None: the single env's next episode
            plain, peak_m, _ = phases.phase_returns(env, phases.zero_residual, seed)
            assert peak_m > 2e-7  # a contact whose peak the charge can be told from
            assert returns[rig, number] == pytest.approx(plain.sum() - 20.0 * peak_m * 1e6, abs=1e-3)


def test_the_drive_timing_probes_shipped_scheme_is_the_environment():
    """research/drive_timing.py steps one physics step at a time; its ``shipped`` scheme is the
    environment as it runs (x equal to rounding: one step at a time is not MuJoCo's ``nstep`` loop
    bit for bit), and each other scheme changes x by far more."""
    import argparse

    from microg_env.controllers import make_controller
    from microg_env.envs.landing import MicroGravityLandingEnv
    from microg_env.rollout.episode import run_with_metrics

    probe = importlib.import_module("drive_timing")
    env = MicroGravityLandingEnv(condition=1, drive_scheme="mujoco")
    metrics = run_with_metrics(env, make_controller("feedforward", env.settings.control_period_s), seed=0,
                               duration_s=1.0)[2]  # fmt: skip
    args = argparse.Namespace(overrides={}, duration=1.0, own_friction=False, integrator="implicitfast")
    free_falls = {}
    for scheme in probe.SCHEMES:
        args.scheme = scheme
        free_falls[scheme] = probe.run("feedforward", 1, 100.0, args)[0]
    assert free_falls["shipped"] == pytest.approx(metrics.flexible_unit_excursion_free_fall_m * 1e6, rel=1e-9)
    assert all(
        abs(value / free_falls["shipped"] - 1) > 1e-3 for scheme, value in free_falls.items() if scheme != "shipped"
    )
    args.scheme, args.own_friction = "midpoint", True
    assert probe.run("feedforward", 1, 100.0, args)[0] != free_falls["midpoint"]
