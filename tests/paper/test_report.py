"""microg reproduce: every number of the report comes from the runs and the metrics module."""

import json
from pathlib import Path

import pytest

from microg_env.cli import main
from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.paper import figures, report, reproduction
from microg_env.paper.calibration import with_pad
from microg_env.paper.tables import PUBLISHED
from microg_env.params import RigParams
from microg_env.rollout.episode import run_with_metrics
from microg_env.scenarios import CONDITIONS

DURATION = 12.0  # long enough for every condition's first contact (and the Eq. 17 free falls)


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "reproduction"
    assert main(["reproduce", "--out", str(out), "--duration", str(DURATION), "--quiet"]) == 0
    return out, json.loads((out / "report.json").read_text()), (out / "report.md").read_text()


@pytest.mark.slow
def test_report_files(reproduced):
    out, _, markdown = reproduced
    for name in figures.FIGURES:
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
        assert f"]({name})" in markdown
    for heading in (
        "Table 3",
        "Table 4",
        "Table 5",
        "Table 6",
        "Eq. (17)",
        "Balancer",
        "Section 2 closed form",
        "Differences",
    ):
        assert heading in markdown


@pytest.mark.slow
def test_table_3_prints_the_papers_table_3(reproduced):
    """The report's Table 3 printed Table 6's 131.2 for condition 1, where the paper's Table 3 has 130.20."""
    _, _, markdown = reproduced
    assert "| 1 | collision acceleration (mm/s²) | 130.2 |" in markdown
    assert "| 1 | 131.20 |" in markdown  # Table 6 keeps its own value


@pytest.mark.parametrize("pad", reproduction.PADS)
@pytest.mark.parametrize("number", [1, 2, 3])
@pytest.mark.slow
def test_report_numbers_are_the_metrics_of_the_runs(reproduced, pad, number):
    _, summary, markdown = reproduced
    params = with_pad(RigParams(), pad)
    assert summary["pads"][pad]["stiffness_n_per_m"] == params.pad.stiffness_n_per_m
    env = MicroGravityLandingEnv(scenario=CONDITIONS[number], params=params)
    _, _, metrics = run_with_metrics(
        env, make_controller("pid", env.settings.control_period_s), seed=0, duration_s=DURATION
    )
    assert summary["metrics"][pad][str(number)] == json.loads(json.dumps(metrics.as_dict()))
    assert f"{metrics.max_deformation_m * 1e3:.2f}" in markdown
    assert f"{metrics.collision_accel_m_s2 * 1e3:.2f}" in markdown
    for accel in metrics.descent_accel_m_s2:
        assert f"{accel * 1e3:.3f}" in markdown
    paper = PUBLISHED[number]
    residual = 100 * (metrics.max_deformation_m * 1e3 - paper.measured_max_deformation_mm)
    residual /= paper.measured_max_deformation_mm
    assert summary["rig_residuals_pct"][pad]["max_deformation"][number - 1] == pytest.approx(residual)
    assert f"{residual:+.2f} %" in markdown


@pytest.mark.slow
def test_calibrated_rig_within_the_papers_worst_errors(reproduced):
    _, summary, _ = reproduced
    assert summary["calibrated_within_paper_worst_errors"] is True
    assert sum(summary["calibrated_better_than_paper"]) >= 4


@pytest.mark.slow
def test_interrupted_write_leaves_the_previous_report(reproduced, tmp_path, monkeypatch):
    out = tmp_path / "reproduction"
    out.mkdir()
    (out / "report.md").write_text("previous report")
    fake = reproduction.Reproduction(
        runs={},
        calibration=None,
        simulation_fit=None,
        pads={},
        eq17={},
        drift={},
        duration_s=1.0,
        seed=0,
        controller="pid",
    )

    def interrupted(_):
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "findings", lambda rep: {})
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


@pytest.mark.slow
def test_eq17_and_drift_sections_come_from_their_runs(reproduced):
    _, summary, markdown = reproduced
    literal = summary["eq17_compensation_error_pct"]["literal/ki4000"]
    restoring = summary["eq17_compensation_error_pct"]["restoring/ki4000"]
    assert all(e > 1.0 for n in ("1", "2") for e in literal[n])  # the paper's fast descents
    assert all(e < 0.0 for n in ("1", "2", "3") for e in restoring[n])  # a restoring QZS is slow
    drift = summary["drift_fifty_gram_stage_error_pct"]
    spread = {k: max(v) - min(v) for k, v in drift.items() if k != "seeds"}
    assert spread["support_lander"] > spread["frame_support"]
    assert f"spread {spread['support_lander']:.2f} pp" in markdown


def test_the_fresh_clone_default_output_folder_is_created(tmp_path, monkeypatch):
    """`microg reproduce` on a fresh clone: results/ is not in git, and the default --out is in it."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(reproduction, "compute", lambda **kwargs: pytest.fail("validated before running"))
    assert main(["reproduce", "--quiet", "--duration", "0"]) == 2  # a bad option still creates nothing
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_the_differences_section_states_the_numbers_report_json_records(reproduced):
    """The prose reads its numbers from one record (report.json's "differences"), not from physics
    computed inside the text."""
    _, summary, markdown = reproduced
    found = summary["differences"]
    section = markdown.split("## Differences from the paper, explained", 1)[1]
    low, high = found["descent_error_pct"]
    assert f"this model's are\n   {low:+.2f} % to {high:+.2f} %" in section
    assert f"−(k/Ki)/(M + m + k/Ki) = {found['integral_lag_error_pct']:+.2f} %" in section
    assert f"({found['force_error_n']:.2f} N at most)" in section
    assert f"a pad {found['simulation_fit_stiffness_ratio']:.2f} times stiffer" in section
    assert len(found["instant_change_um"]) == 3


@pytest.mark.slow
def test_the_report_is_rendered_from_its_findings_record_alone(reproduced):
    """report.json holds every number report.md states: the page renders again from the file."""
    _, summary, markdown = reproduced
    assert report.render_markdown(summary) == markdown


def test_the_committed_report_is_its_committed_findings_record_rendered():
    folder = Path(__file__).resolve().parents[2] / "docs" / "reproduction"
    found = json.loads((folder / "report.json").read_text())
    assert report.render_markdown(found) == (folder / "report.md").read_text()
    found["differences"]["force_error_n"] *= 2  # a number changed in the record shows on the page
    assert report.render_markdown(found) != (folder / "report.md").read_text()
