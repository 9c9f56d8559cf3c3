"""How reports print a number: one format, and one mark for a number a run did not give."""

from __future__ import annotations

import math

#: What a report prints where a run gave no number (None or NaN: a window it did not reach).
MISSING = "–"


def format_number(value: float | None, spec: str, scale: float = 1.0) -> str:
    """``value`` times ``scale`` in ``format``'s ``spec``, or :data:`MISSING`."""
    if value is None or not math.isfinite(value):
        return MISSING
    return format(value * scale, spec)
