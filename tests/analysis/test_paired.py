"""Paired statistics of microg compare: the sign test, the seed-resampling bootstrap and the pairing."""

import math

import numpy as np
import pytest

from microg_env.analysis.paired import cluster_bootstrap_ratio, paired, sign_test_p
from microg_env.experiments.comparison import Case, CaseResult, Comparison


def test_sign_test_against_the_binomial_by_hand():
    # 8 non-zero differences, 1 positive: 2 (C(8,0) + C(8,1)) / 2^8 = 2 x 9 / 256.
    assert sign_test_p([-1, -2, -3, -1, -1, -5, -2, 4, 0, 0]) == pytest.approx(18 / 256)
    assert sign_test_p([-1] * 10) == pytest.approx(2 / 1024)  # every one a win
    assert sign_test_p([1, -1]) == 1.0  # a tie in counts: p capped at 1
    assert math.isnan(sign_test_p([0.0, 0.0]))


def test_the_bootstrap_resamples_whole_seeds():
    """Two seeds, each with ratio exactly 0.5 or 2 in sum: the interval holds only ratios that
    resamples of whole seeds can make (0.5, 2 and their mixes), never an episode's own ratio."""
    values = np.array([1.0, 1.0, 4.0, 4.0])
    reference = np.array([2.0, 2.0, 2.0, 2.0])
    low, high = cluster_bootstrap_ratio(values, reference, np.array([7, 7, 9, 9]))
    assert low == pytest.approx(0.5)
    assert high == pytest.approx(2.0)
    # One cluster per episode on identical pairs: every resample is the ratio itself.
    assert cluster_bootstrap_ratio(values, values / 2, np.arange(4)) == pytest.approx((2.0, 2.0))


def test_paired_statistics_of_a_hand_made_case():
    values = [1.0, 2.0, 3.0, 8.0, math.nan]
    reference = [2.0, 4.0, 6.0, 4.0, 1.0]
    p = paired(values, reference, [1, 2, 3, 4, 5])
    assert p.episodes == 4  # the NaN pair is dropped
    assert p.seeds == 4
    assert p.ratio == pytest.approx(14 / 16)
    assert p.wins == pytest.approx(3 / 4)
    assert p.sign_p == pytest.approx(2 * (1 + 4) / 16)  # 1 loss in 4: 2 (C(4,0) + C(4,1)) / 2^4, capped
    assert p.ratio_low <= p.ratio <= p.ratio_high


def _result(controller, scenario, seed, value):
    values = {"collision_excursion_m": value}
    return CaseResult(Case(controller, scenario, seed), metrics=None, values=values)


def test_a_comparison_pairs_by_scenario_and_seed_whatever_the_order():
    c = Comparison(("a", "b"), {}, (1, 2), False, 1e-3, None, reference="b")
    c.results.extend(
        [
            _result("a", "s", 1, 1.0),
            _result("a", "s", 2, 3.0),
            _result("b", "s", 2, 6.0),  # b's seeds in the other order
            _result("b", "s", 1, 4.0),
        ]
    )
    p = c.paired("a", "collision_excursion_m")
    assert p.ratio == pytest.approx(4.0 / 10.0)
    assert p.wins == 1.0
    assert p.sign_p == pytest.approx(0.5)  # 2 seeds, both won: 2 / 2^2
