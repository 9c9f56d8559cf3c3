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
    tests, and rebuild it whenever that worker's tests of the file are not consecutive."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("suite_conftest", REPO / "tests" / "conftest.py")
    conftest = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conftest)
    fixtures = {
        path.relative_to(REPO).as_posix()
        for path in (REPO / "tests").rglob("test_*.py")
        if re.search(r"@pytest\.fixture\(scope=\"module\"", path.read_text(encoding="utf-8"))
    }
    assert fixtures
    assert fixtures <= {start.split("::")[0] for start in conftest.GROUPS}, fixtures
