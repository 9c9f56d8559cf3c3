"""Study pages: a campaign's results table turned into Markdown with figures (``report:`` in a
campaign file names one of :data:`STUDIES`). Each page groups the table's successful runs by the
swept keys (pyarrow), fills its template with the groups' means, extremes and failure counts, and
draws its figures from the same groups; every number on a page is read from the table."""

from __future__ import annotations

from pathlib import Path

from microg_env.experiments.studies import (
    controller_sensitivity,
    fifty_gram_floor,
    landing_monte_carlo,
    period_bandwidth,
    sensitivity,
    transmission,
)
from microg_env.experiments.studies.groups import nothing_completed, successes
from microg_env.files import write_text

#: The study pages by the name a campaign's ``report:`` gives: each module's ``render(campaign,
#: table, folder)`` returns the page's lines and draws its figures, its ``COLUMNS`` are the keys
#: the campaign must sweep or sample, and its ``check(campaign)``, where it has one, refuses (ValueError)
#: a campaign the page cannot read.
STUDIES = {
    "period-bandwidth": period_bandwidth,
    "fifty-gram-floor": fifty_gram_floor,
    "landing-monte-carlo": landing_monte_carlo,
    "sensitivity": sensitivity,
    "controller-sensitivity": controller_sensitivity,
    "transmission": transmission,
}
#: The page of a campaign folder.
REPORT_FILE = "report.md"


def write_study(campaign, table, folder: Path) -> Path:
    """Write ``folder/report.md`` and its figures for ``campaign``'s results ``table`` (a page that
    says so where no run completed)."""
    if successes(table).num_rows:
        lines = STUDIES[campaign.report].render(campaign, table, folder)
    else:
        lines = nothing_completed(campaign, table, folder)
    path = folder / REPORT_FILE
    write_text(path, "\n".join(lines).rstrip() + "\n")
    return path
