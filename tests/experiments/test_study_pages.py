"""Study pages read whatever a campaign's table holds (#44): the period-bandwidth page without a
re-tuned PID, with no value of a metric, and with groups whose runs all failed; the sensitivity
page's run counts by run, not by design point."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from microg_env.analysis.formatting import MISSING
from microg_env.experiments.campaign import Campaign, Run
from microg_env.experiments.store import result_row
from microg_env.experiments.studies import sensitivity, write_study
from microg_env.rollout.runner import RunResult

GAIN, FRICTION = "servo.speed_loop_gain_hz", "qzs.guide_friction_n"
SHORT = {"scenario": "condition-1", "duration_s": 1}
ERROR = "summary_compensation_error"
GRAVITY = "summary_residual_gravity_g"
FREE_FALL = "flexible_unit_excursion_free_fall_m"
COLLISION = "flexible_unit_excursion_collision_m"
#: A completed run's stand-in metrics.
METRICS = {ERROR: 0.25, GRAVITY: 2e-6, FREE_FALL: 1.5e-6, COLLISION: 3e-6}


def _row(run: Run, ok: bool, **values) -> dict:
    """``run``'s row as the store writes it: a failed run's, or a completed one with ``values`` (its
    other metrics none, as a run that reached no window has)."""
    row = result_row(RunResult(run.spec, None, "RuntimeError: boom"), run.columns)
    return row | {"status": "ok", "error": None} | values if ok else row


def _cells(page: str) -> list[list[str]]:
    """The period-bandwidth page's table: each row's cells."""
    lines = [line for line in page.splitlines() if line.startswith("| ") and not line.startswith("| controller")]
    return [line.removeprefix("| ").removesuffix(" |").split(" | ") for line in lines]


# -- period-bandwidth ------------------------------------------------------------------------------


def _period_bandwidth(**extra) -> Campaign:
    sweep = {"control_period_us": [1000, 500], GAIN: [100], "controller": ["pid", "feedforward"]}
    return Campaign.from_dict({"name": "pb", "base": SHORT, "sweep": sweep, "report": "period-bandwidth"} | extra)


#: The page's groups, in its order: (controller, period).
GROUPS = [("pid", "1000"), ("pid", "500"), ("feedforward", "1000"), ("feedforward", "500")]
NONE = f"{MISSING} / {MISSING}"


def test_the_period_bandwidth_page_renders_a_campaign_without_a_retuned_pid(tmp_path):
    """With no `pid-retuned` the tuned-gain columns hold no value at all (Parquet's null type) and
    the page raised ArrowNotImplementedError after every run had run."""
    campaign = _period_bandwidth()
    table = pa.Table.from_pylist([_row(run, True, **METRICS) for run in campaign.runs()])
    assert pa.types.is_null(table.schema.field("tuned_kp_per_s").type)
    page = write_study(campaign, table, tmp_path).read_text()
    numbers = ["100", "0.250", "2.0e-06", "1.50 / 1.50", "3.00 / 3.00", "0", MISSING]
    assert _cells(page) == [[*group, *numbers] for group in GROUPS]
    assert (tmp_path / "period_bandwidth.png").is_file()


def test_the_period_bandwidth_page_renders_a_table_without_any_value(tmp_path):
    """Runs too short to reach any window: every metric null; the figure's log axes raised."""
    campaign = _period_bandwidth()
    page = write_study(campaign, pa.Table.from_pylist([_row(run, True) for run in campaign.runs()]), tmp_path)
    numbers = ["100", MISSING, MISSING, NONE, NONE, "0", MISSING]
    assert _cells(page.read_text()) == [[*group, *numbers] for group in GROUPS]
    assert (tmp_path / "period_bandwidth.png").is_file()


def test_the_period_bandwidth_page_lists_each_group_with_its_failures(tmp_path):
    """The groups were read from the successful rows: a group whose runs all failed was left off."""
    campaign = _period_bandwidth(seeds=[1, 2])
    collision = {1000: 4e-6, 500: 2e-6}

    def completed(run: Run) -> bool:
        return run.spec.controller == "pid" and not (run.spec.control_period_us == 1000 and run.spec.seed == 2)

    rows = [
        _row(run, True, **METRICS | {COLLISION: collision[run.spec.control_period_us]})
        if completed(run)
        else _row(run, False)
        for run in campaign.runs()
    ]
    page = write_study(campaign, pa.Table.from_pylist(rows), tmp_path).read_text()
    assert "from 8 runs (5 failed)" in page
    assert _cells(page) == [
        ["pid", "1000", "100", "0.250", "2.0e-06", "1.50 / 1.50", "4.00 / 4.00", "1", MISSING],
        ["pid", "500", "100", "0.250", "2.0e-06", "1.50 / 1.50", "2.00 / 2.00", "0", MISSING],
        ["feedforward", "1000", "100", MISSING, MISSING, NONE, NONE, "2", MISSING],
        ["feedforward", "500", "100", MISSING, MISSING, NONE, NONE, "2", MISSING],
    ]


# -- sensitivity -----------------------------------------------------------------------------------

#: A Morris design whose 3 trajectories share points: 9 design points, 4 runs per controller and seed.
MORRIS = {
    "name": "m",
    "base": {"scenario": "condition-2", "duration_s": 0.3},
    "sweep": {"controller": ["pid", "feedforward"]},
    "samples": {
        "method": "morris",
        "trajectories": 3,
        "levels": 4,
        "seed": 3,
        "draw": {GAIN: {"uniform": [50.0, 200.0]}, FRICTION: {"uniform": [0.05, 0.2]}},
    },
    "seeds": [1000, 1001],
    "report": "sensitivity",
}


def _lost(run: Run) -> bool:
    """The stand-in's runs lost at a stroke limit: the design's most repeated point."""
    return run.columns[GAIN] == 50.0 and run.columns[FRICTION] == 0.05


def _sensitivity_table(campaign: Campaign, reached: bool) -> pa.Table:
    """Each run completed, lost where :func:`_lost`, its x at the collision set if ``reached``."""
    rows = []
    for run in campaign.runs():
        x = 1e-6 * run.columns[GAIN] if reached else None
        rows.append(_row(run, True, termination_reason="stroke_limit" if _lost(run) else None, **{COLLISION: x}))
    return pa.Table.from_pylist(rows)


def _sections(page: str) -> dict[str, str]:
    return {section.split("\n")[0]: section for section in page.split("\n## `controller` = ")[1:]}


@pytest.mark.slow
def test_the_sensitivity_page_counts_each_section_by_run(tmp_path):
    """A repeated design point was counted once per repeat: a 16-run page said "6 of 18 runs" in
    each of its two sections, and its shares were weighted by the repeats."""
    campaign = Campaign.from_dict(MORRIS)
    runs = campaign.runs()
    design = len(campaign.sample_points()) * len(campaign.seeds)
    page = write_study(campaign, _sensitivity_table(campaign, reached=True), tmp_path).read_text()
    assert f"from {len(runs)} runs (0 failed)" in page
    sections = _sections(page)
    assert list(sections) == ["pid", "feedforward"]
    for controller, section in sections.items():
        mine = [run for run in runs if run.spec.controller == controller]
        assert len(mine) < design  # the design repeats points
        lost = sum(map(_lost, mine))
        assert f"{lost} of {len(mine)} runs ended at a stroke limit (condition-2: {lost})." in section
        for key in (GAIN, FRICTION):
            levels = sorted({run.columns[key] for run in mine})
            shares = [
                sum(_lost(r) for r in mine if r.columns[key] == v) / sum(r.columns[key] == v for r in mine)
                for v in levels
            ]
            assert (
                f"| `{key}` | " + ", ".join(f"{v:.4g}: {s:.0%}" for v, s in zip(levels, shares, strict=True)) + " |"
                in section
            )


@pytest.mark.slow
def test_the_sensitivity_page_says_so_where_a_section_reached_no_quantity(tmp_path):
    campaign = Campaign.from_dict(MORRIS)
    page = write_study(campaign, _sensitivity_table(campaign, reached=False), tmp_path).read_text()
    for section in _sections(page).values():
        numbers = section.split(sensitivity.QUANTITIES_HEADING)[1].split("\n\n![")[0]
        assert numbers.strip().splitlines() == [sensitivity.NOTHING_REACHED]


@pytest.mark.slow
def test_the_sensitivity_page_gives_mu_star_with_its_interval_and_sigma(tmp_path):
    """x at the collision set to the speed loop's gain in µm (linear, friction no part): every
    elementary effect of the gain is its range, 150 µm, so mu* is 150 with no spread (interval 0,
    sigma 0), and the friction's is 0."""
    campaign = Campaign.from_dict(MORRIS)
    page = write_study(campaign, _sensitivity_table(campaign, reached=True), tmp_path).read_text()
    assert "mu* ± its 95 % bootstrap half-width, sigma" in page
    for section in _sections(page).values():
        row = next(line for line in section.splitlines() if line.startswith("| x at the collision"))
        assert f"`{GAIN}`: 150 ± 0, sigma 0; `{FRICTION}`: 0 ± 0, sigma 0 |" in row


# -- controller-sensitivity ------------------------------------------------------------------------

PLANT_GAIN, PLANT_FRICTION = f"plant_overrides.{GAIN}", f"plant_overrides.{FRICTION}"
RANKING = MORRIS | {
    "base": {"duration_s": 0.3},
    "sweep": {"controller": ["pid", "feedforward"], "scenario": ["condition-1", "condition-2"]},
    "samples": MORRIS["samples"]
    | {"draw": {PLANT_GAIN: {"uniform": [50.0, 200.0]}, PLANT_FRICTION: {"uniform": [0.05, 0.2]}}},
    "report": "controller-sensitivity",
}


def _ranking_table(campaign: Campaign, lose: Run | None = None) -> pa.Table:
    """x at the collision, condition 1 / condition 2: 2 / 4 µm for the PID, g / 3 g µm for the
    feed-forward, g = 1 + gain / 100 Hz. At a design point their means are 3 and 2 g µm, and the
    ratio of the means 2 g / 3, linear in the gain (1.0 over its 50 to 200 Hz), the friction no
    part (the mean of the ratios, 0.625 g, or condition 1's alone, g / 2, differ). x in free fall
    1 µm for both. ``lose``: a run that ended at a stroke limit."""
    rows = []
    for run in campaign.runs():
        weight = 1.0 if run.spec.scenario == "condition-1" else (2.0 if run.spec.controller == "pid" else 3.0)
        x = 2e-6 if run.spec.controller == "pid" else 1e-6 * (1.0 + run.columns[PLANT_GAIN] / 100.0)
        lost = "stroke_limit" if lose is not None and run.spec == lose.spec else None
        rows.append(_row(run, True, termination_reason=lost, **{COLLISION: weight * x, FREE_FALL: 1e-6}))
    return pa.Table.from_pylist(rows)


@pytest.mark.slow
def test_the_controller_sensitivity_page_gives_each_ratios_range_and_its_mu_star(tmp_path):
    """The stand-in's ratio of means moves linearly with the gain alone (1.0 over its range): mu*
    1.0 with no spread, the friction's 0, points below 1 where the ratio is; the free-fall ratio is
    1 everywhere. A lost run takes its design point (both schedules' mean) out and says so."""
    campaign = Campaign.from_dict(RANKING)
    page = write_study(campaign, _ranking_table(campaign), tmp_path).read_text()
    points = campaign.sample_points()
    ratios = np.array([2.0 * (1.0 + p[PLANT_GAIN] / 100.0) / 3.0 for p in points])
    spread = f"{np.median(ratios):.3g}× ({ratios.min():.3g} to {ratios.max():.3g})"
    own, row = (line for line in page.splitlines() if line.startswith("| `feedforward` | x at the collision"))
    assert "`speed_loop_gain_hz`: 3 ± 0, sigma 0; `guide_friction_n`: 0 ± 0, sigma 0 |" in own  # in µm
    assert f"| {spread} | {np.mean(ratios < 1.0):.0%} | 3 of 3 |" in row
    assert "`speed_loop_gain_hz`: 1.00 ± 0.00, sigma 0.00; `guide_friction_n`: 0.00 ± 0.00, sigma 0.00 |" in row
    _, free = (line for line in page.splitlines() if line.startswith("| `feedforward` | x in free fall"))
    assert "| 1× (1 to 1) | 0% |" in free
    runs = sum(run.spec.controller == "pid" for run in campaign.runs())  # a repeated point runs once
    assert runs < 2 * len(points)
    assert f"| `pid` | x at the collision | 3 (3 to 3) | 0 of {runs} |" in page
    assert (tmp_path / "controller_sensitivity.png").is_file()
    lost = next(run for run in campaign.runs() if run.spec.controller == "feedforward")
    page = write_study(campaign, _ranking_table(campaign, lose=lost), tmp_path).read_text()
    own, row = (line for line in page.splitlines() if line.startswith("| `feedforward` | x at the collision"))
    assert f"| 1 of {runs} |" in own
    at = [all(p[k] == lost.columns[k] for k in (PLANT_GAIN, PLANT_FRICTION)) for p in points]
    kept = sum(not any(at[i : i + 3]) for i in range(0, len(points), 3))  # 3 points a trajectory
    assert 0 < kept < 3
    assert f"| {kept} of 3 |" in row  # a trajectory with the lost run's point is not analysed


def test_the_controller_sensitivity_page_needs_controllers_to_compare_and_pools_nothing_else():
    with pytest.raises(ValueError, match="compares controllers"):
        Campaign.from_dict(RANKING | {"sweep": {"controller": ["pid"], "scenario": ["condition-1"]}})
    periods = {"controller": ["pid", "feedforward"], "control_period_us": [500, 1000]}
    with pytest.raises(ValueError, match="not 'control_period_us'"):
        Campaign.from_dict(RANKING | {"sweep": periods})


def test_a_sensitivity_page_gives_the_value_the_controllers_assume():
    """The base's overrides (or a rig file's) are what the controllers assume, not params.py's."""
    campaign = Campaign.from_dict(RANKING | {"base": {"duration_s": 0.3, "overrides": {GAIN: 120.0}}})
    assert f"| `{PLANT_GAIN}` | 50 to 200 | 120 |" in sensitivity.ranges_table(campaign)
    assert f"| `{PLANT_FRICTION}` | 0.05 to 0.2 | 0.2 |" in sensitivity.ranges_table(campaign)  # params.py's
    drawn = Campaign.from_dict(MORRIS)  # not the design's first point
    assert sensitivity.ranges_table(drawn)[2:] == [
        f"| `{GAIN}` | 50 to 200 | 100 |",
        f"| `{FRICTION}` | 0.05 to 0.2 | 0.2 |",
    ]
