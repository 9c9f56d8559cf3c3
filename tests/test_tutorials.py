"""The tutorials in docs/tutorials run as written, each at a small size, and leave what they say
they write (the issue's budget: three minutes together on a CPU)."""

import json
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq

TUTORIALS = Path(__file__).resolve().parents[1] / "docs" / "tutorials"


def _tutorial(name: str, tmp_path: Path, *args: str) -> str:
    result = subprocess.run(
        [sys.executable, str(TUTORIALS / name), "--out", str(tmp_path), *args],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        check=False,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return result.stdout


def test_every_tutorial_is_tested():
    assert sorted(p.name for p in TUTORIALS.glob("*.py")) == [
        "01_quickstart.py",
        "02_train_residual.py",
        "03_campaign_dataframe.py",
    ]


def test_quickstart_runs_an_episode_and_plots_it(tmp_path):
    out = _tutorial("01_quickstart.py", tmp_path, "--duration", "6")
    assert "one step = 0.001 s" in out
    assert "compensation error per stage: ['+0.3" in out  # the PID's, Table 3's order
    assert (tmp_path / "quickstart.png").read_bytes()[:4] == b"\x89PNG"


def test_training_tutorial_trains_and_compares_paired_against_adaptive(tmp_path):
    out = _tutorial("02_train_residual.py", tmp_path, "--timesteps", "2048", "--seeds", "2", "--duration", "7")
    folder = tmp_path / "comparison"
    assert sorted(p.name for p in folder.iterdir()) == [
        "comparison.json",
        "comparison.md",
        "metrics.png",
        "x_landing.png",
    ]
    data = json.loads((folder / "comparison.json").read_text())
    assert data["controllers"] == ["my-residual", "adaptive", "feedforward"]
    assert data["labels"]["my-residual"].endswith("policy")
    assert data["randomize"] == "wider"
    pair = data["paired"]["my-residual"]["collision_excursion_m"]
    assert f"collision_excursion_m: {pair['ratio']:.3f} [" in out
    (run,) = (tmp_path / "logs" / "ppo").iterdir()
    assert (run / "policy").is_dir()


def test_campaign_tutorial_reads_its_table_into_pandas_and_plots_it(tmp_path):
    out = _tutorial("03_campaign_dataframe.py", tmp_path, "--duration", "6")
    assert "12 runs stored, 0 failed" in out
    table = pq.read_table(tmp_path / "pad-stiffness" / "results.parquet")
    assert table.num_rows == 12
    assert sorted(set(table.column("pad.stiffness_n_per_m").to_pylist())) == [3000, 4666, 9387]
    assert (tmp_path / "pad-stiffness.png").read_bytes()[:4] == b"\x89PNG"
