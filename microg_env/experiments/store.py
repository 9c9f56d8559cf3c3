"""A campaign's results: one row per run in Parquet part files, written as batches finish.

``DIR/runs/part-*.parquet`` holds the rows, one file per finished batch, each written to a
temporary name and renamed, so an interrupted campaign leaves whole files only. A run is stored
once it has a row of this microg version; a later row of the same spec hash (a failed run retried,
a run of another version's row) supersedes an earlier one. ``DIR/results.parquet`` is the
campaign's table: its own runs, one row each. The table counts as the oldest part, so a folder
kept with its table alone (a committed study) resumes from it.
"""

from __future__ import annotations

import json
import math
import os
import re
import uuid
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from microg_env.analysis.metrics import RunMetrics
from microg_env.experiments.comparison import QUANTITIES
from microg_env.files import atomic_path
from microg_env.rollout.runner import RunResult, versions
from microg_env.rollout.spec import RANDOMIZE
from microg_env.validate import fault

#: Prefix of the comparison's summary quantities (``microg compare``'s, one value per run).
SUMMARY_PREFIX = "summary_"
#: The campaign's table in its folder.
RESULTS_FILE = "results.parquet"
#: A terminal's colour and cursor codes, which an error from a Ray worker carries (not stored).
TERMINAL_CODES = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")
#: Status of a run that completed (its metrics are set) and of one that raised.
OK, FAILED = "ok", "failed"
#: What :meth:`ResultStore.statuses` says of a row another microg version wrote.
STALE = "stale"


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, list):
        return [_clean(v) for v in value]
    return value


def result_row(result: RunResult, columns: Mapping[str, Any]) -> dict[str, Any]:
    """The row of ``result``: identity, the campaign's ``columns`` (swept and sampled values), every
    metric (per-stage metrics as lists; NaN as null), the comparison's summary quantities
    (``summary_compensation_error``: mean |error| over the stages, %; ...), the PID
    gains a re-tuned controller used, and provenance (spec and versions as JSON)."""
    spec = result.spec
    row: dict[str, Any] = {
        "spec_hash": spec.hash,
        "status": OK if result.ok else FAILED,
        "error": None if result.error is None else TERMINAL_CODES.sub("", result.error),
        "scenario": spec.scenario,
        "controller": spec.controller,
        "seed": spec.seed,
        "randomize": spec.randomize is not False,  # the plant drawn from the seed
        "randomize_drive": spec.randomize is not False and RANDOMIZE[spec.randomize].draws_drive,  # and the drive
        "randomize_preset": {False: "none", True: "plant"}.get(spec.randomize, spec.randomize),
        "sensor_set": spec.sensor_set,
        "control_period_us": spec.control_period_us,
        "physics_step_us": spec.physics_step_us,
        "duration_s": spec.duration_s,
    }
    row |= {name: value for name, value in columns.items() if name not in row}
    metrics = result.metrics
    for name in RunMetrics.__dataclass_fields__:
        if name == "unavailable":
            row[name] = None if metrics is None else json.dumps(metrics.unavailable)
        else:
            row[name] = None if metrics is None else _clean(getattr(metrics, name))
    for name, quantity in QUANTITIES.items():
        row[SUMMARY_PREFIX + name] = None if metrics is None else _clean(float(quantity.of(metrics)))
    for name in ("kp_per_s", "ki_per_s2", "kd"):
        row[f"tuned_{name}"] = result.tuned_gains.get(name)
    row["wall_s"] = _clean(result.wall_s)
    row["spec"] = json.dumps(spec.as_dict(), sort_keys=True)
    row["versions"] = json.dumps(result.versions, sort_keys=True)
    return row


def _concatenate(parts: list[pa.Table]) -> bool:
    """Whether ``parts`` make one table (their columns promote to common types)."""
    try:
        pa.concat_tables(parts, promote_options="permissive")
    except pa.ArrowException:
        return False
    return True


class ResultStore:
    """The Parquet rows of one campaign folder (module docstring)."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.parts = self.folder / "runs"
        self.results = self.folder / RESULTS_FILE

    def write(self, rows: Sequence[Mapping[str, Any]]) -> Path:
        """Store ``rows`` as one new part file (written whole, then renamed into place)."""
        self.parts.mkdir(parents=True, exist_ok=True)
        path = self.parts / f"part-{uuid.uuid4().hex}.parquet"
        with atomic_path(path) as temporary:
            pq.write_table(pa.Table.from_pylist(list(rows)), temporary)
        return path

    def table(self, hashes: Iterable[str] | None = None) -> pa.Table:
        """Every stored row, the latest per spec hash (an ok row over a failed one), in the order of
        ``hashes`` (only those) if given."""
        files = sorted(self.parts.glob("part-*.parquet"), key=lambda p: p.stat().st_mtime_ns)
        if self.results.is_file():
            files.insert(0, self.results)
        if not files:
            return pa.table({})
        parts = []
        for path in files:
            try:
                part = pq.read_table(path)
                for name in ("spec_hash", "status"):
                    if part.schema.field(name).type != pa.string():
                        raise ValueError(f"its {name} column holds {part.schema.field(name).type}, not strings")
            except (pa.ArrowException, KeyError, OSError, ValueError) as error:
                raise self._damaged(path, error) from None
            parts.append(part)
        try:
            table = pa.concat_tables(parts, promote_options="permissive")
        except pa.ArrowException as error:  # a part's columns clash with the others': the one without
            # which the rest make one table, the newest such (of two parts, the later written)
            odd = next((i for i in reversed(range(len(parts))) if _concatenate(parts[:i] + parts[i + 1 :])), -1)
            raise self._damaged(files[odd], error) from None
        rows: dict[str, int] = {}
        statuses = table.column("status").to_pylist()
        for i, spec_hash in enumerate(table.column("spec_hash").to_pylist()):
            if spec_hash not in rows or statuses[i] == OK or statuses[rows[spec_hash]] != OK:
                rows[spec_hash] = i
        order = list(rows) if hashes is None else [h for h in hashes if h in rows]
        return table.take([rows[h] for h in order])

    def _damaged(self, path: Path, error: Exception) -> ValueError:
        return ValueError(
            f"campaign results: {'table' if path == self.results else 'part file'} {str(path)!r} cannot be read "
            f"with the others ({fault(error)}); move it out of {str(path.parent)!r} and run the campaign again "
            "(its runs are run again)"
        )

    def statuses(self) -> dict[str, str]:
        """The stored status of each spec hash; :data:`STALE` for a row another microg version wrote
        (what the same spec computes may have changed since: it runs again)."""
        table = self.table()
        if not table.num_rows:
            return {}
        hashes, statuses = table.column("spec_hash").to_pylist(), table.column("status").to_pylist()
        made = table.column("versions").to_pylist() if "versions" in table.column_names else [None] * len(hashes)
        current = versions()["microg-env"]
        for i, written in enumerate(made):
            if written is not None and json.loads(written).get("microg-env", current) != current:
                statuses[i] = STALE
        return dict(zip(hashes, statuses, strict=True))

    def export(self, path: str | os.PathLike, hashes: Sequence[str]) -> pa.Table:
        """Write the rows of ``hashes`` (one per run) to ``path`` whole, and return them."""
        table = self.table(hashes)
        with atomic_path(path) as temporary:
            pq.write_table(table, temporary)
        return table
