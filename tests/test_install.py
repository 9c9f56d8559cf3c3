"""A wheel built from the repository carries the MJCF and works from any folder.

The wheel is installed (not editable) into a fresh virtual environment. Its dependencies
(mujoco, gymnasium, numpy) are borrowed from the environment running the tests through a .pth
line, so the test needs no network; the package itself must come from the new environment.
"""

import json
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


def test_wheel_contains_the_mjcf(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in ("scene.xml", "rig.xml", "README.md"):
        assert f"microg_env/mjcf/{name}" in names


def test_installed_wheel_builds_and_drops_from_another_folder(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
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
        [str(python), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)],
        check=True,
        capture_output=True,
    )
    borrowed = {sysconfig.get_paths()["purelib"], *site.getsitepackages()}
    (Path(purelib) / "borrowed_dependencies.pth").write_text("\n".join(sorted(borrowed)) + "\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    probe = subprocess.run(
        [
            str(python),
            "-c",
            "import microg_env; r = microg_env.build_rig(); print(microg_env.__file__, r.pad_contacts)",
        ],
        check=True,
        capture_output=True,
        text=True,
        cwd=elsewhere,
    )
    location, contacts = probe.stdout.split()
    assert Path(location).is_relative_to(env_dir)
    assert int(contacts) > 0
    drop = subprocess.run(
        [str(bindir / "microg"), "drop", "--json"], check=True, capture_output=True, text=True, cwd=elsewhere
    )
    assert abs(json.loads(drop.stdout)["contact_time_s"]["rel_error"]) < 0.01
