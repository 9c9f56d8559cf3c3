"""Repository hygiene: lint, format, and CI running the README's own test command."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _quick_start_commands() -> list[str]:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```bash\n(.+?)\n```", section)


def test_quick_start_is_two_commands_and_ci_runs_the_second():
    commands = _quick_start_commands()
    assert len(commands) == 2
    assert all("\n" not in command for command in commands)
    ci_lines = (REPO / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    assert commands[1] in ci_lines


@pytest.mark.parametrize("args", [["check", "."], ["format", "--check", "."]], ids=["lint", "format"])
def test_ruff_is_clean(args):
    pytest.importorskip("ruff", reason="ruff is in the dev extra")
    result = subprocess.run(
        [sys.executable, "-m", "ruff", *args], cwd=REPO, capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_every_file_whose_tests_share_a_module_fixture_runs_on_one_worker():
    """The README's ``--dist loadgroup`` runs a group of tests/conftest.py's GROUPS on one worker; a
    file with a module-scoped fixture left out would build it on each worker that takes one of its
    tests. Every entry names a test file, or a test function in it."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("suite_conftest", REPO / "tests" / "conftest.py")
    conftest = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conftest)
    module_fixture = re.compile(r"@pytest\.fixture\([^)]*scope=[\"']module[\"']")
    fixtures = {
        path.relative_to(REPO).as_posix()
        for path in (REPO / "tests").rglob("test_*.py")
        if module_fixture.search(path.read_text(encoding="utf-8"))
    }
    assert "tests/paper/test_calibration.py" in fixtures
    assert fixtures <= {entry for entry in conftest.GROUPS if "::" not in entry}, fixtures
    for entry in conftest.GROUPS:
        path, _, name = entry.partition("::")
        assert (REPO / path).is_file(), entry
        assert not name or re.search(rf"^def {name}\(", (REPO / path).read_text(encoding="utf-8"), re.M), entry
    name = "tests/rollout/test_processes.py::test_a_killed_campaign_leaves_no_ray_process_behind_and_resumes_whole"
    assert conftest.group_of(name) == "ray"
    assert conftest.group_of(f"{name}[SIGKILL]") == "ray"  # a parametrisation of it
    assert conftest.group_of(f"{name}_too") is None
    assert conftest.group_of(f"{name}_too[SIGKILL]") is None
    assert conftest.group_of("tests/test_install.py::test_wheel") == "tests/test_install.py"
    assert conftest.group_of("tests/test_install2.py::test_wheel") is None
