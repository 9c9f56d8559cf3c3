"""Policy folders as they are read and deployed: a card is the task its policy was trained on, said
once each (no unknown or repeated key, an env_id its env_kwargs agree with, a known sensor set); a
policy runs only on a rig whose sensors it read in training, and sees there what training showed it;
a network that would act blind or give NaN is refused, naming its folder."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from microg_env.cli import main
from microg_env.controllers.policy import MLPPolicy
from microg_env.controllers.registry import (
    check_controller_name,
    check_policy_folder,
    deployed_hidden,
    load_policy,
    make_controller,
    policy_card,
    shipped_policies,
    shipped_policy_folder,
)
from microg_env.interface import CARD_FILE, NETWORK_FILE, OBSERVATION_INDEX, SENSOR_SETS
from microg_env.rollout.spec import RunSpec
from microg_env.task import ACTING_KEYS

#: The rigs each shipped policy reads all it read in training on: each hides the pad force and the
#: accelerometer, which the paper's rig lacks, from its agent.
RUNS_ON = {
    "command-ppo": {"extended", "paper"},
    "gains-ppo": {"extended", "paper"},
    "residual-sac-setpoint": {"extended", "paper"},
}
PAPER_ONLY = SENSOR_SETS["paper"]


def _policy(tmp_path: Path, name: str = "residual-sac-setpoint", **env_kwargs) -> Path:
    """A copy of shipped policy ``name`` with ``env_kwargs`` changed in its card."""
    folder = tmp_path / "policy"
    shutil.copytree(shipped_policy_folder(name), folder)
    card = json.loads((folder / CARD_FILE).read_text())
    card["env_kwargs"] |= env_kwargs
    (folder / CARD_FILE).write_text(json.dumps(card))
    return folder


def _reads_every_sensor(tmp_path: Path) -> Path:
    """A policy that reads the pad force and the accelerometer (as the residuals before 0.26.0 did)."""
    return _policy(tmp_path, hidden_observations=["support_position"])


# -- sensor sets -------------------------------------------------------------------------------------


def test_each_policy_runs_on_the_sensor_sets_whose_readings_it_was_trained_on(tmp_path):
    assert set(shipped_policies()) == set(RUNS_ON)
    every_sensor = str(_reads_every_sensor(tmp_path))
    for name, rigs in (*RUNS_ON.items(), (every_sensor, {"extended"})):
        folder = shipped_policy_folder(name) if name in RUNS_ON else name
        assert "sensor_set" not in policy_card(folder)["env_kwargs"]  # the default: extended
        for rig in SENSOR_SETS:
            if rig in rigs:
                assert check_controller_name(name, rig) == name
            else:
                with pytest.raises(
                    ValueError, match=f"policy {name!r} was trained on the 'extended' sensor set"
                ) as refused:
                    check_controller_name(name, rig)
                message = str(refused.value)
                assert f"which the {rig!r} sensor set lacks" in message
                assert "lander_accel, pad_force" in message


def test_a_policy_on_a_rig_lacking_what_it_read_is_refused_before_any_run(tmp_path, monkeypatch, capsys):
    """RunSpec (campaigns, ``microg run``), ``compare`` and the CLI refuse it before a run starts."""
    from microg_env.experiments import comparison

    every_sensor = str(_reads_every_sensor(tmp_path))

    def no_run(*args, **kwargs):
        raise AssertionError("a run started")

    monkeypatch.setattr(comparison, "run_many", no_run)
    refused = f"{every_sensor!r} was trained on the 'extended' sensor set"
    with pytest.raises(ValueError, match=re.escape(refused)):
        RunSpec("condition-1", every_sensor, sensor_set="paper")
    assert RunSpec("condition-1", "residual-sac-setpoint", sensor_set="paper").sensor_set == "paper"
    with pytest.raises(ValueError, match=re.escape(refused)):
        comparison.compare(["adaptive", every_sensor], ["condition-1"], seeds=1, sensor_set="paper")
    code = main(["compare", "--controllers", f"adaptive,{every_sensor}", "--sensors", "paper"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert f"--controllers: policy {refused}" in err
    assert "'paper'" in err


class Recording:
    """A policy that records the observations it is shown."""

    def __init__(self, policy) -> None:
        self.policy, self.seen = policy, []

    def predict(self, observation, deterministic=True):
        self.seen.append(np.array(observation))
        return self.policy.predict(observation, deterministic)


def test_a_policy_trained_on_the_papers_rig_sees_there_and_on_every_sensor_what_training_showed(tmp_path):
    """Trained on the paper's rig, a policy read 0 for the pad force and the accelerometer: deployed
    with every sensor it reads 0 there too; a policy trained on both rigs runs on both as it is."""
    folder = _policy(tmp_path, sensor_set="paper", hidden_observations=[])
    readings = np.linspace(0.1, 1.0, len(OBSERVATION_INDEX), dtype=np.float32)
    for rig in SENSOR_SETS:
        controller = make_controller(str(folder), 1e-3, sensor_set=rig)
        controller.policy = recording = Recording(controller.policy)
        shown = readings.copy()
        shown[[OBSERVATION_INDEX[entry] for entry in SENSOR_SETS[rig]]] = 0.0  # what the rig reads
        controller(shown)
        expected = shown.copy()
        expected[[OBSERVATION_INDEX[entry] for entry in PAPER_ONLY]] = 0.0
        expected[[OBSERVATION_INDEX["previous_action"], OBSERVATION_INDEX["base_command"]]] = 0.0  # the first decision
        np.testing.assert_array_equal(recording.seen[0][0], expected)
    mixed = _policy(tmp_path / "mixed", sensor_set="mixed")
    for rig in (*SENSOR_SETS, "mixed"):
        assert check_controller_name(str(mixed), rig) == str(mixed)
    with pytest.raises(ValueError, match=r"which the 'paper' sensor set \(drawn by 'mixed'\) lacks"):
        check_controller_name(str(_reads_every_sensor(tmp_path / "every")), "mixed")


# -- cards -------------------------------------------------------------------------------------------


#: The acting keys that another key's value needs (the task refuses them without it).
NEEDS = {"residual_gate_m": ("residual_gate_on",), "residual_highpass_hz": ("residual_highpass_order",)}


def _contradictions():
    """Each acting key left out of a card whose env_id registers it at another value than its
    default: the environment trained with the registered value, a deployment would read the default."""
    from dataclasses import fields

    from microg_env.task import TaskSettings

    defaults = {option.name: option.default for option in fields(TaskSettings)}
    ours = [
        spec for spec in gym.registry.values() if spec.entry_point == "microg_env.envs.landing:MicroGravityLandingEnv"
    ]
    for key in ACTING_KEYS:
        spec = next((spec for spec in ours if key in spec.kwargs and spec.kwargs[key] != defaults[key]), None)
        if spec is None:  # no id registers it at another value than its default
            continue
        left_out = (key, *NEEDS.get(key, ()))
        env_kwargs = {k: v for k, v in spec.kwargs.items() if k not in left_out}
        yield f"{key} left out of {spec.id}", {"env_id": spec.id, "env_kwargs": env_kwargs}, key


def _bad_cards():
    """(case, card text, what the error names) for every kind of bad card."""
    card = json.loads((shipped_policy_folder("residual-sac-setpoint") / CARD_FILE).read_text())
    for value in ["telepathy", "Paper", "", None, 1, True, ["paper"], {"paper": 1}]:
        yield (
            f"sensor_set {value!r}",
            json.dumps(card | {"env_kwargs": card["env_kwargs"] | {"sensor_set": value}}),
            ("sensor_set"),
        )
    yield "unknown key", json.dumps(card | {"sensor_sets": "paper"}), "unknown key 'sensor_sets'"
    yield (
        "unknown env_kwargs key",
        json.dumps(card | {"env_kwargs": card["env_kwargs"] | {"sensors": "paper"}}),
        ("env_kwargs.sensors is not a setting"),
    )
    text = json.dumps(card)
    yield "repeated key", text.replace('"seed": 5', '"seed": 5, "seed": 1'), "key 'seed' is given twice"
    yield (
        "repeated env_kwargs key",
        text.replace('"decision_period": 5', '"decision_period": 5, "decision_period": 1'),
        ("key 'decision_period' is given twice"),
    )
    for env_id in ["CartPole-v1", "MicroGravityLanding-v9", 1, None]:
        yield f"env_id {env_id!r}", json.dumps(card | {"env_id": env_id}), "env_id must be one of"
    retired = "MicroGravityLanding-Residual-v5"  # a policy of 0.25.0 or before, trained on it
    yield "env_id retired", json.dumps(card | {"env_id": retired}), f"env_id {retired} is retired: microg-env 0.25.0"
    for case, contradiction, key in _contradictions():
        # without action_mode the residual settings left make a speed task, which the task refuses first
        named = "only action_mode 'residual'" if key == "action_mode" else f"env_kwargs leaves out {key}"
        yield case, json.dumps(card | contradiction), named


BAD_CARDS = list(_bad_cards())


def test_every_acting_key_has_a_registered_id_to_contradict():
    # gain_limit: every id registers its default, so a card that leaves it out deploys as trained
    assert [key for *_, key in _contradictions()] == [key for key in ACTING_KEYS if key != "gain_limit"]


@pytest.mark.parametrize(("case", "text", "named"), BAD_CARDS, ids=[case for case, *_ in BAD_CARDS])
def test_a_generated_bad_card_is_refused_in_one_line_naming_the_card(case, text, named, tmp_path, capsys):
    folder = _policy(tmp_path)
    (folder / CARD_FILE).write_text(text)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    code = main(["run", "--controller", str(folder), "--duration", "0.01", "--json"])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert str(folder / CARD_FILE) in err, err
    assert named in err, err
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_a_card_may_change_an_acting_setting_of_its_env_id_as_a_training_entry_may(tmp_path):
    """An entry may train v7 on another base controller: its card is v7's with it."""
    kwargs = dict(gym.spec("MicroGravityLanding-Residual-v7").kwargs)
    folder = _policy(tmp_path, **kwargs | {"base_controller": "adaptive"})
    card = json.loads((folder / CARD_FILE).read_text())
    (folder / CARD_FILE).write_text(json.dumps(card | {"env_id": "MicroGravityLanding-Residual-v7"}))
    assert policy_card(folder)["env_kwargs"]["base_controller"] == "adaptive"


# -- the network ---------------------------------------------------------------------------------------


def _network(**changes) -> MLPPolicy:
    rng = np.random.default_rng(0)
    size = len(OBSERVATION_INDEX)
    values = {
        "weights": (rng.normal(0.0, 0.5, (4, size)), rng.normal(0.0, 0.5, (1, 4))),
        "biases": (np.zeros(4), np.zeros(1)),
        "activation": "tanh",
        "squash": True,
        "obs_mean": np.zeros(size),
        "obs_var": np.ones(size),
        "clip_obs": 10.0,
        "epsilon": 1e-8,
    }
    return MLPPolicy(**values | changes)


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        ({"clip_obs": 0.0}, "clip_obs"),
        ({"clip_obs": -10.0}, "clip_obs"),
        ({"clip_obs": float("nan")}, "clip_obs"),
        ({"clip_obs": float("inf")}, "clip_obs"),
        ({"clip_obs": 1e-30}, "clip_obs must be at least 1"),  # a blind policy, accepted in 0.16
        ({"clip_obs": 0.5}, "clip_obs must be at least 1"),
        ({"epsilon": -1e-3}, "epsilon"),
        ({"epsilon": float("nan")}, "epsilon"),
        ({"epsilon": float("inf")}, "epsilon"),
        ({"epsilon": 0.0, "obs_var": np.r_[np.ones(9), 0.0]}, r"obs_var \+ epsilon"),
        ({"mean_clip": -1.0}, "mean_clip"),
        ({"squash": "false"}, "squash"),
    ],
)
def test_a_network_that_would_act_blind_or_give_nan_is_refused(changes, named):
    assert np.isfinite(_network().predict(np.ones(len(OBSERVATION_INDEX)))[0]).all()
    with pytest.raises(ValueError, match=named):
        _network(**changes)


@pytest.mark.parametrize(("key", "value"), [("epsilon", -1.0), ("clip_obs", 0.0), ("clip_obs", -5.0)])
def test_a_policy_file_with_a_blind_or_nan_normalisation_is_refused_naming_its_folder(key, value, tmp_path, capsys):
    folder = _policy(tmp_path)
    with np.load(folder / NETWORK_FILE) as data:
        arrays = {name: data[name] for name in data.files}
    meta = json.loads(str(arrays["meta"])) | {key: value}
    np.savez(folder / NETWORK_FILE, **arrays | {"meta": np.array(json.dumps(meta))})
    with pytest.raises(ValueError, match=rf"policy folder {str(folder)!r}: cannot read {NETWORK_FILE} \({key} must be"):
        check_policy_folder(folder)
    code = main(["run", "--controller", str(folder), "--duration", "0.01", "--json"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert str(folder) in err, err
    assert key in err, err


# -- a comparison's controllers --------------------------------------------------------------------------


def test_one_policy_spelled_twice_in_a_comparison_is_refused_naming_both_spellings(tmp_path, monkeypatch):
    from microg_env.experiments import comparison

    def no_run(*args, **kwargs):
        raise AssertionError("a run started")

    monkeypatch.setattr(comparison, "run_many", no_run)
    folder = _policy(tmp_path)
    monkeypatch.chdir(tmp_path)
    for other in ("./policy", str(folder), "policy/../policy"):
        with pytest.raises(ValueError, match="is given twice") as refused:
            comparison.compare(["policy", other], ["condition-1"], seeds=1)
        assert "'policy'" in str(refused.value)
        assert repr(other) in str(refused.value)


@pytest.mark.parametrize(
    ("settings", "named"),
    [
        ({"residual_gate_on": "setpoint", "residual_gate_m": None}, "there is no gate to place"),
        ({"residual_highpass_order": 2, "residual_highpass_hz": 0.0}, "there is no high-pass to cascade"),
        ({"action_mode": "speed"}, "only action_mode 'residual' or 'gains' has it"),
    ],
)
def test_a_card_is_read_through_the_tasks_own_check(settings, named, tmp_path, capsys):
    """Cards the environment would refuse were deployed with the refused setting ignored (a gate
    point without a gate, a second high-pass stage without a corner, a speed policy with a base)."""
    folder = _policy(tmp_path)
    card = json.loads((folder / CARD_FILE).read_text())
    card["env_kwargs"] = {k: v for k, v in (card["env_kwargs"] | settings).items() if v is not None}
    (folder / CARD_FILE).write_text(json.dumps(card))
    with pytest.raises(ValueError, match=named):
        check_controller_name(str(folder))


# -- one record for how a policy acts -------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(RUNS_ON))
def test_the_env_the_card_and_the_loader_read_one_acting_record(name):
    """How a policy acts is one record (``ActingSettings``): its fields are the cards' acting keys,
    the task's settings extend it, and the environment its card names, the card and the loaded
    controller hold the same one (the loader adds only the sensors the rig lacks to its hidden
    entries). No task setting is copied onto the environment or its core: they are read from
    ``settings``, one place."""
    from dataclasses import fields, replace

    from microg_env.task import ActingSettings, TaskSettings

    assert tuple(option.name for option in fields(ActingSettings)) == ACTING_KEYS
    assert issubclass(TaskSettings, ActingSettings)
    card = json.loads((shipped_policy_folder(name) / CARD_FILE).read_text())
    env = gym.make(card["env_id"], **card["env_kwargs"]).unwrapped
    assert env.settings.acting == ActingSettings.of(card["env_kwargs"])
    controller = load_policy(shipped_policy_folder(name), env.settings.control_period_s)
    hidden = deployed_hidden(card["env_kwargs"])
    assert controller.acting == replace(env.settings.acting, hidden_observations=hidden)
    for key in (*ACTING_KEYS, "control_period_s", "sensor_set"):
        assert not hasattr(env, key), key
        assert not hasattr(env.core, key), key


def test_a_bad_acting_value_is_refused_by_the_one_check_wherever_it_comes_from(tmp_path):
    """The same check, and the same words, for gym.make's keyword, a card's env_kwargs and a
    record made directly."""
    from microg_env.task import ActingSettings

    words = "residual_gate_on 'setpoint': there is no gate to place"
    with pytest.raises(ValueError, match=words):
        ActingSettings(action_mode="residual", residual_gate_on="setpoint")
    with pytest.raises(ValueError, match=words):
        gym.make("MicroGravityLanding-v1", action_mode="residual", residual_gate_on="setpoint")
    folder = _policy(tmp_path, action_mode="residual", residual_gate_m=None, residual_gate_on="setpoint")
    with pytest.raises(ValueError, match=words):
        policy_card(folder)


def test_a_policy_controller_refuses_a_base_its_action_mode_does_not_have():
    """A residual acts on a base controller and a speed command without one: the two disagreeing is
    refused when the controller is made, not found out in an episode."""
    from microg_env.controllers.policy import PolicyController
    from microg_env.task import ActingSettings

    residual = ActingSettings(action_mode="residual", base_controller="feedforward")
    with pytest.raises(ValueError, match="action_mode 'residual' acts on a base controller, got base NoneType"):
        PolicyController(object(), residual)
    with pytest.raises(ValueError, match="action_mode 'speed' acts without a base controller, got base Feedforward"):
        PolicyController(object(), ActingSettings(), make_controller("feedforward", 1e-3))
    assert PolicyController(object(), residual, make_controller("feedforward", 1e-3)).acting == residual


def test_a_policy_named_by_many_specs_is_read_once_until_its_files_change(tmp_path, monkeypatch):
    """Spec validation checks a policy folder once per contents of its card and network, and
    again (and refuses it) once a file changed, even to one of the same size."""
    from microg_env.controllers import registry

    folder, reads = _policy(tmp_path), []
    read = registry.check_policy_folder
    monkeypatch.setattr(registry, "check_policy_folder", lambda f: reads.append(f) or read(f))
    for _ in range(3):
        check_controller_name(str(folder))
    assert len(reads) == 1
    size = (folder / CARD_FILE).stat().st_size
    (folder / CARD_FILE).write_text("{}".ljust(size))  # the same size, and maybe the same mtime
    with pytest.raises(ValueError, match="not a policy card"):
        check_controller_name(str(folder))
    assert len(reads) == 2
