"""Study (e): the transmission's compliance. The belt and the screw as one spring between motor and
support (``ScrewStageParams.transmission_stiffness_n_per_m``), from rigid (the model's default
assumption) to soft, per controller: how much the rigid default flatters each excursion."""

from __future__ import annotations

import math
from pathlib import Path

import pyarrow as pa

from microg_env.analysis.formatting import format_number
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

STIFFNESS = "screw.transmission_stiffness_n_per_m"
#: The swept columns the page reads.
COLUMNS = (STIFFNESS,)
#: The estimate of params.py (ScrewStageParams): the stiffness the findings read.
ESTIMATE_N_PER_M = 1e8
#: The metrics of the page: (column, scale to the printed unit, format, printed as).
METRICS = (
    ("summary_free_fall_excursion_m", 1e6, ".3f", "x in free fall (µm)"),
    ("summary_collision_excursion_m", 1e6, ".3f", "x at the collision (µm)"),
    ("summary_collision_instant_m", 1e6, ".3f", "Δx, first 5 ms of contact (µm)"),
    ("summary_compensation_error", 1.0, ".4f", "\\|compensation error\\| (%)"),
)
KEYS = ["controller", STIFFNESS]


def _stiffness(value: float) -> str:
    return "rigid" if math.isinf(value) else f"{value:.0e} N/m".replace("e+0", "e")


def render(campaign, table: pa.Table, folder: Path) -> list[str]:
    ok = finite(successes(table), *(column for column, *_ in METRICS))
    cells = grouped(ok, KEYS, [(column, "mean") for column, *_ in METRICS])
    failures = grouped(failed(table), KEYS, [("failed", "sum")])
    controllers = in_order(ok, "controller")
    stiffnesses = sorted(set(ok[STIFFNESS].to_pylist()), reverse=True)  # rigid first
    header = ["controller", "transmission", *(f"{label}: mean, change" for *_, label in METRICS), "failures"]
    rows = []
    for controller in controllers:
        rigid = cells.get((controller, math.inf), {})
        for stiffness in stiffnesses:
            cell = cells.get((controller, stiffness), {})
            row = [f"`{controller}`", _stiffness(stiffness)]
            for column, scale, form, _ in METRICS:
                value, base = cell.get(f"{column}_mean"), rigid.get(f"{column}_mean")
                change = "" if math.isinf(stiffness) or not base else f", {_change(value / base)}"
                row.append(format_number(value, form, scale) + change)
            row.append(str(failures.get((controller, stiffness), {}).get("failed_sum", 0)))
            rows.append(row)
    lines = page_header(campaign, table, folder) + markdown_table(header, rows) + [""]
    lines += _findings(cells, controllers)
    lines += _softest(cells, failures, controllers, stiffnesses)
    _draw(cells, controllers, stiffnesses, folder)
    return [
        *lines,
        "",
        "![Excursions against the transmission's stiffness, per controller](transmission.png)",
        "",
    ]


def _change(ratio: float) -> str:
    """A ratio to the rigid transmission's value: a percentage, or a factor past 10 times."""
    return f"×{ratio:.0f}" if ratio >= 10 else f"{(ratio - 1) * 100:+.1f} %"


def _findings(cells: dict, controllers: list) -> list[str]:
    """At the estimate: each controller's excursions against the rigid transmission's."""
    lines = [f"At the estimate ({_stiffness(ESTIMATE_N_PER_M)}), against the rigid transmission (means over the runs):"]
    for controller in controllers:
        rigid, estimate = cells.get((controller, math.inf)), cells.get((controller, ESTIMATE_N_PER_M))
        if not rigid or not estimate:
            continue
        changes = [
            f"{label[: label.index(' (')]} {_change(estimate[f'{column}_mean'] / rigid[f'{column}_mean'])}"
            for column, _, _, label in METRICS[:3]
        ]
        lines.append(f"- `{controller}`: " + ", ".join(changes) + ".")
    return lines


def _softest(cells: dict, failures: dict, controllers: list, stiffnesses: list) -> list[str]:
    """At the softest transmission: each controller's x at the collision and its lost runs (the
    means include the runs that ended at a stroke limit)."""
    softest = min(stiffnesses)
    if math.isinf(softest):
        return []
    parts = []
    for controller in controllers:
        value = cells.get((controller, softest), {}).get(f"{METRICS[1][0]}_mean")
        lost = failures.get((controller, softest), {}).get("failed_sum", 0)
        parts.append(f"`{controller}` {format_number(value, '.1f', 1e6)} µm ({lost} runs lost)")
    return [
        "",
        f"At {_stiffness(softest)} (the means include the runs that lost the lander), x at the collision: "
        + ", ".join(parts)
        + ".",
    ]


def _draw(cells: dict, controllers: list, stiffnesses: list, folder: Path) -> None:
    """transmission.png: each excursion's mean against the finite stiffnesses (log axis), a line
    per controller, its rigid value a dotted level."""
    finite_k = sorted(k for k in stiffnesses if math.isfinite(k))
    figure = figure_class()(figsize=(11, 4.0), layout="constrained")
    axes = figure.subplots(1, 3)
    for ax, (column, scale, _, label) in zip(axes, METRICS[:3], strict=True):
        for controller, marker in zip(controllers, "osd^v", strict=False):
            values = [cells.get((controller, k), {}).get(f"{column}_mean") for k in finite_k]
            line = ax.plot(finite_k, [v * scale for v in values], f"-{marker}", label=f"{controller}")[0]
            rigid = cells.get((controller, math.inf), {}).get(f"{column}_mean")
            if rigid is not None:
                ax.axhline(rigid * scale, ls=":", color=line.get_color())
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("transmission stiffness (N/m); dotted: rigid")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)
    save_figure(figure, folder / "transmission.png")
