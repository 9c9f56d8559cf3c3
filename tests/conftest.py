"""Test setup: headless rendering (MuJoCo reads MUJOCO_GL when it is first imported), shared facts."""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import gymnasium as gym
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


#: What one worker runs together under the README's ``--dist loadgroup``, by group: a test file
#: (``path``), or one test function with its parametrisations (``path::name``). The tests that start
#: Ray ("ray": one starts a cluster on a fixed port, and Ray instances side by side starve each
#: other on two cores), and the files whose tests share a module-scoped fixture (a calibration, a
#: reproduction, a training run), so that it is built once. tests/test_repo.py checks that every
#: file with a module-scoped fixture is here as a file and that every entry names a test.
GROUPS = {
    "tests/experiments/test_experiments.py": "ray",
    "tests/rollout/test_processes.py::test_a_killed_campaign_leaves_no_ray_process_behind_and_resumes_whole": "ray",
    "tests/rollout/test_processes.py::test_a_campaign_stopped_by_sigterm_runs_only_what_is_missing": "ray",
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
            "tests/rollout/test_logs.py",
            "tests/test_install.py",
        )
    },
}


def group_of(nodeid: str) -> str | None:
    """The :data:`GROUPS` group of the test ``nodeid`` (relative to the repository), if any."""
    for entry, group in GROUPS.items():
        if nodeid.startswith(f"{entry}::" if "::" not in entry else f"{entry}[") or nodeid == entry:
            return group
    return None


#: A few short runs that compile every numba kernel of the package into its cache.
WARM_UP = """
from microg_env.rollout.runner import run, run_all
from microg_env.rollout.spec import RunSpec

for controller in ("pid", "pid-dom", "adaptive-dither", "residual-sac-setpoint"):
    run(RunSpec("condition-2", controller, 0, duration_s=0.05))
run_all([RunSpec("condition-2", "pid", seed, duration_s=0.05) for seed in (0, 1)])
"""


def pytest_configure(config: pytest.Config) -> None:
    """In a pytest-xdist worker: pin it (:func:`_pin_worker`). Before the workers start: compile the
    package's numba kernels into their cache (:mod:`microg_env.compiled`), once, here (the tree the
    tests import) and in a process started outside the tree (the installed copy, which commands run
    from other folders import). On a fresh clone every process that found a cache empty compiled the
    kernels itself, about 13 CPU-seconds each: the workers, and the commands, Ray workers and
    process pools the tests start. The two copies compile side by side, one a core."""
    if hasattr(config, "workerinput"):
        _pin_worker(config.workerinput)
        return
    if not getattr(config.option, "numprocesses", None):
        return
    with tempfile.TemporaryDirectory() as folder:
        outside = subprocess.Popen(
            [sys.executable, "-c", WARM_UP], cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
        )
        try:
            exec(WARM_UP, {})
            _, errors = outside.communicate(timeout=600)
        finally:
            if outside.poll() is None:
                outside.kill()
                outside.wait()
        if outside.returncode:
            raise subprocess.CalledProcessError(outside.returncode, outside.args, stderr=errors)


def _pin_worker(workerinput: dict) -> None:
    """A pytest-xdist worker kept to a core of its own: what its tests start (threads, processes)
    stays there (:func:`microg_env.workers.usable_cores`). Two workers' spinning thread pools on
    every core made an identification 4x as slow."""
    number = str(workerinput["workerid"]).removeprefix("gw")
    if not hasattr(os, "sched_setaffinity") or not number.isdigit() or int(workerinput["workercount"]) < 2:
        return
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) > 1:
        os.sched_setaffinity(0, {cores[int(number) % len(cores)]})


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """In a pytest-xdist worker: the ungrouped tests marked ``slow`` before the other ungrouped
    ones, each set in its order. pytest-xdist deals out the groups first (the largest first), then
    the single tests in this order: quick tests, not a 25-second tutorial, end the run on both
    workers. (Each worker reorders its own identical collection alike.)"""
    if hasattr(config, "workerinput"):
        items.sort(key=lambda item: group_of(item.nodeid) is None and item.get_closest_marker("slow") is None)


@pytest.hookimpl(optionalhook=True)  # a run without pytest-xdist has no such hook
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """``--dist loadgroup``: pytest-xdist deals the tests out one by one, but those of a group in
    :data:`GROUPS` as one unit. (pytest-xdist's own ``xdist_group`` marks are not read: with pytest
    9.2 its loadgroup no longer groups them.) Any other ``--dist``: pytest-xdist's own scheduler."""
    if config.getoption("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return group_of(nodeid) or nodeid

    return GroupScheduling(config, log)


@pytest.fixture(autouse=True, scope="session")
def _stable_baselines3_logs_in_the_sessions_folder(tmp_path_factory):
    """A model learning without a log folder (the plain-SB3 tests) makes an empty one in the system's
    temporary folder each time; here it goes to the session's, which pytest cleans up."""
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3"))


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
