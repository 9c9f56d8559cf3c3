"""The reproduction's figures: the equivalents of the paper's Figures 3-7, three conditions each,
Table 1's pad solid and the calibrated pad dashed."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from microg_env.analysis.metrics import contacts
from microg_env.analysis.plots import envelope, figure_class, save_figure
from microg_env.paper.reproduction import NUMBERS, Reproduction
from microg_env.rollout.runner import RunResult
from microg_env.trajectory import Trajectory
from microg_env.workers import process_pool

PAD_LABELS = {"paper": "Table 1 pad", "calibrated": "calibrated pad"}
FIGURES = {
    "fig3_flexible_unit.png": "Figure 3: flexible-unit displacement x",
    "fig4_acceleration.png": "Figure 4: lander acceleration",
    "fig5_force_deformation.png": "Figure 5: collision force against deformation",
    "fig6_velocity_deformation.png": "Figure 6: deformation velocity against deformation",
    "fig7_displacement.png": "Figure 7: lander displacement (foot height)",
}


def _first_contact(trajectory: Trajectory) -> slice:
    found = contacts(trajectory)
    return slice(found[0].start, found[0].end) if found else slice(0, 0)


def render_figures(rep: Reproduction, names: Iterable[str] = tuple(FIGURES)) -> dict[str, object]:
    """The equivalents of the paper's Figures 3-7 (those of ``names``), three conditions each."""
    figure = figure_class()
    made = {}
    for name in names:
        title = FIGURES[name]
        fig = figure(figsize=(8, 8), layout="constrained")
        axes = fig.subplots(3, 1)
        for ax, number in zip(axes, NUMBERS, strict=True):
            for pad, style in (("paper", "-"), ("calibrated", "--")):
                run = rep.runs[pad, number]
                _draw(name, ax, run, style, PAD_LABELS[pad])
            if name == "fig7_displacement.png":
                reference = rep.runs["paper", number].reference
                ax.plot(reference.time_s, reference.foot_height_m * 1e3, ":", color="k", label="ideal reference")
            ax.set_title(f"condition {number}", fontsize=10)
            ax.grid(alpha=0.3)
        axes[0].legend(loc="best", fontsize=8)
        fig.suptitle(title)
        made[name] = fig
    return made


def save_figures(rep: Reproduction, folder: Path, workers: int = 1) -> None:
    """Render and save every figure into ``folder``, shared between ``workers`` processes (this one
    and ``workers - 1`` more; drawing and PNG encoding take about a second in all)."""
    workers = max(1, min(workers, len(FIGURES)))
    shares = [tuple(FIGURES)[i::workers] for i in range(workers)]
    if workers == 1:
        _save(rep, folder, shares[0])
        return
    with process_pool(workers - 1) as pool:
        others = [pool.submit(_save, rep, folder, share) for share in shares[1:]]
        _save(rep, folder, shares[0])
        for other in others:
            other.result()


def _save(rep: Reproduction, folder: Path, names: tuple[str, ...]) -> None:
    for name, fig in render_figures(rep, names).items():
        save_figure(fig, Path(folder) / name)


def _draw(name: str, ax, run: RunResult, style: str, label: str) -> None:
    t = run.trajectory
    contact = _first_contact(t)
    if name == "fig3_flexible_unit.png":  # the cogging ripple as a band, so neither pad hides the other
        centres, low, mean, high = envelope(t.time_s, t.x_m * 1e6)
        line = ax.plot(centres, mean, style, lw=0.9, label=f"{label}: mean per bin")[0]
        ax.fill_between(centres, low, high, color=line.get_color(), alpha=0.25, lw=0, label=f"{label}: min-max per bin")
        ax.set_ylabel("x [µm]")
        ax.set_xlabel("time [s]")
    elif name == "fig4_acceleration.png":
        ax.plot(t.time_s, t.lander_accel_m_s2 * 1e3, style, lw=0.7, label=label)
        ax.set_ylabel("acceleration [mm/s²]")
        ax.set_xlabel("time [s]")
    elif name == "fig5_force_deformation.png":
        ax.plot(-t.foot_height_m[contact] * 1e3, t.pad_force_n[contact], style, label=label)
        ax.set_ylabel("collision force [N]")
        ax.set_xlabel("deformation [mm]")
    elif name == "fig6_velocity_deformation.png":
        ax.plot(-t.foot_height_m[contact] * 1e3, -t.lander_velocity_m_s[contact] * 1e3, style, label=label)
        ax.set_ylabel("deformation velocity [mm/s]")
        ax.set_xlabel("deformation [mm]")
    else:
        ax.plot(t.time_s, t.foot_height_m * 1e3, style, label=label)
        ax.set_ylabel("foot height [mm]")
        ax.set_xlabel("time [s]")
