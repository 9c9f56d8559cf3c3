"""Study (f): the controllers' ranking over the plant's unknowns. A Morris design (SALib) over rig
parameters, run by several controllers (the sweep's ``controller``) on several schedules: at each
design point a controller's headline quantity is its mean over the schedules and seeds, and its
ratio to the sweep's first controller (the reference) is the quotient of the two means, as a
comparison's headline ratio is. The page gives each quantity's and each ratio's spread over the
design, and ranks the unknowns by Morris's mu* of the ratio: which unknown moves the ranking."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa

from microg_env.analysis.plots import figure_class, save_figure
from microg_env.experiments.studies import sensitivity
from microg_env.experiments.studies.groups import markdown_table, page_header
from microg_env.validate import shown

#: The swept columns the page reads.
COLUMNS = ("controller",)
#: The headline quantities: (label, column), in µm.
QUANTITIES = (
    ("x at the collision", "flexible_unit_excursion_collision_m"),
    ("x in free fall", "flexible_unit_excursion_free_fall_m"),
)
#: Bootstrap resamples of mu*'s interval.
RESAMPLES = 1000

INTRO = """\
A Morris design (SALib): {trajectories} trajectories x ({assumptions} assumptions + 1) points on a {levels}-level \
grid. At each point every controller runs every schedule ({schedules}) on seed{s} {seeds}: {runs} runs. \
A controller's quantity at a point is its mean over those runs; a point counts where none was lost. \
The ratios are to `{reference}`, the sweep's first controller. A point the design repeats counts once per \
repeat in the medians, ranges and shares below, and its runs once in the runs lost. The ranges:
"""
SPREAD_INTRO = """\
The spread is over the design's points (a grid that covers the ranges, not a probability sample): the median, \
and the smallest to the largest. mu* is the quantity's change for one assumption moved over its whole range, \
from the trajectories whose every point counts; ± is SALib's bootstrap 95 % half-width over them \
({resamples} resamples), sigma the spread of the elementary effects (as large as mu*: the effect depends on the \
other assumptions).
"""
RATIO_INTRO = """\
A ratio is the controller's mean over the schedules divided by the reference's, at each point; its mu* and \
sigma as above, in the ratio's unit.
"""


def check(campaign) -> None:
    """ValueError unless ``campaign`` is a Morris design over rig parameters (:func:`sensitivity.check`)
    that sweeps two or more controllers, the reference first."""
    sensitivity.check(campaign)
    controllers = campaign.sweep.get("controller")
    if not isinstance(controllers, list) or len(controllers) < 2:
        raise ValueError("report 'controller-sensitivity' compares controllers: sweep controller: [reference, ...]")
    others = [key for key in campaign.sweep if key not in ("controller", "scenario")]
    if others:
        raise ValueError(
            f"report 'controller-sensitivity' pools each controller's schedules at a design point; it sweeps "
            f"controller and scenario only, not {shown(others[0])}"
        )


def _means(campaign, table: pa.Table) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, tuple[int, int]]]:
    """Each controller's quantity at each design point ({controller: {column: (points,) in µm}}, NaN
    where a run of the point was lost), and each controller's (lost, total) runs, a run that the
    design repeats counted once."""
    design, stored = sensitivity.design_rows(campaign, table)
    hashes: dict[str, list[list[str]]] = {}  # per controller: per schedule and seed, each point's run
    for point, runs, _ in design:
        hashes.setdefault(point["controller"], []).append(runs)
    means, lost = {}, {}
    for controller, runs in hashes.items():
        rows = [[stored.get(h) for h in per_run] for per_run in runs]
        failed = np.array([[row is None or row["termination_reason"] is not None for row in r] for r in rows])
        by_run = dict(zip((h for per_run in runs for h in per_run), failed.ravel(), strict=True))  # repeats once
        lost[controller] = (int(sum(by_run.values())), len(by_run))
        means[controller] = {}
        for _, column in QUANTITIES:
            values = np.array([[sensitivity.stored_value(row, column) for row in r] for r in rows])
            means[controller][column] = np.where(failed, np.nan, values).mean(axis=0) * 1e6
    return means, lost


def render(campaign, table: pa.Table, folder: Path) -> list[str]:
    draw = campaign.samples["draw"]
    keys, levels = list(draw), campaign.samples.get("levels", 4)
    means, lost = _means(campaign, table)
    controllers = list(means)
    reference = controllers[0]
    seeds = campaign.seeds
    lines = page_header(campaign, table, folder)
    lines += INTRO.format(
        trajectories=campaign.samples["trajectories"],
        assumptions=len(keys),
        levels=levels,
        schedules=", ".join(campaign.sweep.get("scenario", [])) or "the base's",
        s="s" if len(seeds) > 1 else "",
        seeds=", ".join(map(str, seeds)),
        runs=table.num_rows,
        reference=reference,
    ).splitlines()
    lines.append("")
    lines += sensitivity.ranges_table(campaign)

    unit = campaign.morris_design()
    ranked = _Ranking(keys, levels, unit)
    lines += ["", "## Each controller over the ranges", "", *SPREAD_INTRO.format(resamples=RESAMPLES).splitlines(), ""]
    rows = []
    for controller in controllers:
        for label, column in QUANTITIES:
            values = means[controller][column]
            counted, top = ranked(values, "{:.3g}")
            lost_runs = f"{lost[controller][0]} of {lost[controller][1]}"
            rows.append([f"`{controller}`", label, _spread(values), lost_runs, counted, top])
    header = ["controller", "quantity", "µm: median (smallest to largest)", "runs lost", "trajectories"]
    lines += markdown_table([*header, "largest mu* in µm (assumption: mu* ± half-width, sigma)"], rows)

    ratios: dict[str, np.ndarray] = {}
    rows = []
    for controller in controllers[1:]:
        for label, column in QUANTITIES:
            ratio = means[controller][column] / means[reference][column]
            if label == QUANTITIES[0][0]:
                ratios[controller] = ratio
            counted, top = ranked(ratio, "{:.2f}")
            finite = ratio[np.isfinite(ratio)]
            below = f"{np.mean(finite < 1.0):.0%}" if finite.size else "—"
            rows.append([f"`{controller}`", label, _spread(finite, "×"), below, counted, top])
    lines += ["", f"## Each ratio to `{reference}` over the ranges", ""]
    lines += RATIO_INTRO.splitlines()
    lines.append("")
    header = ["controller", "quantity", "ratio: median (smallest to largest)", "points below 1", "trajectories"]
    lines += markdown_table([*header, "largest mu* (assumption: mu* ± half-width, sigma)"], rows)
    _draw(ratios, reference, campaign.sample_points(), keys, folder)
    caption = f"Each controller's x at the collision over `{reference}`'s at each design point, by assumption"
    return [*lines, "", f"![{caption}](controller_sensitivity.png)", ""]


class _Ranking:
    """Morris's mu* of a quantity at the design's points (:data:`RESAMPLES` bootstrap), from the
    trajectories whose every point counts: (how many of them, the two largest as text)."""

    def __init__(self, keys: list[str], levels: int, unit: np.ndarray) -> None:
        self.keys, self.levels, self.unit = keys, levels, unit
        self.problem = {"num_vars": len(keys), "names": keys, "bounds": [[0.0, 1.0]] * len(keys)}

    def __call__(self, values: np.ndarray, number: str) -> tuple[str, str]:
        from SALib.analyze import morris

        steps = len(self.keys) + 1
        whole = np.isfinite(values).reshape(-1, steps).all(axis=1)
        counted = f"{whole.sum()} of {whole.size}"
        if whole.sum() < 2:
            return counted, "too few trajectories counted"
        keep = np.repeat(whole, steps)
        analysed = morris.analyze(
            self.problem, self.unit[keep], values[keep], num_levels=self.levels, num_resamples=RESAMPLES, seed=0
        )
        mu_star, sigma, half = (np.asarray(analysed[k]) for k in ("mu_star", "sigma", "mu_star_conf"))
        top = "; ".join(
            f"`{self.keys[j].rpartition('.')[2]}`: {number.format(mu_star[j])} ± {number.format(half[j])}, "
            f"sigma {number.format(sigma[j])}"
            for j in np.argsort(-mu_star)[:2]
        )
        return counted, top


def _spread(values: np.ndarray, suffix: str = "") -> str:
    """``median (smallest to largest)`` of the finite ``values``."""
    finite = values[np.isfinite(values)]
    if not finite.size:
        return "—"
    low, mid, high = np.min(finite), np.median(finite), np.max(finite)
    return f"{mid:.3g}{suffix} ({low:.3g} to {high:.3g})"


def _draw(ratios: dict[str, np.ndarray], reference: str, points: list[dict], keys: list[str], folder: Path) -> None:
    """controller_sensitivity.png: each controller's ratio at each design point against each assumption."""
    columns = min(3, len(keys))
    rows = math.ceil(len(keys) / columns)
    figure = figure_class()(figsize=(4.0 * columns, 3.0 * rows), layout="constrained")
    panels = np.atleast_1d(figure.subplots(rows, columns)).ravel()
    for ax, key in zip(panels, keys, strict=False):
        values = np.array([point[key] for point in points], dtype=float)
        for controller, ratio in ratios.items():
            ax.plot(values, ratio, "o", markersize=3, alpha=0.7, label=controller)
        ax.axhline(1.0, color="0.3", linewidth=0.8)
        ax.set_xlabel(key.removeprefix("plant_overrides."), fontsize=8)
        ax.set_ylabel(f"x at the collision / {reference}'s", fontsize=8)
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
    for ax in panels[len(keys) :]:
        ax.set_visible(False)
    panels[0].legend(fontsize=7)
    save_figure(figure, folder / "controller_sensitivity.png")
