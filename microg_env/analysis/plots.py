"""Figures of runs (matplotlib, the ``report`` extra), written atomically."""

from __future__ import annotations

from pathlib import Path

from microg_env.analysis.trajectory import Trajectory
from microg_env.files import atomic_path


def figure_class():
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ValueError("plots need matplotlib: pip install 'microg-env[report]'") from None
    return Figure


def save_figure(figure, path: Path) -> None:
    """Save ``figure`` to ``path`` atomically, in the format its suffix names."""
    path = Path(path)
    with atomic_path(path) as temporary:
        figure.savefig(temporary, format=path.suffix[1:].lower(), dpi=110, bbox_inches="tight")


def plot_run(trajectory: Trajectory, reference: Trajectory, title: str, path: Path) -> None:
    """Foot height, x, lander acceleration and pad force over time, the ideal reference dashed."""
    figure = figure_class()(figsize=(9, 8), layout="constrained")
    axes = figure.subplots(4, 1, sharex=True)
    t, tr = trajectory.time_s, reference.time_s
    axes[0].plot(t, trajectory.foot_height_m * 1e3, label="rig")
    axes[0].plot(tr, reference.foot_height_m * 1e3, "--", label="ideal microgravity")
    axes[0].set_ylabel("foot height [mm]")
    axes[0].legend(loc="upper right")
    axes[1].plot(t, trajectory.x_m * 1e6, color="C2")
    axes[1].set_ylabel("x [µm]")
    axes[2].plot(t, trajectory.lander_accel_m_s2 * 1e3, lw=0.6, label="rig")
    axes[2].plot(tr, reference.lander_accel_m_s2 * 1e3, "--", label="ideal microgravity")
    axes[2].set_ylabel("lander accel [mm/s$^2$]")
    axes[3].plot(t, trajectory.pad_force_n, label="rig")
    axes[3].plot(tr, reference.pad_force_n, "--", label="ideal microgravity")
    axes[3].set_ylabel("pad force [N]")
    axes[3].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
    figure.suptitle(title)
    save_figure(figure, path)
