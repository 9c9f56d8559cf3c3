"""A run rendered headless (``MUJOCO_GL=egl`` or ``osmesa``), the time, x and the pad force written
on every frame and plotted over the last seconds in an inset (the µm motion the rig is about does
not show in the picture): ``microg run --video FILE``.

GIF needs only Pillow (a dependency of imageio); MP4 needs imageio's FFmpeg plugin
(``pip install imageio-ffmpeg``). Frames are taken at ``fps`` of simulated time, so the video plays
in real time; the file is written atomically when the run ends.
"""

from __future__ import annotations

import os
import sys
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from microg_env.files import atomic_path

#: The formats ``--video`` writes.
VIDEO_SUFFIXES = (".gif", ".mp4")
#: Frame size, pixels, and frames per second of simulated time.
VIDEO_SIZE, VIDEO_FPS = (480, 360), 20
#: The inset: the last INSET_S of x and of the pad force, sampled every INSET_SAMPLE_S, in a box
#: of INSET_SIZE pixels at the frame's bottom right; x in µm, symmetric about 0, the force from 0.
INSET_S, INSET_SAMPLE_S, INSET_SIZE = 4.0, 0.005, (200, 120)
#: The inset's colours (x, pad force).
X_COLOUR, FORCE_COLOUR = (255, 196, 0), (80, 200, 255)


def display_opens() -> bool:
    """Whether GLFW can open an OpenGL window on this process's display (``DISPLAY`` may name one
    that is not there, or an X server without GLX, where GLFW starts but makes no window)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    import glfw

    reporting, glfw.ERROR_REPORTING = glfw.ERROR_REPORTING, "ignore"  # a failure is an answer here
    try:
        if not glfw.init():
            return False
        try:
            glfw.window_hint(glfw.VISIBLE, glfw.FALSE)
            window = glfw.create_window(1, 1, "microg", None, None)
            if window:
                glfw.destroy_window(window)
            return bool(window)
        finally:
            glfw.default_window_hints()
            glfw.terminate()
    finally:
        glfw.ERROR_REPORTING = reporting


def check_video_support(path: Path) -> None:
    """Raise ValueError now (not after the run) if ``path``'s format cannot be written here, and pick
    EGL for headless rendering where no ``MUJOCO_GL`` is set and no display opens (read when the
    first frame is rendered)."""
    if "MUJOCO_GL" not in os.environ and not display_opens():
        os.environ["MUJOCO_GL"] = "egl"
    if path.suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ValueError(
                f"--video {str(path)!r}: MP4 needs imageio-ffmpeg (pip install imageio-ffmpeg); or write a .gif"
            ) from None


def _font(size: int):
    """(DejaVu Sans, "µ") where the system or matplotlib has it; else (Pillow's default, "u"): the
    default font has no µ."""
    from PIL import ImageFont

    try:
        return ImageFont.truetype("DejaVuSans.ttf", size), "µ"
    except OSError:
        pass
    try:
        from matplotlib import font_manager

        return ImageFont.truetype(font_manager.findfont("DejaVu Sans", fallback_to_default=False), size), "µ"
    except (ImportError, ValueError, OSError):
        return ImageFont.load_default(size=size), "u"


class InsetHistory:
    """x and the pad force over the last INSET_S of a run, one row every INSET_SAMPLE_S: what the
    video's inset and the live view's plots draw."""

    def __init__(self) -> None:
        self.rows: deque[tuple[float, float, float]] = deque()  # (t s, x m, pad force N)

    def record(self, info: dict[str, Any]) -> None:
        """Keep this step if a sample is due, and drop what has left the window."""
        t = info["time_s"]
        if not self.rows or t >= self.rows[-1][0] + INSET_SAMPLE_S - 1e-9:
            self.rows.append((t, info["x_m"], info["pad_force_n"]))
        while self.rows[0][0] < t - INSET_S:
            self.rows.popleft()

    def recent(self) -> np.ndarray:
        """The window's rows, (n, 3)."""
        return np.array(self.rows, dtype=float).reshape(-1, 3)


class LandingVideo:
    """Collects annotated frames from an ``rgb_array`` environment; ``write()`` saves them."""

    def __init__(self, path: str | Path, title: str, fps: int = VIDEO_FPS) -> None:
        self.path, self.title, self.fps = Path(path), title, fps
        self.frames: list[Any] = []
        self._next_s = 0.0
        self.history = InsetHistory()

    def __call__(self, env, info: dict[str, Any]) -> None:
        """Record x and the pad force; take a frame when simulated time reaches the next one
        (``run_episode``'s ``on_step``)."""
        self.history.record(info)
        if info["time_s"] + 1e-9 < self._next_s:
            return
        self._next_s += 1.0 / self.fps
        # Palette images (an adaptive 128-colour palette): a third of the memory of RGB frames.
        self.frames.append(self._annotated(env.render(), info).convert("P", palette=1, colors=128))

    def _annotated(self, frame: np.ndarray, info: dict[str, Any]):
        from PIL import Image, ImageDraw

        image = Image.fromarray(frame)
        draw = ImageDraw.Draw(image)
        font, micro = _font(14)
        lines = (
            self.title,
            f"t = {info['time_s']:6.2f} s   foot height {info['foot_height_m'] * 1e3:7.2f} mm (pad top: 0)",
            f"x = {info['x_m'] * 1e6:+7.3f} {micro}m   pad force {info['pad_force_n']:6.2f} N",
        )
        draw.rectangle((0, 0, image.width, 8 + 19 * len(lines)), fill=(0, 0, 0))
        for i, line in enumerate(lines):
            draw.text((8, 4 + 19 * i), line, fill=(255, 255, 255), font=font)
        self._inset(draw, image.width - INSET_SIZE[0] - 6, image.height - INSET_SIZE[1] - 6, info["time_s"])
        return image

    def _inset(self, draw, left: int, top: int, now_s: float) -> None:
        """x (upper half) and the pad force (lower half) over the last INSET_S, newest at the right."""
        width, height = INSET_SIZE
        draw.rectangle((left, top, left + width, top + height), fill=(0, 0, 0))
        recent = self.history.recent()
        font, micro = _font(10)
        half = height // 2
        x_um, force = recent[:, 1] * 1e6, recent[:, 2]
        x_scale = max(float(np.abs(x_um).max(initial=0.0)), 0.01)
        force_scale = max(float(force.max(initial=0.0)), 1.0)
        columns = left + (recent[:, 0] - (now_s - INSET_S)) / INSET_S * width
        # pixel rows: x about the upper half's middle, the force up from the lower half's bottom
        x_rows = top + half / 2 + 6 - x_um / x_scale * (half / 2 - 10)
        force_rows = top + 2 * half - 4 - force / force_scale * (half - 16)
        for rows, row_top, colour, text in (
            (x_rows, top, X_COLOUR, f"x ±{x_scale:.3g} {micro}m"),
            (force_rows, top + half, FORCE_COLOUR, f"pad force 0-{force_scale:.3g} N"),
        ):
            draw.line((left, row_top + half - 1, left + width, row_top + half - 1), fill=(70, 70, 70))
            if len(rows) > 1:
                draw.line(list(zip(columns.tolist(), rows.tolist(), strict=True)), fill=colour, width=1)
            draw.text((left + 4, row_top + 2), text, fill=colour, font=font)
        draw.text((left + width - 52, top + 2), f"last {INSET_S:g} s", fill=(170, 170, 170), font=font)

    def write(self) -> Path:
        if not self.frames:
            raise ValueError(f"--video {str(self.path)!r}: the run produced no frame")
        with atomic_path(self.path) as temporary:
            if self.path.suffix.lower() == ".gif":
                self.frames[0].save(
                    temporary,
                    format="GIF",
                    save_all=True,
                    append_images=self.frames[1:],
                    duration=round(1000 / self.fps),
                    loop=0,
                )
            else:
                import imageio.v2 as imageio

                with imageio.get_writer(temporary, format="FFMPEG", fps=self.fps, macro_block_size=8) as writer:
                    for frame in self.frames:
                        writer.append_data(np.asarray(frame.convert("RGB")))
        return self.path
