"""The research probes behind docs/research-log.md: the partial oracles, the fine-tuning probe, the
gain and reward breakdowns, the drive's timing and scheme, the fifty-gram fit and plain SB3. Run with
``pytest research`` (the default suite collects ``tests/`` only)."""

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
        ("partial_oracles", ["--seeds", "1000", "--duration", "0.3"], "cogging and speed loop"),
        (
            "friction_structure",
            ["--scenarios", "heavy-second", "--seeds", "1000", "--coulomb", "0.2", "--duration", "0.3"],
            "the Coulomb level alone",
        ),
        ("fifty_gram_joint_fit", [], "| joint, relative | -7.08 |"),
        ("plain_sb3", ["--seeds", "0", "--steps", "64", "--episodes", "1", "--zero"], "| zero action | | "),
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
    ],
)
@pytest.mark.slow
def test_probe_runs(name, args, expected, monkeypatch, capsys):
    module = importlib.import_module(name)
    assert module.main(args) == 0
    assert expected in capsys.readouterr().out


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
        ([str(path), "--reference", "ref"], "no controller 'residual-sac-setpoint' in it"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            gain.main(bad)
        assert exit_.value.code == 2
        assert message in capsys.readouterr().err


def test_reward_by_phase_splits_the_gated_policys_return_where_its_gate_opens(monkeypatch, capsys):
    """The gated policy acts from the first contact on, so its return before it is the zero
    residual's exactly, on both rigs, while it moves the first contact's peak; the table has a row
    per rig; a count of no episodes is refused."""
    import gymnasium as gym
    import numpy as np

    phases = importlib.import_module("reward_by_phase")
    env_id = "MicroGravityLanding-Residual-v6"
    act = phases.policy_actor(env_id, "residual-sac-setpoint")
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
        (["--policy", "gains-ppo"], "policy 'gains-ppo' was trained with 'ppo', not sac"),
        (["--set", "sensor_set=ruler"], "sensor_set"),
        (["--episodes", "501"], "--episodes 1 to 500"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            probe.main(args)
        assert exit_.value.code == 2
        assert message in capsys.readouterr().err
