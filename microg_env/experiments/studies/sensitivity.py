"""Study (d): global sensitivity of the headline numbers. Each headline quantity's spread over the
unpublished assumptions' ranges (the Morris design's points), and the assumptions ranked by
Morris's mu* (the mean |elementary effect|: the change of the quantity when one assumption moves
across its range by one grid step, scaled to the range)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from microg_env.analysis.metrics import COMPARED_WINDOW
from microg_env.analysis.plots import figure_class, save_figure
from microg_env.experiments.studies.groups import finite, markdown_table, page_header, successes, with_stage
from microg_env.params import RigParams, parameter_paths

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
grid, each point run on every scenario; one seed, so the spread is the assumptions', not the noise's. The ranges:
"""
QUANTITIES_INTRO = """
## Headline numbers over the ranges, and what drives them

The spread is over the design's points that completed (a grid that covers the ranges, not a probability \
sample): the 5th to 95th percentile. mu* is in the quantity's unit for one assumption moved over its whole \
range, from the trajectories whose every point reached the quantity.
"""


def _quantities(table: pa.Table) -> pa.Table:
    """The successful runs with a column per headline quantity, null where a run did not reach it."""
    table = with_stage(with_stage(table, "compensation_error_pct", 0), "compensation_error_pct", 1)
    table = with_stage(table, "x_change_after_touchdown_m", COMPARED_WINDOW)
    ratio = pc.subtract(pc.divide(table["max_deformation_m"], table["reference_max_deformation_m"]), 1.0)
    return finite(table.append_column(DEFORMATION_RATIO, ratio), *(column for *_, column in QUANTITIES))


def render(campaign, table: pa.Table, folder: Path) -> list[str]:
    from SALib.analyze import morris

    draw = campaign.samples["draw"]
    keys, levels = list(draw), campaign.samples.get("levels", 4)
    unit, points = campaign.morris_design(), campaign.sample_points()
    stored = {(r["scenario"], *(r[key] for key in keys)): r for r in _quantities(successes(table)).to_pylist()}
    scenarios = list(dict.fromkeys(run.spec.scenario for run in campaign.runs()))
    assumed = parameter_paths(RigParams())
    lines = page_header(campaign, table, folder)
    intro = INTRO.format(trajectories=campaign.samples["trajectories"], assumptions=len(keys), levels=levels)
    lines += [*intro.splitlines(), ""]
    rows = []
    for key, distribution in draw.items():
        ((kind, (low, high)),) = distribution.items()
        scale = " (log grid)" if kind == "loguniform" else ""
        rows.append([f"`{key}`", f"{low:g} to {high:g}{scale}", f"{assumed[key]:g}"])
    lines += markdown_table(["assumption", "range", "as assumed (params.py)"], rows)
    rows_of = {
        scenario: [stored.get((scenario, *(point[key] for key in keys))) for point in points] for scenario in scenarios
    }
    failed = {s: [r is None or r["termination_reason"] is not None for r in rows_of[s]] for s in scenarios}
    lines += ["", "## Runs the tuned PID lost (ended at a stroke limit)", ""]
    lines += _failures(keys, points, failed)
    lines += [*QUANTITIES_INTRO.splitlines(), ""]

    problem = {"num_vars": len(keys), "names": keys, "bounds": [[0.0, 1.0]] * len(keys)}
    ranking: dict[tuple[str, str], np.ndarray] = {}
    steps = len(keys) + 1  # points per trajectory
    rows = []
    for label, unit_name, scale, column in QUANTITIES:
        for scenario in scenarios:
            y = np.array([_value(r, column) * scale for r in rows_of[scenario]], dtype=float)
            whole = np.isfinite(y).reshape(-1, steps).all(axis=1)  # trajectories that reached it at every point
            if whole.sum() < 2:
                continue  # a stage this scenario does not have, or too few trajectories reached it
            keep = np.repeat(whole, steps)
            analysed = morris.analyze(problem, unit[keep], y[keep], num_levels=levels, seed=0)
            mu_star = np.asarray(analysed["mu_star"])
            ranking[label, scenario] = mu_star
            top = "; ".join(f"`{keys[j]}`: {mu_star[j]:.3g}" for j in np.argsort(-mu_star)[:3])
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
    header = ["quantity", "scenario", "median", "5–95 %", "trajectories", "largest mu* (the assumption: mu*)"]
    lines += markdown_table(header, rows)
    _draw(ranking, keys, scenarios, folder)
    return [*lines, "", "![Morris mu* of each headline quantity, by assumption and scenario](sensitivity.png)", ""]


def _value(row: dict | None, column: str) -> float:
    """A quantity of a stored run, NaN where the run is missing or did not reach it."""
    return math.nan if row is None or row[column] is None else float(row[column])


def _failures(keys: list[str], points: list[dict], failed: dict[str, list[bool]]) -> list[str]:
    """How many runs were lost per scenario, and per assumption the share lost at each of its levels
    (over every scenario), the assumption that separates them best first."""
    lost = sum(sum(flags) for flags in failed.values())
    total = sum(len(flags) for flags in failed.values())
    lines = [
        f"{lost} of {total} runs ended at a stroke limit ("
        + ", ".join(f"{scenario}: {sum(flags)}" for scenario, flags in failed.items())
        + ")."
    ]
    if not lost:
        return lines
    spread = []
    for key in keys:
        shares = []
        for level in sorted({point[key] for point in points}):
            at = [f for flags in failed.values() for point, f in zip(points, flags, strict=True) if point[key] == level]
            shares.append((level, sum(at) / len(at)))
        spread.append((max(v for _, v in shares) - min(v for _, v in shares), key, shares))
    spread.sort(key=lambda item: -item[0])
    rows = [
        [f"`{key}`", ", ".join(f"{level:.4g}: {share:.0%}" for level, share in shares)] for _, key, shares in spread
    ]
    return [*lines, "", *markdown_table(["assumption", "share lost at each of its levels"], rows)]


def _draw(ranking: dict, keys: list[str], scenarios: list[str], folder: Path) -> None:
    """sensitivity.png: each quantity's mu* per assumption, a bar per scenario."""
    figure = figure_class()(figsize=(10, 2.2 * len(QUANTITIES)), layout="constrained")
    panels = figure.subplots(len(QUANTITIES), 1)
    for ax, (label, unit_name, _, _) in zip(panels, QUANTITIES, strict=True):
        shown = [s for s in scenarios if (label, s) in ranking]
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
