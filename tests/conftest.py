"""Test setup: headless rendering (MuJoCo reads MUJOCO_GL when it is first imported), shared facts."""

import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(autouse=True)
def _quiet_gymnasium_warnings():
    """Unbounded observation boxes draw a Gymnasium warning; physical quantities are unbounded."""
    gym.logger.min_level = 40
    yield
    gym.logger.min_level = 30


@pytest.fixture
def run_json_keys() -> set[str]:
    """The keys ``microg run --json`` must print (issue: the run metrics)."""
    return {
        "descent_accel_m_s2",
        "ideal_descent_accel_m_s2",
        "compensation_error_pct",
        "residual_gravity_g",
        "flexible_unit_excursion_free_fall_m",
        "flexible_unit_excursion_collision_m",
        "x_change_after_touchdown_m",
        "placement_delay_s",
        "support_force_variation_n",
        "servo_rms_torque_n_m",
        "max_deformation_m",
        "collision_accel_m_s2",
        "contact_time_s",
        "restitution",
        "rebound_height_m",
        "reference_max_deformation_m",
        "reference_rms_height_error_m",
        "unavailable",
    }


@pytest.fixture
def run_tutorial():
    """Run a tutorial of docs/tutorials from a folder with ``--out`` that folder; its standard output."""
    tutorials = Path(__file__).resolve().parents[1] / "docs" / "tutorials"

    def run(name: str, folder: Path, *args: str) -> str:
        result = subprocess.run(
            [sys.executable, str(tutorials / name), "--out", str(folder), *args],
            capture_output=True,
            text=True,
            cwd=folder,
            check=False,
            timeout=300,
        )
        assert result.returncode == 0, result.stderr[-3000:]
        return result.stdout

    return run
