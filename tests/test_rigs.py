"""Rig files (microg_env.rigs): read alike however written, refused in one line naming the file
and the entry, and taken by every command and by gym.make to the same rig and the same episode."""

import json
import re
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import pytest
import yaml

from microg_env import RigParams, load_rig, read_rig
from microg_env.cli import main
from microg_env.controllers.feedforward import plant_model
from microg_env.controllers.registry import make_controller
from microg_env.experiments.campaign import Campaign
from microg_env.experiments.comparison import compare
from microg_env.experiments.comparison_report import render_markdown
from microg_env.params import with_overrides
from microg_env.rollout.episode import run_with_metrics
from microg_env.task import TaskSettings

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "small-lander-rig.toml"
ENV_ID = "microg_env:MicroGravityLanding-v1"


def _file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def test_tables_dotted_keys_and_noted_values_read_alike(tmp_path):
    tables = read_rig(_file(tmp_path, "[lander]\nmass_kg = 300.0\n[pad]\nstiffness_n_per_m = 8000\n"))
    dotted = read_rig(_file(tmp_path, "lander.mass_kg = 300\npad.stiffness_n_per_m = 8000.0\n"))
    noted = read_rig(
        _file(
            tmp_path,
            'description = "ours"\nlander.mass_kg = { value = 300.0, source = "scale" }\n'
            "[pad]\nstiffness_n_per_m = { value = 8000.0 }\n",
        )
    )
    expected = {"lander.mass_kg": 300.0, "pad.stiffness_n_per_m": 8000.0}
    for rig in (tables, dotted, noted):
        assert rig.overrides == expected
        assert all(type(value) is float for value in rig.overrides.values())  # 8000 is the float 8000.0
        assert rig.params == with_overrides(RigParams(), expected)
    assert noted.sources == {"lander.mass_kg": "scale"}
    assert noted.description == "ours"
    assert tables.sources == {}
    assert tables.description == ""
    top = read_rig(_file(tmp_path, "gravity_m_s2 = { value = 9.81, source = 'Potsdam' }\n"))
    assert top.overrides == {"gravity_m_s2": 9.81}
    assert top.sources == {"gravity_m_s2": "Potsdam"}


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("lander.mas_kg = 3.0\n", "unknown parameter 'lander.mas_kg'"),
        ("[landr]\nmass_kg = 3.0\n", "unknown part 'landr'"),
        ('lander.mass_kg = "heavy"\n', "lander.mass_kg must be a float, got 'heavy'"),
        ("lander.mass_kg = 3000.0\n", "LanderParams.mass_kg must be in [1, 620] kg, got 3000.0"),
        ("lander.mass_kg = = 3\n", "is not valid TOML"),
        ("lander.mass_kg = { value = 3.0, unit = 'kg' }\n", "lander.mass_kg must be a value or { value"),
        ("lander.mass_kg = { source = 'scale' }\n", "lander.mass_kg must be a value or { value"),
        ("lander.mass_kg = { value = 3.0, source = 1 }\n", "lander.mass_kg.source must be a string"),
        ("description = 3\n", "description must be a string"),
        ("servo.peak_torque_n_m = nan\n", "servo.peak_torque_n_m must be finite"),
        ("servo.cogging_cycles_per_rev = 7.5\n", "servo.cogging_cycles_per_rev must be a int"),
    ],
)
def test_a_bad_rig_file_is_refused_naming_the_file_and_the_entry(tmp_path, text, words):
    path = _file(tmp_path, text)
    with pytest.raises(ValueError, match="rig file") as caught:
        read_rig(path)
    message = str(caught.value)
    assert message.startswith(f"rig file '{path}'")
    assert "\n" not in message
    assert words in message


def test_a_missing_or_unreadable_rig_file_is_named(tmp_path):
    with pytest.raises(ValueError, match=r"rig file '.*nowhere.toml' does not exist"):
        read_rig(tmp_path / "nowhere.toml")
    with pytest.raises(ValueError, match="is not a regular file"):
        read_rig(tmp_path)


def test_the_worked_example_is_a_different_rig_with_a_source_for_every_value():
    rig = read_rig(EXAMPLE)
    assert rig.params.lander.mass_kg != RigParams().lander.mass_kg
    assert rig.params.qzs.residual_stiffness_n_per_m != RigParams().qzs.residual_stiffness_n_per_m
    assert rig.params.pad.stiffness_n_per_m != RigParams().pad.stiffness_n_per_m
    assert set(rig.sources) == set(rig.overrides)
    assert rig.description


def test_run_with_a_rig_file_is_gym_make_with_its_params(capsys):
    """`microg run --rig` and gym.make(params=load_rig(...)) run the same episode, the model-based
    controller assuming the rig (the paper's lander is twice as heavy)."""
    argv = ["run", "--rig", str(EXAMPLE), "--controller", "adaptive-dither", "--duration", "2", "--seed", "3"]
    assert main([*argv, "--json", "--quiet"]) == 0
    from_cli = json.loads(capsys.readouterr().out)
    params = load_rig(EXAMPLE)
    env = gym.make(ENV_ID, params=params)
    controller = make_controller("adaptive-dither", 1e-3, params)
    _, _, metrics = run_with_metrics(env, controller, seed=3, duration_s=2.0)
    assert json.loads(json.dumps(metrics.as_dict())) == from_cli
    assert env.unwrapped.params.lander.mass_kg == 300.0
    paper_model = make_controller("adaptive-dither", 1e-3)
    _, _, other = run_with_metrics(gym.make(ENV_ID, params=params), paper_model, seed=3, duration_s=2.0)
    assert other.flexible_unit_excursion_free_fall_m != metrics.flexible_unit_excursion_free_fall_m


def test_a_policy_s_base_controller_assumes_the_rig_it_runs_on():
    """The policy loader built its base controller on the paper's rig whatever the rig (issue 46)."""
    params = load_rig(EXAMPLE)
    policy = make_controller("residual-sac-setpoint", 1e-3, params)
    np.testing.assert_array_equal(policy.base.nominal, plant_model(params))
    env = gym.make(ENV_ID, params=params, action_mode="residual", base_controller="adaptive-dither")
    np.testing.assert_array_equal(env.unwrapped.core.base.nominal, plant_model(params))


def test_the_task_takes_a_rig_as_overrides_by_dotted_path():
    overrides = read_rig(EXAMPLE).overrides
    assert TaskSettings(params=overrides).params == load_rig(EXAMPLE)
    with pytest.raises(ValueError, match=r"params: unknown parameter 'lander\.mass'"):
        TaskSettings(params={"lander.mass": 100.0})


def test_export_mjcf_writes_the_rig_of_the_file(tmp_path, capsys):
    out = tmp_path / "rig.xml"
    assert main(["export-mjcf", str(out), "--rig", str(EXAMPLE)]) == 0
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.body("lander").mass[0] == pytest.approx(300.0)


def test_compare_runs_on_the_rig_and_says_so():
    overrides = read_rig(EXAMPLE).overrides
    result = compare(["pid"], ["condition-1"], seeds=1, duration_s=0.3, overrides=overrides)
    assert result.overrides == overrides
    assert result.as_dict()["overrides"] == overrides
    assert "The rig is the paper's with `lander.mass_kg` = 300.0" in render_markdown(result)
    paper = compare(["pid"], ["condition-1"], seeds=1, duration_s=0.3)
    assert paper.results[0].metrics != result.results[0].metrics
    assert "The rig is" not in render_markdown(paper)


def test_a_campaign_s_rig_is_under_its_own_parameters(tmp_path):
    (tmp_path / "rigs").mkdir()
    (tmp_path / "rigs" / "ours.toml").write_text(EXAMPLE.read_text())
    data = {
        "name": "ours",
        "rig": "rigs/ours.toml",  # relative to the campaign file
        "base": {"duration_s": 0.3, "overrides": {"pad.damping_n_s_per_m": 80.0}},
        "sweep": {"lander.mass_kg": [100.0, 200.0]},
    }
    (tmp_path / "campaign.yml").write_text(yaml.safe_dump(data))
    specs = [run.spec for run in Campaign.load(tmp_path / "campaign.yml").runs()]
    assert [s.overrides["lander.mass_kg"] for s in specs] == [100.0, 200.0]  # the sweep's
    for spec in specs:
        assert spec.overrides["pad.damping_n_s_per_m"] == 80.0  # base's
        assert spec.overrides["qzs.residual_stiffness_n_per_m"] == 8000.0  # the rig's
    (tmp_path / "campaign.yml").write_text(yaml.safe_dump(data | {"rig": "nowhere.toml"}))
    with pytest.raises(ValueError, match=r"campaign file .*: rig: rig file .*nowhere.toml' does not exist"):
        Campaign.load(tmp_path / "campaign.yml")


def test_train_takes_the_rig_into_the_run_s_env_kwargs():
    pytest.importorskip("stable_baselines3")
    from microg_env.learning.settings import TrainSettings
    from microg_env.learning.train import resolve

    entry = resolve(TrainSettings(algo="sac", env_id="MicroGravityLanding-Residual-v6", rig=str(EXAMPLE)))
    assert entry.env_kwargs["params"] == read_rig(EXAMPLE).overrides
    assert TaskSettings(**entry.env_kwargs).params == load_rig(EXAMPLE)


def test_a_rig_written_reads_back_as_it_was(tmp_path):
    """What ``microg identify`` writes: every value, source and the description, any part."""
    from microg_env.rigs import RigFile, write_rig

    rig = RigFile(
        {"gravity_m_s2": 9.81, "balancer.placement": "support_lander", "screw.transmission_stiffness_n_per_m": 1e8}
        | read_rig(EXAMPLE).overrides,
        {"gravity_m_s2": 'a "quoted" note, \U0001f680 and a\ttab'} | read_rig(EXAMPLE).sources,
        "a description",
    )
    write_rig(rig, tmp_path / "rig.toml")
    back = read_rig(tmp_path / "rig.toml")
    assert back.overrides == rig.overrides
    assert back.sources == rig.sources
    assert back.description == rig.description


def test_pad_options_replace_only_what_they_name_of_the_rig_s_pad(capsys):
    """--stiffness over a rig file kept the paper's damping, not the file's (a cold review's find)."""
    from argparse import Namespace

    from microg_env.cli.common import rig_overrides

    rig = read_rig(EXAMPLE).overrides
    args = Namespace(rig=str(EXAMPLE), pad="paper", stiffness=2500.0, damping=None)
    assert rig_overrides(args) == rig | {"pad.stiffness_n_per_m": 2500.0}
    named = rig_overrides(Namespace(rig=str(EXAMPLE), pad="calibrated", stiffness=None, damping=None))
    assert named["pad.damping_n_s_per_m"] != rig["pad.damping_n_s_per_m"]  # --pad names the whole pad
    assert rig_overrides(Namespace(rig=str(EXAMPLE), pad="paper", stiffness=None, damping=None)) == rig


def test_every_rig_file_in_the_docs_reads():
    text = (REPO / "docs" / "model.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, re.S)
    assert blocks
    for block in blocks:
        assert read_rig_text(block).overrides


def read_rig_text(text: str):
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "rig.toml"
        path.write_text(text)
        return read_rig(path)
