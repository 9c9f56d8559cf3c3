"""microg reproduce: every number of the report comes from the runs and the metrics module."""

import json
from dataclasses import replace

import pytest

from microg_env.analysis.evaluate import run_with_metrics
from microg_env.cli import main
from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.paper import report
from microg_env.paper.tables import CONDITIONS as PAPER
from microg_env.scenarios import CONDITIONS

DURATION = 12.0  # long enough for every condition's first contact


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "reproduction"
    assert main(["reproduce", "--out", str(out), "--duration", str(DURATION), "--quiet"]) == 0
    return out, json.loads((out / "report.json").read_text()), (out / "report.md").read_text()


def test_report_files(reproduced):
    out, _, markdown = reproduced
    for name in report.FIGURES:
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
        assert f"]({name})" in markdown
    for heading in ("Table 3", "Table 4", "Table 5", "Table 6", "Section 2 closed form", "Differences"):
        assert heading in markdown


@pytest.mark.parametrize("pad", report.PADS)
@pytest.mark.parametrize("number", [1, 2, 3])
def test_report_numbers_are_the_metrics_of_the_runs(reproduced, pad, number):
    _, summary, markdown = reproduced
    stiffness = summary["pads"][pad]["stiffness_n_per_m"]
    damping = summary["pads"][pad]["damping_n_s_per_m"]
    scenario = replace(CONDITIONS[number], pad_stiffness_n_per_m=stiffness, pad_damping_n_s_per_m=damping)
    env = MicroGravityLandingEnv(scenario=scenario)
    _, _, metrics = run_with_metrics(env, make_controller("pid", env.control_period_s), seed=0, duration_s=DURATION)
    assert summary["metrics"][pad][str(number)] == json.loads(json.dumps(metrics.as_dict()))
    assert f"{metrics.max_deformation_m * 1e3:.2f}" in markdown
    assert f"{metrics.collision_accel_m_s2 * 1e3:.2f}" in markdown
    for accel in metrics.descent_accel_m_s2:
        assert f"{accel * 1e3:.3f}" in markdown
    paper = PAPER[number]
    residual = 100 * (metrics.max_deformation_m * 1e3 - paper.measured_max_deformation_mm)
    residual /= paper.measured_max_deformation_mm
    assert summary["rig_residuals_pct"][pad]["max_deformation"][number - 1] == pytest.approx(residual)
    assert f"{residual:+.2f} %" in markdown


def test_calibrated_rig_within_the_papers_worst_errors(reproduced):
    _, summary, _ = reproduced
    assert summary["calibrated_within_paper_worst_errors"] is True
    assert sum(summary["calibrated_better_than_paper"]) >= 4


def test_interrupted_write_leaves_the_previous_report(reproduced, tmp_path, monkeypatch):
    out = tmp_path / "reproduction"
    out.mkdir()
    (out / "report.md").write_text("previous report")
    fake = report.Reproduction(
        runs={}, calibration=None, simulation_fit=None, pads={}, duration_s=1.0, seed=0, controller="pid"
    )

    def interrupted(_):
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "render_markdown", interrupted)
    with pytest.raises(KeyboardInterrupt):
        report.write(fake, out)
    assert (out / "report.md").read_text() == "previous report"
    assert [p.name for p in tmp_path.iterdir()] == ["reproduction"]  # no staging folder left


def test_bad_output_folder(tmp_path):
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("x")
    with pytest.raises(ValueError, match="not a folder"):
        report.check_output(not_a_folder)
    with pytest.raises(ValueError, match="not a report"):
        report.check_output(tmp_path)  # holds "file": never replaced
    with pytest.raises(ValueError, match="does not exist"):
        report.check_output(tmp_path / "missing" / "reproduction")
