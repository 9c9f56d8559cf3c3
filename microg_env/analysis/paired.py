"""Paired statistics of two controllers run on the same episodes (same scenario, seed and plant).

For one metric (larger is worse) and episodes paired by (scenario, seed): the ratio of the
controller's mean to the reference's, with a 95 % bootstrap interval that resamples whole seeds
(a seed's episodes share its noise, drift and, when randomised, much of its plant, so they are not
independent); the share of episodes the controller wins (a lower value); and a two-sided exact
sign test on the seeds' mean differences (ties dropped), so that the test too counts independent
units, not episodes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Bootstrap resamples, and the generator's seed (the interval is reproducible).
RESAMPLES, BOOTSTRAP_SEED = 10_000, 0


@dataclass(frozen=True)
class Paired:
    """A controller against the reference on one metric."""

    episodes: int  # pairs where both reached the metric
    seeds: int  # independent units (clusters)
    ratio: float  # mean(controller) / mean(reference)
    ratio_low: float  # 95 % bootstrap interval of the ratio, resampling seeds
    ratio_high: float
    wins: float  # share of pairs with the controller's value below the reference's
    sign_p: float  # two-sided exact sign test on the seeds' mean differences

    def as_dict(self) -> dict[str, float | int | None]:
        return {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in vars(self).items()}


def sign_test_p(differences: Sequence[float]) -> float:
    """Two-sided exact sign test of median 0 (zero differences dropped): 2 P(K <= min(k, n - k)),
    K ~ Binomial(n, 1/2), at most 1; NaN with no non-zero difference."""
    d = np.asarray(differences, dtype=float)
    d = d[d != 0]
    n = d.size
    if n == 0:
        return math.nan
    k = int(min((d > 0).sum(), (d < 0).sum()))
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


def cluster_bootstrap_ratio(
    values: np.ndarray, reference: np.ndarray, clusters: np.ndarray, resamples: int = RESAMPLES
) -> tuple[float, float]:
    """95 % percentile interval of sum(values) / sum(reference) over resamples of whole clusters."""
    labels, index = np.unique(clusters, return_inverse=True)
    sums = np.zeros((2, labels.size))
    np.add.at(sums[0], index, values)
    np.add.at(sums[1], index, reference)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    draws = rng.integers(0, labels.size, size=(resamples, labels.size))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = sums[0][draws].sum(axis=1) / sums[1][draws].sum(axis=1)
    low, high = np.nanpercentile(ratios, [2.5, 97.5])
    return float(low), float(high)


def paired(values: Sequence[float], reference: Sequence[float], seeds: Sequence[int]) -> Paired:
    """The paired statistics of ``values`` against ``reference`` (the same episodes, in order, run
    from ``seeds``); pairs where either is NaN (a run that did not reach the metric) are dropped."""
    a, b, s = (np.asarray(x, dtype=float) for x in (values, reference, seeds))
    keep = np.isfinite(a) & np.isfinite(b)
    a, b, s = a[keep], b[keep], s[keep]
    if not a.size:
        nan = math.nan
        return Paired(0, 0, nan, nan, nan, nan, nan)
    labels, index = np.unique(s, return_inverse=True)
    per_seed = np.bincount(index, weights=a - b) / np.bincount(index)
    low, high = cluster_bootstrap_ratio(a, b, s)
    ratio = a.mean() / b.mean() if b.mean() != 0 else math.nan
    return Paired(int(a.size), int(labels.size), float(ratio), low, high, float(np.mean(a < b)), sign_test_p(per_seed))
