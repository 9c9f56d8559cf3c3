"""The one number format of the reports: a number a run did not give prints as one mark."""

import math

from microg_env.analysis.formatting import MISSING, format_number


def test_a_number_is_scaled_then_formatted_and_a_missing_one_is_marked():
    assert format_number(0.0134049, ".2f", 1e3) == "13.40"
    assert format_number(-0.00763, "+.3f") == "-0.008"
    for missing in (None, math.nan, math.inf):
        assert format_number(missing, ".2f") == MISSING
    assert MISSING == "–"  # an en dash, as every committed report prints it
