"""Figures of runs (matplotlib, the ``report`` extra), written atomically."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np

from microg_env.analysis.metrics import (
    COMPARED_WINDOW,
    INSTANT_WINDOWS_S,
    contacts,
    in_flight_weights,
    placement_time,
)
from microg_env.files import atomic_path
from microg_env.trajectory import Trajectory

#: The error of a plot without matplotlib (an optional dependency).
NO_MATPLOTLIB = "plots need matplotlib: pip install 'microg-env[report]'"


def figure_class():
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ValueError(NO_MATPLOTLIB) from None
    return Figure


def require_matplotlib() -> None:
    """Raise :func:`figure_class`'s error now if matplotlib is not installed, without importing it
    (a third of a second): a command checks before its runs, and draws after them."""
    if importlib.util.find_spec("matplotlib") is None:
        raise ValueError(NO_MATPLOTLIB)


def save_figure(figure, path: Path) -> None:
    """Save ``figure`` to ``path`` atomically, in the format its suffix names."""
    path = Path(path)
    with atomic_path(path) as temporary:
        figure.savefig(temporary, format=path.suffix[1:].lower(), dpi=110, bbox_inches="tight")


#: Bins of the x panel's envelope across a run: the cogging ripple (tens of Hz) would fill the
#: panel solid at one line per sample, so each bin shows its min-max band and its mean.
ENVELOPE_BINS = 600
#: The inset zoom after the first touchdown, s: x - x(touchdown) sample by sample, the window of
#: the paper's "change at the instant of collision" (``metrics.COMPARED_WINDOW``) shaded.
ZOOM_S = 0.02
#: Line style of each event marked on every panel.
EVENT_STYLES = {
    "weight placed": {"color": "0.35", "ls": ":"},
    "touchdown": {"color": "C3", "ls": "-."},
    "lift-off": {"color": "C2", "ls": "-."},
}


def run_events(trajectory: Trajectory) -> dict[str, list[float]]:
    """Times of the weights placed after the start, the touchdowns and the lift-offs, s."""
    found = contacts(trajectory)
    return {
        "weight placed": sorted(
            {
                t
                for t in (placement_time(trajectory, w) for w in in_flight_weights(trajectory.scenario))
                if math.isfinite(t)
            }
        ),
        "touchdown": [c.touchdown_s for c in found],
        "lift-off": [c.liftoff_s for c in found if c.liftoff_s == c.liftoff_s],
    }


def envelope(t: np.ndarray, y: np.ndarray, bins: int = ENVELOPE_BINS):
    """(bin centres, minimum, mean, maximum) of ``y`` over equal time bins; with no more samples
    than bins, each sample is its own (at its own time)."""
    if len(t) <= bins:
        return t, y, y, y
    edges = np.linspace(t[0], t[-1], bins + 1)
    index = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
    used = np.unique(index)
    low = np.full(len(edges) - 1, np.inf)
    high = np.full(len(edges) - 1, -np.inf)
    np.minimum.at(low, index, y)
    np.maximum.at(high, index, y)
    mean = np.bincount(index, y, len(edges) - 1)[used] / np.bincount(index, minlength=len(edges) - 1)[used]
    return 0.5 * (edges[:-1] + edges[1:])[used], low[used], mean, high[used]


def run_figure(trajectory: Trajectory, reference: Trajectory, title: str, size=(10, 9.5)):
    """Foot height, x, lander acceleration and pad force over time: the ideal-microgravity reference
    dashed, the events marked, x as an envelope with a zoom on the first collision's instant."""
    figure = figure_class()(figsize=size, layout="constrained")
    grid = figure.add_gridspec(5, 1, height_ratios=(1, 1.3, 1, 1, 1.1))
    axes = [figure.add_subplot(grid[0])]
    axes += [figure.add_subplot(grid[k], sharex=axes[0]) for k in range(1, 4)]
    t, tr = trajectory.time_s, reference.time_s
    for ax, rig, ideal, scale, label in (
        (axes[0], trajectory.foot_height_m, reference.foot_height_m, 1e3, "foot height [mm]"),
        (axes[2], trajectory.lander_accel_m_s2, reference.lander_accel_m_s2, 1e3, "lander accel. [mm/s$^2$]"),
        (axes[3], trajectory.pad_force_n, reference.pad_force_n, 1.0, "pad force [N]"),
    ):
        ax.plot(t, rig * scale, lw=0.8, label="rig")
        ax.plot(tr, ideal * scale, "--", color="C1", lw=1.0, label="ideal microgravity")
        ax.set_ylabel(label)
    centres, low, mean, high = envelope(t, trajectory.x_m * 1e6)
    axes[1].fill_between(centres, low, high, color="C0", alpha=0.3, lw=0, label="min-max per bin")
    axes[1].plot(centres, mean, color="C0", lw=0.9, label="mean per bin")
    axes[1].set_ylabel("x [µm]")
    events = run_events(trajectory)
    for ax in axes:
        for name, times in events.items():
            for k, when in enumerate(times):
                ax.axvline(when, lw=0.8, label=name if k == 0 and ax is axes[0] else None, **EVENT_STYLES[name])
        ax.grid(alpha=0.3)
    for ax in axes[:3]:
        ax.tick_params(labelbottom=False)
    axes[3].set_xlabel("time [s]")
    axes[0].legend(loc="upper right", fontsize=8, ncols=2)
    axes[1].legend(loc="upper left", fontsize=8, ncols=2)
    zoom = figure.add_subplot(grid[4])
    if events["touchdown"]:
        _zoom(zoom, trajectory, events["touchdown"][0])
    else:
        zoom.set_axis_off()
        zoom.text(0.5, 0.5, "no touchdown in this run: nothing to zoom on", ha="center", va="center")
    figure.align_ylabels()
    figure.suptitle(title)
    return figure


def _zoom(ax, trajectory: Trajectory, touchdown_s: float) -> None:
    """x - x(touchdown) sample by sample over ZOOM_S from the first touchdown, in ms."""
    t = trajectory.time_s
    inside = (t >= touchdown_s - 0.1 * ZOOM_S) & (t <= touchdown_s + ZOOM_S)
    at_touchdown = float(np.interp(touchdown_s, t, trajectory.x_m))
    ax.plot((t[inside] - touchdown_s) * 1e3, (trajectory.x_m[inside] - at_touchdown) * 1e6, ".-", lw=0.8, ms=3)
    window = INSTANT_WINDOWS_S[COMPARED_WINDOW] * 1e3
    ax.axvspan(0.0, window, color="C3", alpha=0.12, label=f"first {window:g} ms: the paper's instant of collision")
    ax.axvline(0.0, lw=0.8, **EVENT_STYLES["touchdown"])
    ax.set_xlabel("time after the first touchdown [ms]")
    ax.set_ylabel("x − x(touchdown) [µm]")
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)


def plot_run(trajectory: Trajectory, reference: Trajectory, title: str, path: Path) -> None:
    """``run_figure`` saved to ``path``."""
    save_figure(run_figure(trajectory, reference, title), path)


def plot_replay(time_s: np.ndarray, log: dict[str, np.ndarray], model: dict[str, np.ndarray], title: str, path: Path):
    """A log's ruler and encoder beside the model's replay of its commands, and the residuals
    (model minus log; the ruler's with each window's start state removed), saved to ``path``."""
    figure = figure_class()(figsize=(10, 8))
    axes = figure.subplots(4, 1, sharex=True)
    n = len(model["encoder_m"])
    for ax, name, label in ((axes[0], "ruler_m", "x, ruler [um]"), (axes[2], "encoder_m", "support, encoder [mm]")):
        scale = 1e6 if name == "ruler_m" else 1e3
        ax.plot(time_s[:n], log[name][:n] * scale, color="0.5", lw=0.8, label="log")
        ax.plot(time_s[:n], model[name] * scale, color="C0", lw=0.8, label="model")
        ax.set_ylabel(label)
        ax.legend(loc="upper right", fontsize=8)
    for ax, name in ((axes[1], "ruler_m"), (axes[3], "encoder_m")):
        ax.plot(time_s[:n], model[f"{name}_residual"] * 1e9, color="C3", lw=0.6)
        ax.set_ylabel(f"{name.split('_')[0]} residual [nm]")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(title)
    save_figure(figure, path)
