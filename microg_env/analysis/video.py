"""A run rendered headless (``MUJOCO_GL=egl`` or ``osmesa``), the time, x and the pad force written
on every frame: ``microg run --video FILE``.

GIF needs only Pillow (a dependency of imageio); MP4 needs imageio's FFmpeg plugin
(``pip install imageio-ffmpeg``). Frames are taken at ``fps`` of simulated time, so the video plays
in real time; the file is written atomically when the run ends.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from microg_env.files import atomic_path

#: The formats ``--video`` writes.
VIDEO_SUFFIXES = (".gif", ".mp4")
#: Frame size, pixels, and frames per second of simulated time.
VIDEO_SIZE, VIDEO_FPS = (480, 360), 20


def check_video_support(path: Path) -> None:
    """Raise ValueError now (not after the run) if ``path``'s format cannot be written here, and pick
    EGL for headless rendering where no display and no ``MUJOCO_GL`` is set (read when the first
    frame is rendered)."""
    if "MUJOCO_GL" not in os.environ and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        os.environ["MUJOCO_GL"] = "egl"
    if path.suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ValueError(
                f"--video {str(path)!r}: MP4 needs imageio-ffmpeg (pip install imageio-ffmpeg); or write a .gif"
            ) from None


class LandingVideo:
    """Collects annotated frames from an ``rgb_array`` environment; ``write()`` saves them."""

    def __init__(self, path: str | Path, title: str, fps: int = VIDEO_FPS) -> None:
        self.path, self.title, self.fps = Path(path), title, fps
        self.frames: list[Any] = []
        self._next_s = 0.0

    def __call__(self, env, info: dict[str, Any]) -> None:
        """Take a frame when simulated time reaches the next one (``run_episode``'s ``on_step``)."""
        if info["time_s"] + 1e-9 < self._next_s:
            return
        self._next_s += 1.0 / self.fps
        # Palette images (an adaptive 128-colour palette): a third of the memory of RGB frames.
        self.frames.append(self._annotated(env.render(), info).convert("P", palette=1, colors=128))

    def _annotated(self, frame: np.ndarray, info: dict[str, Any]):
        from PIL import Image, ImageDraw, ImageFont

        image = Image.fromarray(frame)
        draw = ImageDraw.Draw(image)
        font = ImageFont.load_default(size=15)
        lines = (
            self.title,
            f"t = {info['time_s']:6.2f} s   foot height {info['foot_height_m'] * 1e3:7.2f} mm (pad top: 0)",
            f"x = {info['x_m'] * 1e6:+7.3f} µm   pad force {info['pad_force_n']:6.2f} N",
        )
        draw.rectangle((0, 0, image.width, 8 + 19 * len(lines)), fill=(0, 0, 0))
        for i, line in enumerate(lines):
            draw.text((8, 4 + 19 * i), line, fill=(255, 255, 255), font=font)
        return image

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
