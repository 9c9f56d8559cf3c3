"""The documentation site and the front door: the site builds without a warning (a broken link, a
page missing from the nav), and the README stays short and links only to files that exist."""

import importlib
import importlib.util
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
    for page in (
        "environment",
        "cli",
        "model",
        "controllers",
        "deployment",
        "paper",
        "studies",
        "speed",
        "development",
    ):
        assert (tmp_path / "site" / page / "index.html").is_file()


@pytest.mark.slow
def test_the_readmes_example_lands_condition_3_under_the_paper_s_pid(capsys):
    """The README's Python example runs a whole episode, as it says: condition 3's 30 s end by the
    schedule, not at a stroke limit, with x within a few µm (random speed commands once ended it at
    the guide's end after 0.2 s)."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert len(blocks) == 1
    exec(compile(blocks[0], "README.md", "exec"), {})  # the repository's own example
    time_s, x_m = (float(value) for value in capsys.readouterr().out.split())
    assert time_s == pytest.approx(30.0)
    assert 0 < abs(x_m) < 5e-6


def test_the_readme_is_a_short_front_door_whose_links_resolve():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert len(text.split()) <= 800
    targets = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text)
    local = [t for t in targets if not t.startswith(("http://", "https://"))]
    assert local, "the README links nothing"
    missing = [t for t in local if not (REPO / t).exists()]
    assert not missing, f"the README links files that do not exist: {missing}"


def test_every_name_the_docs_cite_exists():
    """A module, class or function named as `microg_env.x.y` in the README or the docs site is there
    (CHANGELOG.md names old places on purpose)."""
    pages = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
    names = sorted({n for page in pages for n in re.findall(r"`(microg_env(?:\.[A-Za-z_]\w*)+)", page.read_text())})
    assert len(names) >= 5
    missing = []
    for name in names:
        parts = name.split(".")
        for i in range(len(parts), 0, -1):  # the longest importable module, then attributes
            try:
                found = importlib.import_module(".".join(parts[:i]))
            except ImportError:
                continue
            for attribute in parts[i:]:
                found = getattr(found, attribute, None)
            break
        if found is None:
            missing.append(name)
    assert not missing, f"the docs cite names that do not exist: {missing}"


def test_the_reference_pages_are_written_in_short_sentences():
    """docs/sentence_lengths.py: median sentence at most 20 words, at most 10 % over 40, on the README,
    environment.md, controllers.md, cli.md, studies.md and deployment.md; controllers.md a reference of at most 250
    lines (its history is the research log's)."""
    spec = importlib.util.spec_from_file_location("sentence_lengths", REPO / "docs" / "sentence_lengths.py")
    sentence_lengths = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sentence_lengths)
    for page in sentence_lengths.PAGES:
        median, share, ok = sentence_lengths.report(REPO / page)
        assert ok, f"{page}: median {median} words, {share:.0%} over {sentence_lengths.LONG_WORDS}"
    assert len((REPO / "docs" / "controllers.md").read_text(encoding="utf-8").splitlines()) <= 250
    long_prose = "One claim. " * 5 + " ".join(["Then", *["word"] * 44]) + ". See [a link](x.md), `code`."
    assert sentence_lengths.lengths_of(long_prose) == [2, 2, 2, 2, 2, 45, 4]  # the measure can fail a page
