"""Study (d): global sensitivity of the headline numbers. Each headline quantity's spread over the
unpublished assumptions' ranges (the Morris design's points), and the assumptions ranked by
Morris's mu* (the mean |elementary effect|: the change of the quantity when one assumption moves
across its range by one grid step, scaled to the range). Each combination of the other swept keys
(the controller, ...) is analysed on its own, and with several seeds each point's quantity is the
mean over them: an elementary effect is then the assumptions', with the noise averaged down."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from microg_env.analysis.metrics import COMPARED_WINDOW
from microg_env.analysis.plots import figure_class, save_figure
from microg_env.experiments.studies.groups import finite, markdown_table, page_header, successes, with_stage
from microg_env.params import RigParams, parameter_paths, with_overrides
from microg_env.rollout.spec import spec_entry
from microg_env.validate import shown

#: The swept columns the page reads (the sampled ones are the campaign's).
COLUMNS: tuple[str, ...] = ()
DEFORMATION_RATIO = "max_deformation_over_reference"
#: The headline quantities: (label, unit, scale to the unit, column).
QUANTITIES = (
    ("compensation error, stage 1", "%", 1.0, "compensation_error_pct[0]"),
    ("compensation error, stage 2", "%", 1.0, "compensation_error_pct[1]"),
    ("x at the collision (max over contact)", "µm", 1e6, "flexible_unit_excursion_collision_m"),
    ("x change, 5 ms from touchdown", "µm", 1e6, f"x_change_after_touchdown_m[{COMPARED_WINDOW}]"),
    ("peak deformation against the ideal", "%", 100.0, DEFORMATION_RATIO),
)

INTRO = """\
A Morris design (SALib): {trajectories} trajectories x ({assumptions} assumptions + 1) points on a {levels}-level \
grid, each point run on every scenario{cases}; {seeds}. The ranges:
"""
#: How the intro names the seeds: one, or several averaged per point.
ONE_SEED = "one seed, so the spread is the assumptions', not the noise's"
SEEDS = (
    "{count} seeds ({seeds}), each point's quantity the mean over them (a point counts only where every seed "
    "reached it), so the spread is the assumptions' with the noise averaged down"
)
QUANTITIES_HEADING = "Headline numbers over the ranges, and what drives them"
#: A section's headline numbers where no quantity can be ranked.
NOTHING_REACHED = (
    "No headline quantity was reached at every point of two or more trajectories (what mu* needs), "
    "so this section has no numbers."
)
QUANTITIES_INTRO = """\
The spread is over the design's points that completed (a grid that covers the ranges, not a probability \
sample): the 5th to 95th percentile. mu* is in the quantity's unit for one assumption moved over its whole \
range, from the trajectories whose every point reached the quantity; its interval is SALib's bootstrap over \
those trajectories (1000 resamples, 95 %). sigma, the spread of the elementary effects, as large as mu* \
means the assumption's effect depends on the others (an interaction or a curve).
"""


def _quantities(table: pa.Table) -> pa.Table:
    """The successful runs with a column per headline quantity, null where a run did not reach it."""
    table = with_stage(with_stage(table, "compensation_error_pct", 0), "compensation_error_pct", 1)
    table = with_stage(table, "x_change_after_touchdown_m", COMPARED_WINDOW)
    ratio = pc.subtract(pc.divide(table["max_deformation_m"], table["reference_max_deformation_m"]), 1.0)
    return finite(table.append_column(DEFORMATION_RATIO, ratio), *(column for *_, column in QUANTITIES))


def check(campaign) -> None:
    """ValueError unless ``campaign`` is a Morris design over rig parameters (the page gives each
    one's assumed value)."""
    samples = campaign.samples
    method = samples.get("method", "random") if samples else None
    if method != "morris":
        got = "no samples" if method is None else f"{method} samples"
        raise ValueError(
            f"report {shown(campaign.report)} reads a Morris design (samples: {{method: morris, ...}}), got {got}"
        )
    others = [key for key in samples["draw"] if spec_entry(key)[0] not in ("overrides", "plant_overrides")]
    if others:
        raise ValueError(
            f"report {shown(campaign.report)} moves rig parameters only (its page gives each one's assumed value); "
            f"{shown(others[0])} is not one"
        )


def design_rows(campaign, table: pa.Table) -> tuple[list[tuple[dict, list[str], str]], dict[str, dict]]:
    """The design's runs by identity (spec hash): for each grid point and seed, (the point, the spec
    hash of each design point in order, its scenario); and the completed runs' rows by spec hash,
    with the page's quantities. A design run with no row at all is refused: the table is not of
    this campaign."""
    design = [(point, [spec.hash for spec in specs], specs[0].scenario) for point, _, specs in campaign.sample_runs()]
    runs = list(dict.fromkeys(h for _, hashes, _ in design for h in hashes))  # a repeated point runs once
    listed = set(table["spec_hash"].to_pylist())
    missing = [h for h in runs if h not in listed]
    if missing:
        raise ValueError(
            f"report {shown(campaign.report)}: the results table has no row of {len(missing)} of the design's "
            f"{len(runs)} runs "
            f"(spec hash {missing[0]} first): it is not this campaign's table"
        )
    return design, {row["spec_hash"]: row for row in _quantities(successes(table)).to_pylist()}


def _cases(design: list[tuple[dict, list[str], str]]) -> dict[str, dict[str, list[list[str]]]]:
    """:func:`design_rows`' runs by case: {a combination of the swept keys but the scenario, as the
    page names it ("" if the campaign has one): {scenario: [for each seed, the spec hash of each
    design point in order]}}."""
    cases: dict[str, dict[str, list[list[str]]]] = {}
    for point, hashes, scenario in design:
        case = ", ".join(f"`{key}` = {value}" for key, value in point.items() if key != "scenario")
        cases.setdefault(case, {}).setdefault(scenario, []).append(hashes)
    return cases


def render(campaign, table: pa.Table, folder: Path) -> list[str]:
    draw = campaign.samples["draw"]
    keys, levels = list(draw), campaign.samples.get("levels", 4)
    design, stored = design_rows(campaign, table)
    cases = _cases(design)
    seeds = campaign.seeds
    lines = page_header(campaign, table, folder)
    intro = INTRO.format(
        trajectories=campaign.samples["trajectories"],
        assumptions=len(keys),
        levels=levels,
        cases="" if len(cases) == 1 else ", once for each combination of the other swept keys (a section each)",
        seeds=ONE_SEED if len(seeds) == 1 else SEEDS.format(count=len(seeds), seeds=", ".join(map(str, seeds))),
    )
    lines += [*intro.splitlines(), ""]
    lines += ranges_table(campaign)
    ranking: dict[tuple[str, str], np.ndarray] = {}
    section = "##" if len(cases) == 1 else "###"
    for case, runs_of in cases.items():
        if len(cases) > 1:
            lines += ["", f"## {case}"]
        lines += _case(campaign, case, runs_of, stored, section, ranking)
    _draw(ranking, keys, [_series(case, scenario) for case, runs_of in cases.items() for scenario in runs_of], folder)
    return [*lines, "", "![Morris mu* of each headline quantity, by assumption and scenario](sensitivity.png)", ""]


def ranges_table(campaign) -> list[str]:
    """The design's assumptions: each one's range and the value every controller assumes (the
    paper's rig with the campaign's rig file and base overrides)."""
    assumed = parameter_paths(with_overrides(RigParams(), campaign.base.get("overrides", {})))
    rows = []
    for key, distribution in campaign.samples["draw"].items():
        ((kind, (low, high)),) = distribution.items()
        scale = " (log grid)" if kind == "loguniform" else ""
        rows.append([f"`{key}`", f"{low:g} to {high:g}{scale}", f"{assumed[spec_entry(key)[1]]:g}"])
    return markdown_table(["assumption", "range", "as assumed"], rows)


def _series(case: str, scenario: str) -> str:
    """A bar of the figure: the scenario, after its combination of the other swept keys if any."""
    return f"{case}, {scenario}" if case else scenario


def _case(
    campaign, case: str, runs_of: dict[str, list[list[str]]], stored: dict[str, dict], section: str, ranking: dict
) -> list[str]:
    """One combination's sections (``runs_of`` as :func:`_cases` and ``stored`` as :func:`design_rows`
    give them): its lost runs and its headline numbers, each design point's quantity the mean over
    the seeds; each quantity's mu* goes to ``ranking`` by (quantity, :func:`_series`)."""
    from SALib.analyze import morris

    keys, levels = list(campaign.samples["draw"]), campaign.samples.get("levels", 4)
    unit, points = campaign.morris_design(), campaign.sample_points()
    runs = {
        scenario: {
            h: (point, h not in stored or stored[h]["termination_reason"] is not None)
            for hashes in per_seed
            for point, h in zip(points, hashes, strict=True)
        }
        for scenario, per_seed in runs_of.items()
    }
    lines = ["", f"{section} Runs lost (ended at a stroke limit)", ""]
    lines += _failures(keys, runs)
    lines += ["", f"{section} {QUANTITIES_HEADING}", ""]
    problem = {"num_vars": len(keys), "names": keys, "bounds": [[0.0, 1.0]] * len(keys)}
    steps = len(keys) + 1  # points per trajectory
    rows = []
    for label, unit_name, scale, column in QUANTITIES:
        for scenario, per_seed in runs_of.items():
            y = np.array([[stored_value(stored.get(h), column) for h in hashes] for hashes in per_seed])
            y = y.mean(axis=0) * scale
            whole = np.isfinite(y).reshape(-1, steps).all(axis=1)  # trajectories that reached it at every point
            if whole.sum() < 2:
                continue  # a stage this scenario does not have, or too few trajectories reached it
            keep = np.repeat(whole, steps)
            analysed = morris.analyze(problem, unit[keep], y[keep], num_levels=levels, num_resamples=1000, seed=0)
            mu_star, sigma = np.asarray(analysed["mu_star"]), np.asarray(analysed["sigma"])
            half = np.asarray(analysed["mu_star_conf"])  # SALib's bootstrap over the trajectories, 95 %
            ranking[label, _series(case, scenario)] = mu_star
            top = "; ".join(
                f"`{keys[j]}`: {mu_star[j]:.3g} ± {half[j]:.2g}, sigma {sigma[j]:.3g}" for j in np.argsort(-mu_star)[:3]
            )
            finite_y = y[np.isfinite(y)]
            low, high = np.percentile(finite_y, [5, 95])
            rows.append(
                [
                    f"{label} ({unit_name})",
                    scenario,
                    f"{np.median(finite_y):.3g}",
                    f"{low:.3g} to {high:.3g}",
                    f"{whole.sum()} of {whole.size}",
                    top,
                ]
            )
    if not rows:
        return [*lines, NOTHING_REACHED]
    header = [
        "quantity",
        "scenario",
        "median",
        "5–95 %",
        "trajectories",
        "largest mu* (the assumption: mu* ± its 95 % bootstrap half-width, sigma)",
    ]
    return [*lines, *QUANTITIES_INTRO.splitlines(), "", *markdown_table(header, rows)]


def stored_value(row: dict | None, column: str) -> float:
    """A quantity of a stored run, NaN where the run is missing or did not reach it."""
    return math.nan if row is None or row[column] is None else float(row[column])


def _failures(keys: list[str], runs: dict[str, dict[str, tuple[dict, bool]]]) -> list[str]:
    """How many runs were lost per scenario, and per assumption the share lost at each of its levels
    (over every scenario), the assumption that separates them best first; ``runs``: per scenario,
    each run by spec hash (once, however often the design repeats its point) with its design point
    and whether it was lost."""
    lost = sum(failed for of in runs.values() for _, failed in of.values())
    total = sum(len(of) for of in runs.values())
    lines = [
        f"{lost} of {total} runs ended at a stroke limit ("
        + ", ".join(f"{scenario}: {sum(failed for _, failed in of.values())}" for scenario, of in runs.items())
        + ")."
    ]
    if not lost:
        return lines
    every = [run for of in runs.values() for run in of.values()]
    spread = []
    for key in keys:
        shares = []
        for level in sorted({point[key] for point, _ in every}):
            at = [failed for point, failed in every if point[key] == level]
            shares.append((level, sum(at) / len(at)))
        spread.append((max(v for _, v in shares) - min(v for _, v in shares), key, shares))
    spread.sort(key=lambda item: -item[0])
    rows = [
        [f"`{key}`", ", ".join(f"{level:.4g}: {share:.0%}" for level, share in shares)] for _, key, shares in spread
    ]
    return [*lines, "", *markdown_table(["assumption", "share lost at each of its levels"], rows)]


def _draw(ranking: dict, keys: list[str], series: list[str], folder: Path) -> None:
    """sensitivity.png: each quantity's mu* per assumption, a bar per series (:func:`_series`)."""
    figure = figure_class()(figsize=(10, 2.2 * len(QUANTITIES)), layout="constrained")
    panels = figure.subplots(len(QUANTITIES), 1)
    for ax, (label, unit_name, _, _) in zip(panels, QUANTITIES, strict=True):
        shown = [s for s in series if (label, s) in ranking]
        width = 0.8 / max(len(shown), 1)
        for i, scenario in enumerate(shown):
            ax.barh(np.arange(len(keys)) + i * width, ranking[label, scenario], height=width, label=scenario)
        ax.set_yticks(np.arange(len(keys)) + 0.4 - width / 2, keys, fontsize=7)
        ax.set_xlabel(f"Morris mu* of {label} ({unit_name})", fontsize=8)
        ax.invert_yaxis()
        ax.grid(alpha=0.3, axis="x")
        if shown:
            ax.legend(fontsize=7)
    save_figure(figure, folder / "sensitivity.png")
