"""``microg view`` on a display that opens no OpenGL window: one line and exit 2, before the run."""

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

import microg_env

REPO = Path(microg_env.__file__).resolve().parents[1]  # the checkout under test


@pytest.mark.skipif(shutil.which("Xvfb") is None, reason="needs Xvfb (Debian's xvfb; .ci/run installs it)")
@pytest.mark.slow
def test_view_on_an_x_server_without_glx_is_one_line_and_exit_2(tmp_path):
    """GLFW starts on an X server without GLX but makes no window: the viewer printed GLFW's warning
    and 'could not create window' and exited 1."""
    display = f":{200 + os.getpid() % 100}"
    server = subprocess.Popen(
        ["Xvfb", display, "-extension", "GLX", "-nolisten", "tcp"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        time.sleep(1.0)
        environment = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "WAYLAND_DISPLAY")}
        result = subprocess.run(
            [sys.executable, "-m", "microg_env.cli", "view", "--duration", "1"],
            capture_output=True,
            text=True,
            cwd=tmp_path,
            env=environment | {"DISPLAY": display, "PYTHONPATH": str(REPO)},
            check=False,
            timeout=120,
        )
    finally:
        server.terminate()
        server.wait(timeout=10)
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [
        f"microg: error: microg view needs a display and display {display!r} opens no OpenGL window "
        "(not there, or no GLX) (headless: microg run --video FILE)"
    ]
    assert result.stdout == ""
