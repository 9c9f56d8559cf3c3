"""Sentence lengths of the reference pages: ``python docs/sentence_lengths.py [PAGE.md ...]``.

Counts the words of each prose sentence (code blocks, tables, headings, images and link targets
left out; a list item is a sentence of its own or several) and prints, per page, the median length,
the share of sentences over :data:`LONG_WORDS` words, and the longest three. Exits 1 where a page
breaks :data:`MAX_MEDIAN_WORDS` or :data:`MAX_LONG_SHARE`: the docs are reference, one claim a
sentence.
"""

from __future__ import annotations

import re
import statistics
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: The pages held to the limits.
PAGES = (
    "README.md",
    "docs/environment.md",
    "docs/controllers.md",
    "docs/cli.md",
    "docs/studies.md",
    "docs/deployment.md",
)
MAX_MEDIAN_WORDS = 20
LONG_WORDS = 40
MAX_LONG_SHARE = 0.10
#: Abbreviations whose full stop ends no sentence.
ABBREVIATIONS = ("e.g.", "i.e.", "et al.", "Eq.", "Eqs.", "Fig.", "Figs.", "vs.", "cf.", "No.", "approx.")


def prose(text: str) -> list[str]:
    """The page's prose blocks: paragraphs and list items, without code, tables or headings."""
    text = re.sub(r"```.*?```", "\n\n", text, flags=re.DOTALL)
    blocks, current = [], []
    for line in text.splitlines():
        stripped = line.strip()
        starts_item = re.match(r"([-*+]|\d+[.)])\s", stripped)
        if not stripped or stripped.startswith(("#", "|", "<", "!")) or starts_item:
            if current:
                blocks.append(" ".join(current))
            current = []
            if starts_item:
                current = [stripped[starts_item.end() :]]
            continue
        current.append(stripped)
    if current:
        blocks.append(" ".join(current))
    return blocks


def sentences(block: str) -> list[str]:
    """A prose block split into sentences, with links reduced to their text and code spans to a word."""
    block = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", block)
    block = re.sub(r"`[^`]*`", "CODE", block)
    for abbreviation in ABBREVIATIONS:
        block = block.replace(abbreviation, abbreviation.replace(".", ""))
    parts = re.split(r"(?<=[.!?])\s+(?=[A-Z(\"*_`0-9])", block)
    return [part for part in parts if re.search(r"[A-Za-z]", part)]


def lengths_of(text: str) -> list[int]:
    """The word count of each prose sentence of a Markdown text."""
    return [len(sentence.split()) for block in prose(text) for sentence in sentences(block)]


def lengths(path: Path) -> list[int]:
    return lengths_of(path.read_text(encoding="utf-8"))


def report(path: Path) -> tuple[float, float, bool]:
    """The page's median sentence length, its share over :data:`LONG_WORDS` words, and whether both
    are within the limits."""
    counts = lengths(path)
    median = statistics.median(counts) if counts else 0.0
    share = sum(count > LONG_WORDS for count in counts) / len(counts) if counts else 0.0
    return median, share, median <= MAX_MEDIAN_WORDS and share <= MAX_LONG_SHARE


def main(argv: list[str]) -> int:
    paths = [Path(arg) for arg in argv] or [REPO / page for page in PAGES]
    failed = False
    print(f"| page | sentences | median words | over {LONG_WORDS} | within limits |")
    print("|---|---|---|---|---|")
    for path in paths:
        median, share, ok = report(path)
        failed |= not ok
        shown = path.relative_to(REPO) if path.is_relative_to(REPO) else path
        print(f"| {shown} | {len(lengths(path))} | {median:g} | {share:.0%} | {'yes' if ok else 'no'} |")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
