"""Every benchmark script imports and runs to its end on a tiny budget, so none can rot."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

#: Each script with arguments that make it quick (its physics shortened, one repeat).
SMOKE_ARGS = {
    "bench_run": ["--repeats", "1", "--controllers", "pid,feedforward", "--duration", "2"],
    "bench_batch": ["--sizes", "2", "--periods", "20", "--repeats", "1"],
    "bench_kernel_args": ["--calls", "100", "--repeats", "1"],
    "bench_compare": ["--seeds", "1", "--scenarios", "condition-1", "--duration", "0.5", "--timesteps", "512"],
    "bench_reproduce": ["--repeats", "1", "--duration", "0.5"],
    "convergence": ["--steps-us", "100", "25", "--duration", "0.2", "--controllers", "pid,residual-sac-setpoint"],
    "bench_drive_scheme": ["--sizes", "2", "--seconds", "0.05", "--repeats", "1"],
    "convergence_comparison": [
        "--controllers",
        "pid,feedforward",
        "--reference",
        "pid",
        "--scenarios",
        "heavy-single",
        "--seeds",
        "1",
        "--randomize",
        "none",
        "--duration",
        "0.3",
        "--workers",
        "1",
    ],
    "bench_controller_compute": ["--controllers", "pid,residual-sac-setpoint", "--duration", "0.05", "--repeats", "1"],
    "identifiability": ["--draws", "1", "--workers", "1", "--seconds", "0.3", "0.4", "--max-iterations", "1"],
}


def test_every_benchmark_script_has_a_smoke_run() -> None:
    scripts = {path.stem for path in BENCHMARKS.glob("*.py")} - {"timing"}
    assert scripts == set(SMOKE_ARGS)


@pytest.mark.parametrize("name", sorted(SMOKE_ARGS))
@pytest.mark.slow
def test_benchmark_script_runs(name: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    module = importlib.import_module(name)
    try:
        assert module.main(SMOKE_ARGS[name]) == 0
    finally:
        sys.modules.pop(name, None)
    printed = capsys.readouterr().out
    assert printed.strip(), f"{name} printed nothing"
