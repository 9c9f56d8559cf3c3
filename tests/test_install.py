"""A fresh clone runs the README's quick start; a wheel carries the MJCF and works from any folder.

The package is installed (not editable) into a fresh virtual environment. Its dependencies
(mujoco, gymnasium, numpy, matplotlib) are borrowed from the environment running the tests through
a .pth line, so the tests need no network; the package itself must come from the new environment.
"""

import json
import re
import shlex
import shutil
import site
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(REPO), "--no-deps", "--no-build-isolation", "-q", "-w", str(out)],
        check=True,
        capture_output=True,
    )
    (path,) = out.glob("microg_env-*.whl")
    return path


@pytest.mark.slow
def test_wheel_contains_the_mjcf_and_its_type_marker(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in ("assets/scene.xml", "assets/rig.xml", "py.typed"):
        assert f"microg_env/{name}" in names


def shipped_folders() -> list[str]:
    return sorted(p.parent.name for p in (REPO / "microg_env" / "policies").glob("*/policy.json"))


def test_wheel_contains_the_hyperparameters_and_the_shipped_policy(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    packaged = sorted((REPO / "microg_env" / "hyperparams").glob("*.yml"))
    assert {path.stem for path in packaged} >= {"ppo", "sac", "tqc", "crossq"}
    for path in packaged:
        assert f"microg_env/hyperparams/{path.name}" in names
    assert shipped_folders(), "no policy is shipped"
    # What a shipped policy runs and says of itself; its stable-baselines3 files (only to fine-tune) stay out.
    for name in shipped_folders():
        for file in ("policy.npz", "policy.json", "training.json", "train.log", "evaluations.json"):
            assert f"microg_env/policies/{name}/{file}" in names
        for file in ("model.zip", "vecnormalize.pkl"):
            assert f"microg_env/policies/{name}/{file}" not in names


def _fresh_venv(env_dir: Path, install: list[str], cwd: Path) -> Path:
    """A new virtual environment with ``pip install --no-deps --no-index <install>`` done first (by
    the running environment's pip: the new one needs none of its own), then the running
    environment's packages borrowed for the dependencies; returns its bin folder."""
    venv.create(env_dir, with_pip=False)
    bindir = env_dir / ("Scripts" if sys.platform == "win32" else "bin")
    python = bindir / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    # Install first: with the borrowed folders visible, pip would find microg-env "already there".
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "-q", *install],
        check=True,
        capture_output=True,
        cwd=cwd,
    )
    borrowed = {sysconfig.get_paths()["purelib"], *site.getsitepackages()}
    (Path(purelib) / "borrowed_dependencies.pth").write_text("\n".join(sorted(borrowed)) + "\n")
    return bindir


@pytest.mark.slow
def test_installed_wheel_builds_drops_and_runs_the_shipped_policy_from_another_folder(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    bindir = _fresh_venv(env_dir, [str(wheel)], tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()

    def output(program: str, *args: str) -> str:
        return subprocess.run(
            [str(bindir / program), *args], check=True, capture_output=True, text=True, cwd=elsewhere
        ).stdout

    probe = "import microg_env; r = microg_env.build_rig(); print(microg_env.__file__, r.pad_contacts)"
    location, contacts = output("python", "-c", probe).split()
    assert Path(location).is_relative_to(env_dir)
    assert int(contacts) > 0
    drop = json.loads(output("microg", "drop", "--json"))
    assert abs(drop["contact_time_s"]["rel_error"]) < 0.01
    # The shipped policy (numpy only, with its normalisation) and the packaged hyperparameters.
    run = json.loads(output("microg", "run", "--controller", "residual-sac-setpoint", "--duration", "3", "--json"))
    assert run["termination_reason"] is None
    assert run["flexible_unit_excursion_free_fall_m"] < 1e-6  # the PID's is about 3 um
    hyperparams = (
        "from microg_env.learning.hyperparams import load; print(load('ppo', 'MicroGravityLanding-Command-v1').n_envs)"
    )
    assert output("python", "-c", hyperparams).strip() == "8"


def _quick_start_main_command() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```bash\n(.+?)\n```", section)[0]


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
@pytest.mark.slow
def test_a_fresh_clone_runs_the_quick_start(tmp_path):
    """The README's first command, in a fresh clone (no results/ folder: git ignores it); the
    dependencies are borrowed instead of downloaded, and the runs are shortened with --duration."""
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True, capture_output=True)
    assert not (clone / "results").exists()
    steps = [shlex.split(step) for step in _quick_start_main_command().split("&&")]
    assert len(steps) == 3
    venv_step, install_step, reproduce = steps
    assert venv_step == ["python3", "-m", "venv", ".venv"]
    assert install_step[:2] == [".venv/bin/pip", "install"]
    assert reproduce[:2] == [".venv/bin/microg", "reproduce"]
    # pip builds the clone into a wheel and installs it: here the build runs in this environment
    # (a new venv lacks setuptools >= 69), and the wheel goes into the clone's fresh .venv.
    wheels = tmp_path / "wheels"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            *install_step[2:],
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            wheels,
        ],
        check=True,
        capture_output=True,
        cwd=clone,
    )
    bindir = _fresh_venv(clone / ".venv", [str(next(wheels.glob("microg_env-*.whl")))], clone)
    result = subprocess.run(
        [str(bindir / "microg"), *reproduce[1:], "--duration", "1", "--quiet"],
        cwd=clone,
        capture_output=True,
        text=True,
        check=False,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    assert (clone / "results" / "reproduction" / "report.md").is_file()
