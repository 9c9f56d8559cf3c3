"""The tutorials in docs/tutorials run as written, each at a small size, and leave what they say
they write (the issue's budget: three minutes together on a CPU). The campaign tutorial starts Ray:
its test is in experiments/test_experiments.py, with the campaign tests."""

import json
from pathlib import Path

import pytest

TUTORIALS = Path(__file__).resolve().parents[1] / "docs" / "tutorials"


def test_every_tutorial_is_tested():
    assert sorted(p.name for p in TUTORIALS.glob("*.py")) == [
        "01_quickstart.py",
        "02_train_residual.py",
        "03_campaign_dataframe.py",
    ]


@pytest.mark.slow
def test_quickstart_runs_an_episode_and_plots_it(tmp_path, run_tutorial):
    out = run_tutorial("01_quickstart.py", tmp_path, "--duration", "6")
    assert "one step = 0.001 s" in out
    assert "compensation error per stage: ['+0.3" in out  # the PID's, Table 3's order
    assert (tmp_path / "quickstart.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_training_tutorial_trains_and_compares_paired_against_adaptive_dither(tmp_path, run_tutorial):
    out = run_tutorial("02_train_residual.py", tmp_path, "--timesteps", "2048", "--seeds", "2", "--duration", "7")
    folder = tmp_path / "comparison"
    assert sorted(p.name for p in folder.iterdir()) == [
        "comparison.json",
        "comparison.md",
        "metrics.png",
        "x_landing.png",
    ]
    data = json.loads((folder / "comparison.json").read_text())
    assert data["controllers"] == ["my-residual", "adaptive-dither", "feedforward"]
    assert data["labels"]["my-residual"].endswith("policy")
    assert data["randomize"] == "wider"
    pair = data["paired"]["my-residual"]["collision_excursion_m"]
    assert f"collision_excursion_m: {pair['ratio']:.3f} [" in out
    (run,) = (tmp_path / "logs" / "ppo").iterdir()
    assert (run / "policy").is_dir()
