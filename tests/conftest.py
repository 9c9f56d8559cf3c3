"""Test setup: headless rendering (MuJoCo reads MUJOCO_GL when it is first imported), shared facts."""

import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


#: Test files (or tests, by the start of their id) that one worker runs together under the README's
#: ``--dist loadgroup``, by group: the tests that start Ray ("ray": one starts a cluster on a fixed
#: port, and Ray instances side by side starve each other on two cores), and the files whose tests
#: share a module-scoped fixture (a calibration, a reproduction, a training run), so that it is
#: built once. tests/test_repo.py checks that every file with a module-scoped fixture is here.
GROUPS = {
    "tests/experiments/test_experiments.py": "ray",
    "tests/rollout/test_processes.py::test_a_killed_campaign": "ray",
    **{
        path: path
        for path in (
            "tests/analysis/test_figures.py",
            "tests/cli/test_cli.py",
            "tests/controllers/test_controllers.py",
            "tests/experiments/test_compare.py",
            "tests/learning/test_export_equivalence.py",
            "tests/learning/test_learning.py",
            "tests/learning/test_training_records.py",
            "tests/paper/test_calibration.py",
            "tests/paper/test_report.py",
            "tests/test_install.py",
        )
    },
}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The slow tests first, then the quick ones, each in collection order: the workers deal out the
    long tests while there is work for both, and end on short ones instead of one idling while the
    other runs a long test. (A group goes to a worker with its first test.)"""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """``--dist loadgroup``: pytest-xdist deals the tests out one by one, but those of a group in
    :data:`GROUPS` as one unit. (pytest-xdist's own ``xdist_group`` marks are not read: with pytest
    9.2 its loadgroup no longer groups them.) Any other ``--dist``: pytest-xdist's own scheduler."""
    if config.getoption("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return next((group for start, group in GROUPS.items() if nodeid.startswith(start)), nodeid)

    return GroupScheduling(config, log)


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
