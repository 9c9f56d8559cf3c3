"""Runs as data: :class:`RunSpec` (one run, content-hashed), :func:`run` and :func:`run_all`
(the one runner), campaigns of them on Ray (``microg campaign``)."""

from microg_env.experiments.runner import RunResult, run, run_all, run_many
from microg_env.experiments.spec import RunSpec

__all__ = ["RunResult", "RunSpec", "run", "run_all", "run_many"]
