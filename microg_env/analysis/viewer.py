"""A run shown live in MuJoCo's passive viewer (``microg view``): the environment and a controller
step the rig, the window follows in real time (or ``speed`` times it), with the time, foot height,
x and pad force written in a corner and the last seconds of x and the pad force plotted, the
overlays of ``microg run --video``.

Closing the window ends the run early. The viewer needs a display: on a machine without one the
run is refused before anything starts (``microg run --video`` renders headless instead).
"""

from __future__ import annotations

import os
import threading
import time
from typing import Any

from microg_env.analysis.video import INSET_S, InsetHistory, display_opens

#: How often the window is redrawn at most, Hz of wall-clock time.
FRAME_RATE_HZ = 60.0


class WindowClosed(Exception):
    """The user closed the viewer before the run ended."""


def check_display() -> None:
    """Raise ValueError on a machine the viewer cannot open a window on (GLFW would abort or warn)."""
    if os.environ.get("MUJOCO_GL", "glfw").lower() in {"egl", "osmesa"}:
        raise ValueError(f"microg view needs a window, but MUJOCO_GL is {os.environ['MUJOCO_GL']!r}; unset it")
    if not display_opens():
        shown = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
        where = f"display {shown!r} opens no OpenGL window (not there, or no GLX)" if shown else "DISPLAY is not set"
        raise ValueError(f"microg view needs a display and {where} (headless: microg run --video FILE)")


class LiveView:
    """``run``'s ``on_step``: opens the passive viewer on the environment's model and data at the
    reset, then redraws it with the overlays and paces the run to ``speed`` times real time."""

    def __init__(self, title: str, speed: float = 1.0) -> None:
        self.title, self.speed = title, speed
        self.viewer = None
        self.history = InsetHistory()
        self._threads: list[threading.Thread] = []
        self._start_wall = 0.0
        self._next_frame_wall = 0.0

    def __call__(self, env, info: dict[str, Any]) -> None:
        t = info["time_s"]
        self.history.record(info)
        if self.viewer is None:
            self._open(env)
        wall = time.perf_counter() - self._start_wall
        if wall >= self._next_frame_wall:  # frames by the wall clock: a slow window never slows the run more
            if not self.viewer.is_running():
                raise WindowClosed
            self.viewer.set_texts(self._texts(info, wall))
            self.viewer.set_figures(self._figures())
            self.viewer.sync()
            # the next frame a frame's time after this one ends (a window slower than the rate skips frames)
            self._next_frame_wall = time.perf_counter() - self._start_wall + 1.0 / FRAME_RATE_HZ
        ahead = t / self.speed - (time.perf_counter() - self._start_wall)
        if ahead > 0:  # the simulation is ahead of the asked pace: wait for the clock
            time.sleep(ahead)

    def _open(self, env) -> None:
        import mujoco.viewer

        before = set(threading.enumerate())
        model = env.unwrapped.model
        try:
            self.viewer = mujoco.viewer.launch_passive(
                model, env.unwrapped.data, show_left_ui=False, show_right_ui=False
            )
        except RuntimeError as error:  # macOS: the passive viewer runs only under mjpython
            raise ValueError(f"microg view: {error}") from None
        self._threads = [thread for thread in threading.enumerate() if thread not in before]
        with self.viewer.lock():  # the rig's side camera, as in the videos
            self.viewer.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            self.viewer.cam.fixedcamid = model.camera("side").id
        self._start_wall = time.perf_counter()

    def _texts(self, info: dict[str, Any], wall_s: float):
        import mujoco

        left = "\n".join(("time", "foot height", "x", "pad force", "speed"))
        achieved = info["time_s"] / wall_s if wall_s > 0 else self.speed
        right = "\n".join(
            (
                f"{info['time_s']:.2f} s",
                f"{info['foot_height_m'] * 1e3:.2f} mm",
                f"{info['x_m'] * 1e6:+.3f} um",  # MuJoCo's font has no µ
                f"{info['pad_force_n']:.2f} N",
                f"{achieved:.2g}x real time (asked {self.speed:g}x)",
            )
        )
        return [
            (mujoco.mjtFontScale.mjFONTSCALE_150, mujoco.mjtGridPos.mjGRID_TOPLEFT, self.title, ""),
            (mujoco.mjtFontScale.mjFONTSCALE_150, mujoco.mjtGridPos.mjGRID_BOTTOMLEFT, left, right),
        ]

    def _figures(self):
        """x [µm] and the pad force [N] over the last INSET_S, at the window's bottom right."""
        import mujoco

        recent = self.history.recent()
        now = recent[-1, 0]
        figures = []
        viewport = self.viewer.viewport
        left, bottom, width, height = (
            (viewport.left, viewport.bottom, viewport.width, viewport.height) if viewport else (0, 0, 1200, 900)
        )
        for k, (column, scale, name) in enumerate(((2, 1.0, "pad force [N]"), (1, 1e6, "x [um]"))):  # x on top
            figure = mujoco.MjvFigure()
            mujoco.mjv_defaultFigure(figure)
            figure.title = name
            figure.xlabel = "time [s]"
            figure.flg_extend = 1
            count = min(len(recent), figure.linedata.shape[1] // 2)
            points = recent[-count:]
            figure.linedata[0, : 2 * count : 2] = points[:, 0] - now
            figure.linedata[0, 1 : 2 * count : 2] = points[:, column] * scale
            figure.linepnt[0] = count
            figure.range[0][:] = (-INSET_S, 0.0)
            rect = mujoco.MjrRect(left + width - width // 3, bottom + k * height // 4, width // 3, height // 4)
            figures.append((rect, figure))
        return figures

    def close(self) -> None:
        """Close the window and wait for the viewer's thread (a process that exits while it still
        runs can crash in GLFW's teardown)."""
        if self.viewer is not None:
            self.viewer.close()
            for thread in self._threads:
                thread.join(timeout=10)
