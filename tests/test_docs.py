"""The documentation site and the front door: the site builds without a warning (a broken link, a
page missing from the nav), and the README stays short and links only to files that exist."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_the_docs_site_builds_strictly(tmp_path):
    pytest.importorskip("mkdocs", reason="mkdocs-material is in the docs extra")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=False,
        env=os.environ | {"NO_MKDOCS_2_WARNING": "1"},
    )
    assert result.returncode == 0, result.stderr
    for page in ("environment", "cli", "model", "controllers", "paper", "studies", "speed", "development"):
        assert (tmp_path / "site" / page / "index.html").is_file()


def test_the_readme_is_a_short_front_door_whose_links_resolve():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 150
    targets = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text)
    local = [t for t in targets if not t.startswith(("http://", "https://"))]
    assert local, "the README links nothing"
    missing = [t for t in local if not (REPO / t).exists()]
    assert not missing, f"the README links files that do not exist: {missing}"
