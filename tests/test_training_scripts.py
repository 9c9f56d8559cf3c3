"""The analysis scripts behind the adaptive baseline's settings, the partial oracles of docs/controllers.md, its
returns table and the memory probe run."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

TRAINING = Path(__file__).resolve().parents[1] / "training"


@pytest.mark.parametrize(
    ("name", "args", "expected"),
    [
        ("tune_adaptive", ["--steps", "0.003", "--seeds", "1", "--duration", "0.3"], "step 0.003: J = "),
        ("partial_oracles", ["--seeds", "1000", "--duration", "0.3"], "cogging and speed loop"),
        ("returns_table", ["--seeds", "1", "--scenarios", "training"], "| zero residual (adaptive) | "),
        (
            "memory_probe",
            ["--stack", "2", "--timesteps", "256", "--seeds", "2", "--scenarios", "training"],
            "| training | ",
        ),
    ],
)
@pytest.mark.slow
def test_training_script_runs(name, args, expected, monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(TRAINING))
    module = importlib.import_module(name)
    assert module.main(args) == 0
    assert expected in capsys.readouterr().out
