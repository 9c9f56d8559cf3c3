"""The microg command: output, JSON and one-line errors with exit code 2."""

import json
import subprocess
import sys
from pathlib import Path

import mujoco
import pytest

from microg_env.cli import main

REPO = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "microg_env.cli", *args], capture_output=True, text=True, cwd=REPO, check=False
    )


def test_drop_json_default_is_the_paper_pad(capsys):
    assert main(["drop", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result) == {
        "contact_time_s",
        "restitution",
        "max_deformation_m",
        "fitted_stiffness_n_per_m",
        "fitted_damping_n_s_per_m",
    }
    assert result["fitted_stiffness_n_per_m"]["analytic"] == 4666.0
    assert result["fitted_damping_n_s_per_m"]["analytic"] == 200.0
    assert result["max_deformation_m"]["analytic"] == pytest.approx(0.012438, rel=1e-4)  # 37.3 mm/s
    for entry in result.values():
        assert entry["rel_error"] == pytest.approx((entry["sim"] - entry["analytic"]) / entry["analytic"])
        assert abs(entry["rel_error"]) < 0.01


def test_drop_table_names_the_quantities(capsys):
    assert main(["drop", "--mass", "300", "--stiffness", "10000", "--damping", "500", "--velocity", "0.02"]) == 0
    out = capsys.readouterr().out
    for label in ("contact time", "restitution", "peak deformation", "fitted stiffness", "fitted damping"):
        assert label in out
    assert "M = 300 kg" in out


@pytest.mark.parametrize(
    ("args", "word"),
    [
        (["drop", "--mass", "0"], "mass"),
        (["drop", "--mass", "-620"], "mass"),
        (["drop", "--mass", "nan"], "mass"),
        (["drop", "--mass", "700"], "700"),
        (["drop", "--stiffness", "0"], "stiffness"),
        (["drop", "--damping", "-1"], "damping"),
        (["drop", "--damping", "5000"], "over-damped"),
        (["drop", "--velocity", "0"], "velocity"),
        (["drop", "--velocity", "2"], "thickness"),
        (["drop", "--mass", "heavy"], "heavy"),
        (["drop", "--bogus"], "--bogus"),
        (["fly"], "fly"),
        (["export-mjcf", "/nonexistent-folder/rig.xml"], "nonexistent-folder"),
        (["run", "--condition", "4"], "--condition"),
        (["run", "--load", "heavy"], "heavy"),
        (["run", "--load", "-0.05"], "mass_kg"),
        (["run", "--load", "0.05@20"], "t = 0"),
        (["run", "--load", "0.05", "--load", "1@100"], "descent height"),
        (["run", "--load", "0.05", "--load", "9"], "1e-2 g"),
        (["run", "--height", "600"], "descent_height_m"),
        (["run", "--height", "-5"], "descent_height_m"),
        (["run", "--controller", "lqr"], "--controller"),
        (["run", "--duration", "0"], "duration_s"),
        (["run", "--control-period", "0"], "control_period_s"),
        (["run", "--plot", "/nonexistent-folder/run.png"], "nonexistent-folder"),
        (["run", "--pad", "foam"], "--pad"),
        (["reproduce", "--out", "/nonexistent-folder/reproduction"], "nonexistent-folder"),
        (["reproduce", "--duration", "-1"], "duration"),
        (["reproduce", "--out", "."], "not a report"),
        (["reproduce", "--seed", "x"], "--seed"),
        (["calibrate", "--bogus"], "--bogus"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, word):
    result = _run(*args)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert word in lines[0]
    assert "Traceback" not in result.stderr
    assert result.stdout == ""


def test_export_mjcf_writes_a_model_that_compiles(tmp_path, capsys):
    out = tmp_path / "rig_resolved.xml"
    assert main(["export-mjcf", str(out), "--load", "0.05"]) == 0
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.body("load_0").mass[0] == pytest.approx(0.05)
    assert model.geom_solref[model.geom("pad").id, 0] < 0  # the computed pad contact is in it
    assert list(tmp_path.iterdir()) == [out]  # no temporary file left behind


def test_run_json_keys_and_signs(capsys, run_json_keys):
    assert main(["run", "--condition", "2", "--duration", "6", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert run_json_keys <= set(result)
    assert result["ideal_descent_accel_m_s2"] == [pytest.approx(-1.0 * 9.8009 / 621.0)]
    assert result["descent_accel_m_s2"][0] < 0  # down is negative
    assert result["collision_accel_m_s2"] > 0  # the pad pushes up


def test_run_custom_loads_table_and_plot(tmp_path, capsys):
    plot = tmp_path / "run.png"
    args = ["run", "--load", "0.05", "--load", "1.0@30", "--height", "60", "--duration", "4", "--plot", str(plot)]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "custom" in out
    assert "stage 2" in out
    assert "compensation error" in out
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert list(tmp_path.iterdir()) == [plot]
