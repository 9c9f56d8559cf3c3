"""The tools in training/ a user runs: the adaptive baseline's tuner, the returns table and the seed
selection. (The research probes and their tests are in research/.)"""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np
import pytest

TRAINING = Path(__file__).resolve().parents[1] / "training"


@pytest.mark.parametrize(
    ("name", "args", "expected"),
    [
        ("tune_adaptive", ["--steps", "0.003", "--seeds", "1", "--duration", "0.3"], "step 0.003: J = "),
        ("tune_adaptive", ["--dither", "60", "--seeds", "1", "--duration", "0.3"], "dither 60 nm, 10 ms: J = "),
        ("returns_table", ["--seeds", "1", "--scenarios", "training"], "| zero residual (adaptive-dither) | "),
    ],
)
@pytest.mark.slow
def test_training_script_runs(name, args, expected, monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(TRAINING))
    module = importlib.import_module(name)
    assert module.main(args) == 0
    assert expected in capsys.readouterr().out


@pytest.mark.slow
def test_select_seed_scores_runs_by_the_mean_excursion_on_validation_episodes(monkeypatch, tmp_path, capsys):
    """The seed selection of docs/research-log.md (there on 200 episodes), on the shipped residual policy and 4:
    the selection cost (mean excursion), the paired ratio to the zero residual, the worst excursion
    beside it; runs of two tasks, and counts of episodes that would reach no seed or a test seed, are refused."""
    import shutil

    from microg_env.controllers.registry import shipped_policy_folder

    monkeypatch.syspath_prepend(str(TRAINING))
    select_seed = importlib.import_module("select_seed")
    runs = [tmp_path / "v6", tmp_path / "gains"]
    for run, name in zip(runs, ("residual-sac-setpoint", "gains-ppo"), strict=True):
        shutil.copytree(shipped_policy_folder(name), run / "policy")
    assert select_seed.main(["--episodes", "4", str(runs[0])]) == 0
    out = capsys.readouterr().out
    assert out.startswith("4 validation episodes, seeds 500-503, sensor set extended\n")
    assert "| zero residual (adaptive-dither) |  | 0.0919 | 0.0045 | 0.874 | 1.000x | 1.390 | 0.603 |" in out
    assert f"| {runs[0]} | 5 | 0.0724 | 0.0045 | 0.679 | 0.777x | 1.021 | 0.603 |" in out
    assert out.strip().endswith(f"lowest selection cost: {runs[0]}")
    lines = {}
    for rig in ("extended", "paper"):  # --sensor-set: the same episodes on another rig
        assert select_seed.main(["--episodes", "2", "--sensor-set", rig, str(runs[0])]) == 0
        out = capsys.readouterr().out
        assert out.startswith(f"2 validation episodes, seeds 500-501, sensor set {rig}\n")
        lines[rig] = [line for line in out.splitlines() if line.startswith("| zero residual")]
    assert lines["extended"] != lines["paper"]  # the base flies differently without the pad force
    with pytest.raises(SystemExit, match="trained on another task"):
        select_seed.main([str(run) for run in runs])
    with pytest.raises(SystemExit):
        select_seed.main(["--episodes", "0", str(runs[0])])
    assert "--episodes must be 1 to 500 (no test seed), got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        select_seed.main(["--episodes", "501", str(runs[0])])  # seed 1000 is the comparison's
    assert "got 501" in capsys.readouterr().err


def test_returns_table_runs_a_policy_on_its_own_task_only(monkeypatch, capsys):
    """The setpoint-gated residual (trained on v6) acts alike on v7, whose reward alone differs; the
    gain schedule is refused there before any row runs."""
    monkeypatch.syspath_prepend(str(TRAINING))
    returns_table = importlib.import_module("returns_table")
    assert returns_table.ENV_IDS == (
        "MicroGravityLanding-Residual-v7",
        "MicroGravityLanding-Residual-v6",
        "MicroGravityLanding-GainScheduling-v1",
        "MicroGravityLanding-Command-v1",
    )
    for env_id in returns_table.ENV_IDS[:2]:
        returns_table.policy_actor(env_id, "residual-sac-setpoint")
    with pytest.raises(ValueError, match="policy 'gains-ppo' was trained with action_mode 'gains'"):
        returns_table.policy_actor("MicroGravityLanding-Residual-v7", "gains-ppo")
    with pytest.raises(SystemExit) as exit_:
        returns_table.main(["--env", "MicroGravityLanding-Residual-v7", "--policies", "gains-ppo"])
    assert exit_.value.code == 2
    captured = capsys.readouterr()
    assert "--policies: policy 'gains-ppo' was trained with action_mode 'gains'" in captured.err
    assert captured.out == ""


def test_returns_table_reads_a_cards_left_out_acting_key_as_its_default(tmp_path, monkeypatch):
    """A card that writes a default its id leaves out (the command's decision period of one) is
    that id's; a card whose decision period is another is refused."""
    import json
    import shutil

    from microg_env.controllers.registry import shipped_policy_folder
    from microg_env.interface import CARD_FILE

    monkeypatch.syspath_prepend(str(TRAINING))
    returns_table = importlib.import_module("returns_table")
    folder, env_id = tmp_path / "explicit", "MicroGravityLanding-Command-v1"
    shutil.copytree(shipped_policy_folder("command-ppo"), folder)
    card = json.loads((folder / CARD_FILE).read_text())
    assert "decision_period" not in card["env_kwargs"]
    card["env_kwargs"]["decision_period"] = 1
    (folder / CARD_FILE).write_text(json.dumps(card))
    returns_table.policy_actor(env_id, str(folder))
    card["env_kwargs"]["decision_period"] = 5
    (folder / CARD_FILE).write_text(json.dumps(card))
    with pytest.raises(ValueError, match=f"trained with decision_period 5, not {env_id}'s 1"):
        returns_table.policy_actor(env_id, str(folder))


@pytest.mark.slow
def test_the_aligned_residual_task_ranks_the_ladder_as_its_metric_does(monkeypatch):
    """training/reward_ladder.py on 4 of v7's draws: its return ranks the nine rungs as x at the
    collision does (Spearman >= 0.9), where v6's x0 of 10 nm does not, on the same rollouts. The
    return it scores offline from x at every period is the one the environment pays (the zero
    residual on the first seed, the shipped policy on the first seed whose last step is short)."""
    import gymnasium as gym

    from microg_env.task import TaskSettings

    monkeypatch.syspath_prepend(str(TRAINING))
    ladder = importlib.import_module("reward_ladder")
    returns_table = importlib.import_module("returns_table")
    ids, policy = ("MicroGravityLanding-Residual-v6", "MicroGravityLanding-Residual-v7"), "residual-sac-setpoint"
    scales = [gym.spec(env_id).kwargs.get("reward_scale_m", TaskSettings().reward_scale_m) for env_id in ids]
    assert scales == [1e-8, 1e-6]
    rungs = ladder.run_ladder(ids[1], policy, range(1000, 1004))
    assert len(rungs) == 9
    result = ladder.report(ids[1], policy, rungs, scales)["by_scale"]
    assert result["1e-08"]["spearman"] < 0.9
    assert result["1e-06"]["spearman"] >= ladder.MIN_SPEARMAN
    env = gym.make(ids[1])
    by_name = {rung.name: rung for rung in rungs}
    # the first seed whose last step runs fewer than 5 periods (the environment pays their mean)
    short = next(i for i, x in enumerate(by_name[f"{policy} x1"].x_m) if x.size % 5)
    for name, act, i in (
        ("adaptive-dither (zero residual)", lambda obs: np.zeros(1, dtype=np.float32), 0),
        (f"{policy} x1", returns_table.policy_actor(ids[1], policy), short),
    ):
        offline = by_name[name].returns(1e-6, env.unwrapped.core.x_limit_m, 5, contact_only=False)
        assert offline[i] == pytest.approx(returns_table.episode_return(env, act, 1000 + i), rel=1e-9), (name, i)
    assert ladder.spearman([1, 2, 3, 4], [10, 20, 30, 25]) == pytest.approx(0.8)


@pytest.mark.slow
def test_the_gain_scheduling_task_ranks_the_ladder_as_its_metric_does(monkeypatch):
    """training/reward_ladder.py on 4 of the gain-scheduling id's draws: its return ranks the fifteen
    rungs (the PIDs, three classical controllers, five constant schedules, the shipped `gains-ppo`
    x0.5, x1, x1.5 and x-1, random) as x at the collision does (Spearman >= 0.9), and pays the
    policy more than its base on every draw; a constant schedule's return scored offline is the one
    the gains environment pays for that action held."""
    import gymnasium as gym

    monkeypatch.syspath_prepend(str(TRAINING))
    ladder = importlib.import_module("reward_ladder")
    returns_table = importlib.import_module("returns_table")
    env_id = "MicroGravityLanding-GainScheduling-v1"
    rungs = ladder.run_ladder(env_id, "gains-ppo", range(1000, 1004))
    assert [rung.name for rung in rungs][-1] == "random"
    assert len(rungs) == 15
    result = ladder.report(env_id, "gains-ppo", rungs, [1e-6])["by_scale"]["1e-06"]
    assert result["spearman"] >= ladder.MIN_SPEARMAN
    assert result["policy_minus_base"] > 0.0
    assert result["policy_minus_base_sign_p"] == 0.125  # above the base on all 4 draws
    env = gym.make(env_id)
    by_name = {rung.name: rung for rung in rungs}
    for name in ("pid-dom (zero action)", "Ki x1/2"):
        action = np.array(ladder.SCHEDULES.get(name, (0.0, 0.0, 0.0)), dtype=np.float32)
        offline = by_name[name].returns(1e-6, env.unwrapped.core.x_limit_m, 5, contact_only=False)
        paid = returns_table.episode_return(env, lambda obs, action=action: action, 1000)
        assert offline[0] == pytest.approx(paid, rel=1e-9), name
    assert by_name["Ki x1/2"].collision_m.mean() > by_name["pid-dom (zero action)"].collision_m.mean()


@pytest.mark.slow
def test_the_command_task_ranks_the_ladder_as_its_metric_does(monkeypatch):
    """training/reward_ladder.py on 4 of the command id's draws: its return ranks the sixteen rungs
    (five classical controllers, the PID under five constant schedules, the zero action, the shipped
    `command-ppo` x0.5, x1, x1.5 and x-1, random) as x at the collision does (Spearman >= 0.9); the
    zero action (the support held still) reaches the guide's end, the policy does not; the returns
    scored offline are those the command environment pays for the zero action and the policy."""
    import gymnasium as gym

    monkeypatch.syspath_prepend(str(TRAINING))
    ladder = importlib.import_module("reward_ladder")
    returns_table = importlib.import_module("returns_table")
    env_id, policy = "MicroGravityLanding-Command-v1", "command-ppo"
    rungs = ladder.run_ladder(env_id, policy, range(1000, 1004))
    assert len(rungs) == 16
    result = ladder.report(env_id, policy, rungs, [1e-6])["by_scale"]["1e-06"]
    assert result["spearman"] >= ladder.MIN_SPEARMAN
    env = gym.make(env_id)
    limit = env.unwrapped.core.x_limit_m
    by_name = {rung.name: rung for rung in rungs}
    assert (by_name["zero action"].collision_m > 0.9 * limit).all()  # the support held still: the guide's end
    assert (by_name[f"{policy} x1"].collision_m < 1e-4).all()
    for name, act in (
        ("zero action", lambda obs: np.zeros(1, dtype=np.float32)),
        (f"{policy} x1", returns_table.policy_actor(env_id, policy)),
    ):
        offline = by_name[name].returns(1e-6, limit, 1, contact_only=False)
        assert offline[0] == pytest.approx(returns_table.episode_return(env, act, 1000), rel=1e-9), name
