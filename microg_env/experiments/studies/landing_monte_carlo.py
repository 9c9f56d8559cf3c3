"""Study (c): a Monte Carlo landing campaign, each controller's metrics over scenarios, plants and seeds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from microg_env.analysis.formatting import MISSING
from microg_env.analysis.plots import figure_class, save_figure
from microg_env.experiments.studies.groups import (
    failed,
    finite,
    grouped,
    in_order,
    markdown_table,
    page_header,
    successes,
)

#: The swept columns the page reads.
COLUMNS: tuple[str, ...] = ()
COLLISION = "flexible_unit_excursion_collision_m"
#: The page's metrics: (column, scale to the printed unit, label, format); the first three are drawn.
QUANTITIES = (
    ("summary_compensation_error", 1.0, "\\|compensation error\\| (%)", ".3f"),
    ("flexible_unit_excursion_free_fall_m", 1e6, "x in free fall (µm)", ".2f"),
    (COLLISION, 1e6, "x at the collision (µm)", ".2f"),
    ("summary_deformation_error", 100.0, "\\|peak deformation − ideal\\| (%)", ".4f"),
    ("restitution", 1.0, "restitution", ".3f"),
)


def render(campaign, table: pa.Table, folder: Path) -> list[str]:
    ok = finite(successes(table), *(column for column, *_ in QUANTITIES))
    by_controller = grouped(ok, ["controller"], [("controller", "count"), *((c, "list") for c, *_ in QUANTITIES)])
    failures = grouped(failed(table), ["controller"], [("failed", "sum")])
    by_scenario = grouped(ok, ["controller", "scenario"], [(COLLISION, "list")])
    controllers, scenarios = in_order(ok, "controller"), in_order(ok, "scenario")

    rows = []
    for controller in controllers:
        cell = by_controller[controller,]
        cells = [_spread(cell[f"{column}_list"], scale, spec) for column, scale, _, spec in QUANTITIES]
        failures_of = failures.get((controller,), {}).get("failed_sum", 0)
        rows.append([controller, str(cell["controller_count"]), str(failures_of), *cells])
    lines = page_header(campaign, table, folder)
    lines += ["Per controller over every scenario, plant and seed: mean, 5th–95th percentile and worst.", ""]
    lines += markdown_table(["controller", "runs", "failures", *(label for _, _, label, _ in QUANTITIES)], rows)
    lines += ["", "x at the collision by scenario, µm: mean (worst)", ""]
    rows = []
    for controller in controllers:
        cells = []
        for scenario in scenarios:
            values = _values(by_scenario.get((controller, scenario), {}).get(f"{COLLISION}_list", []), 1e6)
            cells.append(f"{values.mean():.2f} ({values.max():.2f})" if values.size else MISSING)
        rows.append([controller, *cells])
    lines += markdown_table(["controller", *scenarios], rows)
    _draw(by_controller, controllers, folder)
    return [*lines, "", "![Distributions of the landing metrics by controller](landing_monte_carlo.png)", ""]


def _values(listed: list, scale: float) -> np.ndarray:
    """A group's values of one metric in the printed unit, those a run did not reach left out."""
    return np.array([v * scale for v in listed if v is not None])


def _spread(listed: list, scale: float, spec: str) -> str:
    """Mean (5th–95th percentile; worst)."""
    values = _values(listed, scale)
    if not values.size:
        return MISSING
    p5, p95 = np.percentile(values, [5, 95])
    return f"{values.mean():{spec}} ({p5:{spec}}–{p95:{spec}}; {values.max():{spec}})"


def _draw(by_controller: dict, controllers: list, folder: Path) -> None:
    """landing_monte_carlo.png: box plots (5th–95th percentile whiskers) of the first three metrics."""
    figure = figure_class()(figsize=(11, 4))
    axes = figure.subplots(1, 3)
    for ax, (column, scale, label, _) in zip(axes, QUANTITIES[:3], strict=True):
        ax.boxplot([_values(by_controller[c,][f"{column}_list"], scale) for c in controllers], whis=(5, 95))
        ax.set_xticks(range(1, len(controllers) + 1), controllers, fontsize=7, rotation=20, ha="right")
        ax.set_yscale("log")
        ax.set_title(label.replace("\\", ""), fontsize=9)
    figure.tight_layout()
    save_figure(figure, folder / "landing_monte_carlo.png")
