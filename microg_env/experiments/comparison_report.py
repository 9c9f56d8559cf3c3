"""The comparison as Markdown, JSON and figures (``microg compare --out``); it computes nothing that
:mod:`microg_env.experiments.comparison` does not."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from microg_env.analysis.formatting import format_number
from microg_env.analysis.paired import Paired
from microg_env.analysis.plots import figure_class, save_figure
from microg_env.experiments.comparison import QUANTITIES, X_WINDOW_S, Comparison
from microg_env.experiments.comparison_settings import CONFIRMATION_SEED
from microg_env.files import check_output_folder, replace_folder

#: What a comparison folder holds.
COMPARISON_FILES = ("comparison.md", "comparison.json", "x_landing.png", "metrics.png")
#: The controller the others are measured against, where it is compared.
BASELINE = "pid"


def _spec(value: float) -> str:
    """Three significant figures, fixed-point where it reads well."""
    magnitude = abs(value)
    if magnitude == 0 or not math.isfinite(magnitude):
        return ".3g"
    return ".2e" if magnitude < 1e-3 or magnitude >= 1e4 else ".3g"


def _summary_cell(c: Comparison, controller: str, name: str, scenario: str | None = None) -> str:
    quantity, s = QUANTITIES[name], c.summary(controller, name, scenario)
    if not math.isfinite(s.mean):
        return "-"
    spec = _spec(s.mean * quantity.scale)
    return (
        f"{format_number(s.mean, spec, quantity.scale)} ± {format_number(s.std, spec, quantity.scale)} "
        f"({format_number(s.worst, spec, quantity.scale)})"
    )


#: What the floor rows are (:data:`~microg_env.experiments.comparison.FLOORS`), in words.
FLOOR_TEXT = (
    "The floor rows are reference points, not controllers and not bounds: `oracle`, told each episode's plant, "
    "on the same episode with the drive a perfect speed source (`floor-ideal-drive`) or without cogging and "
    "friction (`floor-no-cogging-friction`); the control delay and the sensors' noise stay. They show what is "
    "left once the drive's imperfections go."
)
#: The sensor sets in words.
SENSORS = {
    "extended": "every sensor (grating ruler, encoder, pad force, accelerometer)",
    "paper": "the paper's sensors (grating ruler and encoder; no pad force, no accelerometer)",
}


def _paired_cell(p: Paired) -> str:
    if not p.episodes:
        return "-"
    return f"{p.ratio:.3g} [{p.ratio_low:.3g}, {p.ratio_high:.3g}], wins {p.wins:.0%}, p = {p.sign_p:.2g}"


def _ratio_cell(p: Paired) -> str:
    if not p.episodes:
        return "-"
    return f"{p.ratio:.3g} [{p.ratio_low:.3g}, {p.ratio_high:.3g}], p = {p.sign_p:.2g}"


def render_markdown(c: Comparison) -> str:
    """The headline table (mean ± std (worst) over scenarios and seeds), ratios to the PID, and the
    per-scenario means."""
    plant = {
        False: "the nominal plant",
        True: "randomised plants (lander, pad, friction, weights drawn from each seed)",
        "full": "randomised plants and drives (lander, pad, friction, weights, cogging, motor friction law, "
        "speed loop, torque filter drawn from each seed)",
        "wider": "randomised plants and drives from ranges 1.5 times wider than training's (lander, pad, friction, "
        "weights, cogging, motor friction law, speed loop, torque filter drawn from each seed)",
    }[c.randomize]
    lines = ["# Controller comparison", ""]
    if c.first_seed == CONFIRMATION_SEED:
        lines += [
            "These are the confirmation seeds: run once per release, after every design decision, never to make one.",
            "",
        ]
    own_plant = ", so each episode meets a plant of its own" if c.randomize else ""
    changed = ", ".join(f"`{path}` = {value!r}" for path, value in c.overrides.items())
    rig = f" The rig is the paper's with {changed}." if changed else ""
    lines += [
        f"Controllers {', '.join(c.controllers)} on the same scenarios and seeds "
        f"({_count(c.seeds_per_scenario, 'seed')} per scenario, each scenario its own{own_plant}), {plant}, "
        f"every imperfection on, {SENSORS[c.sensor_set]}, control period "
        f"{c.control_period_s * 1e6:g} us, physics step {c.physics_step_s * 1e6:g} us.{rig} Every scenario is held out "
        "of training:",
        "",
    ]

    for name, scenario in c.scenarios.items():
        duration = scenario.duration_s if c.duration_s is None else min(scenario.duration_s, c.duration_s)
        seeds = c.seeds[name]
        lines.append(
            f"- `{name}`: {scenario.loads_text}; from {scenario.descent_height_m * 1e3:g} mm; {duration:g} s; "
            f"seeds {seeds[0]}-{seeds[-1]}"
        )
    if c.floors:
        lines += ["", FLOOR_TEXT]
    lines += [
        "",
        "Mean ± std (worst) over every scenario and seed; failures are episodes ended at a stroke limit.",
        "",
        "| controller | " + " | ".join(f"{q.label} [{q.unit}]" for q in QUANTITIES.values()) + " | failures |",
        "|---|" + "---|" * (len(QUANTITIES) + 1),
    ]
    for controller in c.rows:
        cells = [_summary_cell(c, controller, name) for name in QUANTITIES]
        lines.append(f"| {controller} | " + " | ".join(cells) + f" | {c.failure_rate(controller):.0%} |")
    if BASELINE in c.controllers and len(c.rows) > 1:
        lines += [
            "",
            f"Mean of each metric relative to `{BASELINE}`'s (below 1 is better):",
            "",
            "| controller | " + " | ".join(q.label for q in QUANTITIES.values()) + " |",
            "|---|" + "---|" * len(QUANTITIES),
        ]
        for controller in c.rows:
            if controller == BASELINE:
                continue
            ratios = []
            for name in QUANTITIES:
                mine, theirs = c.summary(controller, name).mean, c.summary(BASELINE, name).mean
                ratio = mine / theirs if theirs else math.nan
                ratios.append(format_number(ratio, ".3g"))
            lines.append(f"| {controller} | " + " | ".join(ratios) + " |")
    if c.reference is not None and len(c.rows) > 1:
        lines += [
            "",
            f"Paired against `{c.reference}` on the same scenarios and seeds: ratio of means [95 % interval, "
            "resampling seeds], share of episodes won, and the sign test's p over the seeds' mean differences:",
            "",
            "| controller | " + " | ".join(q.label for q in QUANTITIES.values()) + " |",
            "|---|" + "---|" * len(QUANTITIES),
        ]
        for controller in c.rows:
            if controller != c.reference:
                cells = [_paired_cell(c.paired(controller, name)) for name in QUANTITIES]
                lines.append(f"| {controller} | " + " | ".join(cells) + " |")
    if c.reference is not None and len(c.rows) > 1 and len(c.scenarios) > 1:
        quantity = QUANTITIES["collision_excursion_m"]
        lines += [
            "",
            f"{quantity.label}, paired against `{c.reference}` per scenario: ratio of means [95 % interval] and "
            "the sign test's p:",
            "",
            "| controller | " + " | ".join(f"`{s}`" for s in c.scenarios) + " |",
            "|---|" + "---|" * len(c.scenarios),
        ]
        for controller in c.rows:
            if controller != c.reference:
                cells = [_ratio_cell(c.paired(controller, "collision_excursion_m", scenario=s)) for s in c.scenarios]
                lines.append(f"| {controller} | " + " | ".join(cells) + " |")
    for name in ("collision_excursion_m", "compensation_error"):
        quantity = QUANTITIES[name]
        lines += [
            "",
            f"{quantity.label} [{quantity.unit}] per scenario, mean ± std (worst):",
            "",
            "| controller | " + " | ".join(f"`{s}`" for s in c.scenarios) + " |",
            "|---|" + "---|" * len(c.scenarios),
        ]
        for controller in c.rows:
            cells = [_summary_cell(c, controller, name, s) for s in c.scenarios]
            lines.append(f"| {controller} | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"Figures: `x_landing.png` (the peak |x| in each {PEAK_WINDOW_S * 1e3:g} ms around the first touchdown, "
        "each scenario's first seed), `metrics.png` (each metric's "
        f"ratio to `{plot_reference(c)}`'s on the same episodes, with its 95 % interval; a ratio beyond "
        f"{OFF_SCALE:g} is an arrow with its value, an interval running past the panel ends in one). Every case's "
        "values: `comparison.json`.",
        "",
    ]
    return "\n".join(lines)


#: x_landing.png draws each controller's peak |x| in windows of this length, s: the excursions the
#: metrics read, not the oscillation between them, which drawn as x turns ten controllers into one
#: band.
PEAK_WINDOW_S = 0.05
#: x_landing.png's vertical axis, µm, in decades: the PID's 10 µm and the learned 0.1 µm in one panel.
PEAK_LIMITS_UM = (0.001, 30.0)
PEAK_TICKS_UM = (0.001, 0.01, 0.1, 1.0, 10.0)
#: What x_landing.png's title says of the plants, by ``Comparison.randomize``.
PLANT_TITLES = {
    False: "",
    True: ", randomised plant",
    "full": ", randomised plant and drive",
    "wider": ", plant and drive from ranges wider than training's",
}


def windowed_peak(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The edges of consecutive :data:`PEAK_WINDOW_S` windows over :data:`X_WINDOW_S` and the peak
    |x| in each (NaN where no sample falls); a window holds its start, not its end, and the last
    one both."""
    start, end = X_WINDOW_S
    count = round((end - start) / PEAK_WINDOW_S)
    edges = np.linspace(start, end, count + 1)
    # each sample's window, its position rounded to 1e-9 windows so that a sample on an edge is not
    # put in the window before by the float error of t - start
    index = np.floor(np.round((t - start) / PEAK_WINDOW_S, 9)).astype(np.int64)
    index[t == end] = count - 1
    inside = (index >= 0) & (index < count)
    peaks = np.full(count, -np.inf)
    np.maximum.at(peaks, index[inside], np.abs(x[inside]))
    peaks[peaks == -np.inf] = np.nan
    return edges, peaks


def render_figures(c: Comparison) -> dict[str, object]:
    """``x_landing.png``: each controller's peak |x| in each :data:`PEAK_WINDOW_S` from 1 s before
    to 3 s after the touchdown, one panel per scenario; ``metrics.png``: :func:`paired_figure`."""
    figure_type = figure_class()
    n = len(c.scenarios)
    landing = figure_type(figsize=(9, 2.4 * n), layout="constrained")
    axes = np.atleast_1d(landing.subplots(n, 1, sharex=True))
    for ax, scenario in zip(axes, c.scenarios, strict=True):
        for i, controller in enumerate(c.rows):
            for result in c.runs(controller, scenario):
                if result.x_window is not None:
                    edges, peaks = windowed_peak(*result.x_window)
                    ax.stairs(peaks * 1e6, edges, baseline=None, lw=1.2, color=row_colour(c, i), label=controller)
        ax.axvline(0.0, color="k", lw=0.5)
        ax.set_yscale("log")
        ax.set_ylim(*PEAK_LIMITS_UM)
        ax.set_yticks(PEAK_TICKS_UM, [f"{tick:g}" for tick in PEAK_TICKS_UM])
        ax.set_ylabel(f"peak |x| per {PEAK_WINDOW_S * 1e3:g} ms [µm]")
        ax.set_title(scenario, fontsize=9)
        ax.grid(alpha=0.3)
    if axes[0].get_legend_handles_labels()[0]:  # no touchdown, no line
        axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time from the first touchdown [s]")
    axes[-1].set_xlim(*X_WINDOW_S)
    landing.suptitle(f"x during the landing, each scenario's first seed{PLANT_TITLES[c.randomize]}")

    return {"x_landing.png": landing, "metrics.png": paired_figure(c)}


#: A ratio past this many times the reference's mean is drawn as an arrow at the panel's edge with
#: its value written, and an interval reaching past it ends in an arrow at the edge, so that the
#: PID's 30 times does not flatten the sub-µm controllers' intervals around 1.
OFF_SCALE = 4.0


def row_colour(c: Comparison, row: int):
    """The colour of row ``row`` of ``c.rows`` in both figures: matplotlib's ten cycle colours while
    they suffice, else tab20's twenty, so that no two rows share one."""
    if len(c.rows) <= 10:
        return f"C{row}"
    from matplotlib import colormaps

    return colormaps["tab20"](row % 20)


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def plot_reference(c: Comparison) -> str:
    """The controller metrics.png pairs the others against: ``--reference``, else the PID, else the
    first."""
    return c.reference or (BASELINE if BASELINE in c.controllers else c.controllers[0])


def paired_figure(c: Comparison, size: tuple[float, float] | None = None):
    """``metrics.png``: one panel per metric, each controller's ratio of means to the reference on
    the same episodes, with its 95 % interval resampling seeds (:mod:`microg_env.analysis.paired`),
    on a linear axis with the reference's 1 marked."""
    reference = plot_reference(c)
    others = [name for name in c.rows if name != reference]
    height = 1.3 + 0.4 * max(len(others), 1)
    columns = math.ceil(len(QUANTITIES) / 2)
    figure = figure_class()(figsize=size or (3.4 * columns, 2 * height), layout="constrained")
    panels = figure.subplots(2, columns, sharey=True).ravel()
    for ax, (name, quantity) in zip(panels, QUANTITIES.items(), strict=True):
        found = [(row, c.paired(other, name, reference)) for row, other in enumerate(others)]
        found = [(row, p) for row, p in found if p.episodes and math.isfinite(p.ratio)]
        # each point on the scale shows its interval, cut at OFF_SCALE; a point past it is an arrow
        shown = [x for _, p in found if p.ratio <= OFF_SCALE for x in (p.ratio_low, min(p.ratio_high, OFF_SCALE))]
        low = min([1.0, *shown])
        left = low * 0.9 if low > 0.5 else 0.0  # from 0 unless every interval is close to 1
        right = max([1.0, *shown]) * 1.1
        for row, p in found:
            color = row_colour(c, c.rows.index(others[row]))
            if p.ratio > right:  # off the scale: an arrow at the edge and the value
                ax.plot(right, row, ">", color=color, ms=7)
                ax.annotate(f"{p.ratio:.3g}×", (right, row), xytext=(-6, 5), textcoords="offset points", ha="right")
                continue
            cut = p.ratio_high > right  # the interval runs on past the panel: it ends in an arrow there
            high = right if cut else p.ratio_high
            ax.errorbar(p.ratio, row, xerr=[[p.ratio - p.ratio_low], [high - p.ratio]], fmt="o", color=color, capsize=3)
            if cut:
                ax.plot(right, row, ">", color=color, ms=5)
        ax.axvline(1.0, color="k", lw=0.8)
        ax.set_xlim(left, right)
        ax.set_title(f"{quantity.label} [{quantity.unit}]", fontsize=9)
        ax.set_xlabel(f"ratio to {reference}'s mean", fontsize=8)
        ax.grid(alpha=0.3, axis="x")
    panels[0].set_yticks(range(len(others)), others)
    panels[0].set_ylim(max(len(others), 1) - 0.5, -0.5)
    if not others:
        for ax in panels:
            ax.text(0.5, 0.5, "one controller: nothing to pair", ha="center", va="center", transform=ax.transAxes)
    figure.suptitle(
        f"Paired against {reference} on the same {_count(len(c.scenarios), 'scenario')} × "
        f"{_count(c.seeds_per_scenario, 'seed')} each{PLANT_TITLES[c.randomize]}:\n"
        "ratio of means and its 95 % interval resampling seeds (below 1 is better)",
        fontsize=10,
    )
    return figure


def check_output(out: str | Path) -> None:
    """Raise ValueError if ``out`` cannot take a comparison (before any run)."""
    check_output_folder(out, "--out", COMPARISON_FILES, "a comparison")


def write(c: Comparison, out: str | Path) -> Path:
    """Write the Markdown, the JSON and the figures into ``out``, replacing it only when complete."""
    check_output(out)

    def fill(staging: Path) -> None:
        (staging / "comparison.md").write_text(render_markdown(c), encoding="utf-8")
        (staging / "comparison.json").write_text(json.dumps(c.as_dict(), indent=2) + "\n", encoding="utf-8")
        for name, figure in render_figures(c).items():
            save_figure(figure, staging / name)

    return replace_folder(Path(os.path.abspath(out)), fill)
