"""Training runs' records: every hyperparameter an entry holds is checked before a run folder is
written (the model built and its policy exported), refusals name the file and the key; a resume
keeps the records of one timeline; a resume of another algorithm's checkpoint is named."""

import inspect
import json
import math
import re
import shutil
from pathlib import Path

import pytest
import yaml

import microg_env  # noqa: F401  (registers the environments)
from microg_env.cli import main
from microg_env.learning import export
from microg_env.learning import hyperparams as hp
from microg_env.learning import train as training
from microg_env.learning.train import TrainSettings, algorithm, resolve, resumed_run, train

pytest.importorskip("stable_baselines3")
pytest.importorskip("sb3_contrib")
ENV_ID = "MicroGravityLanding-Residual-v7"
#: A change that leaves a key out of the entry.
ABSENT = object()


def _conf(tmp_path: Path, algo: str, **changes) -> Path:
    """The packaged entry of ``algo`` with a test's budget and ``changes``, as a ``-conf`` file."""
    entry = yaml.safe_load(hp.packaged_file(algo).read_text())[ENV_ID]
    entry |= {"n_envs": 1, "n_timesteps": 64, "policy_kwargs": "dict(net_arch=[8])"}
    entry |= {"n_steps": 64, "batch_size": 32, "n_epochs": 1} if algo == "ppo" else {}
    entry |= {"learning_starts": 16, "buffer_size": 1000, "batch_size": 16} if algo != "ppo" else {}
    entry = {key: value for key, value in (entry | changes).items() if value is not ABSENT}
    path = tmp_path / f"{algo}.yml"
    path.write_text(yaml.safe_dump({ENV_ID: entry}))
    return path


def _settings(tmp_path: Path, algo: str, conf: Path, **kwargs) -> TrainSettings:
    defaults = {"env_id": ENV_ID, "eval_freq": 64, "eval_episodes": 1, "checkpoint_freq": 64, "command": "pytest"}
    return TrainSettings(algo=algo, hyperparams=str(conf), log_folder=str(tmp_path / "logs"), **(defaults | kwargs))


def _refused_before_a_run(tmp_path: Path, algo: str, key: str, message: str = "", **changes) -> None:
    """``train`` refuses the entry on one line naming its file and ``key`` first (and saying
    ``message``), and writes nothing."""
    conf = _conf(tmp_path, algo, **changes)
    with pytest.raises(ValueError, match="^" + re.escape(f"{conf.name}[{ENV_ID}].{key}") + "[ :]") as refusal:
        train(_settings(tmp_path, algo, conf))
    text = str(refusal.value)
    assert message in text, text
    assert "\n" not in text
    assert not (tmp_path / "logs").exists()


# -- hyperparameters refused before anything is written ------------------------------------------

#: The float arguments each algorithm takes, and whether a negative value is one of theirs.
FLOAT_KEYS = {
    "ppo": ("learning_rate", "gamma", "gae_lambda", "clip_range", "clip_range_vf", "ent_coef", "vf_coef"),
    "sac": ("learning_rate", "tau", "gamma", "ent_coef", "target_entropy"),
    "tqc": ("learning_rate", "tau", "gamma", "ent_coef", "target_entropy"),
    "crossq": ("learning_rate", "gamma", "ent_coef", "target_entropy"),
}
FLOAT_KEYS["ppo"] += ("max_grad_norm", "target_kl")
#: policy_kwargs' floats, by the algorithms whose policies take them.
POLICY_FLOAT_KEYS = {
    "ppo": ("log_std_init",),
    "sac": ("log_std_init", "clip_mean"),
    "tqc": ("log_std_init", "clip_mean"),
    "crossq": ("log_std_init", "clip_mean", "batch_norm_momentum", "batch_norm_eps"),
}
#: Floats whose negative values are meant (an entropy target below 0 is the default, -dim(A)).
SIGNED_KEYS = ("target_entropy", "log_std_init", "clip_mean")


def _bad_numbers():
    for algo, keys in FLOAT_KEYS.items():
        for key in keys:
            for value in (math.nan, math.inf, -1.0):
                if not (value < 0 and key in SIGNED_KEYS):
                    yield pytest.param(algo, key, {key: value}, id=f"{algo}-{key}={value}")
    for algo, keys in POLICY_FLOAT_KEYS.items():
        for key in keys:
            for value in (math.nan, math.inf, -1.0):
                if not (value < 0 and key in SIGNED_KEYS):
                    changes = {"policy_kwargs": {"net_arch": [8], key: value}}
                    yield pytest.param(algo, f"policy_kwargs.{key}", changes, id=f"{algo}-policy_kwargs.{key}={value}")
    for key, values in {
        "clip_obs": (0.0, -1.0, math.nan, 1e-30, 0.5),
        "clip_reward": (0.0, math.inf),
        "epsilon": (0.0, -1e-8),
    }.items():
        for value in values:
            changes = {"normalize": {"norm_obs": True, key: value}}
            yield pytest.param("ppo", f"normalize.{key}", changes, id=f"normalize.{key}={value}")


@pytest.mark.parametrize(("algo", "key", "changes"), list(_bad_numbers()))
def test_a_non_finite_or_out_of_range_number_is_refused_by_file_and_key_before_a_run(tmp_path, algo, key, changes):
    """NaN and infinities anywhere, and values out of range where the algorithm checks none: each
    used to pass the check and fail mid-run (ent_coef NaN, target_entropy inf) or train on silently
    (clip_obs 0: every observation 0), with the run folder written."""
    top = key.split(".")[0]
    accepted = inspect.signature(algorithm(algo)).parameters
    assert top in accepted or top == "normalize", f"{key} is not an argument of {algo}"
    _refused_before_a_run(tmp_path, algo, key, **changes)


@pytest.mark.parametrize(
    ("algo", "key", "value"),
    [
        ("sac", "learning_starts", -1),
        ("sac", "gradient_steps", 0),  # never updates the policy
        ("sac", "target_update_interval", 0),  # divided by zero at the first update
        ("tqc", "stats_window_size", 0),
        ("crossq", "train_freq", 0),  # collects nothing
        ("sac", "train_freq", [1, "week"]),
        ("ppo", "sde_sample_freq", -2),
        ("ppo", "ent_coef", "auto"),  # PPO's is a number: a TypeError at the first update
        ("sac", "ent_coef", "auto_inf"),
        ("sac", "ent_coef", "auto_0"),
        ("tqc", "ent_coef", "automatic"),
        ("sac", "target_entropy", "high"),
    ],
)
def test_integers_and_texts_out_of_their_range_are_refused_by_file_and_key_before_a_run(tmp_path, algo, key, value):
    _refused_before_a_run(tmp_path, algo, key, **{key: value})


@pytest.mark.parametrize(
    ("algo", "key", "changes"),
    [
        ("tqc", "policy_kwargs.n_quantiles", {"policy_kwargs": {"n_quantiles": 0}, "top_quantiles_to_drop_per_net": 0}),
        # TQC drops 2 of each critic's quantiles by default: none was kept (checked only where the file set the 2)
        (
            "tqc",
            "policy_kwargs.n_quantiles",
            {"policy_kwargs": {"n_quantiles": 2}, "top_quantiles_to_drop_per_net": ABSENT},
        ),
        ("sac", "policy_kwargs.n_critics", {"policy_kwargs": {"n_critics": 0}}),
        ("sac", "policy_kwargs.net_arch[1]", {"policy_kwargs": {"net_arch": [8, 1e400]}}),
        ("ppo", "env_kwargs.residual_limit_m", {"env_kwargs": {"residual_limit_m": math.nan}}),
    ],
)
def test_numbers_inside_policy_kwargs_and_env_kwargs_are_named_by_their_path(tmp_path, algo, key, changes):
    _refused_before_a_run(tmp_path, algo, key, **changes)


@pytest.mark.parametrize(
    ("algo", "changes", "key", "message"),
    [
        ("ppo", {"n_steps": 1}, "n_steps", "PPO refuses it"),  # a rollout of one step
        ("ppo", {"n_steps": 1, "batch_size": 1}, "batch_size", "PPO refuses it"),  # two faults: the first named
        ("ppo", {"normalize": {"norm_obs": True, "clip": 3}}, "normalize.clip", "PPO refuses it"),
        ("sac", {"policy_kwargs": {"net_arch": [8], "width": 3}}, "policy_kwargs.width", "SAC refuses it"),
    ],
)
def test_what_the_algorithm_refuses_when_built_is_named_by_the_key_that_makes_it_pass(
    tmp_path, algo, changes, key, message
):
    """The model is built on the run's environments; the refusal used to name the entry, not the key."""
    _refused_before_a_run(tmp_path, algo, key, message, **changes)


def test_what_the_exporter_refuses_is_refused_before_a_run_named_by_its_key(tmp_path, monkeypatch):
    """The untrained actor is exported as the run's best will be: an exporter that cannot deploy an
    option (here one refusing ELU) refuses it before the run, not at the first new best."""
    exporter = export.export_policy

    def refusing_elu(model, normalization):
        if any(type(module).__name__ == "ELU" for module in model.policy.modules()):
            raise ValueError("this exporter computes no ELU")
        return exporter(model, normalization)

    monkeypatch.setattr(export, "export_policy", refusing_elu)
    changes = {"policy_kwargs": "dict(net_arch=[8], activation_fn=nn.ELU)"}
    message = "its policy cannot be exported: this exporter computes no ELU"
    _refused_before_a_run(tmp_path, "sac", "policy_kwargs.activation_fn", message, **changes)


def _deployable_cases():
    for algo, names in (("ppo", hp.ACTIVATION_NAMES), ("sac", ("Tanh", "ELU"))):  # PPO's actor and SAC's
        for name in names:
            changes = {"policy_kwargs": f"dict(net_arch=[8], activation_fn=nn.{name})"}
            yield pytest.param(algo, changes, "policy_kwargs.activation_fn", id=f"{algo}-{name}")
    for algo in ("sac", "tqc", "crossq"):  # a gSDE head: clip_mean's clip before the tanh
        yield pytest.param(algo, {"use_sde": True}, "use_sde", id=f"{algo}-use_sde")


@pytest.mark.parametrize(("algo", "changes", "key"), list(_deployable_cases()))
def test_an_option_is_refused_before_a_run_exactly_when_its_policy_cannot_be_exported(tmp_path, algo, changes, key):
    """ELU, and SAC's gSDE head, passed the check and failed at the first new best, with the run
    folder written and no checkpoint to resume."""
    from microg_env.learning.vec_env import BatchedVecEnv

    conf = _conf(tmp_path, algo, **changes)
    params = hp.load(algo, ENV_ID, conf)
    venv = BatchedVecEnv.make(1, **params.env_kwargs)
    try:
        model = algorithm(algo)(params.policy, venv, device="cpu", **hp.algo_arguments(params))
        export.export_policy(model, None)
        exportable = True
    except ValueError:
        exportable = False
    finally:
        venv.close()
    if exportable:
        assert resolve(_settings(tmp_path, algo, conf)).algo_kwargs == params.algo_kwargs
    else:
        _refused_before_a_run(tmp_path, algo, key, "its policy cannot be exported", **changes)


def test_the_cli_names_the_file_and_key_of_a_non_finite_hyperparameter_and_writes_nothing(tmp_path, capsys):
    conf = _conf(tmp_path, "sac", ent_coef=math.nan)
    logs = tmp_path / "logs"
    assert (
        main(["train", "--algo", "sac", "--env", ENV_ID, "-conf", str(conf), "--log-folder", str(logs), "--quiet"]) == 2
    )
    err = capsys.readouterr().err
    assert err == f"microg: error: --hyperparams: sac.yml[{ENV_ID}].ent_coef must be a finite number, got nan\n"
    assert not logs.exists()


# -- a resume keeps the records of one timeline --------------------------------------------------


class _Killed(Exception):
    """A kill: nothing of the run's own handling runs (only context managers unwind)."""


class _Costs:
    """Evaluation costs chosen by the step evaluated (the validation episodes replaced), so a test
    decides which evaluations are a new best; the base controller's (before any step) costs 1."""

    def __init__(self) -> None:
        self.steps, self.table, self.kill_after = 0, {}, math.inf

    def progress(self, done: int, total: int) -> None:
        self.steps = done
        if done > self.kill_after:
            raise _Killed

    def validate(self, run, controller):
        return [], 0.0, self.table.get(self.steps, 1.0) if self.steps else 1.0


@pytest.fixture
def costs(monkeypatch):
    costs = _Costs()
    monkeypatch.setattr(training._Run, "validate", lambda run, controller: costs.validate(run, controller))
    return costs


def _run_settings(tmp_path: Path, timesteps: int) -> TrainSettings:
    conf = _conf(tmp_path, "ppo", n_envs=2, n_steps=32, batch_size=64)
    return _settings(tmp_path, "ppo", conf, checkpoint_freq=128, timesteps=timesteps)


def test_a_model_evaluated_before_its_first_update_is_never_the_best(tmp_path, costs):
    """SAC evaluated at 64 steps, before learning_starts (100): its untrained policy, here the lowest
    cost, is recorded but not kept; the best is the first evaluation after an update (it was the
    untrained model, as rl_zoo3's best_model.zip can be)."""
    conf = _conf(tmp_path, "sac", learning_starts=100)
    costs.table = {64: 0.1, 128: 0.5, 192: 0.4}
    folder = train(_settings(tmp_path, "sac", conf, timesteps=192), progress=costs.progress)
    assert _rows(folder) == [(64, False, 0.1), (128, True, 0.5), (192, True, 0.4)]
    assert _card(folder)["timesteps"] == 192
    assert "eval at 64 steps: cost 0.1" in (folder / "train.log").read_text()
    assert "(before its first update: never the best)" in (folder / "train.log").read_text()


def test_ppo_is_evaluated_after_the_update_that_ends_its_rollout(tmp_path, costs):
    """One rollout of 2 x 32 steps, evaluations due at 32 and 64 steps: PPO's policy changes only
    after the rollout, so one evaluation runs, at the run's end, of the updated model, the run's
    best (with the rule against untrained bests alone, both ran inside the rollout, before the
    update, and the run ended without a policy)."""
    conf = _conf(tmp_path, "ppo", n_envs=2, n_steps=32, batch_size=64)
    costs.table = {32: 0.5, 64: 0.4}
    folder = train(_settings(tmp_path, "ppo", conf, eval_freq=32, timesteps=64), progress=costs.progress)
    assert _rows(folder) == [(64, True, 0.4)]
    assert _card(folder)["timesteps"] == 64
    assert "best evaluation cost 0.4" in (folder / "train.log").read_text().splitlines()[-1]


def test_a_run_that_ends_before_its_first_update_says_so(tmp_path, costs):
    """SAC stopped at 64 steps, before learning_starts: no best model, and the log says why."""
    conf = _conf(tmp_path, "sac", learning_starts=100)
    folder = train(_settings(tmp_path, "sac", conf, timesteps=64), progress=costs.progress)
    assert not (folder / "policy").exists()
    last = (folder / "train.log").read_text().splitlines()[-1]
    assert "best evaluation cost none (the run ended before its first update)" in last


@pytest.fixture(scope="module")
def killed_run(tmp_path_factory):
    """A PPO run evaluated every 64 steps, checkpointed every 128, killed after its evaluation at
    192 (a new best, its model saved) and before its next checkpoint: latest.json says 128."""
    tmp_path = tmp_path_factory.mktemp("killed")
    costs = _Costs()
    costs.table, costs.kill_after = {64: 0.5, 128: 0.4, 192: 0.1}, 192
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(training._Run, "validate", lambda run, controller: costs.validate(run, controller))
        with pytest.raises(_Killed):
            train(_run_settings(tmp_path, 256), progress=costs.progress)
    folder = tmp_path / "logs" / "ppo" / f"{ENV_ID}_1"
    assert json.loads((folder / "checkpoints" / "latest.json").read_text())["timesteps"] == 128
    assert _rows(folder) == [(64, True, 0.5), (128, True, 0.4), (192, True, 0.1)]
    assert _card(folder)["timesteps"] == 192  # the discarded session's best is the one on disk
    return tmp_path, folder


def _rows(folder: Path) -> list[tuple[int, bool, float]]:
    return [
        (row["timesteps"], row["best"], row["cost"]) for row in json.loads((folder / "evaluations.json").read_text())
    ]


def _card(folder: Path) -> dict:
    return json.loads((folder / "policy" / "policy.json").read_text())


def _resume(killed_run, tmp_path: Path, costs: _Costs, table: dict, legacy: bool = False) -> Path:
    """The killed run copied to ``tmp_path`` and resumed to 256 steps with evaluation costs ``table``;
    ``legacy``: without the best models kept in checkpoints/ (a run of 0.16)."""
    source_tmp, source = killed_run
    folder = tmp_path / "logs" / "ppo" / source.name
    shutil.copytree(source, folder)
    shutil.copy(source_tmp / "ppo.yml", tmp_path / "ppo.yml")
    if legacy:
        for copy in (folder / "checkpoints").glob("best_policy_*"):
            shutil.rmtree(copy)
    costs.table = table
    train(_run_settings(tmp_path, 256), resume_folder=folder, progress=costs.progress)
    return folder


@pytest.mark.slow
def test_a_resume_drops_the_killed_sessions_evaluations_and_puts_back_the_best_model(killed_run, tmp_path, costs):
    """The resumed session evaluates 192 again and never beats 128's cost: the killed session's 192
    (cost 0.1) used to stay in evaluations.json beside the new 192, and its model stayed the best."""
    folder = _resume(killed_run, tmp_path, costs, {192: 0.45, 256: 0.42})
    assert _rows(folder) == [(64, True, 0.5), (128, True, 0.4), (192, False, 0.45), (256, False, 0.42)]
    card = _card(folder)
    assert (card["timesteps"], card["validation"]["cost"]) == (128, 0.4)
    assert (folder / "best_model.zip").read_bytes() == (folder / "policy" / "model.zip").read_bytes()
    assert json.loads((folder / "checkpoints" / "latest.json").read_text())["best_cost"] == 0.4
    assert sorted(p.name for p in (folder / "checkpoints").glob("*best_policy_*")) == ["best_policy_128_steps"]
    assert "back to the checkpoint at 128 steps: 1 evaluation(s) after it dropped" in (folder / "train.log").read_text()


@pytest.mark.slow
def test_a_resume_leaves_one_evaluation_per_step_and_one_best_timeline(killed_run, tmp_path, costs):
    """The resumed session's 192 beats everything: two rows of step 192, both best, used to follow."""
    folder = _resume(killed_run, tmp_path, costs, {192: 0.05, 256: 0.3})
    assert _rows(folder) == [(64, True, 0.5), (128, True, 0.4), (192, True, 0.05), (256, False, 0.3)]
    card = _card(folder)
    assert (card["timesteps"], card["validation"]["cost"]) == (192, 0.05)
    assert card["resume_commands"] == ["pytest"]  # the resumed session's model, not the killed one's


@pytest.mark.slow
def test_a_run_that_kept_no_copy_of_its_best_says_no_kept_evaluation_is_on_disk(killed_run, tmp_path, costs):
    """A run of 0.16 kept no copy of its best models: the killed session's best is removed, and
    the evaluations kept no longer claim a best model on disk; the next evaluation is the best."""
    folder = _resume(killed_run, tmp_path, costs, {192: 0.45, 256: 0.42}, legacy=True)
    assert _rows(folder) == [(64, False, 0.5), (128, False, 0.4), (192, True, 0.45), (256, True, 0.42)]
    assert _card(folder)["timesteps"] == 256
    assert "the best model of step 192 removed" in (folder / "train.log").read_text()


# -- a resume of another algorithm's checkpoint -----------------------------------------------------


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_an_args_yml_naming_another_algorithm_than_its_checkpoints_is_named(killed_run, tmp_path, capsys):
    """args.yml saying sac over a PPO checkpoint used to raise an AttributeError loading the model."""
    folder = tmp_path / "run"
    shutil.copytree(killed_run[1], folder)
    args = folder / "args.yml"
    args.write_text(args.read_text().replace("algo: ppo", "algo: sac"))
    before = _tree(folder)
    message = f"--resume: {str(args)!r} names algo sac, but its checkpoint .*rl_model_128_steps.zip' holds a PPO model"
    with pytest.raises(ValueError, match=message):
        resumed_run(folder, TrainSettings(timesteps=512))
    assert main(["train", "--resume", str(folder), "--timesteps", "512", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(f"microg: error: {message}\n", err), err
    assert _tree(folder) == before


@pytest.mark.slow
def test_an_option_a_resume_cannot_change_is_named_with_both_values(killed_run, tmp_path, capsys):
    folder = tmp_path / "run"
    shutil.copytree(killed_run[1], folder)
    assert main(["train", "--resume", str(folder), "--algo", "sac", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"--algo cannot change ('sac' asked, 'ppo' in {str(folder / 'args.yml')!r})" in err


@pytest.mark.parametrize(
    ("key", "text"),
    [
        ("normalize", "{'norm_obs': True, 'clip_obs': 5.0, 'norm_obs': False}"),
        ("policy_kwargs", "{'net_arch': [8], 'net_arch': [64, 64]}"),
    ],
)
def test_a_key_given_twice_in_a_dict_string_is_refused_before_a_run(tmp_path, key, text):
    """The YAML loader refuses a repeated key, but a dict written as a string kept its last value."""
    _refused_before_a_run(tmp_path, "ppo", key, "is given twice", **{key: text})
