"""Study (a): the control period against the speed loop's bandwidth, per controller."""

from __future__ import annotations

import math
from pathlib import Path

import pyarrow as pa

from microg_env.analysis.formatting import MISSING, format_number
from microg_env.analysis.plots import figure_class, save_figure
from microg_env.experiments.studies.groups import (
    failed,
    finite,
    grouped,
    markdown_table,
    page_header,
    successes,
)
from microg_env.experiments.tuning import RETUNE_KI

#: The swept columns the page reads.
BANDWIDTH = "servo.speed_loop_gain_hz"
COLUMNS = (BANDWIDTH,)
KEYS = ["controller", "control_period_us", BANDWIDTH]
#: The metrics of the page's table and figure: (column, scale to the printed unit, printed as).
ERROR = "summary_compensation_error"
GRAVITY = "summary_residual_gravity_g"
FREE_FALL = "flexible_unit_excursion_free_fall_m"
COLLISION = "flexible_unit_excursion_collision_m"
FIGURE_PANELS = (
    (ERROR, 1.0, "|compensation error| (%)"),
    (FREE_FALL, 1e6, "max |x| in free fall (µm)"),
    (COLLISION, 1e6, "max |x| at the collision (µm)"),
)
HEADER = [
    "controller",
    "period (µs)",
    "speed loop (Hz)",
    "\\|compensation error\\| (%)",
    "residual gravity error (g)",
    "x in free fall, mean / worst (µm)",
    "x at the collision, mean / worst (µm)",
    "failures",
    "re-tuned Kp (1/s), Ki (1/s²)",
]


def render(campaign, table: pa.Table, folder: Path) -> list[str]:
    ok = finite(successes(table), ERROR, GRAVITY, FREE_FALL, COLLISION)
    cells = grouped(
        ok,
        KEYS,
        [
            (ERROR, "mean"),
            (GRAVITY, "mean"),
            (FREE_FALL, "mean"),
            (FREE_FALL, "max"),
            (COLLISION, "mean"),
            (COLLISION, "max"),
            ("tuned_kp_per_s", "first"),
            ("tuned_ki_per_s2", "first"),
        ],
    )
    failures = grouped(failed(table), KEYS, [("failed", "sum")])
    groups = _groups(campaign)
    controllers = list(dict.fromkeys(controller for controller, _, _ in groups))
    periods = sorted({period for _, period, _ in groups}, reverse=True)
    bandwidths = sorted({bandwidth for _, _, bandwidth in groups})

    rows = []
    for group in groups:
        cell = cells.get(group, {})
        failures_of = failures.get(group)
        kp, ki = cell.get("tuned_kp_per_s_first"), cell.get("tuned_ki_per_s2_first")
        rows.append(
            [
                group[0],
                f"{group[1]:g}",
                f"{group[2]:g}",
                format_number(cell.get(f"{ERROR}_mean"), ".3f"),
                format_number(cell.get(f"{GRAVITY}_mean"), ".1e"),
                f"{format_number(cell.get(f'{FREE_FALL}_mean'), '.2f', 1e6)} / "
                f"{format_number(cell.get(f'{FREE_FALL}_max'), '.2f', 1e6)}",
                f"{format_number(cell.get(f'{COLLISION}_mean'), '.2f', 1e6)} / "
                f"{format_number(cell.get(f'{COLLISION}_max'), '.2f', 1e6)}",
                MISSING if failures_of is None else str(failures_of["failed_sum"]),
                f"{kp:g}, {ki:g}" if kp is not None else MISSING,
            ]
        )
    lines = page_header(campaign, table, folder) + markdown_table(HEADER, rows) + [""]
    lines += _findings(ok, cells, controllers, periods, bandwidths)
    _draw(cells, controllers, periods, bandwidths, folder)
    return [
        *lines,
        "",
        "![Errors and excursions against control period and speed-loop bandwidth](period_bandwidth.png)",
        "",
    ]


def _groups(campaign) -> list[tuple]:
    """The page's groups, (controller, period, bandwidth), of the campaign's runs (a group whose
    runs all failed included): the controllers in the campaign's order, then the periods longest
    first, then the bandwidths lowest first."""
    found = dict.fromkeys(
        (run.spec.controller, run.spec.control_period_us, run.columns[BANDWIDTH]) for run in campaign.runs()
    )
    controllers = list(dict.fromkeys(controller for controller, _, _ in found))
    return sorted(found, key=lambda group: (controllers.index(group[0]), -group[1], group[2]))


def _findings(ok: pa.Table, cells: dict, controllers: list, periods: list, bandwidths: list) -> list[str]:
    """The worst residual gravity, each controller's range of x at the collision, and where the
    re-tuned Ki sits at the edge of its grid."""
    lines = []
    worst_gravity = max(ok[GRAVITY].drop_null().to_pylist(), default=math.nan)
    if math.isfinite(worst_gravity):
        lines.append(
            f"- Largest residual gravity error of any run: {worst_gravity:.1e} g "
            f"({'below' if worst_gravity < 1e-4 else 'above'} the 10⁻⁴ g level)."
        )
    for controller in controllers:
        points = [
            (cells[controller, p, b][f"{COLLISION}_mean"], p, b)
            for p in periods
            for b in bandwidths
            if cells.get((controller, p, b), {}).get(f"{COLLISION}_mean") is not None
        ]
        if points:
            (low, p_low, b_low), (high, p_high, b_high) = min(points), max(points)
            lines.append(
                f"- `{controller}`: x at the collision from {high * 1e6:.2f} µm ({p_high:g} µs, {b_high:g} Hz) "
                f"to {low * 1e6:.2f} µm ({p_low:g} µs, {b_low:g} Hz)."
            )
    edge = sorted({(p, b) for (_, p, b), cell in cells.items() if cell["tuned_ki_per_s2_first"] == max(RETUNE_KI)})
    if edge:
        where = ", ".join(f"{p:g} µs / {b:g} Hz" for p, b in edge)
        lines.append(
            f"- The re-tuned Ki sits at the top of the tuning grid ({max(RETUNE_KI):g} 1/s²) at {where}: "
            "there a wider grid might lower the PID's numbers further."
        )
    return lines


def _draw(cells: dict, controllers: list, periods: list, bandwidths: list, folder: Path) -> None:
    """period_bandwidth.png: each metric's mean against the period, a line per controller and
    bandwidth, on log axes (a panel no run gave a positive value says so instead)."""
    figure = figure_class()(figsize=(11, 4.2))
    axes = figure.subplots(1, 3)
    for ax, (column, scale, label) in zip(axes, FIGURE_PANELS, strict=True):
        reached = False
        for controller, style in zip(controllers, ("-o", "--s", ":^"), strict=False):
            for bandwidth in bandwidths:
                means = [cells.get((controller, p, bandwidth), {}).get(f"{column}_mean") for p in periods]
                values = [math.nan if mean is None else mean * scale for mean in means]
                ax.plot(periods, values, style, label=f"{controller}, {bandwidth:g} Hz")
                reached |= any(value > 0 for value in values)
        if reached:
            ax.set_xscale("log")
            ax.set_yscale("log")
        else:
            ax.text(0.5, 0.5, "no run gave a value", transform=ax.transAxes, ha="center", va="center")
            ax.set_xticks([])
            ax.set_yticks([])
        ax.set_xlabel("control period (µs)")
        ax.set_title(label, fontsize=9)
        ax.invert_xaxis()
    axes[0].legend(fontsize=7)
    figure.tight_layout()
    save_figure(figure, folder / "period_bandwidth.png")
