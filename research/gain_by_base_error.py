"""Where a controller gains on its reference and where it loses: a comparison's paired episodes
binned by what the reference itself leaves.

A residual policy is trained on plants drawn around the nominal one, and its base controller
leaves some of them a large excursion and others a small one; a residual that cannot tell them
apart adds the same correction to both. Binning the paired episodes of a ``microg compare`` result
by the reference's own excursion shows it: the ratio (controller / reference, of the bin's means)
and the share of episodes the controller wins, per bin. docs/research-log.md's "The nominal plant"
ran it with ``--controller residual-sac-gated`` (retired in 0.26.0) on the held-out comparisons of
the time, and ``--edges 0.25,0.5,1`` on ``docs/comparison``. Episodes either controller left without a value
(a run that ended early) are counted and left out.

Run: ``python research/gain_by_base_error.py RESULT/comparison.json [--controller residual-sac-setpoint]
[--reference adaptive-dither] [--quantity collision_excursion_m] [--edges 0.5,1,2,4]``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
from pathlib import Path

import numpy as np


def paired(result: dict, controller: str, reference: str, quantity: str) -> np.ndarray:
    """(reference, controller) values of ``quantity`` on each episode both ran (same scenario and
    seed); a value left out (null, not finite) reads NaN."""
    values = {
        (c["controller"], c["scenario"], c["seed"]): np.nan if c["values"][quantity] is None else c["values"][quantity]
        for c in result["cases"]
    }
    for name in (controller, reference):
        if not any(key[0] == name for key in values):
            raise ValueError(f"no controller {name!r} in it")
    pairs = [
        (value, values[controller, scenario, seed])
        for (name, scenario, seed), value in values.items()
        if name == reference and (controller, scenario, seed) in values
    ]
    if not pairs:
        raise ValueError(f"no episode has both {controller!r} and {reference!r}")
    return np.array(pairs, dtype=float)


def bin_edges(text: str) -> list[float]:
    """``--edges``: finite, positive and increasing, or a ValueError naming the value."""
    try:
        edges = [float(edge) for edge in text.split(",")]
    except ValueError:
        raise ValueError(f"--edges must be comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(edge) and edge > 0 for edge in edges) or any(b <= a for a, b in itertools.pairwise(edges)):
        raise ValueError(f"--edges must be positive, finite and increasing, got {text!r}")
    return edges


def binned(pairs: np.ndarray, edges: list[float]) -> list[tuple[float, float, int, float, float, float]]:
    """Per bin of the reference's value (``edges`` in the quantity's display unit, open at the
    top): its low and high edge, episodes, the reference's and the controller's mean, and the share
    of episodes the controller wins (a lower value)."""
    bounds = [0.0, *edges, np.inf]
    rows = []
    for low, high in itertools.pairwise(bounds):
        inside = pairs[(pairs[:, 0] >= low) & (pairs[:, 0] < high)]
        if inside.size:
            base, mine = inside.mean(axis=0)
            rows.append((low, high, len(inside), base, mine, float(np.mean(inside[:, 1] < inside[:, 0]))))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("result", type=Path, help="a comparison.json written by microg compare")
    parser.add_argument("--controller", default="residual-sac-setpoint")
    parser.add_argument("--reference", default="adaptive-dither")
    parser.add_argument("--quantity", default="collision_excursion_m")
    parser.add_argument("--edges", default="0.5,1,2,4", help="bin edges in the quantity's display unit")
    args = parser.parse_args(argv)
    try:
        edges = bin_edges(args.edges)
    except ValueError as error:
        parser.error(str(error))
    try:
        result = json.loads(args.result.read_text(encoding="utf-8"))
        quantities = result["quantities"]
        if args.quantity not in quantities:
            parser.error(f"--quantity {args.quantity!r}: not one of {', '.join(quantities)}")
        unit = quantities[args.quantity]
        pairs = paired(result, args.controller, args.reference, args.quantity) * unit["si_unit_times"]
    except (OSError, ValueError, KeyError, TypeError) as error:
        parser.error(f"{args.result}: {type(error).__name__}: {error}")
    kept = np.isfinite(pairs).all(axis=1)
    print(f"{unit['label']} ({unit['unit']}) of {args.controller} against {args.reference}, by {args.reference}'s")
    if not kept.all():
        print(f"({np.count_nonzero(~kept)} episodes without a value of either left out)")
    print("| reference's | episodes | reference | controller | ratio | controller wins |")
    print("|---|---|---|---|---|---|")
    for low, high, count, base, mine, won in binned(pairs[kept], edges):
        ratio = f"{mine / base:.2f}x" if base > 0 else "-"
        print(f"| {low:g} to {high:g} | {count} | {base:.3f} | {mine:.3f} | {ratio} | {won:.0%} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
