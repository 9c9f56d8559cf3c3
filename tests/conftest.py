"""Test setup: headless rendering (MuJoCo reads MUJOCO_GL when it is first imported)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
