"""Every test under research/ carries the ``research`` marker: ``pytest research`` runs them, the
default suite (``tests/``) never collects them."""

from pathlib import Path

import pytest

RESEARCH = Path(__file__).resolve().parent


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.is_relative_to(RESEARCH):
            item.add_marker(pytest.mark.research)
